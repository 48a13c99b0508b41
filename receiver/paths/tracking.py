"""Path tracking: the paths' lives, carrier phases, towers and first paths (:mod:`receiver.paths`).

:class:`PathTracker` runs, per batch of frames, the fit
(:mod:`receiver.paths.fit`) and the detection (:mod:`receiver.paths.detection`)
and keeps each path's state between batches:

1. **Lives.** A new path is confirmed (reported) once its delay has held
   still, above ``survival_snr_db``, for ``confirm_batches`` batches; a path
   below ``survival_snr_db`` for ``lost_batches`` batches, or that drifts
   closer than ``min_separation`` to an older one, is dropped.
2. **Carrier phase.** A path's frequency is the phase of its amplitude from
   one frame to the next (``receiver.cfo.cfo_from_theta``, as the PN CFO
   estimate), and eq. 9-11 integrate it (``receiver.ranging``). A cycle slip
   (:func:`slip_kernel`): frames whose phase step departs from the path's
   smoothed frequency by more than ``slip_sigmas`` times its phase noise are
   bridged with the smoothed frequency; a run of them that adds up to half a
   cycle or more is flagged as a slip. A run that lasts the smoothing time
   constant ``frequency_time_s`` is a lasting frequency step, not a burst:
   the reference restarts at the run's mean frequency, so one step is one
   slip rather than a flag that never clears.
3. **Towers.** Paths within ``tower_gap`` of one another belong to one tower
   (the delay spread of a street is a few chips; the towers of a
   single-frequency network are hundreds of metres apart, tens of chips).
   Each tower's earliest confirmed path that has lived ``first_path_batches``
   batches is its first path, the direct-path candidate; the differences of
   the towers' first-path phases give clock-free range differences.
4. **Doppler check** (an option, off by default: ``docs/paths.md``). A first
   path may still be a pair under a third of a chip whose phase follows the
   stronger member, a reflection: every ``doppler.hop_frames`` frames
   :class:`receiver.delay_doppler.FirstPathDoppler` maps the CIR around tower
   0's first path in delay and Doppler and moves the first-path frequency to
   the Doppler line whose super-resolved earliest path comes first.
5. **Guard-interval span** (``guard_span``, on by default). The CIR of the
   header's cyclic extension sees paths within -postamble..preamble of the
   window start; an SFN's towers may arrive up to the guard interval (the
   header's length) apart. With ``guard_span`` the tracker reads the header
   correlation on views (:meth:`receiver.channel_estimate.ChannelEstimator.view_taps`):
   core-period windows shifted so that a group of paths lies inside the
   view's cyclic extension. Each path lives in one view; every view of a
   batch is fitted at once (:func:`receiver.paths.fit.fit_views_kernel`), a
   path's pulse scaled in each view by the share of its header chips in that
   window (the rest is body data, noise there) and each view weighted by its
   noise, so a tower's aliases in the others' views are explained and never
   taken for paths. One further view per batch, in turn, scans the lags no
   view covers. A path found at lag l may be an alias of one at ``l + k P``
   (the m-sequence period); in the batch after its birth a view centred on
   each such candidate checks it: where the path really is, its own view
   holds all of its header chips, the others at most a third, so the
   residual there stands out and the path moves to that candidate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.records import PathBatch, PathFlag
from receiver import CLOCK_PATHS, DEFAULT_CLOCK_PATH, DEFAULT_GUARD_SPAN
from receiver.cfo import cfo_from_theta
from receiver.channel_estimate import view_first_lag
from receiver.delay_doppler import DopplerConfig, FirstPathDoppler
from receiver.paths.detection import detect_paths, detection_threshold
from receiver.paths.fit import (
    PULSE_OVERSAMPLING,
    _pulse_tables_cached,
    fit_paths_kernel,
    fit_views_kernel,
    model_residual_kernel,
)
from receiver.ranging import held_doppler

#: Towers whose clock-free range differences go to ``/receiver/frames`` (towers 1 and 2 against tower 0).
RANGE_DIFFERENCE_TOWERS = 2
#: Guard-interval span: a view's detection threshold is at least this many standard deviations of its
#: residual's spread across lags beyond what white noise gives (:meth:`PathTracker._view_limit`). A path
#: whose header only partly lies in a view's window leaves a residual there that does not average out over
#: a batch (the partial m-sequence sums of neighbouring header phases are alike), with peaks several of
#: those standard deviations above the median (docs/paths.md, "The guard-interval span").
STRUCTURE_SIGMAS = 8.0
#: Guard-interval span: a path moves to an alias candidate whose power in the view centred there exceeds
#: this share of its power where it was found (:meth:`PathTracker._resolve_aliases`). Were the path at the
#: candidate, that view would hold all of its header chips and the view it was found in at most 0.65 of
#: them (at least 0.4 of its power there, read between two columns); were it not, at most a third (0.11).
ALIAS_SHARE = 0.5
#: Guard-interval span: a view that holds at least this share of a path's header chips fits the path's
#: amplitude; one that holds less takes out a nuisance pulse of its own amplitude in its place. The partial
#: m-sequence sums of a share c bend the fit by about sqrt(c (1 - c) / P) of the path's amplitude, while
#: the view adds c^2 of its information (docs/decisions.md, D44).
FULL_COVERAGE = 0.5


@dataclass(frozen=True)
class PathConfig:
    """Path-tracker settings (:mod:`receiver.paths` and its modules' docstrings).

    Attributes
    ----------
    taps_before, taps_after : int or None
        Delay span of the CIR around the frame's window start, samples; None:
        the header's whole cyclic extension (PN420: -83..82, PN945: -217..217).
    block_frames : int
        Frames per delay update.
    delay_gain, rate_gain : float
        Gains of each path's delay loop (per block) and of its rate.
    max_delay_step : float
        Largest delay correction per block of a path not yet confirmed, samples.
    steady_delay_step : float
        Largest delay correction per block of a confirmed path, samples.
    max_run_move : float
        Largest drift of a path's lag over frames fitted with the same pulses, samples
        (:func:`receiver.paths.fit.fit_paths_kernel`).
    false_alarm : float
        Probability that noise alone crosses the detection threshold, per lag and batch.
    relative_floor_db : float
        A new path must be at least this strong relative to the strongest path, dB.
    survival_snr_db : float
        Per-frame tap SNR of a path's fitted amplitude (mean over a batch) below which it fades, dB.
    lost_batches : int
        Consecutive fading batches after which a path is dropped.
    confirm_batches : int
        Consecutive steady batches (delay correction below ``steady_move``)
        a new path needs before it is reported: a fitting artefact wanders, a
        path holds still.
    steady_move : float
        Largest delay-loop correction over a batch of a steady path, samples.
    first_path_batches : int
        Batches a confirmed path must have lived before it can be its tower's
        first path (a young path may still be a fitting artefact).
    min_separation : float
        Paths closer than this (samples) are merged into the older one.
    tower_gap : float
        Paths more than this (samples) from every path of a tower start a new tower.
    max_paths : int
        Paths tracked at most.
    max_births : int
        New paths per batch at most.
    settle_batches : int
        Batches a new path's delay loop needs to converge; no path is born
        within ``settle_guard`` of a younger one.
    settle_guard : float
        Samples around a settling path where no path is born.
    slip_sigmas : float
        Phase-step outlier threshold, in standard deviations of the path's phase noise.
    slip_min_cycles : float
        Smallest phase-step departure that counts as an outlier, cycles.
    frequency_time_s : float
        Time constant of each path's smoothed frequency (the slip reference), s.
    doppler : DopplerConfig
        The first path's Doppler check (:class:`receiver.delay_doppler.FirstPathDoppler`;
        ``frames=0`` switches it off).
    clock_path : {"first", "steadiest"}
        Which path's mean carrier offset over the static window is the f_s of
        the path ranges (eq. 9): the first path's own, or that of the path
        whose phase stays closest to a straight line there
        (:meth:`receiver.ranging.PathRanging.steadiest_path_offset_hz`).
    guard_span : bool
        Track paths up to the guard interval (the header's length) before
        and after the window start, on views of the header correlation, with
        the m-sequence period's ambiguity resolved (module docstring, step 5),
        where the header phase rotates (on by default: the towers of a
        single-frequency network may arrive that far apart); off, or with a
        constant header phase: the header's cyclic extension (``taps_before``,
        ``taps_after``).
    """

    taps_before: int | None = None
    taps_after: int | None = None
    block_frames: int = 16
    delay_gain: float = 0.3
    rate_gain: float = 0.02
    max_delay_step: float = 0.2
    steady_delay_step: float = 0.01
    max_run_move: float = 0.05
    false_alarm: float = 1e-7
    relative_floor_db: float = -35.0
    survival_snr_db: float = 6.0
    lost_batches: int = 3
    confirm_batches: int = 3
    steady_move: float = 0.05
    first_path_batches: int = 14
    min_separation: float = 0.35
    tower_gap: float = 20.0
    max_paths: int = 12
    max_births: int = 1
    settle_batches: int = 2
    settle_guard: float = 1.5
    slip_sigmas: float = 6.0
    slip_min_cycles: float = 0.05
    frequency_time_s: float = 0.1
    doppler: DopplerConfig = field(default_factory=DopplerConfig)
    clock_path: str = DEFAULT_CLOCK_PATH
    guard_span: bool = DEFAULT_GUARD_SPAN

    def __post_init__(self) -> None:
        if self.clock_path not in CLOCK_PATHS:
            raise ValueError(f"PathConfig.clock_path must be one of {CLOCK_PATHS}, got {self.clock_path!r}")

    def span(self, mode: PnMode) -> tuple[int, int]:
        """``(taps_before, taps_after)`` for a header mode (the cyclic extension unless set)."""
        m = mode.value
        return (m.postamble if self.taps_before is None else self.taps_before,
                m.preamble if self.taps_after is None else self.taps_after)


# ---- cycle slips ---------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def slip_kernel(cfo_hz: np.ndarray, dt_s: np.ndarray, sigma_cycles: np.ndarray, smooth_hz: float,
                run_cycles: float, run_s: float, alpha: float, sigmas: float, min_cycles: float,
                bridged: np.ndarray, slips: np.ndarray) -> tuple[float, float, float]:
    """Bridge and flag phase-step outliers of one path over a batch (module docstring, step 2).

    Parameters
    ----------
    cfo_hz : (F,) float64
        The path's frequency per frame (NaN: no phase pair).
    dt_s : (F,) float64
        Time to the previous frame, s.
    sigma_cycles : (F,) float64
        Standard deviation of the frame's phase step from noise, cycles.
    smooth_hz : float
        Smoothed frequency before the batch (NaN: not yet known).
    run_cycles : float
        Departure accumulated by the outlier run still open at the batch start, cycles.
    run_s : float
        Duration of that run so far, s.
    alpha : float
        Smoothing weight per second (``dt / time constant`` per frame).
    sigmas, min_cycles : float
        Outlier threshold: ``max(sigmas * sigma, min_cycles)``.
    bridged : (F,) float64, out
        ``cfo_hz`` with outliers replaced by the smoothed frequency.
    slips : (F,) bool, out
        True on the frames of an outlier run that added up to half a cycle or
        more (of this batch: a run open at the batch start is flagged from the
        batch's first frame, the earlier ones having been written already).

    Returns
    -------
    smooth_hz, run_cycles, run_s : float
        State for the next batch.

    Notes
    -----
    The reference is frozen during an outlier run so that a burst does not
    pull it; a run that outlasts the time constant ``1 / alpha`` is a lasting
    frequency step (a new dominant phase, a changed Doppler), and the
    reference restarts at the run's mean frequency ``smooth_hz + run_cycles
    / run_s``. Without the restart such a step would be flagged, frame after
    frame, for the rest of the path's life.
    """
    n = cfo_hz.shape[0]
    run_start = 0
    for k in range(n):
        slips[k] = False
        f = cfo_hz[k]
        if not np.isfinite(f):
            bridged[k] = f
            continue
        if not np.isfinite(smooth_hz):
            smooth_hz = f
        departure = (f - smooth_hz) * dt_s[k]
        if abs(departure) > max(sigmas * sigma_cycles[k], min_cycles):
            if run_cycles == 0.0:
                run_start = k
            run_cycles += departure
            run_s += dt_s[k]
            bridged[k] = smooth_hz
            if abs(run_cycles) >= 0.5:
                for j in range(run_start, k + 1):
                    slips[j] = True
            if run_s * alpha >= 1.0:
                smooth_hz += run_cycles / run_s
                run_cycles, run_s = 0.0, 0.0
        else:
            run_cycles, run_s = 0.0, 0.0
            bridged[k] = f
            smooth_hz += min(alpha * dt_s[k], 1.0) * (f - smooth_hz)
    return smooth_hz, run_cycles, run_s


def slip_reference(cfo_hz: np.ndarray, dt_s: np.ndarray, sigma_cycles: np.ndarray, smooth_hz: float,
                   run_cycles: float, run_s: float, alpha: float, sigmas: float,
                   min_cycles: float) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """Plain-Python :func:`slip_kernel` (returns ``bridged, slips, smooth_hz, run_cycles, run_s``)."""
    bridged = np.empty(len(cfo_hz))
    slips = np.zeros(len(cfo_hz), dtype=bool)
    run_start = 0
    for k, f in enumerate(cfo_hz):
        if not np.isfinite(f):
            bridged[k] = f
            continue
        if not np.isfinite(smooth_hz):
            smooth_hz = f
        departure = (f - smooth_hz) * dt_s[k]
        if abs(departure) > max(sigmas * sigma_cycles[k], min_cycles):
            if run_cycles == 0.0:
                run_start = k
            run_cycles += departure
            run_s += dt_s[k]
            bridged[k] = smooth_hz
            if abs(run_cycles) >= 0.5:
                slips[run_start: k + 1] = True
            if run_s * alpha >= 1.0:
                smooth_hz += run_cycles / run_s
                run_cycles, run_s = 0.0, 0.0
        else:
            run_cycles, run_s = 0.0, 0.0
            bridged[k] = f
            smooth_hz += min(alpha * dt_s[k], 1.0) * (f - smooth_hz)
    return bridged, slips, smooth_hz, run_cycles, run_s


@njit(cache=True, nogil=True)
def step_paths_kernel(cfo_hz: np.ndarray, dt_s: np.ndarray, sigma_cycles: np.ndarray, smooth_hz: np.ndarray,
                      run_cycles: np.ndarray, run_s: np.ndarray, alpha: float, sigmas: float, min_cycles: float,
                      moved: np.ndarray, power: np.ndarray, noise: np.ndarray, steady_move: float, survival: float,
                      confirm_batches: int, steady: np.ndarray, confirmed: np.ndarray, bridged: np.ndarray,
                      slips: np.ndarray) -> None:
    """One batch of every path in one call: :func:`slip_kernel` per path, then its steadiness (module docstring).

    Parameters
    ----------
    cfo_hz, sigma_cycles : (F, n) float64
        Each path's frequency per frame (Hz) and phase-step noise (cycles), as in :func:`slip_kernel`.
    dt_s : (F,) float64
        Time to the previous frame, s.
    smooth_hz, run_cycles, run_s : (n,) float64, in/out
        Each path's slip-detector state (:func:`slip_kernel`), carried to the next batch.
    alpha, sigmas, min_cycles : float
        As in :func:`slip_kernel`.
    moved : (n,) float64
        Each path's delay-loop correction over the batch, samples.
    power, noise : (n,) float64
        Each path's mean amplitude power and amplitude noise over the batch.
    steady_move, survival : float
        A path holds still when it moved less than ``steady_move`` samples with
        ``power >= survival * noise``.
    confirm_batches : int
        Steady batches in a row that confirm a path.
    steady : (n,) int64, in/out
        Steady batches in a row.
    confirmed : (n,) bool, in/out
        Confirmed paths (a confirmed path stays confirmed).
    bridged : (F, n) float64, out
        ``cfo_hz`` with each path's outliers bridged.
    slips : (F, n) bool, out
        Each path's frames flagged as a cycle slip.
    """
    for i in range(cfo_hz.shape[1]):
        smooth_hz[i], run_cycles[i], run_s[i] = slip_kernel(
            cfo_hz[:, i], dt_s, sigma_cycles[:, i], smooth_hz[i], run_cycles[i], run_s[i], alpha, sigmas,
            min_cycles, bridged[:, i], slips[:, i])
        steady[i] = steady[i] + 1 if abs(moved[i]) < steady_move and power[i] >= survival * noise[i] else 0
        confirmed[i] = confirmed[i] or steady[i] >= confirm_batches


# ---- the tracker ---------------------------------------------------------------------------

@dataclass
class _Path:
    """State of one tracked path.

    ``delay`` (samples, on the lock's frame grid) and ``rate`` (samples per
    frame) are its delay loop; ``age``, ``steady`` and ``fading`` count
    batches (lived, held still, below the survival SNR); ``prev_*`` carry
    its last amplitude and window start to the next batch's phase step;
    ``smooth_hz``, ``run_cycles`` and ``run_s`` are the slip detector's state; ``power``
    and ``noise`` its mean amplitude power and amplitude noise over the last
    batch; ``born`` until its first row is written; ``first`` while it is
    its tower's first path. With the guard-interval span, ``view`` is the
    shift of the view the path lives in, and ``pending`` maps each alias
    candidate ``k`` (the path at ``delay + k P``) to the index of the view
    that checks it in the next batch (module docstring, step 5); a pending path has no
    tower yet (``tower_id`` -1).
    """

    path_id: int
    tower_id: int
    delay: float
    rate: float
    age: int = 0
    steady: int = 0
    confirmed: bool = False
    fading: int = 0
    prev_amplitude: complex = complex(np.nan, np.nan)
    prev_start: int = 0
    smooth_hz: float = np.nan
    run_cycles: float = 0.0
    run_s: float = 0.0
    power: float = 0.0
    noise: float = 0.0
    born: bool = True
    first: bool = False
    view: int = 0
    pending: dict[int, int] = field(default_factory=dict)


@dataclass
class PathUpdate:
    """What the tracker found in one batch of frames.

    Attributes
    ----------
    rows : PathBatch
        One row per frame and confirmed path (``doppler_hz`` and
        ``range_change_m`` still NaN: :class:`receiver.ranging.PathRanging` fills them).
    first_path : dict of str to ndarray
        The per-frame first-path columns of ``/receiver/frames`` (:data:`dtmbnav_core.records.FIRST_PATH_FILL`),
        ``first_path_range_change_m`` left to the range integrator.
    """

    rows: PathBatch
    first_path: dict[str, np.ndarray] = field(default_factory=dict)


class PathTracker:
    """Detects, separates and tracks the propagation paths in each frame's PN-header CIR.

    One tracker serves a receiver run; :meth:`new_lock` drops the paths when
    the receiver re-acquires (path ids keep counting; the towers' range
    differences continue from their last values, holding their last rate
    across the gap, as eq. 11 does).

    Parameters
    ----------
    mode : PnMode
        Header mode of the lock (PN420 or PN945).
    carrier_hz : float
        RF carrier, Hz (wavelength of the range differences).
    config : PathConfig
    resample : (up, down)
        The receiver's resampling ratio (the resampler shapes the pulse).
    rotating : bool
        Whether the lock's header phase changes from frame to frame. The
        guard-interval span needs it: with a constant phase a view's partial
        m-sequence sums are the same every frame, so they neither average out
        over a batch nor bend a path's phase at random; the tracker then
        keeps to the header's cyclic extension (:attr:`guard`).
    """

    def __init__(self, mode: PnMode, carrier_hz: float, config: PathConfig | None = None,
                 resample: tuple[int, int] = (1, 1), rotating: bool = True) -> None:
        self.config = config or PathConfig()
        self.wavelength_m = SPEED_OF_LIGHT_MPS / carrier_hz
        #: The views the last plan_views gave (a new lock between the plan and its batch keeps them).
        self._planned: tuple[int, ...] = ()
        self._resample = resample
        self._next_id = 0
        self._range_difference = np.zeros(RANGE_DIFFERENCE_TOWERS)
        self._difference_hz = np.zeros(RANGE_DIFFERENCE_TOWERS)
        self._difference_started = np.zeros(RANGE_DIFFERENCE_TOWERS, dtype=bool)
        self._last_t_s: float | None = None
        self.new_lock(mode, rotating)

    def new_lock(self, mode: PnMode, rotating: bool = True) -> None:
        """Forget the paths and towers (a new acquisition); keep ids and range differences counting.

        ``rotating``: whether the new lock's header phase changes from frame to frame.
        """
        m = mode.value
        if m.cyclic_length == 0:
            raise ValueError(f"{mode.name}: path tracking needs a cyclic header (PN420 or PN945)")
        self.mode = mode
        #: Whether the tracker follows paths up to the guard interval (``guard_span`` with a rotating header).
        self.guard = self.config.guard_span and rotating
        self.__dict__.pop("_scan_shifts", None)      # the scan's views are the mode's
        self.taps_before, self.taps_after = self.config.span(mode)
        if not (0 <= self.taps_before <= m.postamble and 0 <= self.taps_after <= m.preamble
                and self.taps_before + self.taps_after > 0):
            raise ValueError(f"{mode.name}: a path span of -{self.taps_before}..{self.taps_after} samples must lie "
                             f"within the header's cyclic extension (-{m.postamble}..{m.preamble})")
        self.header_gain = m.header_power_ratio * m.period
        self.table, self.dtable = _pulse_tables_cached(m.period, *self._resample)
        self.paths: list[_Path] = []
        self._doppler = (FirstPathDoppler(self.config.doppler, self.table, PULSE_OVERSAMPLING, self.lag0,
                                          m.frame_length) if self.config.doppler.frames > 0 else None)
        self._towers: list[float] = []       # last first-path grid delay of each tower
        self._start_ref: int | None = None
        self._index_ref = 0
        self._next_index: int | None = None    # frame after the last batch
        self._loop_batches = 0               # batches since the timing loop (re)started
        # Guard-interval span (module docstring, step 5): the views of the next batch, the scan's turn, each
        # view's tap noise power from its last batch, the last frame's window start on the delay grid.
        self._views: tuple[int, ...] = (0,)
        self._groups: list[int] = [0]
        self._scan_index: int | None = None
        self._checks: dict[int, int] = {}
        self._scan_turn = 0
        self._view_floor: dict[int, float] = {}
        self._last_offset = 0.0

    @property
    def view_lead(self) -> int:
        """Samples before a frame's window start that its views may read (0 without ``guard_span``)."""
        m = self.mode.value
        return m.header_length - m.preamble + 1 if self.guard else 0

    def _clean_span(self, shift: int) -> tuple[int, int]:
        """Lags a view sees with all of a path's header chips in its window: its cyclic extension."""
        m = self.mode.value
        return shift - m.postamble, shift + m.preamble

    def _group_of(self, lag: float, groups: list[int]) -> int | None:
        """The view among ``groups`` whose cyclic extension holds ``lag`` (the nearest shift of several), or None."""
        inside = [g for g in groups if self._clean_span(g)[0] <= lag < self._clean_span(g)[1]]
        return min(inside, key=lambda g: abs(lag - g)) if inside else None

    @cached_property
    def _scan_shifts(self) -> np.ndarray:
        """Shifts of the views that scan, in turn, the lags up to the guard interval on either side (of the mode).

        On each side the views' cyclic extensions tile the lags from the
        frame's own view's edge to the guard interval (the header's length).
        """
        m = self.mode.value
        width = m.preamble + m.postamble
        guard = m.header_length
        after = np.linspace(width, guard - m.preamble, max(int(np.ceil((guard - m.preamble) / width)), 1))
        before = np.linspace(-width, -(guard - m.postamble), max(int(np.ceil((guard - m.postamble) / width)), 1))
        return np.rint(np.ravel(np.column_stack([after, before]))).astype(np.int64)

    def _alias_candidates(self, lag: float) -> list[int]:
        """Whole m-sequence periods k != 0 with ``lag + k P`` within the guard interval."""
        m = self.mode.value
        reach = m.header_length // m.period + 1
        return [k for k in range(-reach, reach + 1) if k != 0 and abs(lag + k * m.period) <= m.header_length]

    def plan_views(self) -> tuple[int, ...]:
        """The views (shifts, samples) the next batch needs: () without the guard-interval span (:attr:`guard`).

        Every view a path lives in (and the frame's own, shift 0), in order
        of shift; the scan's next view (unless a path lives there); for every
        path born in the last batch a view centred on each of its alias
        candidates.
        """
        if not self.guard:
            return ()
        groups = sorted({0} | {p.view for p in self.paths})
        views = list(groups)
        scan = int(self._scan_shifts[self._scan_turn % len(self._scan_shifts)])
        self._scan_turn += 1
        self._scan_index = None if scan in groups else len(views)
        if self._scan_index is not None:
            views.append(scan)
        self._checks = {}
        for i, p in enumerate(self.paths):
            lag = p.delay - self._last_offset
            for k in p.pending:
                p.pending[k] = len(views)
                self._checks[len(views)] = i
                views.append(round(lag + k * self.mode.value.period))
        self._groups = groups
        self._views = self._planned = tuple(views)
        return self._views

    def break_phase(self) -> None:
        """The next frame's phase does not follow from the last one (samples were dropped between them).

        Every path's next phase step is left out (its frequency NaN for that
        frame); delays, amplitudes and towers go on. Across a re-acquisition
        that only skipped dropped samples the caller keeps the window starts
        on the real clock, so the paths' delays continue, and calls this
        instead of :meth:`new_lock` (the new lock's coarse CFO changes every
        phase).
        """
        for p in self.paths:
            p.prev_amplitude = complex(np.nan, np.nan)
        self._loop_batches = 0
        if self._doppler is not None:
            self._doppler.restart()

    @property
    def lag0(self) -> int:
        """Lag of the CIR's first column."""
        return -self.taps_before

    def update(self, taps: np.ndarray, noise_tap: np.ndarray, starts: np.ndarray, frame_index: np.ndarray,
               eta: np.ndarray, t_s: np.ndarray, coarse_cfo_hz: float, views: np.ndarray | None = None) -> PathUpdate:
        """Fit, track and report the paths of a batch of frames.

        Parameters
        ----------
        taps : (F, L) complex64
            CIR over the tracker's span (``span_taps``).
        noise_tap : (F,)
            Tap noise floor of each frame.
        starts : (F,) int64
            Window starts (stream samples at 7.56 Msps).
        frame_index : (F,) int64
            Frame counter.
        eta : (F,) float64
            Normalised sampling offset per frame (``receiver.cfo.cfo_from_theta``).
        t_s : (F,) float64
            Frame times, s.
        coarse_cfo_hz : float
            The coarse CFO removed from the CIR.
        views : (F, V, P) complex64, optional
            With the guard-interval span (:attr:`guard`): the taps of the views :meth:`plan_views` named
            for this batch (``taps`` then serves the Doppler check only).
        """
        cfg = self.config
        count = len(starts)
        nominal = self.mode.value.frame_length
        if self._start_ref is None:
            self._start_ref, self._index_ref = int(starts[0]), int(frame_index[0])
        elif self._next_index is not None and frame_index[0] != self._next_index:
            # A re-acquisition across a drop resumes at another frame than the next: frames skipped (the paths
            # drifted with the clock meanwhile), or frames the lost lock went on taking after the drop and the
            # new lock takes again (the paths were carried past them).
            for p in self.paths:
                p.delay += p.rate * (int(frame_index[0]) - self._next_index)
        self._next_index = int(frame_index[-1]) + 1
        offsets = ((starts - self._start_ref) - (frame_index - self._index_ref) * nominal).astype(np.float64)
        paths = self.paths
        n = len(paths)
        delay = np.array([p.delay for p in paths], dtype=np.float64)
        rate = np.array([p.rate for p in paths], dtype=np.float64)
        # A path that has held still moves no faster than a path can (walking: hundredths of a chip per
        # second): a spurious neighbour cannot drag it away.
        max_step = np.array([cfg.steady_delay_step if p.confirmed else cfg.max_delay_step for p in paths])
        delay_before, rate_before = delay.copy(), rate.copy()    # the fit updates delay and rate in place
        if self.guard:
            if views is None:
                raise ValueError("PathTracker.update: guard_span needs the views of plan_views")
            if views.shape[1] == len(self._planned) != len(self._views):
                # A new lock came between the plan and its batch (the lock's first batch after a loss): the
                # batch is fitted on the views the new lock plans, which every plan holds (the frame's own).
                views = views[:, [self._planned.index(shift) for shift in self._views]]
            amplitudes, lags, amp_variance, tap_noise, path_noise, found_in = self._fit_views(
                views, offsets, delay, rate, max_step)
        else:
            amplitudes, lags, amp_variance, tap_noise, path_noise, found_in = self._fit_span(
                taps, noise_tap, offsets, delay, rate, max_step)
        dt = np.diff(np.concatenate([[t_s[0] if self._last_t_s is None else self._last_t_s], t_s]))
        power = np.abs(amplitudes) ** 2
        step = np.diff(np.concatenate([[starts[0]], starts]))

        # Each path's frequency from its phase step (as the PN CFO estimate) and the step's noise: each frame's
        # phase has variance var / (2 |a|^2), the step twice that.
        prev = np.vstack([[p.prev_amplitude for p in paths], amplitudes[:-1]]) if n else amplitudes
        path_step = np.repeat(step[:, None], n, axis=1)
        path_step[0] = starts[0] - np.array([p.prev_start for p in paths], dtype=np.int64)
        cfo = cfo_from_theta(np.conj(amplitudes) * prev, np.maximum(path_step, 1), eta[:, None], coarse_cfo_hz)
        sigma = np.sqrt(amp_variance / np.maximum(power, 1e-30)) / (2.0 * np.pi)
        bridged = np.empty((count, n))
        slips = np.zeros((count, n), dtype=bool)
        mean_power = power.mean(axis=0)
        moved = delay - (delay_before + rate_before * count)
        smooth_hz = np.array([p.smooth_hz for p in paths], dtype=np.float64)
        run_cycles = np.array([p.run_cycles for p in paths], dtype=np.float64)
        run_s = np.array([p.run_s for p in paths], dtype=np.float64)
        steady = np.array([p.steady for p in paths], dtype=np.int64)
        confirmed = np.array([p.confirmed for p in paths], dtype=np.bool_)
        # Every path's slips and steadiness in one call; a path is confirmed once it has held still, above the
        # survival SNR, for confirm_batches batches.
        step_paths_kernel(cfo, dt, sigma, smooth_hz, run_cycles, run_s, 1.0 / cfg.frequency_time_s, cfg.slip_sigmas,
                          cfg.slip_min_cycles, moved, mean_power, path_noise, cfg.steady_move,
                          10.0 ** (cfg.survival_snr_db / 10.0), cfg.confirm_batches, steady, confirmed, bridged, slips)
        last_start = int(starts[-1])
        for p, *state in zip(paths, delay.tolist(), rate.tolist(), smooth_hz.tolist(), run_cycles.tolist(),
                             run_s.tolist(), amplitudes[-1].tolist(), mean_power.tolist(),
                             path_noise.tolist(), steady.tolist(), confirmed.tolist()):
            (p.delay, p.rate, p.smooth_hz, p.run_cycles, p.run_s, p.prev_amplitude, p.power, p.noise, p.steady,
             p.confirmed) = state
            p.prev_start = last_start

        if self.guard:
            self._resolve_aliases(count, offsets)
        first_of = self._choose_first_paths(paths, lags)
        rows = self._rows(paths, amplitudes, lags, rate, bridged, slips, tap_noise, t_s, frame_index)
        first = self._first_paths(paths, first_of, lags, bridged, power, tap_noise, t_s, dt)
        if self._doppler is not None:
            # The first path of tower 0 may be a pair under a third of a chip: its frequency is the stronger one's.
            i = first_of.get(0)
            first["first_path_cfo_hz"] += self._doppler.update(
                taps, starts, frame_index, None if i is None else float(lags[-1, i]),
                None if i is None else amplitudes[:, i])
        self._last_t_s = float(t_s[-1])
        # The timing loop's period settles during the first batch after an acquisition: no drift from it there.
        loop_drift = float(np.mean(eta)) * nominal if self._loop_batches > 0 else 0.0
        self._loop_batches += 1
        self._last_offset = float(offsets[-1])
        self._maintain(found_in, offsets, count, loop_drift)
        return PathUpdate(rows, first)

    # ---- the fit over the span or the views ------------------------------------------------

    def _fit_span(self, taps: np.ndarray, noise_tap: np.ndarray, offsets: np.ndarray, delay: np.ndarray,
                  rate: np.ndarray, max_step: np.ndarray) -> tuple:
        """The fit over the header's cyclic extension (:func:`fit_paths_kernel`).

        Returns the amplitudes and lags ``(F, n)``, each amplitude's noise
        variance ``(F, n)``, the tap noise each path's SNR is taken against
        ``(F, n)``, each path's mean amplitude noise ``(n,)`` and the births
        of the batch as a function of ``(strongest, offset, existing,
        settled)`` (:meth:`_maintain`); ``delay`` and ``rate`` are updated.
        """
        cfg = self.config
        count, n = len(offsets), len(delay)
        amplitudes = np.zeros((count, n), np.complex128)
        lags = np.zeros((count, n))
        variance = np.zeros((count, n))
        residual = np.zeros(taps.shape[1])
        fit_paths_kernel(taps, offsets, self.lag0, delay, rate, max_step, self.table, self.dtable,
                         PULSE_OVERSAMPLING, cfg.block_frames, cfg.delay_gain, cfg.rate_gain, cfg.max_run_move,
                         amplitudes, lags, variance, residual)
        noise = np.maximum(noise_tap.astype(np.float64), 1e-30)
        noise_floor = float(np.mean(noise))
        power = residual / (noise_floor * count)

        def found_in(strongest: float, offset: float, existing: np.ndarray,
                     settled: np.ndarray) -> list[tuple[float, int]]:
            limit = max(detection_threshold(count, cfg.false_alarm),
                        10.0 ** (cfg.relative_floor_db / 10.0) * strongest / noise_floor)
            return [(lag, 0) for lag in detect_paths(power, self.lag0, limit, existing, settled, cfg.min_separation,
                                                     cfg.settle_guard,
                                                     min(cfg.max_births, cfg.max_paths - len(self.paths)))]

        return (amplitudes, lags, variance * noise[:, None], np.broadcast_to(noise[:, None], (count, n)),
                noise_floor * variance.mean(axis=0), found_in)

    def _coverage(self, shifts: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Share of each path's header chips inside each view's window, ``(V, n)``.

        A path at lag ``lam`` holds its header in samples ``lam .. lam + Ng``;
        view s correlates the P samples from ``preamble + s`` on.
        """
        m = self.mode.value
        start = m.preamble + np.asarray(shifts, dtype=np.float64)[:, None]
        overlap = np.minimum(start + m.period, lam[None, :] + m.header_length) - np.maximum(start, lam[None, :])
        return np.clip(overlap, 0.0, m.period) / m.period

    def _fit_views(self, views: np.ndarray, offsets: np.ndarray, delay: np.ndarray, rate: np.ndarray,
                   max_step: np.ndarray) -> tuple:
        """The fit over the views paths live in, at once (:func:`fit_views_kernel`; module docstring, step 5).

        A path's amplitude comes from the views that hold at least
        :data:`FULL_COVERAGE` of its header chips, its pulse scaled by their
        share. In a view that holds less, that part is a pulse with an
        amplitude of its own (a nuisance): its partial m-sequence sums would
        bend the path's phase more than the view's information helps. The scan's and the alias checks' views are not fitted:
        every path's pulse, at its share of header chips, is taken out of
        them with the fitted amplitudes (:func:`model_residual_kernel`), so a
        path that is not where the fit has it stands out there. Each view is
        weighted by its tap noise power: its last batch's, or for a new view
        the median of its taps' power (its paths fill a few of its P lags).
        Afterwards each view's noise is the median of its residual, which a
        path's SNR, slip threshold and survival, and the detection in that
        view, are measured against. Returns what :meth:`_fit_span` does.
        """
        cfg = self.config
        m = self.mode.value
        count, n, period = len(offsets), len(delay), m.period
        shifts = np.asarray(self._views, dtype=np.int64)
        n_views = len(shifts)
        if views.shape[1:] != (n_views, period):
            raise ValueError(f"PathTracker.update: views of shape {views.shape[1:]}, planned {(n_views, period)}")
        floor = np.maximum([self._view_floor[int(s)] if int(s) in self._view_floor else
                            float(np.median(np.mean(views[:, v].real ** 2 + views[:, v].imag ** 2, axis=0)))
                            for v, s in enumerate(shifts)], 1e-30)
        weight = 1.0 / np.sqrt(floor)
        coverage = self._coverage(shifts, delay + rate * 0.5 * (count - 1) - offsets[count // 2]) * weight[:, None]
        full = coverage >= FULL_COVERAGE * weight[:, None]
        lag_axis = shifts[:, None] + view_first_lag(self.mode) + np.arange(period)[None, :]
        fitted = np.arange(n_views) < len(self._groups)
        # The fitted views: each path at full coverage, plus a nuisance pulse per view that holds part of it.
        part_view, part_path = np.nonzero(fitted[:, None] & (coverage > 0.0) & ~full)
        scale = np.zeros((n_views, n + len(part_view)))
        scale[:, :n] = np.where(full, coverage, 0.0)
        scale[part_view, n + np.arange(len(part_view))] = weight[part_view]
        delay_all, rate_all = np.concatenate([delay, delay[part_path]]), np.concatenate([rate, rate[part_path]])
        amplitudes = np.zeros((count, len(delay_all)), np.complex128)
        lags = np.zeros((count, len(delay_all)))
        variance = np.zeros((count, len(delay_all)))
        residual = np.zeros((n_views, period))
        on = np.flatnonzero(fitted)
        fit_residual = np.zeros(len(on) * period)
        fit_views_kernel((views[:, on] * weight[on].astype(np.float32)[None, :, None]).reshape(count, -1), offsets,
                         lag_axis[on].ravel().astype(np.float64), np.repeat(on, period), scale, delay_all, rate_all,
                         np.concatenate([max_step, np.zeros(len(part_view))]), self.table, self.dtable,
                         PULSE_OVERSAMPLING, cfg.block_frames, cfg.delay_gain, cfg.rate_gain, cfg.max_run_move,
                         amplitudes, lags, variance, fit_residual)
        delay[:], rate[:] = delay_all[:n], rate_all[:n]
        residual[on] = fit_residual.reshape(len(on), period)
        off = np.flatnonzero(~fitted)
        if len(off):
            # A check view keeps the pulse of the path it checks (the evidence for its candidate).
            for v, i in self._checks.items():
                coverage[v, i] = 0.0
            left = np.zeros(len(off) * period)
            model_residual_kernel((views[:, off] * weight[off].astype(np.float32)[None, :, None]).reshape(count, -1),
                                  lag_axis[off].ravel().astype(np.float64), np.repeat(off, period), coverage,
                                  amplitudes[:, :n], lags[:, :n], self.table, PULSE_OVERSAMPLING, cfg.block_frames,
                                  cfg.max_run_move, left)
            residual[off] = left.reshape(len(off), period)
        residual /= count
        ratio = np.maximum(np.median(residual, axis=1), 1e-30)       # each view's noise over the assumed one
        tap_floor = floor * ratio
        # The next batch's weights; of two views at one shift the first's (a check keeps its path's pulse in).
        self._view_floor = dict(zip(shifts.tolist()[::-1], tap_floor.tolist()[::-1]))
        self._view_power = residual / ratio[:, None]                  # residual over each view's noise, per lag
        self._view_noise = tap_floor
        # The spread of each view's residual across its lags beyond white noise's (1 / sqrt(F)).
        spread = 1.4826 * np.median(np.abs(self._view_power - 1.0), axis=1)
        self._view_structure = np.sqrt(np.maximum(spread ** 2 - 1.0 / count, 0.0))
        own = np.array([self._groups.index(p.view) for p in self.paths], dtype=np.int64)
        variance = variance[:, :n]

        def found_in(strongest: float, offset: float, existing: np.ndarray,
                     settled: np.ndarray) -> list[tuple[float, int]]:
            return self._views_found(count, strongest, existing, settled)

        return (amplitudes[:, :n], lags[:, :n], variance * ratio[own][None, :],
                np.broadcast_to(tap_floor[own][None, :], (count, n)), variance.mean(axis=0) * ratio[own], found_in)

    def _view_limit(self, count: int, strongest: float, view: int) -> float:
        """Detection threshold in view ``view``'s noise units.

        That of the cyclic span (false alarm, relative floor), or
        :data:`STRUCTURE_SIGMAS` times the excess spread of the view's
        residual across its lags above its median, if higher: where a path's
        header lies partly in the window, the residual has peaks no noise
        floor predicts. In a view without such paths the excess is nil.
        """
        cfg = self.config
        return max(detection_threshold(count, cfg.false_alarm),
                   10.0 ** (cfg.relative_floor_db / 10.0) * strongest / self._view_noise[view],
                   1.0 + STRUCTURE_SIGMAS * self._view_structure[view])

    def _views_found(self, count: int, strongest: float, existing: np.ndarray,
                     settled: np.ndarray) -> list[tuple[float, int]]:
        """New paths in the views' residuals: ``(lag, view)`` of the strongest, at most ``max_births``.

        A view in which paths live detects on the lags of its cyclic
        extension that are nearer its shift than any other such view's; the
        scan's view on those of its cyclic extension that no such view covers,
        within the guard interval, and a path it finds gets a view centred on it.
        """
        cfg = self.config
        first = view_first_lag(self.mode)
        candidates: list[tuple[float, float, int]] = []
        for v, shift in enumerate(self._views):
            group = v < len(self._groups)
            if not group and v != self._scan_index:
                continue
            power = self._view_power[v]
            lo, hi = self._clean_span(shift)
            for lag in detect_paths(power, shift + first, self._view_limit(count, strongest, v), existing, settled,
                                    cfg.min_separation, cfg.settle_guard, len(power)):
                owner = self._group_of(lag, self._groups)
                if group and owner == shift:
                    candidates.append((float(power[round(lag) - shift - first]), lag, shift))
                elif not group and owner is None and lo <= lag < hi and abs(lag) <= self.mode.value.header_length:
                    candidates.append((float(power[round(lag) - shift - first]), lag, round(lag)))
        births: list[tuple[float, int]] = []
        for _, lag, view in sorted(candidates, reverse=True):
            if len(births) >= min(cfg.max_births, cfg.max_paths - len(self.paths)):
                break
            if all(abs(lag - b) >= 1.0 for b, _ in births):
                births.append((lag, view))
        return births

    def _resolve_aliases(self, count: int, offsets: np.ndarray) -> None:
        """Move each path born in the last batch to the alias candidate its views show (module docstring, step 5).

        The fit took the path where it was found, at lag l of its own view.
        The view centred on a candidate ``l + k P`` keeps the path's pulse;
        at the candidate it holds the path with all of its header chips if
        the path is there, else with the third or less of them that window
        holds of a path at l (and with the same share of whatever else lies
        around l unfitted). The path moves to the candidate whose power there
        crosses the view's detection threshold and exceeds the view's noise by
        :data:`ALIAS_SHARE` of the path's power at l (its fitted power and
        the residual around it); the strongest such candidate wins, and
        without one the path stays. Then it joins a tower.
        """
        period = self.mode.value.period
        first = view_first_lag(self.mode)
        offset = float(np.mean(offsets))
        strongest = max((p.power for p in self.paths), default=0.0)
        grid = np.arange(len(self.table) - 1) / PULSE_OVERSAMPLING

        def around(view: int, lag: float) -> float:
            """Peak tap power of a pulse at ``lag`` in view ``view``'s residual, its noise included.

            The residual's power on the three columns nearest ``lag``, less
            their noise, over the pulse's energy there: a column's own power
            would miss up to 0.6 of the peak of a pulse half a chip off it,
            and a path is compared with its fitted power.
            """
            column = round(lag) - self._views[view] - first
            columns = np.arange(max(column - 1, 0), min(column + 2, period))
            pulse = np.interp(np.mod(columns + self._views[view] + first - lag, period), grid, self.table[:-1],
                              period=period) ** 2
            noise = self._view_noise[view]
            excess = float(np.sum(self._view_power[view, columns]) - len(columns)) * noise
            return max(excess, 0.0) / max(float(np.sum(pulse)), 1e-12) + noise

        for p in self.paths:
            if not p.pending:
                continue
            lag = p.delay - 0.5 * count * p.rate - offset
            here = p.power + around(self._groups.index(p.view), lag)
            best, best_k = 0.0, 0
            for k, v in p.pending.items():
                level = around(v, lag + k * period)
                floor = self._view_noise[v]
                if level > max(best, floor + ALIAS_SHARE * here, self._view_limit(count, strongest, v) * floor):
                    best, best_k = level, k
            if best_k:
                moved = lag + best_k * period
                p.delay += best_k * period
                owner = self._group_of(moved, self._groups)
                p.view = round(moved) if owner is None else owner
                p.steady = 0
            p.pending = {}
            p.tower_id = self._tower_of(p.delay)

    # ---- per-batch bookkeeping -------------------------------------------------------------

    def _choose_first_paths(self, paths: list[_Path], lags: np.ndarray) -> dict[int, int]:
        """Tower id -> index of its first path: the earliest confirmed, mature path (mean lag over the batch).

        A fading path does not become a first path; the first path stays one
        while it lives (a short fade does not hand its range to a reflection).
        A tower without a first path waits while an earlier confirmed path of
        it is still maturing or fades (it matures within
        ``first_path_batches``, recovers or is dropped within
        ``lost_batches``): a later path born before it, a reflection or a
        fitting artefact beside the direct path, would otherwise give the
        tower's range difference its own frequency until the earlier path
        takes over.
        """
        first: dict[int, int] = {}
        waiting: dict[int, float] = {}     # each tower's earliest confirmed path that is not yet eligible
        has_first = {p.tower_id for p in paths if p.first}
        mean_lag = lags.mean(axis=0) if len(lags) else np.zeros(len(paths))
        for i, p in enumerate(paths):
            if not p.confirmed:
                continue
            if p.age < self.config.first_path_batches or (p.fading and not p.first):
                waiting[p.tower_id] = min(waiting.get(p.tower_id, np.inf), float(mean_lag[i]))
            elif p.tower_id not in first or mean_lag[i] < mean_lag[first[p.tower_id]]:
                first[p.tower_id] = i
        for tower in [t for t, i in first.items() if t not in has_first and waiting.get(t, np.inf) < mean_lag[i]]:
            del first[tower]
        for i, p in enumerate(paths):
            p.first = first.get(p.tower_id) == i
        return first

    def _rows(self, paths: list[_Path], amplitudes: np.ndarray, lags: np.ndarray, rate: np.ndarray,
              bridged: np.ndarray, slips: np.ndarray, noise: np.ndarray, t_s: np.ndarray,
              frame_index: np.ndarray) -> PathBatch:
        """One row per frame and confirmed path, frame-major (all paths of a frame together)."""
        confirmed = np.flatnonzero(np.array([p.confirmed for p in paths], dtype=np.bool_))
        count, c = len(t_s), len(confirmed)
        if c == 0:
            return PathBatch.concatenate([])
        kept = [paths[i] for i in confirmed]
        # (F, c) columns, raveled in C order: frame k's rows are k * c .. k * c + c - 1, in path order.
        flags = np.where(slips[:, confirmed], np.uint8(PathFlag.CYCLE_SLIP), np.uint8(0))
        flags |= np.array([(PathFlag.FIRST_PATH if p.first else 0) | (PathFlag.FADING if p.fading else 0)
                           for p in kept], dtype=np.uint8)
        flags[0] |= np.array([PathFlag.BORN if p.born else 0 for p in kept], dtype=np.uint8)
        with np.errstate(divide="ignore"):
            snr = 10.0 * np.log10(np.abs(amplitudes[:, confirmed]) ** 2 / (noise * self.header_gain)[:, confirmed])
        for p in kept:
            p.born = False
        nan = np.full(count * c, np.nan)
        return PathBatch(t_s=np.repeat(t_s, c), frame_index=np.repeat(frame_index, c),
                         path_id=np.tile(np.array([p.path_id for p in kept]), count),
                         tower_id=np.tile(np.array([p.tower_id for p in kept]), count),
                         delay_s=(lags[:, confirmed] / SYMBOL_RATE_HZ).ravel(),
                         delay_rate=np.tile(rate[confirmed] / self.mode.value.frame_length, count),
                         cfo_hz=bridged[:, confirmed].ravel(), snr_db=snr.ravel(), flags=flags.ravel(),
                         doppler_hz=nan, range_change_m=nan.copy())

    def _first_paths(self, paths: list[_Path], first: dict[int, int], lags: np.ndarray, bridged: np.ndarray,
                     power: np.ndarray, noise: np.ndarray, t_s: np.ndarray, dt: np.ndarray) -> dict[str, np.ndarray]:
        """The per-frame first-path columns and the towers' range differences."""
        count = len(t_s)
        out = {"first_path_cfo_hz": np.full(count, np.nan), "first_path_delay_s": np.full(count, np.nan),
               "first_path_snr_db": np.full(count, np.nan, np.float32), "first_path_id": np.full(count, -1, np.int32),
               "tower_count": np.full(count, len(first), np.uint8)}
        cfo_of = {t: bridged[:, i] for t, i in first.items()}
        if 0 in first:
            i = first[0]
            with np.errstate(divide="ignore"):
                snr = 10.0 * np.log10(power[:, i] / (noise[:, i] * self.header_gain))
            out.update(first_path_cfo_hz=bridged[:, i].copy(), first_path_delay_s=lags[:, i] / SYMBOL_RATE_HZ,
                       first_path_snr_db=snr.astype(np.float32), first_path_id=np.full(count, paths[i].path_id, np.int32))
        for slot in range(RANGE_DIFFERENCE_TOWERS):
            column = np.full(count, np.nan)
            tower = slot + 1
            if tower in first and 0 in first:
                if not self._difference_started[slot]:
                    self._difference_started[slot] = True
                    self._range_difference[slot] = 0.0
                    dt = dt.copy()
                    dt[0] = 0.0
                difference = held_doppler(cfo_of[tower] - cfo_of[0], self._difference_hz[slot])
                column = self._range_difference[slot] - self.wavelength_m * np.cumsum(difference * dt)
                self._range_difference[slot] = float(column[-1])
                # The rate held across a later gap: the batch's median, not its last frame's (a path that is
                # being lost ends on wild frequencies, which, held over a gap, would make the range jump).
                measured = cfo_of[tower] - cfo_of[0]
                measured = measured[np.isfinite(measured)]
                if len(measured):
                    self._difference_hz[slot] = float(np.median(measured))
            elif self._difference_started[slot]:
                # Tower missing in this batch: hold its rate, as eq. 11 does across gaps.
                self._range_difference[slot] -= self.wavelength_m * self._difference_hz[slot] * float(np.sum(dt))
            out[f"range_difference_change_{tower}_m"] = column
        return out

    def _maintain(self, found_in: Callable[[float, float, np.ndarray, np.ndarray], list[tuple[float, int]]],
                  offsets: np.ndarray, count: int, loop_drift: float) -> None:
        """Ages, fading and merging of the paths (module docstring, step 1), then births (:func:`detect_paths`).

        ``found_in(strongest, offset, existing, settled)`` gives the births,
        ``(lag, view)`` (:meth:`_fit_span`); ``loop_drift`` is the grid drift
        per frame the timing loop's period gives over the batch (the
        sampling offset times the frame length), samples per frame.
        """
        cfg = self.config
        survival = 10.0 ** (cfg.survival_snr_db / 10.0)
        strongest = max((p.power for p in self.paths), default=0.0)
        relative = 10.0 ** (cfg.relative_floor_db / 10.0)
        keep: list[_Path] = []
        for p in self.paths:
            p.age += 1
            p.fading = p.fading + 1 if (p.power < survival * p.noise or p.power < relative * strongest) else 0
            if p.fading < cfg.lost_batches:
                keep.append(p)
        # Merge paths that drifted together: the older one stays.
        keep.sort(key=lambda p: p.delay)
        merged: list[_Path] = []
        for p in keep:
            if merged and p.delay - merged[-1].delay < cfg.min_separation:
                if p.age > merged[-1].age:
                    merged[-1] = p
                continue
            merged.append(p)
        self.paths = merged
        if len(self.paths) >= cfg.max_paths:
            return
        # The residual is the batch's, about its middle frame; the delays are those of the frame after it.
        offset = float(np.mean(offsets))
        existing = np.array([p.delay - 0.5 * count * p.rate - offset for p in self.paths])
        settled = np.array([p.age >= cfg.settle_batches for p in self.paths], dtype=bool)
        found = found_in(strongest, offset, existing, settled)
        # Every path's delay drifts with the receiver clock (the sampling offset): a new path starts with the
        # drift the confirmed paths agree on. Without them it starts still, unless the timing loop's drift is
        # more than half what a path's delay loop can follow (max_delay_step per update): a crystal tens of ppm
        # off moves the grid by hundredths of a sample per frame. Below that the loop's noise (about 1e-3
        # samples per frame over a batch) would only disturb a path that can find its drift itself.
        rates = [p.rate for p in self.paths if p.confirmed]
        followable = cfg.max_delay_step / cfg.block_frames
        drift = float(np.median(rates)) if rates else (loop_drift if abs(loop_drift) > 0.5 * followable else 0.0)
        for lag, view in sorted(found):
            delay = lag + offset + 0.5 * count * drift
            # With the guard-interval span a new path may be an alias: it joins a tower once it is resolved. One
            # found within tower_gap of a resolved path of its view is that tower's (a street's multipath): the
            # view checking its candidate would hold that tower's own alias there, at a third of its power,
            # with the residual a strong path leaves around it.
            near = any(p.view == view and p.tower_id >= 0 and abs(p.delay - delay) <= cfg.tower_gap
                       for p in self.paths)
            pending = dict.fromkeys(self._alias_candidates(lag), -1) if self.guard and not near else {}
            self.paths.append(_Path(self._next_id, -1 if pending else self._tower_of(delay), delay, drift, view=view,
                                    pending=pending))
            self._next_id += 1
        self.paths.sort(key=lambda p: p.delay)
        self._update_towers()

    def _tower_of(self, delay: float) -> int:
        """Tower of a new path: the tower with a path within ``tower_gap``, else a new one."""
        gap = self.config.tower_gap
        best, best_distance = -1, np.inf
        for p in self.paths:
            distance = abs(p.delay - delay)
            if p.tower_id >= 0 and distance <= gap and distance < best_distance:
                best, best_distance = p.tower_id, distance
        if best >= 0:
            return best
        for tower, first_delay in enumerate(self._towers):
            if abs(first_delay - delay) <= gap:
                return tower
        self._towers.append(delay)
        return len(self._towers) - 1

    def _update_towers(self) -> None:
        for tower in range(len(self._towers)):
            delays = [p.delay for p in self.paths if p.tower_id == tower]
            if delays:
                self._towers[tower] = min(delays)
