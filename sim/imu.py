"""IMU simulator: a handheld phone or a foot-mounted MEMS unit carried on a :class:`~sim.walk.Walk`.

Kinematics
----------
Navigation frame ENU (x east, y north, z up). The sensor frame is x = right,
y = forward, z = up (out of the phone's screen, or out of the foot's instep).
The attitude is built as yaw-pitch-roll: rotate about up by ``-yaw`` (yaw is
clockwise from north, like the heading), then about the sensor's x axis by
``pitch`` (nose up positive), then about its y axis by ``roll``.

- ``phone``: carried as ``imu.carriage`` says (:data:`CARRIAGES`). The body
  follows the smooth truth track; on top of it each step adds the gait: a
  vertical bounce whose peak-to-peak acceleration follows Weinberg's relation
  for this walker, ``P = ((1 + step_gain_error) L / K_walker)^4`` (so a PDR
  calibrated with ``step_gain_error = 0`` sees steps ``1 + step_gain_error``
  too long), scaled by the part of it that reaches the phone, a forward surge
  at the step frequency and a sideways sway at half of it. The gait is
  zero-mean over each step, so it does not move the phone away from the truth
  track. Held in the hand (``hand``, ``texting``) the phone points a few
  degrees off the walking direction (a per-walk mount offset) and wobbles
  (pitch at the step frequency, roll and yaw at half of it). In a trouser
  pocket or a hand swinging at the side it rides on a limb that swings about
  the hip or the shoulder at half the step frequency (a pendulum that fades in
  over a leg's first step and out over its last); the pocket adds the pocket
  leg's heel strikes and a stride-frequency asymmetry between the legs. At
  the ear it rides with the head, in a bag on a pendulum of its own; the walk
  may hand the phone from one carriage to another
  (``imu.carriage_changes``). The carriages' models live in
  :mod:`sim.carriage`.
- ``foot-mems``: strapped to the right foot. The foot stands still (stance)
  on the ground beside the path and swings to its next footprint in
  ``FOOT_SWING_S`` before each of its heel strikes (every other step), with a
  minimum-jerk horizontal profile, a lift of ``FOOT_LIFT_M`` and a toe-off /
  heel-strike pitch; velocity is exactly zero during stance (what a ZUPT
  filter relies on).

Sensor errors (per axis, drawn from the seed): white noise, a constant bias
plus a random-walk wander, scale-factor errors; the z gyro bias can be set
(``gyro_bias_dps``) and a late extra bias can switch on (``heading_drift_*``).
The magnetometer sees the Earth field (a Wuhan-like field, see
:data:`EARTH_FIELD_UT`) plus a disturbance near every building footprint that
decays with distance, plus noise; a device without one (``magnetometer =
false``) writes zeros, as an imported log without one does.

Sample times: uniform at ``rate_hz`` unless ``time_jitter`` scatters them (each
time stamp independently about its nominal time; the readings are those at the
scattered times) and ``gaps_per_minute`` drops runs of ``gap_s`` seconds, as a
phone's operating system does. Their random draws, and the pocket's placement,
come from sub-streams of the IMU stream, so that switching them on changes no
other error.

Angular rates are the central difference of the attitude (rotation vector of
``R(t-dt)^T R(t+dt)`` over ``2 dt``); accelerations are the central second
difference of the truth position plus the analytic gait terms.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from dtmbnav_core.constants import GRAVITY_MPS2
from dtmbnav_core.records import ImuLog
from dtmbnav_core.resampling import interpolate
from sim.carriage import CARRIAGES, Motion, attitude_ypr, carriage_motion, change_carriage, resample_walk
from sim.scenario import Building, ImuConfig, Scenario
from sim.walk import Walk

#: Random stream of the IMU (the walk and the GNSS use other stream ids).
IMU_STREAM = 2
#: Sub-stream of the IMU stream for the magnetic disturbance directions.
MAG_SCENE_SUBSTREAM = 1
#: Sub-streams of the IMU stream for the sample-time jitter and gaps, and for the phone's place in a pocket.
TIMING_SUBSTREAM = 2
CARRIAGE_SUBSTREAM = 3
#: Largest jitter offset of a time stamp from its nominal time, in sample intervals (keeps the order).
MAX_TIME_OFFSET = 0.45
#: Earth field in ENU, uT: Wuhan (30.5 N, 114.3 E), total about 50 uT,
#: inclination about 45 deg down, declination about -3.5 deg (west), WMM-like.
EARTH_FIELD_UT = 50.0 * np.array([np.cos(np.radians(45.0)) * np.sin(np.radians(-3.5)),
                                  np.cos(np.radians(45.0)) * np.cos(np.radians(-3.5)),
                                  -np.sin(np.radians(45.0))])
#: Distance over which a building's magnetic disturbance decays by 1/e, m.
MAG_DISTURBANCE_DECAY_M = 6.0
#: Foot swing duration and lift, and the foot's lateral offset from the path, m.
FOOT_SWING_S = 0.4
FOOT_LIFT_M = 0.08
FOOT_OFFSET_M = 0.09
#: Peak foot pitch during the swing (toe-off down, heel-strike up), rad.
FOOT_PITCH_RAD = np.radians(25.0)


@dataclass(frozen=True)
class ImuPreset:
    """Error model and carriage of one IMU kind.

    Attributes
    ----------
    mount : str
        ``"hand"`` or ``"foot"``.
    accel_noise_mps2 : float
        White noise per sample, 1 sigma, m/s^2.
    accel_bias_mps2 : float
        Constant bias, 1 sigma per axis, m/s^2.
    accel_scale_error : float
        Scale-factor error, 1 sigma per axis (relative).
    gyro_noise_dps_rthz : float
        Angle random walk density, deg/s/sqrt(Hz) (per-sample sigma is this
        times sqrt(rate)).
    gyro_bias_range_dps : tuple of float
        Initial bias magnitude drawn uniformly in this range (random sign), deg/s.
    gyro_bias_walk_dps_rts : float
        Bias random walk, deg/s/sqrt(s).
    gyro_scale_error : float
        Scale-factor error, 1 sigma per axis (relative).
    mag_noise_ut : float
        Magnetometer white noise, uT.
    mag_offset_ut : float
        Residual hard-iron offset after the device's calibration, 1 sigma per axis, uT.
    weinberg_k_m : float
        The walker's true Weinberg gain of the body's bounce (bounce to step length), m.
    mount_yaw_sigma_rad : float
        Spread of the device's yaw offset from the walking direction, rad.
    """

    mount: str
    accel_noise_mps2: float
    accel_bias_mps2: float
    accel_scale_error: float
    gyro_noise_dps_rthz: float
    gyro_bias_range_dps: tuple[float, float]
    gyro_bias_walk_dps_rts: float
    gyro_scale_error: float
    mag_noise_ut: float
    mag_offset_ut: float
    weinberg_k_m: float
    mount_yaw_sigma_rad: float


#: The presets of ``ImuConfig.preset`` (docs/scenarios.md: phone accel noise ~0.02 m/s^2,
#: gyro 0.01 deg/s/sqrt(Hz), bias 0.1-0.5 deg/s that wanders; how a phone is held is its carriage).
PRESETS: dict[str, ImuPreset] = {
    "phone": ImuPreset(mount="hand", accel_noise_mps2=0.02, accel_bias_mps2=0.03, accel_scale_error=0.005,
                       gyro_noise_dps_rthz=0.01, gyro_bias_range_dps=(0.1, 0.5), gyro_bias_walk_dps_rts=0.002,
                       gyro_scale_error=0.003, mag_noise_ut=0.3, mag_offset_ut=1.0, weinberg_k_m=0.47,
                       mount_yaw_sigma_rad=np.radians(5.0)),
    "foot-mems": ImuPreset(mount="foot", accel_noise_mps2=0.01, accel_bias_mps2=0.01, accel_scale_error=0.002,
                           gyro_noise_dps_rthz=0.005, gyro_bias_range_dps=(0.02, 0.1),
                           gyro_bias_walk_dps_rts=0.0005, gyro_scale_error=0.001, mag_noise_ut=0.3,
                           mag_offset_ut=1.0, weinberg_k_m=0.47, mount_yaw_sigma_rad=0.0),
}


@dataclass(frozen=True)
class ImuErrors:
    """The sensor errors a simulation drew (truth for tests and drift predictions).

    Attributes
    ----------
    gyro_bias_radps : ndarray, shape (N, 3)
        Gyro bias at each sample (constant + wander + late drift), rad/s.
    gyro_scale : ndarray, shape (3,)
        Gyro scale-factor errors (relative).
    accel_bias_mps2 : ndarray, shape (3,)
        Accelerometer bias, m/s^2.
    accel_scale : ndarray, shape (3,)
        Accelerometer scale-factor errors (relative).
    mount_yaw_rad : float
        Device yaw minus walking direction, rad.
    weinberg_k_m : float
        The walker's true Weinberg gain, m.
    """

    gyro_bias_radps: np.ndarray
    gyro_scale: np.ndarray
    accel_bias_mps2: np.ndarray
    accel_scale: np.ndarray
    mount_yaw_rad: float
    weinberg_k_m: float


def _foot_motion(walk: Walk, t_s: np.ndarray) -> Motion:
    """Right foot: stance on footprints beside the path, minimum-jerk swings between them."""
    # Footprints: the stops and every other heel strike of each leg (the right foot's).
    first_in_leg = walk.first_of_leg
    leg_id = np.cumsum(first_in_leg) - 1
    index_in_leg = np.arange(len(walk.step_t_s)) - np.flatnonzero(first_in_leg)[leg_id]
    last_in_leg = np.concatenate([first_in_leg[1:], [True]])
    # The right foot takes every second step and closes up beside the left at every stop
    # (a short shuffle at the leg's last strike when that one was the left foot's).
    right_strike = (index_in_leg % 2 == 1) | last_in_leg
    strike_t = walk.step_t_s[right_strike]
    prev_t = np.concatenate([[0.0], strike_t[:-1]])
    departures = walk.step_start_t_s[first_in_leg]
    # A swing ends at the strike and lasts FOOT_SWING_S, or less after a short standstill.
    swing_start = np.maximum(strike_t - FOOT_SWING_S,
                             np.maximum(prev_t, departures[leg_id[right_strike]]) + 0.05)
    swing_dur = strike_t - swing_start

    def footprint(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy, heading = resample_walk(walk, t)
        right = np.column_stack([np.cos(heading), -np.sin(heading)])
        return xy + FOOT_OFFSET_M * right, heading

    start_xy, start_heading = footprint(np.array([0.0]))
    strike_xy, strike_heading = footprint(strike_t)
    from_xy = np.vstack([start_xy, strike_xy[:-1]])
    from_heading = np.concatenate([start_heading, strike_heading[:-1]])

    j = np.searchsorted(strike_t, t_s, side="left")  # the swing that ends next
    j = np.minimum(j, len(strike_t) - 1)
    tau = np.clip((t_s - swing_start[j]) / swing_dur[j], 0.0, 1.0)
    in_swing = (t_s > swing_start[j]) & (t_s < strike_t[j])
    after_last = t_s >= strike_t[-1]
    tau = np.where(after_last, 1.0, tau)
    big_t = swing_dur[j]
    delta = strike_xy[j] - from_xy[j]
    # Minimum-jerk profile mj(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 and its second derivative.
    mj_acc = np.where(in_swing, 60.0 * tau - 180.0 * tau**2 + 120.0 * tau**3, 0.0) / big_t**2
    mj = 10.0 * tau**3 - 15.0 * tau**4 + 6.0 * tau**5
    acc = np.zeros((len(t_s), 3))
    acc[:, :2] = delta * mj_acc[:, None]
    acc[:, 2] = np.where(in_swing, FOOT_LIFT_M * 2.0 * np.pi**2 / big_t**2 * np.cos(2.0 * np.pi * tau), 0.0)
    turn = np.angle(np.exp(1j * (strike_heading[j] - from_heading[j])))
    yaw = from_heading[j] + turn * mj
    pitch = np.where(in_swing, -FOOT_PITCH_RAD * np.sin(2.0 * np.pi * tau), 0.0)
    return Motion(attitude=attitude_ypr(yaw, pitch, np.zeros_like(yaw)), acc_enu_mps2=acc)


def _body_rates(attitude: Rotation, dt_s: float) -> np.ndarray:
    """Angular rate in the sensor frame from consecutive attitudes (central difference), rad/s."""
    n = len(attitude)
    rates = np.zeros((n, 3))
    rates[1:-1] = (attitude[:-2].inv() * attitude[2:]).as_rotvec() / (2.0 * dt_s)
    rates[0], rates[-1] = rates[1], rates[-2]
    return rates


def _distance_to_polygon(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance from points (N x 2) to a polygon's boundary, m."""
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    ab = b - a
    rel = xy[:, None, :] - a[None, :, :]
    u = np.clip(np.sum(rel * ab, axis=2) / np.sum(ab * ab, axis=1), 0.0, 1.0)
    closest = a[None, :, :] + u[:, :, None] * ab[None, :, :]
    return np.min(np.linalg.norm(xy[:, None, :] - closest, axis=2), axis=1)


def magnetic_disturbance_ut(xy: np.ndarray, buildings: list[Building], peak_ut: float,
                            rng: np.random.Generator) -> np.ndarray:
    """Disturbance field near buildings (steel frames, parked cars), ENU uT, N x 3.

    Each building adds a field of fixed random direction whose strength is
    ``peak_ut * exp(-d / MAG_DISTURBANCE_DECAY_M)`` at distance ``d`` from
    its footprint.
    """
    field = np.zeros((len(xy), 3))
    for building in buildings:
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        d = _distance_to_polygon(xy, np.asarray(building.polygon_m, dtype=np.float64))
        field += peak_ut * np.exp(-d / MAG_DISTURBANCE_DECAY_M)[:, None] * direction
    return field


def _gyro_bias(preset: ImuPreset, scenario: Scenario, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gyro bias over time: constant + random walk + the scenario's late z drift, rad/s (N x 3)."""
    cfg = scenario.imu
    lo, hi = preset.gyro_bias_range_dps
    initial = rng.uniform(lo, hi, 3) * rng.choice([-1.0, 1.0], 3)
    if cfg.gyro_bias_dps is not None:
        initial[2] = cfg.gyro_bias_dps
    dt = t_s[1] - t_s[0]
    walk = np.cumsum(rng.standard_normal((len(t_s), 3)), axis=0) * preset.gyro_bias_walk_dps_rts * np.sqrt(dt)
    bias_dps = initial + walk
    if cfg.heading_drift_start_s is not None:
        bias_dps[:, 2] += np.where(t_s >= cfg.heading_drift_start_s, cfg.heading_drift_dps, 0.0)
    return np.radians(bias_dps)


def simulate_imu_with_errors(scenario: Scenario, walk: Walk) -> tuple[ImuLog, ImuErrors]:
    """Simulate the scenario's IMU on a walk and return the errors it drew.

    Parameters
    ----------
    scenario : Scenario
        Uses ``scenario.imu``, ``scenario.channel.buildings`` and ``scenario.seed``.
    walk : Walk
        The walker (from :func:`sim.walk.simulate_walk`).

    Returns
    -------
    ImuLog, ImuErrors
        Samples at ``scenario.imu.rate_hz`` over the whole walk (at uneven times and
        with runs missing where ``time_jitter`` and ``gaps_per_minute`` say so), and
        the error truth (``gyro_bias_radps`` at the samples returned).

    Raises
    ------
    ValueError
        Unknown preset or carriage, a carriage other than ``hand`` (or a carriage
        change) on the foot, a non-positive rate, a jitter or gap setting out of
        range, carriage changes out of order or overlapping, or a ``swing_deg`` with
        no swinging arm to set.
    """
    cfg = scenario.imu
    if cfg.preset not in PRESETS:
        raise ValueError(f"imu.preset: unknown {cfg.preset!r}; known: {sorted(PRESETS)}")
    if cfg.carriage not in CARRIAGES:
        raise ValueError(f"imu.carriage: unknown {cfg.carriage!r}; known: {sorted(CARRIAGES)}")
    if cfg.rate_hz <= 0:
        raise ValueError(f"imu.rate_hz must be > 0, got {cfg.rate_hz}")
    preset = PRESETS[cfg.preset]
    if preset.mount != "hand" and (cfg.carriage != "hand" or cfg.carriage_changes):
        raise ValueError(f"imu.carriage: {cfg.carriage!r} applies to the phone preset only, not {cfg.preset!r}")
    _check_carriage_changes(cfg)
    if not 0.0 <= cfg.time_jitter <= 0.2:
        raise ValueError(f"imu.time_jitter must lie in [0, 0.2], got {cfg.time_jitter}")
    if cfg.gaps_per_minute < 0 or cfg.gap_s <= 0:
        raise ValueError(f"imu.gaps_per_minute must be >= 0 and imu.gap_s > 0, got {cfg.gaps_per_minute}, "
                         f"{cfg.gap_s}")
    carriage = CARRIAGES[cfg.carriage]
    rng = np.random.default_rng([scenario.seed, IMU_STREAM])
    dt = 1.0 / cfg.rate_hz
    t_s = np.arange(int(np.floor(walk.track.t_s[-1] * cfg.rate_hz)) + 1) * dt
    n = len(t_s)

    mount_yaw = float(rng.normal(0.0, preset.mount_yaw_sigma_rad)) if preset.mount_yaw_sigma_rad > 0 else 0.0
    if preset.mount == "hand":
        motion = _phone_motion(scenario, walk, t_s, preset, mount_yaw)
    else:
        motion = _foot_motion(walk, t_s)

    specific_force_enu = motion.acc_enu_mps2 + np.array([0.0, 0.0, GRAVITY_MPS2])
    true_acc = motion.attitude.inv().apply(specific_force_enu)
    true_gyro = _body_rates(motion.attitude, dt)
    xy, _ = resample_walk(walk, t_s)
    # The magnetic scene has its own stream so that adding a building changes no other error.
    scene_rng = np.random.default_rng([scenario.seed, IMU_STREAM, MAG_SCENE_SUBSTREAM])
    field_enu = EARTH_FIELD_UT + magnetic_disturbance_ut(xy, scenario.channel.buildings,
                                                         cfg.mag_disturbance_ut, scene_rng)
    true_mag = motion.attitude.inv().apply(field_enu)
    sample_t, keep = _sample_times(cfg, t_s, np.random.default_rng([scenario.seed, IMU_STREAM, TIMING_SUBSTREAM]))
    if sample_t is not t_s:
        # The motion is smooth on the scale of a sample interval: its readings at the uneven times are
        # interpolated; the noise and bias below are drawn per sample as on the uniform grid.
        true_acc, true_gyro, true_mag = (interpolate(t_s, v, sample_t) for v in (true_acc, true_gyro, true_mag))

    errors = ImuErrors(
        gyro_bias_radps=_gyro_bias(preset, scenario, t_s, rng),
        gyro_scale=rng.normal(0.0, preset.gyro_scale_error, 3),
        accel_bias_mps2=rng.normal(0.0, preset.accel_bias_mps2, 3),
        accel_scale=rng.normal(0.0, preset.accel_scale_error, 3),
        mount_yaw_rad=mount_yaw, weinberg_k_m=preset.weinberg_k_m / carriage.bounce_scale**0.25)
    gyro_sigma = np.radians(preset.gyro_noise_dps_rthz) * np.sqrt(cfg.rate_hz)
    gyro = (true_gyro * (1.0 + errors.gyro_scale) + errors.gyro_bias_radps
            + gyro_sigma * rng.standard_normal((n, 3)))
    acc = (true_acc * (1.0 + errors.accel_scale) + errors.accel_bias_mps2
           + preset.accel_noise_mps2 * rng.standard_normal((n, 3)))
    mag = (true_mag + rng.normal(0.0, preset.mag_offset_ut, 3)
           + preset.mag_noise_ut * rng.standard_normal((n, 3)))
    if not cfg.magnetometer:
        mag = np.zeros_like(mag)
    imu = ImuLog(t_s=sample_t, acc_mps2=acc, gyro_radps=gyro, mag_ut=mag)
    if keep.all():
        return imu, errors
    return imu.select(keep), dataclasses.replace(errors, gyro_bias_radps=errors.gyro_bias_radps[keep])


def _check_carriage_changes(cfg: ImuConfig) -> None:
    """Raise ValueError for an unknown carriage, a change before the previous one ends, or a stray ``swing_deg``."""
    end_s = 0.0
    for i, change in enumerate(cfg.carriage_changes):
        where = f"imu.carriage_changes[{i}]"
        if change.carriage not in CARRIAGES:
            raise ValueError(f"{where}: unknown carriage {change.carriage!r}; known: {sorted(CARRIAGES)}")
        if change.duration_s <= 0 or change.t_s < end_s:
            raise ValueError(f"{where}: needs duration_s > 0 and t_s >= {end_s} (the previous change's end), "
                             f"got t_s = {change.t_s}, duration_s = {change.duration_s}")
        end_s = change.t_s + change.duration_s
    names = [cfg.carriage] + [change.carriage for change in cfg.carriage_changes]
    if cfg.swing_deg is not None and not any(CARRIAGES[name].swings_arm for name in names):
        raise ValueError(f"imu.swing_deg: none of the walk's carriages {names} swings an arm")


def _phone_motion(scenario: Scenario, walk: Walk, t_s: np.ndarray, preset: ImuPreset, mount_yaw_rad: float) -> Motion:
    """The phone in its carriage, handled into the next ones at the times ``imu.carriage_changes`` says.

    Each carriage draws its randomness (placement, head turns, jostling) from its own
    sub-stream of the carriage stream (the first one from the carriage stream itself), so
    that adding a change leaves the carriages before it as they were.
    """
    cfg = scenario.imu

    def motion(k: int, name: str) -> Motion:
        carriage = CARRIAGES[name]
        if cfg.swing_deg is not None and carriage.swings_arm:
            carriage = dataclasses.replace(carriage, swing_rad=np.radians(cfg.swing_deg))
        stream = [scenario.seed, IMU_STREAM, CARRIAGE_SUBSTREAM] + ([k] if k else [])
        return carriage_motion(walk, t_s, preset.weinberg_k_m, carriage, cfg.step_gain_error, mount_yaw_rad,
                               np.random.default_rng(stream))

    result = motion(0, cfg.carriage)
    for k, change in enumerate(cfg.carriage_changes, start=1):
        result = change_carriage(result, motion(k, change.carriage), t_s, change.t_s, change.duration_s)
    return result


def _sample_times(cfg: ImuConfig, t_s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The times the samples are taken at, and which of them the device delivers.

    Returns ``t_s`` itself when ``cfg.time_jitter`` is 0. Otherwise each time
    scatters about its nominal one by ``time_jitter / sqrt(2)`` intervals (so
    that an interval, the difference of two, scatters by ``time_jitter``),
    clipped to :data:`MAX_TIME_OFFSET` intervals so that the order is kept and
    to the span of ``t_s``. Gaps: a Poisson number of runs of ``gap_s`` seconds
    (``gaps_per_minute`` on average) start at uniformly drawn times; their
    samples are dropped.
    """
    times = t_s
    dt = t_s[1] - t_s[0]
    if cfg.time_jitter > 0:
        offsets = np.clip(rng.normal(0.0, cfg.time_jitter / np.sqrt(2.0), len(t_s)), -MAX_TIME_OFFSET,
                          MAX_TIME_OFFSET)
        times = np.clip(t_s + offsets * dt, t_s[0], t_s[-1])
    keep = np.ones(len(t_s), dtype=bool)
    if cfg.gaps_per_minute > 0:
        count = rng.poisson(cfg.gaps_per_minute * (t_s[-1] - t_s[0]) / 60.0)
        for start in rng.uniform(t_s[0], t_s[-1], count):
            keep &= (times < start) | (times >= start + cfg.gap_s)
    return times, keep


def simulate_imu(scenario: Scenario, walk: Walk) -> ImuLog:
    """Simulate the scenario's IMU on a walk (see :func:`simulate_imu_with_errors`)."""
    return simulate_imu_with_errors(scenario, walk)[0]
