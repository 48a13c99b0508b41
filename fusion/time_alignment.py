"""Capture-to-phone time alignment: where the receiver's clock sits on the IMU's.

A field recording has two clocks: the SDR capture's (``t_s`` of the receiver,
from its first sample, stamped once with the capture's start time) and the
phone's (the IMU log, stamped by the phone's own clock). Their offset
``tau`` (the capture's start on the IMU's time base, s) comes first,
coarsely, from the two files' UTC stamps (:func:`coarse_offset_s`): as good
as the phone's and the SDR host's clocks, which can be a second apart. It is
then refined from the motion itself (:func:`align_range_to_pdr`).

**Fine alignment.** The receiver's range rate is the walker's velocity
projected on the direction from the tower, ``rdot(t) = v(t) . u(t)``. The
PDR knows ``v`` only up to a rotation (its heading is relative until the
fusion solves it) and the tower direction ``u`` barely turns over a walk, so
over the walk

    (A1)  ``rdot(t) = a vE_pdr(t + tau) + b vN_pdr(t + tau) + c + d t + noise``

with unknown ``a``, ``b`` (the rotation and the projection together), a
constant ``c`` and a slope ``d`` (what is left of the receiver's oscillator
offset and its drift). ``a`` and ``b`` are their own on each piece of
:attr:`AlignmentConfig.piece_s`: the PDR's heading drifts with its gyro's
bias and its step lengths' scale with the gait, so its frame turns and
stretches slowly against the true one, and one pair for a whole walk would
read that slow turn as a shift in time. Both velocities are box averages over the same
window, ``(p(t + w/2) - p(t - w/2)) / w``, which smooths the PDR's
step-by-step motion and the per-frame range noise alike without shifting
either in time. For each trial ``tau`` on a grid about the coarse offset,
(A1) is solved by linear least squares on one fixed set of times; ``tau``
is the minimum of the residual sum of squares ``S(tau)``, refined by a
parabola through the grid's three best points. The information is in the
changes of velocity (starts, stops, turns): a straight walk at constant
speed fixes nothing, and its uncertainty says so.

**Which range.** Where the receiver's path tracker holds tower 0's first
path (:class:`PathRanges`), a window takes that path's range rate: it is the
direct path whenever the tracker holds it, while the SI carriers' range
follows whatever arrives strongest, a reflection where buildings block the
tower, whose rate is the walker's velocity projected on another direction
and wanders as the reflecting walls change. Windows across a first-path
origin break (a slip or a change of path), or without a first path, take the
SI carriers' range rate.

**Uncertainty.** Near its minimum, ``S(tau) ~ S_min + k (tau - tau_hat)^2``;
the Gauss-Newton covariance of ``tau`` is ``2 s^2 / S''`` with ``s^2`` the
residual variance per independent sample. The residuals are correlated: the
PDR's velocity errors last a stride or more, and a reflected range wanders
for as long as the walker passes one wall. So ``s^2`` is the sample variance
times the residuals' integrated autocorrelation time in samples (the sum of
their autocorrelation up to its first zero), not a fixed window. Where the
motion or the range is poor, ``S(tau)`` is no parabola: it is flat or holds
further minima (steps repeat every half second), and its curvature at the
best point says little. The stated sigma is therefore the largest of three
(:func:`offset_sigma_s`): the curvature's; the half-width of the offsets
whose ``S`` lies within ``s^2`` of the minimum (the profile's 1-sigma
interval, which a flat or many-minima curve widens); and the spread of the
offsets found leaving out one piece of :attr:`AlignmentConfig.piece_s` at a
time (a delete-one jackknife over pieces long enough to hold a reflection's
wander). The PDR's own step timing
(:attr:`AlignmentConfig.step_timing_sigma_s`) is added to it in quadrature:
a shift of every step's events against the body's motion, which the motion
cannot reveal. Where the total exceeds :attr:`AlignmentConfig.useful_sigma_s`,
the walk left too little to align on (:attr:`TimeAlignment.too_little`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.records import PathRangeSeries, RangeSeries, Track


@dataclass(frozen=True)
class AlignmentConfig:
    """Settings of the fine time alignment.

    Attributes
    ----------
    search_s : float
        Half-width of the searched offsets about the coarse offset, s.
    step_s : float
        Spacing of the searched offsets, s.
    velocity_window_s : float
        Box window of both velocities, s: long enough to average over a
        stride (two steps), short enough to keep starts, stops and turns.
    grid_rate_hz : float
        Rate of the times (A1) is solved on, Hz.
    piece_s : float
        Length of the pieces of the walk that each get their own ``a``, ``b`` of (A1), s.
    max_gap_s : float
        A velocity window with a longer stretch of invalid receiver frames
        is left out, s.
    coarse_sigma_s : float
        Uncertainty of the coarse offset from the two files' UTC stamps, s:
        a phone's network-set clock and an SDR host's clock each within
        about half a second of UTC.
    step_timing_sigma_s : float
        Uncertainty of where the PDR's steps sit in time against the body's
        motion, s: a step starts and ends at events the step detector finds in
        the accelerometer, a small fraction of a step from where the foot and
        the body move, and that shift is the same on every step, so no length
        of walk averages it out. It is added in quadrature to the motion's sigma.
    useful_sigma_s : float
        A fine offset more uncertain than this is too little to align on, s:
        at walking speed (1.3 m/s) the range moves 0.13 m in it, half the
        filters' range sigma on a good link
        (:attr:`fusion.observations.AggregationConfig.base_sigma_m`).
    """

    search_s: float = 3.0
    step_s: float = 0.01
    velocity_window_s: float = 1.0
    grid_rate_hz: float = 20.0
    piece_s: float = 20.0
    max_gap_s: float = 0.1
    coarse_sigma_s: float = 1.0
    step_timing_sigma_s: float = 0.025
    useful_sigma_s: float = 0.1


@dataclass(frozen=True)
class TimeAlignment:
    """The capture's start on the IMU's time base, and how it was found.

    Attributes
    ----------
    offset_s : float
        The offset used: add it to the receiver's ``t_s`` to get IMU time, s.
    sigma_s : float
        Its 1-sigma uncertainty, s (0 where given or recorded exactly).
    source : str
        ``"given"`` (``--time-offset``), ``"simulation record"``, ``"fine"``
        (:func:`align_range_to_pdr`) or ``"coarse"`` (UTC stamps only).
    coarse_offset_s, coarse_sigma_s : float
        The offset from the UTC stamps and its uncertainty, s (NaN without stamps).
    fine_offset_s, fine_sigma_s : float
        The offset from the motion and its uncertainty, s (NaN where not run).
    too_little : bool
        The fine offset's uncertainty is over :attr:`AlignmentConfig.useful_sigma_s`:
        the walk left too little to align on (a blocked direct path, a walk without starts, stops or turns).
    """

    offset_s: float
    sigma_s: float
    source: str
    coarse_offset_s: float = float("nan")
    coarse_sigma_s: float = float("nan")
    fine_offset_s: float = float("nan")
    fine_sigma_s: float = float("nan")
    too_little: bool = False

    @property
    def disagrees(self) -> bool:
        """Whether the coarse and fine offsets differ by more than their combined 1-sigma uncertainty."""
        if not (np.isfinite(self.coarse_offset_s) and np.isfinite(self.fine_offset_s)):
            return False
        return abs(self.fine_offset_s - self.coarse_offset_s) > np.hypot(self.coarse_sigma_s, self.fine_sigma_s)

    def describe(self) -> str:
        """One line for the user: the offset, its uncertainty and where it came from."""
        text = f"capture starts at {self.offset_s:+.3f} s on the IMU clock ({self.source}"
        if np.isfinite(self.fine_sigma_s) and self.source == "fine":
            text += f", +-{1e3 * self.fine_sigma_s:.0f} ms"
        if np.isfinite(self.coarse_offset_s):
            text += f"; UTC stamps say {self.coarse_offset_s:+.3f} s"
        text += ")"
        if self.too_little:
            text += (f"; WARNING: the motion fixes it only to +-{1e3 * self.fine_sigma_s:.0f} ms, too little to align "
                     "on (a blocked direct path, or a walk without stops and turns)")
            if self.source != "fine":
                text += ": the UTC stamps' offset is kept"
        return text


def coarse_offset_s(capture_start_utc_ns: int, imu_start_utc_ns: int) -> float:
    """The capture's start on the IMU's time base from the two files' UTC stamps, s."""
    return (int(capture_start_utc_ns) - int(imu_start_utc_ns)) * 1e-9


def _window_velocity(t_s: np.ndarray, position_m: np.ndarray, at_s: np.ndarray, window_s: float) -> np.ndarray:
    """Box-averaged velocity ``(p(t + w/2) - p(t - w/2)) / w`` at ``at_s`` (linear interpolation), m/s."""
    half = 0.5 * window_s
    return (np.interp(at_s + half, t_s, position_m) - np.interp(at_s - half, t_s, position_m)) / window_s


def range_rate(ranges: RangeSeries, grid_s: np.ndarray, config: AlignmentConfig) -> np.ndarray:
    """The receiver's box-averaged range rate at ``grid_s`` (receiver time), m/s; NaN where a window is not
    inside one lock segment's valid frames (a gap longer than ``config.max_gap_s``)."""
    out = np.full(len(grid_s), np.nan)
    segments = ranges.segment_id if ranges.segment_id is not None else np.zeros(len(ranges.t_s), np.int32)
    half = 0.5 * config.velocity_window_s
    for segment in np.unique(segments[ranges.valid]):
        keep = ranges.valid & (segments == segment)
        t, r = ranges.t_s[keep], ranges.range_change_m[keep]
        if len(t) < 2:
            continue
        inside = (grid_s - half >= t[0]) & (grid_s + half <= t[-1])
        # A window holds no gap longer than max_gap_s: the longest frame spacing across it.
        spacing = np.diff(t)
        long_gaps = t[:-1][spacing > config.max_gap_s], t[1:][spacing > config.max_gap_s]
        for gap_start, gap_end in zip(*long_gaps):
            inside &= ~((grid_s + half > gap_start) & (grid_s - half < gap_end))
        out[inside] = _window_velocity(t, r, grid_s[inside], config.velocity_window_s)
    return out


def first_path_ranges(first_path: PathRangeSeries) -> RangeSeries:
    """The first path's range as a :class:`RangeSeries` whose lock segments are its runs between origin breaks
    (a slip or a change of path: the range goes on from a new origin there, so no window may span one)."""
    return RangeSeries(t_s=first_path.t_s, range_change_m=first_path.range_change_m, snr_db=first_path.snr_db,
                       valid=first_path.valid, segment_id=np.cumsum(first_path.slip).astype(np.int32))


def correlation_time(residuals: np.ndarray) -> float:
    """Integrated autocorrelation time of a sequence, in samples: ``1 + 2 sum rho_k`` over the lags ``k >= 1``
    before its autocorrelation ``rho`` first drops to zero or below (1 for white residuals)."""
    x = residuals - residuals.mean()
    n = len(x)
    spectrum = np.fft.rfft(x, 2 * n)   # zero-padded: a linear, not circular, autocorrelation
    acf = np.fft.irfft(np.abs(spectrum) ** 2)[:n]
    if acf[0] <= 0.0:
        return 1.0
    rho = acf / acf[0]
    first_zero = int(np.argmax(rho <= 0.0)) or n
    return float(1.0 + 2.0 * np.sum(rho[1:first_zero]))


def _refined_minimum(lags: np.ndarray, rss: np.ndarray) -> tuple[float, float]:
    """The offset of least ``S`` refined by a parabola through the grid's three best points, and ``S''`` there
    (NaN at the edge of the search, where no parabola is fitted), s and m^2/s^4."""
    best = int(np.argmin(rss))
    if not 0 < best < len(lags) - 1:
        return float(lags[best]), float("nan")
    step = lags[1] - lags[0]
    left, mid, right = rss[best - 1:best + 2]
    curvature = (left - 2.0 * mid + right) / step ** 2
    shift = 0.5 * step * (left - right) / (left - 2.0 * mid + right) if curvature > 0 else 0.0
    return float(lags[best] + shift), float(curvature)


def offset_sigma_s(lags: np.ndarray, rss: np.ndarray, piece_rss: np.ndarray, variance: float) -> float:
    """1-sigma uncertainty of the offset of least ``S(tau)`` (module docstring, "Uncertainty"), s.

    Parameters
    ----------
    lags : ndarray
        The searched offsets, evenly spaced, s.
    rss : ndarray
        ``S`` of (A1) at each offset, m^2/s^2.
    piece_rss : ndarray, shape (len(lags), pieces)
        Each piece's share of ``S``, m^2/s^2.
    variance : float
        Residual variance per independent sample, m^2/s^2.

    Returns
    -------
    float
        The largest of the curvature's sigma, the profile's half-width and the delete-one-piece jackknife's
        spread, s; inf where the minimum lies at the edge of the search or ``S`` is not convex there.
    """
    offset, curvature = _refined_minimum(lags, rss)
    if not curvature > 0:
        return float("inf")
    curvature_sigma = np.sqrt(2.0 * variance / curvature)
    # The profile: every offset whose S is within one sigma's worth of the minimum's.
    within = rss - rss.min() <= variance
    profile_sigma = float(np.max(np.abs(lags[within] - offset)))
    # Delete-one-piece jackknife. Each piece has its own a, b, so leaving one out leaves the others' fits as
    # they are (only c and d would move a little): its S is the walk's less that piece's share.
    pieces = piece_rss.shape[1]
    jackknife_sigma = 0.0
    if pieces >= 2:
        left_out = np.array([_refined_minimum(lags, rss - piece_rss[:, k])[0] for k in range(pieces)])
        jackknife_sigma = float(np.sqrt((pieces - 1) / pieces * np.sum((left_out - left_out.mean()) ** 2)))
    return float(max(curvature_sigma, profile_sigma, jackknife_sigma))


def align_range_to_pdr(ranges: RangeSeries, track: Track, coarse_s: float,
                       config: AlignmentConfig = AlignmentConfig(),
                       first_path: PathRangeSeries | None = None) -> tuple[float, float]:
    """Fine offset of the receiver's clock on the IMU's, from the motion (eq. A1 of the module docstring).

    Parameters
    ----------
    ranges : RangeSeries
        The receiver's SI-carrier range change on the receiver's own time base
        (``t_s`` from the capture's first sample).
    track : Track
        The PDR track on the IMU's time base (its own frame: any heading).
    coarse_s : float
        The offset searched about, s (the UTC stamps', or 0 without them).
    config : AlignmentConfig
    first_path : PathRangeSeries, optional
        Tower 0's first-path range on the same time base as ``ranges``: where it has a window, its range rate
        is taken in place of the SI carriers' (module docstring, "Which range"). None: the SI carriers' only.

    Returns
    -------
    offset_s, sigma_s : float
        The capture's start on the IMU time base and its 1-sigma uncertainty, s: :func:`offset_sigma_s` and
        :attr:`AlignmentConfig.step_timing_sigma_s` in quadrature (inf where the best offset lies at the edge
        of the search).

    Raises
    ------
    ValueError
        Too little overlap of the two records over the searched offsets to fit (A1).
    """
    half = 0.5 * config.velocity_window_s
    lags = coarse_s + np.arange(-config.search_s, config.search_s + 0.5 * config.step_s, config.step_s)
    # One fixed set of receiver times for every lag: windows inside the PDR track at every lag.
    lo = max(ranges.t_s[0], track.t_s[0] - lags[0]) + half
    hi = min(ranges.t_s[-1], track.t_s[-1] - lags[-1]) - half
    grid = np.arange(lo, hi, 1.0 / config.grid_rate_hz) if hi > lo else np.zeros(0)
    rdot = range_rate(ranges, grid, config)
    if first_path is not None:
        direct = range_rate(first_path_ranges(first_path), grid, config)
        rdot = np.where(np.isfinite(direct), direct, rdot)
    use = np.isfinite(rdot)
    grid, rdot = grid[use], rdot[use]
    per_window = config.velocity_window_s * config.grid_rate_hz
    if len(grid) < 4 * per_window:
        raise ValueError(f"time alignment: the receiver's valid frames and the IMU log overlap by "
                         f"{len(grid) / config.grid_rate_hz:.1f} s over offsets {lags[0]:+.1f}..{lags[-1]:+.1f} s; "
                         f"at least {4 * config.velocity_window_s:g} s are needed")
    t_rel = (grid - grid.mean()) / max(np.ptp(grid), 1e-9)
    piece = np.minimum((grid - grid[0]) // config.piece_s, max(np.ptp(grid) // config.piece_s - 1, 0)).astype(int)
    pieces = piece[-1] + 1
    in_piece = piece[:, None] == np.arange(pieces)   # the last piece takes a short remainder

    def residuals(lag: float) -> np.ndarray:
        """(A1)'s least-squares residuals at one trial offset, m/s."""
        vx = _window_velocity(track.t_s, track.x_m, grid + lag, config.velocity_window_s)
        vy = _window_velocity(track.t_s, track.y_m, grid + lag, config.velocity_window_s)
        design = np.column_stack([vx[:, None] * in_piece, vy[:, None] * in_piece, np.ones_like(grid), t_rel])
        # Normal equations: a few dozen columns against thousands of rows, solved hundreds of times.
        coefficients = np.linalg.lstsq(design.T @ design, design.T @ rdot, rcond=None)[0]
        return rdot - design @ coefficients

    piece_rss = np.array([np.bincount(piece, residuals(lag) ** 2, minlength=pieces) for lag in lags])
    rss = piece_rss.sum(axis=1)
    offset, _ = _refined_minimum(lags, rss)
    best = residuals(float(lags[np.argmin(rss)]))
    dof = len(grid) - 2 * pieces - 3   # a and b of each piece, c, d and tau
    variance = float(np.sum(best ** 2)) / dof * correlation_time(best)
    return offset, float(np.hypot(offset_sigma_s(lags, rss, piece_rss, variance), config.step_timing_sigma_s))
