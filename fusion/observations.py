"""From the receiver's 1800 frames/s range and the PDR's steps to filter epochs.

The receiver integrates the Doppler every signal frame (1800 frames/s for
PN420) while the PDR produces one row per step (about 2 per second). The
filters run once per step, so each step needs one range observation and its
noise. The rule, applied per step time ``t_n``:

1. Take the receiver frames with ``|t - t_n| <= window_s / 2``.
2. Keep the frames the receiver marks valid (no gap, lock, quality flags).
3. If fewer than ``min_valid_fraction`` of the frames expected in the window
   (from the median frame interval) are valid, the epoch has no range
   observation (``range_change_m`` is NaN): a gap or a fade is skipped, not
   interpolated across.
4. Otherwise the observation is the mean range change of the valid frames.
   Averaging is not there to beat down per-frame noise (the integrated range
   telescopes and its frame noise is millimetres, docs/method.md §2): it makes the
   observation insensitive to which frame is nearest the step peak and to the
   odd flagged frame.
5. Its standard deviation is ``base_sigma_m`` (the drift/multipath error the
   integrated range accumulates over a walk, which is what limits it), inflated
   where the link is weak: the phase-noise variance grows as 1/SNR, and low
   SNR is where the direct path is blocked and a reflection sets the phase, so
   ``sigma = base_sigma_m * sqrt(max(1, 10^((good_snr_db - snr)/10)))`` with
   ``snr`` the mean SNR of the valid frames in dB, and a further factor
   ``1 / sqrt(valid fraction)`` for partly flagged windows.
6. **Multipath.** A reflection whose Doppler differs from the direct path's
   (a wall ahead while the tower is behind) bends the integrated range by up
   to a metre per second, at a healthy SNR. What gives it away is fading:
   two comparable paths with different Dopplers beat, so the SI-carrier
   power swings, where a line-of-sight link (direct path plus weak diffuse
   scattering, Rician K ~ 10 dB) stays steady. The Rician K-factor is
   estimated from the moments of the linear SNR over ``fading_window_s``
   around the step (Greenstein et al. 1999:
   ``gamma = Var(P) / E(P)^2``, ``K = sqrt(1 - gamma) / (1 - sqrt(1 - gamma))``)
   and an epoch with ``K < min_rician_k_db`` has no range observation. A
   reflection with the direct path's Doppler (walking along a wall) does not
   fade and does not bend the range, so it is rightly kept.

7. **Segments.** The receiver restarts its range at each re-acquisition
   (``segment_id``; the range is held flat across the gap, docs/schema.md):
   how far the walker moved during the gap is unknown. An epoch whose window
   reaches into a new segment, or which follows a change of segment since the
   previous epoch, has no range observation, and the range returns after
   rule 5's ``settle_s``: what follows is a range from a new origin.

Where an epoch has no range observation, the integrated range may have
jumped or drifted (a gap, a fade, a multipath stretch, a new segment): the
particle filter lets its range offset wander there
(:mod:`fusion.particle_filter`). The first kept epoch after a change of
segment is marked as a new origin, as a path channel's after an origin break
(rule 8): the filters re-anchor the range there (:mod:`fusion.kalman`,
:mod:`fusion.particle_filter`).

**Path channels** (:class:`PathRanges`: the first-path range to each tower,
and the difference of tower k's and tower 0's first-path ranges; docs/paths.md)
follow rules 1-5 per channel with :class:`PathAggregationConfig`, and these
instead of rules 6 and 7 (a resolved path does not beat against the others):

8. A frame flagged as a slip, and a frame where the path's age drops (the
   path was lost and found again), is an origin break: an epoch whose
   window holds one has no observation, and the next epoch that has one is
   marked as a new origin (the filters re-anchor the channel there).
9. An epoch whose path is younger than ``min_path_age_s`` (mean over the
   window) has no observation, and the sigma of rule 5 grows by a further
   ``sqrt(1 + path_settle_s / age)``: a freshly found path may be a sidelobe
   or a passing reflection, and a path that has held for a while is the
   better bet.

**Standstills.** Where the PDR has no step for longer than the step
detector's longest step (``StepDetectorConfig.max_step_s``: the walker stood
still), and before the first step, the filters get epochs without a step,
every ``epoch_s`` from ``margin_s`` after the last step to ``margin_s``
before the next (:class:`StandstillConfig`). Nothing moves in them, so the
range they see changes only with the receiver clock: with a free-running
clock (:class:`fusion.model.ClockModel`) this is where its rate is observed
directly and re-anchored, the method's f_s calibration (docs/method.md §2)
repeated at every stop. The filters report no track row for them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dtmbnav_core.records import ColumnRecord, PathRanges, PathRangeSeries, PdrSteps, RangeSeries
from fusion import SI_RANGE_USES
from fusion.model import EpochObservation, StepControl, wrap_angle
from fusion.pdr.steps import StepDetectorConfig


@dataclass(frozen=True)
class AggregationConfig:
    """Parameters of the range-to-epoch rule (module docstring).

    Attributes
    ----------
    window_s : float
        Width of the window centred on each step time, s.
    min_valid_fraction : float
        Fraction of the window's expected frames that must be valid.
    base_sigma_m : float
        Range observation standard deviation on a good link, m: above the
        integrated range's own error over a line-of-sight minute, with room
        for the weak multipath the rules let through (chosen on the tuning
        seeds, ``docs/evaluation.md``).
    good_snr_db : float
        SNR at and above which no inflation applies, dB.
    fading_window_s : float
        Width of the window for the Rician K-factor, s (several beat periods
        of paths whose Dopplers differ by a few Hz).
    min_rician_k_db : float or None
        Epochs whose K-factor is below this have no range observation, dB;
        None keeps them all.
    max_snr_deficit_db : float or None
        Epochs whose SNR is this far below the recording's line-of-sight
        level (its ``los_snr_percentile`` percentile epoch SNR) have no range
        observation, dB; None keeps them all.
    los_snr_percentile : float
        Percentile of the epoch SNRs taken as the line-of-sight level.
    settle_s : float
        After an epoch without a range observation, the range comes back
        only once this long has passed with every epoch passing rules 3-6, s.
        A link that recovers for a moment inside a blocked stretch (a lucky
        beat of two reflections) still carries the stretch's range error.
    """

    window_s: float = 0.2
    min_valid_fraction: float = 0.5
    base_sigma_m: float = 0.25
    good_snr_db: float = 10.0
    fading_window_s: float = 2.0
    min_rician_k_db: float | None = 6.0
    max_snr_deficit_db: float | None = 5.0
    los_snr_percentile: float = 90.0
    settle_s: float = 3.0


@dataclass(frozen=True)
class PathAggregationConfig:
    """Parameters of the path channels' rule (module docstring, rules 1-5, 8, 9).

    Attributes
    ----------
    window_s, min_valid_fraction, base_sigma_m, good_snr_db : float
        As :class:`AggregationConfig`.
    min_path_age_s : float
        Epochs whose path is younger than this have no observation, s.
    path_settle_s : float
        Age scale of the sigma's inflation for young paths, s.
    """

    window_s: float = AggregationConfig.window_s
    min_valid_fraction: float = AggregationConfig.min_valid_fraction
    base_sigma_m: float = AggregationConfig.base_sigma_m
    good_snr_db: float = AggregationConfig.good_snr_db
    min_path_age_s: float = 0.5
    path_settle_s: float = 2.0


@dataclass(frozen=True)
class StandstillConfig:
    """Where the filters get epochs without a step (module section "Standstills").

    Attributes
    ----------
    min_gap_s : float
        A longer time between two steps (or before the first) means the
        walker stood still, s: the step detector's own bound.
    margin_s : float
        Standstill epochs keep this clear of the steps around them, s.
    epoch_s : float
        Spacing of the standstill epochs, s.
    """

    min_gap_s: float = StepDetectorConfig.max_step_s
    margin_s: float = 1.0
    epoch_s: float = 0.5


@dataclass
class PathEpochs(ColumnRecord):
    """Path observations at the filter epochs (columns as :class:`FilterEpochs`'s of the same names)."""

    t_s: np.ndarray
    first_path_range_m: np.ndarray
    first_path_sigma_m: np.ndarray
    first_path_new_origin: np.ndarray
    range_difference_m: np.ndarray
    range_difference_sigma_m: np.ndarray
    range_difference_new_origin: np.ndarray
    first_path_code_m: np.ndarray
    range_difference_code_m: np.ndarray
    range_difference_code_sigma_m: np.ndarray


@dataclass
class RangeEpochs(ColumnRecord):
    """Range observations at the filter epochs.

    Attributes
    ----------
    t_s : ndarray
        Epoch time, s.
    range_change_m : ndarray
        Range change since the capture start, m; NaN where dropped.
    sigma_m : ndarray
        Observation standard deviation, m; NaN where dropped.
    snr_db : ndarray
        Mean SNR of the valid frames, dB; NaN where none.
    rician_k_db : ndarray
        Rician K-factor of the link around the epoch, dB (module rule 6);
        NaN where too few valid frames.
    new_origin : ndarray of bool
        Epochs whose observation starts from a new origin (the first kept
        one after a change of segment, module rule 7).
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    sigma_m: np.ndarray
    snr_db: np.ndarray
    rician_k_db: np.ndarray
    new_origin: np.ndarray


@dataclass
class FilterEpochs(ColumnRecord):
    """Everything a filter consumes per epoch (one PDR step, or a moment of a standstill).

    Attributes
    ----------
    t_s : ndarray
        Epoch time, s.
    dt_s : ndarray
        Step duration as the PDR measured it (step length / speed), s; the
        process model moves by ``speed * dt_s``, so a pause between steps
        does not move the walker. 0 for an epoch without a step (a
        standstill, module section "Standstills").
    range_change_m, range_sigma_m : ndarray
        Range observation and its standard deviation, m (NaN: none).
    snr_db : ndarray
        Link SNR of the epoch, dB (NaN: none).
    pdr_heading_rad : ndarray
        PDR heading made absolute with the solved initial heading, rad (an
        epoch without a step holds the last step's).
    pdr_heading_increment_rad : ndarray
        PDR heading change since the previous step (0 for the first, and
        for an epoch without a step), rad.
    pdr_speed_mps : ndarray
        PDR speed, m/s (an epoch without a step holds the last step's).
    pdr_speed_ratio : ndarray
        PDR speed over the previous step's (1 for the first, and for an
        epoch without a step).
    interval_s : ndarray or None
        Time since the previous epoch, s (the first: its ``dt_s``); None
        fills it so.
    first_path_range_m, first_path_sigma_m : ndarray, shape (N, T) or None
        First-path range change to tower k (column k) and its standard
        deviation, m (NaN: none); None: no first-path observations (N, 0).
    first_path_new_origin : ndarray of bool, shape (N, T) or None
        Where column k restarts from a new origin.
    range_difference_m, range_difference_sigma_m, range_difference_new_origin : ndarray, shape (N, T - 1) or None
        The same for the difference of tower k and tower 0 (column k - 1).
    first_path_code_m : ndarray, shape (N, T) or None
        Code range of tower k's first path, m, up to a constant (NaN: none;
        :class:`dtmbnav_core.records.PathRangeSeries`), which the integrity
        monitor checks the first path against (:mod:`fusion.integrity`).
    range_difference_code_m : ndarray, shape (N, T - 1) or None
        Code range difference of tower k and tower 0 (column k - 1), m, with
        the towers' transmit delay offsets taken out as far as they are
        known (:mod:`fusion.transmit_delays`; NaN: none), on which the
        filters anchor the difference's origin
        (:meth:`fusion.model.EpochObservation.anchor_channels`).
    range_difference_code_sigma_m : ndarray, shape (N, T - 1) or None
        Standard deviation of the constant the offsets' uncertainty leaves in
        that code, m; ``inf`` where they are unknown (the code is not used).
    range_new_origin : ndarray of bool or None
        Where the range observation restarts from a new origin (a new
        segment, module rule 7); None: nowhere.
    """

    t_s: np.ndarray
    dt_s: np.ndarray
    range_change_m: np.ndarray
    range_sigma_m: np.ndarray
    snr_db: np.ndarray
    pdr_heading_rad: np.ndarray
    pdr_heading_increment_rad: np.ndarray
    pdr_speed_mps: np.ndarray
    pdr_speed_ratio: np.ndarray
    interval_s: np.ndarray | None = None
    first_path_range_m: np.ndarray | None = None
    first_path_sigma_m: np.ndarray | None = None
    first_path_new_origin: np.ndarray | None = None
    range_difference_m: np.ndarray | None = None
    range_difference_sigma_m: np.ndarray | None = None
    range_difference_new_origin: np.ndarray | None = None
    first_path_code_m: np.ndarray | None = None
    range_difference_code_m: np.ndarray | None = None
    range_difference_code_sigma_m: np.ndarray | None = None
    range_new_origin: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.t_s)
        if self.interval_s is None:
            self.interval_s = np.concatenate([np.asarray(self.dt_s[:1], dtype=np.float64), np.diff(self.t_s)])
        if self.range_new_origin is None:
            self.range_new_origin = np.zeros(n, dtype=bool)
        for name, fill in (("first_path_range_m", np.nan), ("first_path_sigma_m", np.nan),
                           ("first_path_new_origin", False), ("range_difference_m", np.nan),
                           ("range_difference_sigma_m", np.nan), ("range_difference_new_origin", False),
                           ("first_path_code_m", np.nan), ("range_difference_code_m", np.nan),
                           ("range_difference_code_sigma_m", np.inf)):
            if getattr(self, name) is None:
                setattr(self, name, np.full((n, 0), fill))
        super().__post_init__()

    @property
    def is_step(self) -> np.ndarray:
        """Which epochs are PDR steps (the others are standstill epochs)."""
        return np.asarray(self.dt_s) > 0.0

    def initial_heading_speed(self) -> tuple[float, float]:
        """PDR heading (rad) and speed (m/s) of the first step: the filters' initial state."""
        first = int(np.argmax(self.is_step))
        return float(self.pdr_heading_rad[first]), float(self.pdr_speed_mps[first])

    def control(self, n: int) -> StepControl:
        """The process-model control input of epoch ``n``."""
        return StepControl(float(self.dt_s[n]), float(self.pdr_heading_increment_rad[n]),
                           float(self.pdr_speed_ratio[n]), float(self.interval_s[n]))

    def observation(self, n: int) -> EpochObservation:
        """The observation record of epoch ``n`` (NaN where it has no range; no PDR observation without a step)."""
        step = bool(self.is_step[n])
        return EpochObservation(index=n, range_change_m=float(self.range_change_m[n]),
                                range_sigma_m=float(self.range_sigma_m[n]),
                                pdr_heading_rad=float(self.pdr_heading_rad[n]) if step else np.nan,
                                pdr_speed_mps=float(self.pdr_speed_mps[n]) if step else np.nan,
                                first_path_range_m=self.first_path_range_m[n],
                                first_path_sigma_m=self.first_path_sigma_m[n],
                                first_path_new_origin=self.first_path_new_origin[n],
                                range_difference_m=self.range_difference_m[n],
                                range_difference_sigma_m=self.range_difference_sigma_m[n],
                                range_difference_new_origin=self.range_difference_new_origin[n],
                                first_path_code_m=self.first_path_code_m[n],
                                range_difference_code_m=self.range_difference_code_m[n],
                                range_difference_code_sigma_m=self.range_difference_code_sigma_m[n],
                                range_new_origin=bool(self.range_new_origin[n]))


def _check_ranges(ranges: RangeSeries) -> None:
    if len(ranges) < 2:
        raise ValueError(f"ranges: need at least 2 receiver frames, got {len(ranges)}")
    if np.any(np.diff(ranges.t_s) <= 0):
        raise ValueError("ranges.t_s: frame times must increase strictly")


def _window_sums(t_s: np.ndarray, values: np.ndarray, centres: np.ndarray, width_s: float
                 ) -> tuple[np.ndarray, ...]:
    """Sums of each column of ``values`` over ``|t - centre| <= width_s / 2``, by prefix sums (no Python loop)."""
    lo = np.searchsorted(t_s, centres - width_s / 2.0, side="left")
    hi = np.searchsorted(t_s, centres + width_s / 2.0, side="right")
    cum = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    return tuple(cum[hi, j] - cum[lo, j] for j in range(values.shape[1]))


def snr_inflation(snr_db: np.ndarray, good_snr_db: float) -> np.ndarray:
    """Variance factor of module rule 5: ``max(1, 10^((good_snr_db - snr) / 10))``."""
    return np.maximum(1.0, 10.0 ** ((good_snr_db - np.asarray(snr_db, dtype=np.float64)) / 10.0))


def rician_k_db(t_s: np.ndarray, snr_db: np.ndarray, valid: np.ndarray, centres: np.ndarray,
                width_s: float) -> np.ndarray:
    """Moment estimate of the Rician K-factor of the link around each centre time (module rule 6), dB.

    Parameters
    ----------
    t_s, snr_db, valid : ndarray
        Per-frame time (s), SNR (dB) and validity; invalid frames are left out.
    centres : ndarray
        Window centres, s.
    width_s : float
        Window width, s.

    Returns
    -------
    ndarray
        K in dB: ``+inf`` for a steady link, ``-inf`` for Rayleigh fading or
        worse (``gamma >= 1``), NaN where the window holds fewer than 2 valid frames.
    """
    power = np.where(valid, 10.0 ** (np.asarray(snr_db, dtype=np.float64) / 10.0), 0.0)
    n, s1, s2 = _window_sums(t_s, np.stack([valid.astype(np.float64), power, power**2], axis=1), centres, width_s)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        gamma = np.maximum(s2 / n - mean**2, 0.0) / mean**2
        root = np.sqrt(np.clip(1.0 - gamma, 0.0, 1.0))
        k_db = 10.0 * np.log10(root / (1.0 - root))
    return np.where(n >= 2, k_db, np.nan)


def settled(t_s: np.ndarray, passing: np.ndarray, settle_s: float) -> np.ndarray:
    """``passing`` epochs that follow at least ``settle_s`` of passing epochs (the first run counts from the start).

    An epoch in a run of passing epochs is kept when the run began at least
    ``settle_s`` before it, where a run begins at the time of the failing epoch
    before it, or at the first epoch for a run that opens the record.
    """
    passing = np.asarray(passing, dtype=bool)
    if settle_s <= 0.0 or not len(passing):
        return passing
    failed_at = np.where(~passing, t_s, -np.inf)
    last_fail = np.maximum.accumulate(failed_at)
    since = np.where(np.isfinite(last_fail), t_s - last_fail, np.inf)
    return passing & (since >= settle_s)


def segment_breaks(ranges: RangeSeries) -> np.ndarray:
    """Frames that start a new segment: origin breaks of the range (module rule 7)."""
    segment = np.asarray(ranges.segment_id, dtype=np.int64)
    return np.concatenate([[False], np.diff(segment) != 0])


def segment_changes(ranges: RangeSeries, epoch_t_s: np.ndarray, window_s: float,
                    previous_segment: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Epochs whose window reaches into a new segment, or that follow a change of segment (module rule 7).

    The segment at the end of each epoch's window (of the last frame at or
    before it) is compared with the one at its start and with the previous
    epoch's: ``previous_segment`` for the first epoch (a stream's epoch before
    these, :mod:`fusion.streaming`), or its own where None.

    Returns
    -------
    changes : ndarray of bool
    at_end : ndarray of int
        The segment at the end of each epoch's window.
    """
    segment = np.asarray(ranges.segment_id, dtype=np.int64)
    last = len(segment) - 1
    at_start = segment[np.clip(np.searchsorted(ranges.t_s, epoch_t_s - window_s / 2.0, side="left"), 0, last)]
    at_end = segment[np.clip(np.searchsorted(ranges.t_s, epoch_t_s + window_s / 2.0, side="right") - 1, 0, last)]
    before = np.concatenate([at_end[:1] if previous_segment is None else [previous_segment], at_end[:-1]])
    return (at_start != at_end) | (at_end != before), at_end


def new_origins(t_s: np.ndarray, breaks: np.ndarray, epoch_t_s: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Kept epochs with an origin break since the previous kept epoch (or since the start) (module rules 7, 8).

    Parameters
    ----------
    t_s : ndarray
        Frame times, s.
    breaks : ndarray of bool
        Frames at which the series restarts from a new origin.
    epoch_t_s : ndarray
        Epoch times, s.
    keep : ndarray of bool
        Epochs that have an observation.
    """
    return origins_from_counts(origin_counts(t_s, breaks, epoch_t_s), keep)


def origin_counts(t_s: np.ndarray, breaks: np.ndarray, epoch_t_s: np.ndarray) -> np.ndarray:
    """Origin breaks at the frames up to each epoch time (0 before the first frame)."""
    counts = np.cumsum(breaks)[np.clip(np.searchsorted(t_s, epoch_t_s, side="right") - 1, 0, None)]
    return np.where(epoch_t_s < t_s[0], 0, counts)


def origins_from_counts(counts: np.ndarray, keep: np.ndarray, counted_before: int = 0) -> np.ndarray:
    """Kept epochs whose :func:`origin_counts` grew since the previous kept one (or since ``counted_before``)."""
    new_origin = np.zeros(len(counts), dtype=bool)
    new_origin[keep] = np.diff(counts[keep], prepend=counted_before) > 0
    return new_origin


@dataclass
class RangeWindows(ColumnRecord):
    """The module's rules 1-7 at the epoch times, before the line-of-sight cut (rule 5's deficit) and settling.

    Attributes
    ----------
    t_s : ndarray
        Epoch time, s.
    range_change_m, sigma_m : ndarray
        Mean range change of the window's valid frames and its standard deviation, m (NaN: no valid frame).
    snr_db, rician_k_db : ndarray
        As :class:`RangeEpochs` (NaN: none).
    passing : ndarray of bool
        Epochs that pass rules 3, 6 and 7.
    segment_at_end : ndarray of int
        The receiver segment at the end of each epoch's window (:func:`segment_changes`).
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    sigma_m: np.ndarray
    snr_db: np.ndarray
    rician_k_db: np.ndarray
    passing: np.ndarray
    segment_at_end: np.ndarray

    def epochs(self, keep: np.ndarray, new_origin: np.ndarray) -> RangeEpochs:
        """The :class:`RangeEpochs` that keep the ``keep`` epochs' observations."""
        nan = np.full(len(self.t_s), np.nan)
        return RangeEpochs(t_s=self.t_s, range_change_m=np.where(keep, self.range_change_m, nan),
                           sigma_m=np.where(keep, self.sigma_m, nan), snr_db=self.snr_db,
                           rician_k_db=self.rician_k_db, new_origin=new_origin)


def range_windows(ranges: RangeSeries, epoch_t_s: np.ndarray, config: AggregationConfig = AggregationConfig(),
                  previous_segment: int | None = None) -> RangeWindows:
    """Rules 1-7 of the module at each epoch time, each epoch from the frames of its own windows.

    ``previous_segment``: as :func:`segment_changes`.
    """
    _check_ranges(ranges)
    epoch_t_s = np.asarray(epoch_t_s, dtype=np.float64)
    valid = np.asarray(ranges.valid, dtype=bool) & np.isfinite(ranges.range_change_m)
    n_valid, range_sum, snr_lin_sum = _window_sums(
        ranges.t_s, np.stack([valid.astype(np.float64), np.where(valid, ranges.range_change_m, 0.0),
                              np.where(valid, 10.0 ** (ranges.snr_db / 10.0), 0.0)], axis=1),
        epoch_t_s, config.window_s)
    expected = config.window_s / np.median(np.diff(ranges.t_s))
    fraction = np.minimum(n_valid / expected, 1.0)
    k_db = rician_k_db(ranges.t_s, ranges.snr_db, valid, epoch_t_s, config.fading_window_s)
    changes, at_end = segment_changes(ranges, epoch_t_s, config.window_s, previous_segment)
    passing = (fraction >= config.min_valid_fraction) & (n_valid > 0) & ~changes
    if config.min_rician_k_db is not None:
        passing &= ~(k_db < config.min_rician_k_db)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_range = range_sum / n_valid
        snr_db = 10.0 * np.log10(snr_lin_sum / n_valid)
        sigma = config.base_sigma_m * np.sqrt(snr_inflation(snr_db, config.good_snr_db) / fraction)
    return RangeWindows(t_s=epoch_t_s, range_change_m=mean_range, sigma_m=sigma,
                        snr_db=np.where(n_valid > 0, snr_db, np.nan), rician_k_db=k_db, passing=passing,
                        segment_at_end=at_end)


def line_of_sight_snr_db(snr_db: np.ndarray, config: AggregationConfig = AggregationConfig()) -> float:
    """The line-of-sight SNR level of epoch SNRs: their ``los_snr_percentile`` percentile, dB (NaN: none)."""
    snr_db = np.asarray(snr_db, dtype=np.float64)
    if not np.any(np.isfinite(snr_db)):
        return float("nan")
    return float(np.nanpercentile(snr_db, config.los_snr_percentile))


def snr_deficit_passes(snr_db: np.ndarray, los_snr_db: float | np.ndarray,
                       config: AggregationConfig = AggregationConfig()) -> np.ndarray:
    """Epochs whose SNR is not ``max_snr_deficit_db`` below the line-of-sight level (module rule 5; NaN passes)."""
    snr_db = np.asarray(snr_db, dtype=np.float64)
    if config.max_snr_deficit_db is None:
        return np.ones(len(snr_db), dtype=bool)
    return ~(snr_db < np.asarray(los_snr_db) - config.max_snr_deficit_db)


def aggregate_ranges(ranges: RangeSeries, epoch_t_s: np.ndarray,
                     config: AggregationConfig = AggregationConfig()) -> RangeEpochs:
    """Apply the module's aggregation rule at each epoch time.

    The line-of-sight SNR level is the whole recording's (a stream takes the
    epochs' so far: :mod:`fusion.streaming`).

    Parameters
    ----------
    ranges : RangeSeries
        Receiver output, one row per frame.
    epoch_t_s : ndarray
        Epoch (step) times, s.
    config : AggregationConfig

    Returns
    -------
    RangeEpochs
    """
    windows = range_windows(ranges, epoch_t_s, config)
    keep = windows.passing & snr_deficit_passes(windows.snr_db, line_of_sight_snr_db(windows.snr_db, config), config)
    keep = settled(windows.t_s, keep, config.settle_s)
    return windows.epochs(keep, new_origins(ranges.t_s, segment_breaks(ranges), windows.t_s, keep))


def aggregate_path(series: PathRangeSeries, epoch_t_s: np.ndarray,
                   config: PathAggregationConfig = PathAggregationConfig()) -> tuple[np.ndarray, ...]:
    """One path channel at the epoch times (module docstring, rules 1-5, 8, 9).

    Returns
    -------
    range_change_m, sigma_m : ndarray
        Observation and its standard deviation, m (NaN: none).
    new_origin : ndarray of bool
        Epochs whose observation starts from a new origin.
    code_range_m : ndarray
        Mean code range of the window's valid frames that have one, m (NaN:
        too few, as rule 3; not subject to rules 8 and 9: an origin break of
        the carrier leaves the code's constant as it was).
    """
    _check_ranges(series)
    epoch_t_s = np.asarray(epoch_t_s, dtype=np.float64)
    age = np.asarray(series.path_age_s, dtype=np.float64)
    slip = np.asarray(series.slip, dtype=bool)
    breaks = slip | np.concatenate([[False], np.diff(age) < 0])
    valid = np.asarray(series.valid, dtype=bool) & np.isfinite(series.range_change_m) & ~slip
    coded = np.asarray(series.valid, dtype=bool) & np.isfinite(series.code_range_m)
    n_valid, range_sum, snr_lin_sum, age_sum, n_breaks, n_coded, code_sum = _window_sums(
        series.t_s, np.stack([valid.astype(np.float64), np.where(valid, series.range_change_m, 0.0),
                              np.where(valid, 10.0 ** (series.snr_db / 10.0), 0.0), np.where(valid, age, 0.0),
                              breaks.astype(np.float64), coded.astype(np.float64),
                              np.where(coded, series.code_range_m, 0.0)], axis=1), epoch_t_s, config.window_s)
    expected = config.window_s / np.median(np.diff(series.t_s))
    fraction = np.minimum(n_valid / expected, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_range = range_sum / n_valid
        mean_age = age_sum / n_valid
        sigma = config.base_sigma_m * np.sqrt(snr_inflation(10.0 * np.log10(snr_lin_sum / n_valid), config.good_snr_db)
                                              / fraction * (1.0 + config.path_settle_s / mean_age))
    keep = ((fraction >= config.min_valid_fraction) & (n_valid > 0) & (n_breaks == 0)
            & (mean_age >= config.min_path_age_s))
    nan = np.full(len(epoch_t_s), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        code = np.where((n_coded > 0) & (n_coded >= config.min_valid_fraction * expected), code_sum / n_coded, nan)
    return (np.where(keep, mean_range, nan), np.where(keep, sigma, nan),
            new_origins(series.t_s, breaks, epoch_t_s, keep), code)


def aggregate_paths(paths: PathRanges, epoch_t_s: np.ndarray, n_towers: int,
                    config: PathAggregationConfig = PathAggregationConfig()) -> PathEpochs:
    """Every path channel of a recording at the epoch times (:func:`aggregate_path`).

    Raises
    ------
    ValueError
        For a tower index outside the geometry's ``n_towers``.
    """
    epoch_t_s = np.asarray(epoch_t_s, dtype=np.float64)
    n = len(epoch_t_s)

    def columns(series: dict[int, PathRangeSeries], first: int, count: int, what: str) -> list[np.ndarray]:
        out = [np.full((n, count), np.nan), np.full((n, count), np.nan), np.zeros((n, count), dtype=bool),
               np.full((n, count), np.nan)]
        for k, one in series.items():
            if not first <= k < first + count:
                raise ValueError(f"paths.{what}: tower {k} outside {first}..{first + count - 1}")
            for column, values in zip(out, aggregate_path(one, epoch_t_s, config)):
                column[:, k - first] = values
        return out

    first_path = columns(paths.first_path, 0, n_towers, "first_path")
    differences = columns(paths.differences, 1, n_towers - 1, "differences")
    # The differences' codes still hold the towers' transmit delay offsets: unknown until
    # fusion.transmit_delays.tie_code_differences takes them out.
    return PathEpochs(epoch_t_s, *first_path[:3], *differences[:3], first_path_code_m=first_path[3],
                      range_difference_code_m=differences[3],
                      range_difference_code_sigma_m=np.full_like(differences[3], np.inf))


def standstill_times(step_t_s: np.ndarray, start_t_s: float,
                     config: StandstillConfig = StandstillConfig()) -> np.ndarray:
    """Times of the epochs without a step (module section "Standstills"), s.

    Parameters
    ----------
    step_t_s : ndarray
        PDR step times, s.
    start_t_s : float
        Start of the recording (of the receiver's range), s: the first
        standstill runs from there to the first step.
    config : StandstillConfig
    """
    step_t_s = np.asarray(step_t_s, dtype=np.float64)
    before = np.concatenate([[start_t_s], step_t_s[:-1]])
    times = [np.arange(a + config.margin_s, b - config.margin_s + 1e-9, config.epoch_s)
             for a, b in zip(before, step_t_s) if b - a > config.min_gap_s]
    return np.concatenate(times) if times else np.empty(0)


def epoch_times(step_t_s: np.ndarray, start_t_s: float, config: StandstillConfig | None = StandstillConfig()
                ) -> np.ndarray:
    """The filter epochs: the step times and, unless ``config`` is None, the standstill epochs, in order, s."""
    still = np.empty(0) if config is None else standstill_times(step_t_s, start_t_s, config)
    return np.sort(np.concatenate([np.asarray(step_t_s, dtype=np.float64), still]))


def step_durations_s(pdr: PdrSteps) -> np.ndarray:
    """Duration of each step as the PDR measured it: length / speed, s."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = pdr.step_length_m / pdr.speed_mps
    bad = ~np.isfinite(dt) | (dt <= 0)
    if np.any(bad):
        # A zero-speed step carries no displacement; fall back on the time gap.
        gaps = np.diff(pdr.t_s, prepend=pdr.t_s[0] - np.median(np.diff(pdr.t_s)))
        dt = np.where(bad, gaps, dt)
    return dt


def si_range_epochs(range_epochs: RangeEpochs, paths: PathEpochs | None, use: str) -> RangeEpochs:
    """The SI-carrier range epochs the filters take.

    Parameters
    ----------
    range_epochs : RangeEpochs
        :func:`aggregate_ranges`.
    paths : PathEpochs or None
        :func:`aggregate_paths` at the same epochs (None: no path tracker).
    use : {"always", "without-first-path"}
        ``"without-first-path"`` drops the SI range at every epoch where some
        tower's first path is observed (``fusion.SI_RANGE_USES``).

    Returns
    -------
    RangeEpochs
        ``range_epochs`` itself, or a copy with those epochs' range and sigma
        NaN; a new origin among them moves to the next epoch kept.
    """
    if use not in SI_RANGE_USES:
        raise ValueError(f"si range use {use!r}: expected one of {', '.join(SI_RANGE_USES)}")
    if use == "always" or paths is None:
        return range_epochs
    first_path = np.isfinite(paths.first_path_range_m).any(axis=1)
    kept = np.isfinite(range_epochs.range_change_m) & ~first_path
    t_s = range_epochs.t_s
    nan = np.float64(np.nan)
    return replace(range_epochs, range_change_m=np.where(first_path, nan, range_epochs.range_change_m),
                   sigma_m=np.where(first_path, nan, range_epochs.sigma_m),
                   new_origin=new_origins(t_s, range_epochs.new_origin, t_s, kept))


def build_epochs(pdr: PdrSteps, range_epochs: RangeEpochs, initial_heading_rad: float,
                 paths: PathEpochs | None = None) -> FilterEpochs:
    """Filter epochs at the PDR step times and any standstill epochs between them.

    Parameters
    ----------
    pdr : PdrSteps
        PDR output (relative heading).
    range_epochs : RangeEpochs
        :func:`aggregate_ranges` at the epoch times: ``pdr.t_s``, or
        :func:`epoch_times` (the steps and the standstill epochs).
    initial_heading_rad : float
        Solved initial heading (fusion.heading_init), added to the PDR's
        relative heading.
    paths : PathEpochs, optional
        :func:`aggregate_paths` at the same epoch times.

    Returns
    -------
    FilterEpochs
    """
    if len(pdr) < 2:
        raise ValueError(f"pdr: need at least 2 steps, got {len(pdr)}")
    t_s = np.asarray(range_epochs.t_s, dtype=np.float64)
    step = np.clip(np.searchsorted(t_s, pdr.t_s), 0, len(t_s) - 1)
    if not np.array_equal(t_s[step], pdr.t_s) or np.any(np.diff(t_s) <= 0):
        raise ValueError("range_epochs: not aggregated at the PDR step times (and standstill epochs)")
    if paths is not None and not np.array_equal(paths.t_s, t_s):
        raise ValueError("paths: not aggregated at the epoch times of range_epochs")
    heading = np.asarray(pdr.heading_rad, dtype=np.float64)
    speed = np.asarray(pdr.speed_mps, dtype=np.float64)
    if np.any(~np.isfinite(speed) | (speed <= 0)):
        raise ValueError("pdr.speed_mps: every step needs a finite positive speed")
    # Each epoch holds the PDR values of the latest step (the first step's before it); only steps move.
    latest = np.clip(np.searchsorted(pdr.t_s, t_s, side="right") - 1, 0, None)

    def at_steps(values: np.ndarray, elsewhere: float) -> np.ndarray:
        out = np.full(len(t_s), elsewhere)
        out[step] = values
        return out

    return FilterEpochs(
        t_s=t_s,
        dt_s=at_steps(step_durations_s(pdr), 0.0),
        range_change_m=range_epochs.range_change_m,
        range_sigma_m=range_epochs.sigma_m,
        range_new_origin=range_epochs.new_origin,
        snr_db=range_epochs.snr_db,
        pdr_heading_rad=heading[latest] + initial_heading_rad,
        pdr_heading_increment_rad=at_steps(np.asarray(wrap_angle(np.diff(heading, prepend=heading[0]))), 0.0),
        pdr_speed_mps=speed[latest],
        pdr_speed_ratio=at_steps(np.concatenate([[1.0], speed[1:] / speed[:-1]]), 1.0),
        **({} if paths is None else {k: v for k, v in paths.columns().items() if k != "t_s"}),
    )
