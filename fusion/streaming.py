"""Streaming fusion: PDR steps and receiver ranges fed as they come, positions with their stated error out.

:class:`StreamingFusion` takes what :func:`fusion.run.fuse` takes and is then
fed settled PDR steps (:meth:`~StreamingFusion.add_steps`) and receiver range
frames (:meth:`~StreamingFusion.add_ranges`) in chunks, on one clock (the
caller aligns them). It runs the batch path's own pieces in the same order:

1. **Epochs.** Each step is an epoch (with a free-running clock, the
   standstill epochs between two steps too, once the second arrives:
   :func:`fusion.observations.standstill_times` sees only the two). An epoch
   is complete once the range frames reach past every window it is
   aggregated over (``max(window_s, fading_window_s) / 2`` after it); it is
   then aggregated by :func:`fusion.observations.range_windows` on the
   trailing frame buffer, with the state the batch rule carries across
   epochs (the previous epoch's segment, the last failing epoch for
   ``settle_s``, the origin-break count) kept here. The one rule that looks
   at the whole recording, the line-of-sight SNR level (rule 5's deficit),
   takes the epochs up to each one instead: the only place where the
   streamed epochs can differ from the batch's.
2. **Heading.** Eq. 14-15 is solved with the batch's rule
   (:func:`fusion.run.initial_heading`): over the first
   :data:`fusion.heading_init.HEADING_WINDOW_S` of steps, once they are all
   complete, doubling the window while the confidence stays below
   :data:`fusion.heading_init.MIN_CONFIDENCE`. So the filters start from the
   heading the batch starts from (given the same epochs). Until then each
   step is given as the PDR from the start fix rotated by the best heading
   so far (eq. 15 over all complete epochs, re-solved every
   :data:`PROVISIONAL_SOLVE_S` or :data:`PROVISIONAL_SOLVE_FRACTION` of the
   walk so far, whichever is longer), with a covariance that holds that heading's
   uncertainty (:func:`provisional_covariance_m2`), flagged unfiltered.
3. **Filters.** Once the heading is confident the filters start at P0, run
   the buffered epochs (their rows are given again, filtered: a row
   supersedes an earlier one of the same time), then step with each epoch
   as it completes.
4. **Now-cast.** Settled steps come seconds after their samples, so
   :meth:`~StreamingFusion.nowcast` carries the live position on to the
   PDR's provisional steps (those it found after its last settled one, which
   may still change or vanish): from the live filter's latest estimate along
   their displacement, turned by the filter's heading and scaled by its
   speed, with a covariance that adds the displacement's uncertainty
   (before the heading is confident, the provisional stage's rule on them).
   Its rows never enter the filters; each call's rows replace the previous
   call's, and the settled rows supersede them.

Only the filters that need nothing of the epochs ahead run here
(:data:`STREAMING_FILTERS`): the WT-UKF and the adaptive EKF read their
whole epoch history when they are built. Path ranges (first paths, tower
differences) are not streamed: the SI-carrier range is, so the streamed
track compares with :func:`fusion.run.fuse` without ``paths``.

Memory: the range frames are kept only over the trailing window the next
epochs need (bounded by ``step_lag_s``); steps, epochs and track rows grow
with the walk's steps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dtmbnav_core.records import FusedTrack, PdrSteps, RangeSeries
from fusion import STREAMING_FILTERS
from fusion.driver import FusionFilter, step_filter, step_track
from fusion.heading_init import HEADING_WINDOW_S, MIN_CONFIDENCE, HeadingSolution, rotate_pdr
from fusion.model import HEADING, SPEED, STATE_SIZE, Geometry, X, Y, wrap_angle
from fusion.observations import (
    RangeEpochs,
    build_epochs,
    line_of_sight_snr_db,
    origin_counts,
    origins_from_counts,
    range_windows,
    segment_breaks,
    settled,
    snr_deficit_passes,
    standstill_times,
)
from fusion.run import FILTER_BUILDERS, FusionConfig, FusionResult, initial_heading, with_heading_spread

#: How often the provisional heading (eq. 15 over all complete epochs) is re-solved, s of walk, at the least:
#: each solve costs a grid search and a refinement of every local minimum, and the heading moves little between
#: solves.
PROVISIONAL_SOLVE_S = 5.0

#: ... and at the least this fraction of the walk so far apart: a solve costs in proportion to the epochs, so
#: the solves of a heading that stays unconfident (a long straight start) cost a bounded CPU per second of walk
#: instead of one growing with the walk, while the first minute's solves stay 5 s apart.
PROVISIONAL_SOLVE_FRACTION = 0.25

#: The PDR's distance error the provisional positions state, as a fraction of the distance walked (1 sigma):
#: the step-length gain errors eq. 15's scale bounds allow for (0.8-1.25) at about two sigma.
PROVISIONAL_DISTANCE_SIGMA = 0.1

#: How far a settled step may trail the newest range frame, s: the range frames are kept that long back for
#: the epochs of steps still to come (a step later than that finds its window's frames gone).
DEFAULT_STEP_LAG_S = 30.0


@dataclass
class LivePositions(FusedTrack):
    """Positions given since the last poll: a :class:`FusedTrack` (ENU m, its stated covariance) and a stage.

    A row at a time given before supersedes the earlier one (the filters'
    rows for the epochs buffered while the heading was not yet confident).

    Attributes
    ----------
    filtered : ndarray of bool
        True: from the live filter's estimate; False: the heading is not yet
        confident, the row is the PDR from the start fix rotated by the best
        heading so far, with that heading's uncertainty in its covariance.
    nowcast : ndarray of bool
        True: a now-cast row (:meth:`StreamingFusion.nowcast`) at a
        provisional PDR step, carried on from the filter's estimate
        (``filtered``) or from the provisional stage; it never enters the
        filters and is superseded by the settled step's row.
    """

    filtered: np.ndarray
    nowcast: np.ndarray

    @classmethod
    def empty(cls) -> LivePositions:
        """No rows."""
        return cls.of(FusedTrack(*(np.empty(0) for _ in range(8))), filtered=False, nowcast=False)

    @classmethod
    def of(cls, track: FusedTrack, *, filtered: bool, nowcast: bool) -> LivePositions:
        """The rows of ``track``, all of one stage."""
        n = len(track)
        return cls(**track.columns(), filtered=np.full(n, filtered), nowcast=np.full(n, nowcast))


#: The position error a held row adds for a step the PDR may not have seen yet, m (1 sigma per axis): about
#: one step, the most a walker can have moved within the step detector's look-ahead of the newest sample.
HOLD_STEP_SIGMA_M = 0.7


def hold_position(last: LivePositions, t_s: float) -> LivePositions:
    """``last``'s final row carried to ``t_s`` unmoved: the answer at the newest sample when no step followed it.

    Where the PDR has found no step since the last position (the walker stands, or a step is still within
    the detector's look-ahead), the position now is that one, with :data:`HOLD_STEP_SIGMA_M` added on both
    axes for the step that may be under way. The row is flagged ``nowcast`` (it never enters the filters).
    """
    row = last.select(slice(len(last) - 1, len(last)))
    extra = HOLD_STEP_SIGMA_M**2
    return LivePositions(t_s=np.array([float(t_s)]), x_m=row.x_m, y_m=row.y_m, heading_rad=row.heading_rad,
                         speed_mps=np.zeros(1), var_x_m2=row.var_x_m2 + extra, var_y_m2=row.var_y_m2 + extra,
                         cov_xy_m2=row.cov_xy_m2, filtered=row.filtered, nowcast=np.ones(1, dtype=bool))


def provisional_covariance_m2(dx_m: np.ndarray, dy_m: np.ndarray, heading_sigma_rad: np.ndarray | float,
                              start_sigma_m: float) -> np.ndarray:
    """East/north covariance (N x 2 x 2, m^2) of the start fix plus a PDR displacement turned by an uncertain heading.

    The displacement ``d`` (ENU, already rotated by the estimate) is turned by
    an error ``delta ~ N(0, sigma^2)``; the mean square of the moved point
    about the estimate is ``|d|^2 E[(1 - cos delta)^2]`` along ``d`` and
    ``|d|^2 E[sin^2 delta]`` across it (exact for a Gaussian ``delta``, so a
    heading known only to within its mirror, sigma near pi, still states an
    error that holds), plus :data:`PROVISIONAL_DISTANCE_SIGMA` of ``|d|``
    along it and the start fix's ``start_sigma_m`` on both axes.
    """
    dx_m, dy_m = np.asarray(dx_m, dtype=np.float64), np.asarray(dy_m, dtype=np.float64)
    s2 = np.asarray(heading_sigma_rad, dtype=np.float64) ** 2
    d2 = dx_m**2 + dy_m**2
    along = d2 * (1.0 - 2.0 * np.exp(-s2 / 2.0) + 0.5 * (1.0 + np.exp(-2.0 * s2))
                  + PROVISIONAL_DISTANCE_SIGMA**2)
    across = d2 * 0.5 * (1.0 - np.exp(-2.0 * s2))
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(d2)
        u = np.where(d[..., None] > 0, np.stack([dx_m, dy_m], axis=-1) / d[..., None], [1.0, 0.0])
    v = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    return (start_sigma_m**2 * np.eye(2) + along[..., None, None] * u[..., :, None] * u[..., None, :]
            + across[..., None, None] * v[..., :, None] * v[..., None, :])


def provisional_sigma_rad(heading: HeadingSolution | None) -> float:
    """The heading uncertainty a provisional position states: eq. 15's sigma, widened to the runner-up minimum
    while that is nearly as good (its confidence below :data:`MIN_CONFIDENCE`); pi without a solution."""
    if heading is None:
        return float(np.pi)
    sigma = heading.sigma_rad
    if heading.confidence < MIN_CONFIDENCE and len(heading.minima_rad) > 1:
        sigma = float(np.hypot(sigma, wrap_angle(heading.minima_rad[1] - heading.minima_rad[0])))
    return float(min(sigma, np.pi))


def _check_increasing(t_s: np.ndarray, taken, what: str) -> None:
    """ValueError unless ``t_s`` increases, past the last time of the record ``taken`` (None: nothing yet)."""
    t = np.asarray(t_s, dtype=np.float64)
    last = -np.inf if taken is None else float(taken.t_s[-1])
    if np.any(np.diff(t) <= 0) or t[0] <= last:
        raise ValueError(f"{what} must increase past {last} s")


def _concat(first, second):
    """Two column records of one type, one after the other (``first`` None: ``second``)."""
    return second if first is None else type(first).concatenate([first, second])


class StreamingFusion:
    """Fuse PDR steps and receiver ranges as they arrive (module docstring).

    Parameters
    ----------
    start_xy_m, tower_xy_m, filters, tower_height_m, other_towers, start_sigma_m, config
        As :func:`fusion.run.fuse` (``filters`` from :data:`STREAMING_FILTERS`).
    live_filter : str, optional
        The filter whose rows :meth:`poll` gives; None: the first of ``filters``.
    step_lag_s : float
        How far a settled step may trail the newest range frame, s (:data:`DEFAULT_STEP_LAG_S`).

    Raises
    ------
    ValueError
        For a filter that cannot stream, a bad start sigma or ``live_filter`` not among ``filters``.
    """

    def __init__(self, start_xy_m: tuple[float, float], tower_xy_m: tuple[float, float],
                 filters: tuple[str, ...] = STREAMING_FILTERS, *, tower_height_m: float = 0.0,
                 other_towers: tuple[tuple[float, float, float], ...] = (), start_sigma_m: float | None = None,
                 config: FusionConfig = FusionConfig(), live_filter: str | None = None,
                 step_lag_s: float = DEFAULT_STEP_LAG_S) -> None:
        unknown = [f for f in filters if f not in STREAMING_FILTERS]
        if unknown or not filters:
            raise ValueError(f"StreamingFusion: filter(s) {unknown or filters} cannot stream; "
                             f"streamable: {', '.join(STREAMING_FILTERS)}")
        if start_sigma_m is not None:
            if not (np.isfinite(start_sigma_m) and start_sigma_m > 0):
                raise ValueError(f"StreamingFusion: the start fix's sigma must be positive and finite, "
                                 f"got {start_sigma_m}")
            config = replace(config, noise=replace(config.noise, initial_position_m=float(start_sigma_m)))
        self.live_filter = filters[0] if live_filter is None else live_filter
        if self.live_filter not in filters:
            raise ValueError(f"StreamingFusion: live_filter {self.live_filter!r} not among {filters}")
        self.filters = tuple(filters)
        self.config = config
        self.start_xy_m = (float(start_xy_m[0]), float(start_xy_m[1]))
        self.geometry = Geometry(start_xy_m[0], start_xy_m[1], tower_xy_m[0], tower_xy_m[1], tower_height_m,
                                 other_towers)
        self.step_lag_s = step_lag_s
        agg = config.aggregation
        #: How far past an epoch its windows reach, s: it is complete once the frames get there.
        self.reach_s = max(agg.window_s, agg.fading_window_s) / 2.0
        self._standstills = config.standstills if config.clock().free_running else None
        # Inputs: all steps; the trailing range frames, with the origin breaks counted before them.
        self._pdr: PdrSteps | None = None
        self._frames: RangeSeries | None = None
        self._range_start_s: float | None = None
        self._breaks_before_frames = 0
        # Epochs: scheduled (steps seen) and complete (aggregated), with the batch rule's running state.
        self._scheduled_steps = 0
        self._pending_s = np.empty(0)
        self._epochs: RangeEpochs | None = None
        self._snr_history: list[float] = []
        self._previous_segment: int | None = None
        self._last_fail_s: float | None = None
        self._last_kept_count = 0
        # Heading and filters.
        self._window_s = HEADING_WINDOW_S
        self.heading: HeadingSolution | None = None
        self._provisional: HeadingSolution | None = None
        self._provisional_at_s = -np.inf
        self._filters: dict[str, FusionFilter] = {}
        self._tracks: dict[str, list[FusedTrack]] = {name: [] for name in self.filters}
        self._run_epochs = 0
        self._out: list[LivePositions] = []
        self._finished = False

    # ---------------------------------------------------------------- input

    def add_steps(self, steps: PdrSteps) -> None:
        """Take settled PDR steps (PDR frame, continuing the earlier ones; times on the range's clock).

        Raises
        ------
        ValueError
            If their times do not increase past the steps already taken (nothing is taken then).
        """
        self._check_open()
        if not len(steps):
            return
        _check_increasing(steps.t_s, self._pdr, "add_steps: step times")
        self._pdr = _concat(self._pdr, steps)
        self._schedule()
        if self.heading is None:
            self._provisional_rows(len(self._pdr) - len(steps))
        self._advance()

    def add_ranges(self, ranges: RangeSeries) -> None:
        """Take receiver range frames (continuing the earlier ones, on the PDR's clock).

        Raises
        ------
        ValueError
            If their times do not increase past the frames already taken (nothing is taken then).
        """
        self._check_open()
        if not len(ranges):
            return
        _check_increasing(ranges.t_s, self._frames, "add_ranges: frame times")
        if self._range_start_s is None:
            self._range_start_s = float(ranges.t_s[0])
        self._frames = _concat(self._frames, ranges)
        self._schedule()
        self._advance()
        self._trim()

    def poll(self) -> LivePositions:
        """The live filter's positions (or the provisional ones) given since the last poll, in the order given."""
        out = self._out
        self._out = []
        return LivePositions.empty() if not out else LivePositions.concatenate(out)

    def nowcast(self, provisional: PdrSteps) -> LivePositions:
        """Positions at the PDR's provisional steps, carried on from the latest estimate (module docstring, 4).

        Once the heading is confident each row is the live filter's estimate
        at its last epoch plus the PDR's displacement from that epoch's step to
        the provisional one (the settled steps the filter has not run yet
        included), turned into ENU by the filter's heading less the PDR's
        relative heading at that step (the solved initial heading and the
        offset the filter has found since) and scaled by the filter's speed
        over the PDR's there (the step-length gain the range has found). The
        filter's heading rate is left out: over the seconds a now-cast spans
        it turns the path by far less than the heading's sigma. Covariance:
        the filter's position covariance plus
        :func:`provisional_covariance_m2` of the displacement, with the
        filter's heading sigma (the PF's particles' weighted one, a Kalman
        filter's ``P``) grown by ``config.heading_drift_radps`` over the time
        since the epoch. Before, the provisional stage's rows for the steps.

        The filter is only read (its estimate and covariances, no copy); the
        rows never enter the filters. They are flagged ``nowcast``; a later
        call's rows replace them (a provisional step may move or vanish), and
        the settled step's row supersedes them.

        Parameters
        ----------
        provisional : PdrSteps
            The steps after the last settled one (PDR frame, positions
            continuing from it; times on the range's clock, increasing).

        Returns
        -------
        LivePositions
            One row per provisional step (none for none).

        Raises
        ------
        ValueError
            If their times do not increase past the last settled step's, or after :meth:`finish`.
        """
        self._check_open()
        if not len(provisional):
            return LivePositions.empty()
        t = np.asarray(provisional.t_s, dtype=np.float64)
        last = -np.inf if self._pdr is None else float(self._pdr.t_s[-1])
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0) or t[0] <= last:
            raise ValueError(f"nowcast: provisional step times must increase past the last settled step ({last} s)")
        if self.heading is None:
            return LivePositions.of(self._provisional_track(provisional), filtered=False, nowcast=True)
        live = self._filters[self.live_filter]
        state = live.estimate()
        epoch_s = float(self._epochs.t_s[self._run_epochs - 1])
        k = int(np.searchsorted(self._pdr.t_s, epoch_s, "right")) - 1   # the step the filter's last epoch holds
        turn = float(state[HEADING]) - float(self._pdr.heading_rad[k])
        scale = float(state[SPEED]) / float(self._pdr.speed_mps[k])
        dx, dy = rotate_pdr(np.asarray(provisional.x_m) - float(self._pdr.x_m[k]),
                            np.asarray(provisional.y_m) - float(self._pdr.y_m[k]), turn)
        dx, dy = scale * dx, scale * dy
        sigma = np.hypot(np.sqrt(_heading_variance_rad2(live)), self.config.heading_drift_radps * (t - epoch_s))
        cov = live.position_covariance_m2() + provisional_covariance_m2(dx, dy, np.minimum(sigma, np.pi), 0.0)
        track = FusedTrack(t_s=t, x_m=float(state[X]) + dx, y_m=float(state[Y]) + dy,
                           heading_rad=(np.asarray(provisional.heading_rad) + turn) % (2.0 * np.pi),
                           speed_mps=scale * np.asarray(provisional.speed_mps, dtype=np.float64),
                           var_x_m2=cov[:, 0, 0], var_y_m2=cov[:, 1, 1], cov_xy_m2=cov[:, 0, 1])
        return LivePositions.of(track, filtered=True, nowcast=True)

    def finish(self) -> FusionResult:
        """Aggregate what is left, start the filters if the heading never got confident, and give the tracks.

        The heading is then the batch's for this walk (the whole walk's eq. 15
        where no window was confident); :meth:`poll` gives any rows left.

        Raises
        ------
        ValueError
            As :func:`fusion.run.fuse`: fewer than 2 steps, or a range that
            constrains no heading over the whole walk.
        """
        self._check_open()
        self._advance(flush=True)
        if self._pdr is None or len(self._pdr) < 2 or self._epochs is None:
            raise ValueError("StreamingFusion.finish: need at least 2 steps and some range frames")
        if self.heading is None:
            # The batch's own search from the first window not yet ruled out, over the whole walk.
            self._start_filters(self._solve(len(self._pdr), self._window_s))
            self._run_filters()
        self._finished = True
        epochs = build_epochs(self._pdr, self._epochs, self.heading.heading_rad)
        tracks = {name: FusedTrack.concatenate(rows) for name, rows in self._tracks.items()}
        smoothed = {}
        if self.config.smooth:
            for name, fusion_filter in self._filters.items():
                states, covariances = fusion_filter.smoothed()
                smoothed[name] = step_track(epochs, states[:, :STATE_SIZE], covariances)
        return FusionResult(tracks=tracks, heading=self.heading, epochs=epochs, start_xy_m=self.start_xy_m,
                            smoothed=smoothed)

    @property
    def buffered_frames(self) -> int:
        """Range frames held now (the trailing window the next epochs need)."""
        return 0 if self._frames is None else len(self._frames)

    # ---------------------------------------------------------------- epochs

    def _check_open(self) -> None:
        if self._finished:
            raise ValueError("StreamingFusion: already finished")

    def _schedule(self) -> None:
        """Epoch times for the steps not yet scheduled (and the standstills before them)."""
        if self._pdr is None or self._range_start_s is None or self._scheduled_steps == len(self._pdr):
            return
        steps = np.asarray(self._pdr.t_s[self._scheduled_steps:], dtype=np.float64)
        times = [steps]
        if self._standstills is not None:
            before = (self._range_start_s if self._scheduled_steps == 0
                      else float(self._pdr.t_s[self._scheduled_steps - 1]))
            times.append(standstill_times(steps, before, self._standstills))
        self._pending_s = np.concatenate([self._pending_s, np.sort(np.concatenate(times))])
        self._scheduled_steps = len(self._pdr)

    def _advance(self, flush: bool = False) -> None:
        """Aggregate the epochs now complete (all scheduled ones with ``flush``), then heading and filters."""
        if self._frames is None or len(self._frames) < 2 or not len(self._pending_s):
            return
        n = len(self._pending_s) if flush else int(np.searchsorted(self._pending_s,
                                                                     self._frames.t_s[-1] - self.reach_s, "right"))
        if n == 0:
            return
        t, self._pending_s = self._pending_s[:n], self._pending_s[n:]
        self._epochs = _concat(self._epochs, self._aggregate(t))
        if self.heading is None and not flush:
            self._try_heading()
        if self.heading is not None:
            self._run_filters()

    def _aggregate(self, t: np.ndarray) -> RangeEpochs:
        """The batch rule (:func:`fusion.observations.aggregate_ranges`) at ``t`` with the stream's state."""
        agg = self.config.aggregation
        frames = self._frames
        windows = range_windows(frames, t, agg, self._previous_segment)
        # Rule 5's line-of-sight level: the percentile of the epochs' SNRs up to each one.
        los = np.empty(len(t))
        for i, snr in enumerate(windows.snr_db):
            self._snr_history.append(float(snr))
            los[i] = line_of_sight_snr_db(np.asarray(self._snr_history), agg)
        passing = windows.passing & snr_deficit_passes(windows.snr_db, los, agg)
        if self._last_fail_s is None:
            keep = settled(t, passing, agg.settle_s)
        else:  # the last failing epoch before these, as the batch rule sees it
            keep = settled(np.concatenate([[self._last_fail_s], t]), np.concatenate([[False], passing]),
                           agg.settle_s)[1:]
        if not passing.all():
            self._last_fail_s = float(t[~passing][-1])
        counts = self._breaks_before_frames + origin_counts(frames.t_s, segment_breaks(frames), t)
        new_origin = origins_from_counts(counts, keep, self._last_kept_count)
        if keep.any():
            self._last_kept_count = int(counts[keep][-1])
        self._previous_segment = int(windows.segment_at_end[-1])
        return windows.epochs(keep, new_origin)

    def _trim(self) -> None:
        """Drop the range frames no epoch to come needs (keeping the origin-break count)."""
        frames = self._frames
        newest = float(frames.t_s[-1])
        # Epochs to come: the pending ones, and those of steps after the last (at most step_lag_s behind).
        needed = newest - self.step_lag_s
        if self._pdr is not None:
            needed = max(needed, min(newest, float(self._pdr.t_s[-1])))
        if len(self._pending_s):
            needed = min(needed, float(self._pending_s[0]))
        drop = min(int(np.searchsorted(frames.t_s, needed - self.reach_s, "left")), len(frames) - 2)
        if drop <= 0:
            return
        self._breaks_before_frames += int(segment_breaks(frames)[: drop + 1].sum())
        self._frames = frames.select(slice(drop, None))

    # ---------------------------------------------------------------- heading

    def _complete_steps(self) -> int:
        """How many steps have a complete epoch."""
        return int(np.searchsorted(self._pdr.t_s, self._epochs.t_s[-1], "right"))

    def _solve(self, n_steps: int, window_s: float | None) -> HeadingSolution:
        """Eq. 15 (:func:`fusion.run.initial_heading`) on the first ``n_steps`` steps' complete epochs."""
        pdr = self._pdr.select(slice(0, n_steps))
        at_steps = np.searchsorted(self._epochs.t_s, pdr.t_s)
        return initial_heading(pdr, self._epochs, None, at_steps, self.geometry, self.config, window_s)

    def _try_heading(self) -> None:
        """The batch's heading once its window is complete; meanwhile the provisional one."""
        complete = self._complete_steps()
        t = self._pdr.t_s
        while True:
            # The window is complete once a later step is known and every step in it has a complete epoch.
            n = int(np.searchsorted(t, t[0] + self._window_s, "right"))
            if n == len(t) or complete < n:
                break
            try:
                solution = self._solve(n, self._window_s)
            except ValueError:  # the window constrains no heading yet
                solution = None
            if solution is not None and solution.confidence >= MIN_CONFIDENCE:
                self._start_filters(solution)
                return
            self._window_s *= 2.0
        interval = max(PROVISIONAL_SOLVE_S, PROVISIONAL_SOLVE_FRACTION * (self._provisional_at_s - t[0]))
        if complete >= 2 and t[complete - 1] >= self._provisional_at_s + interval:
            self._provisional_at_s = float(t[complete - 1])
            try:
                self._provisional = self._solve(complete, None)
            except ValueError:
                self._provisional = None

    def _provisional_rows(self, first: int) -> None:
        """Steps ``first`` on as the provisional stage's rows (:meth:`_provisional_track`)."""
        track = self._provisional_track(self._pdr.select(slice(first, None)))
        self._out.append(LivePositions.of(track, filtered=False, nowcast=False))

    def _provisional_track(self, steps: PdrSteps) -> FusedTrack:
        """``steps`` (PDR frame, from P0) turned by the best heading so far, with its uncertainty."""
        heading = 0.0 if self._provisional is None else self._provisional.heading_rad
        dx, dy = rotate_pdr(np.asarray(steps.x_m), np.asarray(steps.y_m), heading)
        elapsed = np.asarray(steps.t_s) - float((steps if self._pdr is None else self._pdr).t_s[0])
        sigma = np.hypot(provisional_sigma_rad(self._provisional), self.config.heading_drift_radps * elapsed)
        cov = provisional_covariance_m2(dx, dy, np.minimum(sigma, np.pi), self.config.noise.initial_position_m)
        return FusedTrack(t_s=np.asarray(steps.t_s, dtype=np.float64), x_m=self.start_xy_m[0] + dx,
                          y_m=self.start_xy_m[1] + dy,
                          heading_rad=(np.asarray(steps.heading_rad) + heading) % (2.0 * np.pi),
                          speed_mps=np.asarray(steps.speed_mps, dtype=np.float64), var_x_m2=cov[:, 0, 0],
                          var_y_m2=cov[:, 1, 1], cov_xy_m2=cov[:, 0, 1])

    # ---------------------------------------------------------------- filters

    def _start_filters(self, heading: HeadingSolution) -> None:
        """Start every filter at P0 with the confident heading; they then run the complete epochs."""
        self.heading = heading
        n = self._complete_steps()
        epochs = build_epochs(self._pdr.select(slice(0, n)), self._epochs, heading.heading_rad)
        config = with_heading_spread(self.config, heading)
        for name in self.filters:
            self._filters[name] = FILTER_BUILDERS[name](epochs, self.geometry, config)
            if self.config.smooth:
                self._filters[name].record_history()

    def _run_filters(self) -> None:
        """Step every filter through the complete epochs it has not yet run."""
        epochs_t = self._epochs.t_s
        first = self._run_epochs
        if first >= len(epochs_t):
            return
        # A context of two steps before the new epochs, so that their increments and ratios are the batch's.
        before = int(np.searchsorted(self._pdr.t_s, epochs_t[first], "left"))
        s0 = max(before - 2, 0)
        e0 = 0 if s0 == 0 else int(np.searchsorted(epochs_t, self._pdr.t_s[s0], "left"))
        n_steps = self._complete_steps()
        epochs = build_epochs(self._pdr.select(slice(s0, n_steps)), self._epochs.select(slice(e0, None)),
                              self.heading.heading_rad)
        rows = np.arange(first - e0, len(epochs))
        new = epochs.select(slice(first - e0, None))
        live = None
        for name, fusion_filter in self._filters.items():
            states = np.empty((len(rows), STATE_SIZE))
            covariances = np.empty((len(rows), 2, 2))
            for i, n in enumerate(rows):
                states[i], covariances[i] = step_filter(fusion_filter, epochs, int(n))
            track = step_track(new, states, covariances)
            self._tracks[name].append(track)
            if name == self.live_filter:
                live = track
        self._run_epochs = len(epochs_t)
        if len(live):
            self._out.append(LivePositions.of(live, filtered=True, nowcast=False))


def _heading_variance_rad2(fusion_filter: FusionFilter) -> float:
    """A streaming filter's heading variance, rad^2: its particles' weighted one (the PF's ``summary``), or its
    Kalman covariance ``P``'s (the UKF and rank KF)."""
    covariance = fusion_filter.summary()[1] if hasattr(fusion_filter, "summary") else fusion_filter.P
    return float(covariance[HEADING, HEADING])

