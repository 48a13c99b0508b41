"""Synthetic walks for the fusion tests: a truth path and a PDR made from it with known errors.

Self-contained (no dependency on the walk/IMU simulators), so the filter tests
state exactly which errors the PDR carries: a heading drift, a step-length
gain error and white noise on both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import PathRangeSeries, PdrSteps, RangeSeries, Track
from fusion.model import Geometry
from dtmbnav_core.records import PathRanges
@dataclass
class SyntheticWalk:
    truth: Track
    pdr: PdrSteps
    geometry: Geometry
    initial_heading_rad: float


def polyline_truth(waypoints_m, speed_mps=1.3, still_s=10.0, rate_hz=100.0, pauses=()) -> Track:
    """Constant-speed walk along a polyline after standing still at its first point.

    ``pauses``: (distance walked, m; duration, s) where the walker stops on the way.
    """
    pts = np.asarray(waypoints_m, dtype=float)
    seg = np.diff(pts, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    # Distance walked against time: knots at the start, at each pause's start and end, at the end.
    knot_t, knot_d = [0.0, still_s], [0.0, 0.0]
    for at_m, pause_s in sorted(pauses):
        knot_t.append(knot_t[-1] + (at_m - knot_d[-1]) / speed_mps)
        knot_d.append(at_m)
        knot_t.append(knot_t[-1] + pause_s)
        knot_d.append(at_m)
    knot_t.append(knot_t[-1] + (cum[-1] - knot_d[-1]) / speed_mps)
    knot_d.append(cum[-1])
    t = np.arange(0.0, knot_t[-1], 1.0 / rate_hz)
    dist = np.interp(t, knot_t, knot_d)
    x = np.interp(dist, cum, pts[:, 0])
    y = np.interp(dist, cum, pts[:, 1])
    i = np.clip(np.searchsorted(cum, dist, side="right") - 1, 0, len(seg) - 1)
    heading = np.arctan2(seg[i, 0], seg[i, 1]) % (2 * np.pi)
    speed = np.gradient(dist, t)
    return Track(t, x, y, heading, np.where(speed > 0.5 * speed_mps, speed_mps, 0.0))



def loop_truth(scenario) -> Track:
    """A scenario's loop walked at constant speed, back to its start, after its standstill (no PDR faults)."""
    waypoints = scenario.walk.waypoints_m
    return polyline_truth(waypoints + [waypoints[0]], still_s=scenario.walk.start_still_s)


def make_pdr(truth: Track, still_s: float, *, step_s=0.54, gain=1.0, drift_radps=0.0, heading_noise_rad=0.0,
             length_noise=0.0, seed=0) -> tuple[PdrSteps, float]:
    """PDR steps from the truth: relative heading (+ drift, noise), step length x gain (+ noise)."""
    rng = np.random.default_rng(seed)
    t_steps = np.arange(still_s + step_s, truth.t_s[-1], step_s)
    x_true = np.interp(np.concatenate([[t_steps[0] - step_s], t_steps]), truth.t_s, truth.x_m)
    y_true = np.interp(np.concatenate([[t_steps[0] - step_s], t_steps]), truth.t_s, truth.y_m)
    dx, dy = np.diff(x_true), np.diff(y_true)
    moving = np.hypot(dx, dy) > 0.05  # no step while the walker stands
    t_steps, dx, dy = t_steps[moving], dx[moving], dy[moving]
    length = np.hypot(dx, dy) * gain * (1 + length_noise * rng.standard_normal(len(dx)))
    true_heading = np.arctan2(dx, dy)
    initial = float(true_heading[0] % (2 * np.pi))
    heading = (true_heading - initial + drift_radps * (t_steps - still_s)
               + heading_noise_rad * rng.standard_normal(len(dx)))
    x = np.cumsum(length * np.sin(heading))
    y = np.cumsum(length * np.cos(heading))
    return PdrSteps(t_steps, x, y, heading, length / step_s, length), initial


PARK_LOOP_M = [[0, 0], [0, 28], [20, 36], [33, 14], [19, -4], [0, 0]]


def park_like_walk(*, gain=1.0, drift_dps=0.0, seed=0, tower=(2000.0, 2200.0, 150.0), other_towers=(), laps=1,
                   pauses=()) -> SyntheticWalk:
    """An asymmetric ~116 m loop like the park-loop scenario (``laps`` times), with a PDR carrying the given errors.

    ``other_towers`` (x, y, height) make a single-frequency network; ``pauses`` as :func:`polyline_truth`.
    """
    loop = np.asarray(PARK_LOOP_M, dtype=float)
    truth = polyline_truth(np.concatenate([loop] + [loop[1:]] * (laps - 1)), pauses=pauses)
    pdr, initial = make_pdr(truth, 10.0, gain=gain, drift_radps=np.deg2rad(drift_dps),
                            heading_noise_rad=np.deg2rad(2.0), length_noise=0.03, seed=seed)
    return SyntheticWalk(truth, pdr, Geometry(0.0, 0.0, *tower, other_towers=tuple(other_towers)), initial)


def foot_imu_straight(n_strides=12, stride_m=1.4, stride_s=1.1, stance_s=0.45, heading_rad=0.0, rate_hz=200.0,
                      gyro_bias_radps=np.deg2rad(0.1), accel_noise=0.01, gyro_noise=np.deg2rad(0.05), seed=0):
    """A foot-mounted IMU on a straight walk: flat foot, stance at rest, swing with a raised-cosine speed.

    During the swing the foot also lifts by a raised cosine and pitches (toe up, back to flat
    at heel strike), as a real foot does, so a stance detector sees rotation and a specific
    force that is not gravity alone.

    Returns t_s, acc_mps2 (specific force in the foot frame of dtmbnav_core.records.ImuLog: x right,
    y forward, z up), gyro_radps and the true foot position (N x 2) in ENU.
    """
    rng = np.random.default_rng(seed)
    still = 1.0
    t = np.arange(0.0, still + n_strides * stride_s + still, 1.0 / rate_hz)
    phase = np.clip(t - still, 0.0, n_strides * stride_s)
    k = np.minimum(np.floor(phase / stride_s), n_strides - 1)
    u = phase - k * stride_s - stance_s
    swing_s = stride_s - stance_s
    inside = (u > 0) & (u < swing_s) & (t > still) & (t < still + n_strides * stride_s)
    # Forward speed 1 - cos over the swing integrates to stride_m; its derivative is the acceleration.
    speed = np.where(inside, stride_m / swing_s * (1 - np.cos(2 * np.pi * u / swing_s)), 0.0)
    accel = np.where(inside, stride_m / swing_s * (2 * np.pi / swing_s) * np.sin(2 * np.pi * u / swing_s), 0.0)
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    n = len(t)
    lift_m = 0.15  # vertical (1 - cos) / 2 lift: acceleration lift/2 * (2 pi / swing)^2 cos(.)
    vertical = np.where(inside, lift_m / 2 * (2 * np.pi / swing_s) ** 2 * np.cos(2 * np.pi * u / swing_s), 0.0)
    pitch_rate = np.where(inside, 3.4 * np.sin(2 * np.pi * u / swing_s), 0.0)  # up to ~40 deg pitch
    pitch = np.where(inside, 3.4 * swing_s / (2 * np.pi) * (1 - np.cos(2 * np.pi * u / swing_s)), 0.0)
    # Specific force in the level right/forward/up frame, rotated into the toe-up pitched foot
    # frame (a positive rotation about the right axis x lifts the toe).
    f_fwd, f_up = accel, 9.81 + vertical
    acc = np.zeros((n, 3))
    acc[:, 1] = np.cos(pitch) * f_fwd + np.sin(pitch) * f_up
    acc[:, 2] = -np.sin(pitch) * f_fwd + np.cos(pitch) * f_up
    acc += accel_noise * rng.standard_normal((n, 3))
    gyro = gyro_bias_radps + gyro_noise * rng.standard_normal((n, 3))
    gyro[:, 0] += pitch_rate
    pos = np.stack([dist * np.sin(heading_rad), dist * np.cos(heading_rad)], axis=1)
    return t, acc, gyro, pos


def true_ranges(walk: SyntheticWalk, rate_hz: float = 50.0, tower: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Frame times and the true range change to a tower along the truth at ``rate_hz``."""
    t = np.arange(walk.truth.t_s[0], walk.truth.t_s[-1], 1.0 / rate_hz)
    g = walk.geometry
    r = g.range_m(np.interp(t, walk.truth.t_s, walk.truth.x_m), np.interp(t, walk.truth.t_s, walk.truth.y_m), tower)
    return t, r - g.start_range_m(tower)


def exact_ranges(walk: SyntheticWalk, rate_hz: float = 50.0) -> RangeSeries:
    """Noise-free receiver range change along the truth at ``rate_hz``, every frame valid at 20 dB."""
    t, r = true_ranges(walk, rate_hz)
    return RangeSeries(t, r, np.full(len(t), 20.0), np.ones(len(t), bool))


def path_series(t_s: np.ndarray, range_change_m: np.ndarray, snr_db: float = 20.0) -> PathRangeSeries:
    """A path channel tracked from the start without a slip."""
    n = len(t_s)
    return PathRangeSeries(t_s, range_change_m, np.full(n, snr_db), np.ones(n, bool), np.zeros(n, bool),
                           t_s - t_s[0] + 10.0)


def exact_paths(walk: SyntheticWalk, rate_hz: float = 50.0, first_path: bool = True) -> PathRanges:
    """Noise-free first-path ranges of every tower (if ``first_path``) and the tower differences."""
    ranges = [true_ranges(walk, rate_hz, k) for k in range(walk.geometry.n_towers)]
    t = ranges[0][0]
    return PathRanges(first_path={k: path_series(t, r) for k, (_, r) in enumerate(ranges)} if first_path else {},
                      differences={k: path_series(t, ranges[k][1] - ranges[0][1])
                                   for k in range(1, walk.geometry.n_towers)})


def clock_range_m(t_s: np.ndarray, allan_deviation: float, allan_tau_s: float, seed: int, calibration_s: float = 8.0
                  ) -> np.ndarray:
    """Range (m) a free-running clock adds to a single-tower carrier phase: random-walk FM of the given Allan deviation.

    The rate's random walk has ``q = c^2 3 adev^2 / tau`` (fusion.model.ClockModel); the receiver
    measured f_s over the first ``calibration_s`` (docs/method.md §2), so the mean rate there is removed.
    """
    rng = np.random.default_rng(seed)
    dt = np.diff(t_s, prepend=t_s[0])
    q = SPEED_OF_LIGHT_MPS**2 * 3.0 * allan_deviation**2 / allan_tau_s
    rate = np.cumsum(rng.standard_normal(len(t_s)) * np.sqrt(q * dt))
    rate -= rate[t_s - t_s[0] <= calibration_s].mean()
    return np.cumsum(rate * dt)


def ranges_with_blockage(walk: SyntheticWalk, start_s: float, end_s: float, jump_m: float) -> RangeSeries:
    """:func:`exact_ranges` with no valid frame inside (start_s, end_s) and ``jump_m`` added from ``end_s`` on.

    A blocked stretch: the integrated range comes back off by what it
    picked up while the direct path was gone.
    """
    ranges = exact_ranges(walk)
    blocked = (ranges.t_s > start_s) & (ranges.t_s < end_s)
    return RangeSeries(ranges.t_s, ranges.range_change_m + np.where(ranges.t_s >= end_s, jump_m, 0.0),
                       ranges.snr_db, ranges.valid & ~blocked)
