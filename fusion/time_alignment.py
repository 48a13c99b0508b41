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

**Uncertainty.** Near its minimum, ``S(tau) ~ S_min + k (tau - tau_hat)^2``;
the Gauss-Newton covariance of ``tau`` is ``2 s^2 / S''`` with ``s^2`` the
residual variance. The residuals of box-averaged velocities are correlated
over a window, so ``s^2`` is taken per independent window (the sample
variance times the samples per window).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.records import RangeSeries, Track


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
    """

    search_s: float = 3.0
    step_s: float = 0.01
    velocity_window_s: float = 1.0
    grid_rate_hz: float = 20.0
    piece_s: float = 20.0
    max_gap_s: float = 0.1
    coarse_sigma_s: float = 1.0


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
    """

    offset_s: float
    sigma_s: float
    source: str
    coarse_offset_s: float = float("nan")
    coarse_sigma_s: float = float("nan")
    fine_offset_s: float = float("nan")
    fine_sigma_s: float = float("nan")

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
        return text + ")"


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


def align_range_to_pdr(ranges: RangeSeries, track: Track, coarse_s: float,
                       config: AlignmentConfig = AlignmentConfig()) -> tuple[float, float]:
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

    Returns
    -------
    offset_s, sigma_s : float
        The capture's start on the IMU time base and its 1-sigma uncertainty, s.

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
    use = np.isfinite(rdot)
    grid, rdot = grid[use], rdot[use]
    per_window = config.velocity_window_s * config.grid_rate_hz
    if len(grid) < 4 * per_window:
        raise ValueError(f"time alignment: the receiver's valid frames and the IMU log overlap by "
                         f"{len(grid) / config.grid_rate_hz:.1f} s over offsets {lags[0]:+.1f}..{lags[-1]:+.1f} s; "
                         f"at least {4 * config.velocity_window_s:g} s are needed")
    t_rel = (grid - grid.mean()) / max(np.ptp(grid), 1e-9)
    piece = np.minimum((grid - grid[0]) // config.piece_s, max(np.ptp(grid) // config.piece_s - 1, 0)).astype(int)
    in_piece = piece[:, None] == np.arange(piece[-1] + 1)   # the last piece takes a short remainder
    rss = np.empty(len(lags))
    for i, lag in enumerate(lags):
        vx = _window_velocity(track.t_s, track.x_m, grid + lag, config.velocity_window_s)
        vy = _window_velocity(track.t_s, track.y_m, grid + lag, config.velocity_window_s)
        design = np.column_stack([vx[:, None] * in_piece, vy[:, None] * in_piece, np.ones_like(grid), t_rel])
        coefficients = np.linalg.lstsq(design, rdot, rcond=None)[0]
        rss[i] = float(np.sum((rdot - design @ coefficients) ** 2))
    best = int(np.argmin(rss))
    offset, curvature = float(lags[best]), np.nan
    if 0 < best < len(lags) - 1:
        left, mid, right = rss[best - 1:best + 2]
        curvature = (left - 2.0 * mid + right) / config.step_s ** 2   # S''
        if curvature > 0:
            offset += float(0.5 * config.step_s * (left - right) / (left - 2.0 * mid + right))
    dof = len(grid) - 2 * in_piece.shape[1] - 3   # a and b of each piece, c, d and tau
    variance = rss[best] / dof * per_window
    sigma = float(np.sqrt(2.0 * variance / curvature)) if curvature > 0 else float("inf")
    return offset, sigma
