"""Relative heading from an AHRS (docs/method.md §3) built on the maintained ``ahrs`` package.

Choice of filter. ``ahrs.filters.Madgwick`` (MARG form) is used:

- it has a single gain, ``beta``, which sets how fast the accelerometer and
  magnetometer pull the gyro-integrated attitude; with a small gain the
  heading is essentially the integrated gyro with a slow magnetic anchor, so
  a magnetic disturbance near a building bends it only a little;
- its magnetic step uses only the field's direction in the horizontal plane
  (the reference is rebuilt each sample as ``[b_x, 0, b_z]``), so it is
  insensitive to the local inclination;
- ``ahrs.filters.Mahony`` adds an integral term that estimates the gyro bias
  through the magnetometer: near buildings it learns the disturbance as a
  bias and keeps the heading wrong after the walker has passed; ``EKF`` needs
  a set of noise densities per device and is several times slower.

The phone's static gyro bias is removed first, estimated over the standing
period before the walk (zero angular-rate update; rest is detected from the
gyro's own moving standard deviation, so the first, gentle step is excluded): docs/scenarios.md's walker stands still
there, and a 0.1-0.5 deg/s bias would otherwise dominate the heading drift.

Frames: the ``ahrs`` quaternion rotates the sensor frame into an earth frame
whose z is the measured specific force at rest (up) and whose x is magnetic
north (so y is west). The heading (clockwise from north) is that of the
sensor's forward (y) axis projected on the horizontal; it is made relative by
subtracting its mean over the last second of rest before the walk, because the
device's yaw offset from the walking direction and the magnetic declination
are unknown.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ahrs.filters import Madgwick
from scipy.spatial.transform import Rotation

from dtmbnav_core.moving import moving_std

#: Fewest rest samples for a gyro-bias estimate (else no bias is removed).
MIN_REST_SAMPLES = 50
#: The sensor's forward axis (y in both the phone and foot frames).
FORWARD_AXIS = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class AttitudeConfig:
    """AHRS settings.

    Attributes
    ----------
    gain : float
        Madgwick ``beta`` (rad/s scale of the accelerometer/magnetometer correction).
    use_magnetometer : bool
        MARG (gyro + accel + mag) if True, else gyro + accel only.
    bias_window_s : float
        Longest standing period before the first step used to estimate the gyro bias, s.
    rest_window_s : float
        Window of the moving standard deviation that detects rest, s.
    rest_threshold_radps : float
        Rest: every gyro axis's moving standard deviation below this, rad/s.
    """

    gain: float = 0.005
    use_magnetometer: bool = True
    bias_window_s: float = 8.0
    rest_window_s: float = 0.5
    rest_threshold_radps: float = np.radians(1.0)


@dataclass(frozen=True)
class HeadingEstimate:
    """Relative heading at every IMU sample.

    Attributes
    ----------
    t_s : ndarray
        Sample times, s.
    heading_rad : ndarray
        Heading relative to the initial one, clockwise, unwrapped (continuous), rad.
    gyro_bias_radps : ndarray, shape (3,)
        Gyro bias removed (estimated while standing), rad/s.
    """

    t_s: np.ndarray
    heading_rad: np.ndarray
    gyro_bias_radps: np.ndarray


def standstill_mask(gyro_radps: np.ndarray, rate_hz: float, window_s: float, threshold_radps: float) -> np.ndarray:
    """Samples where the device is at rest: every gyro axis's moving standard deviation is small.

    The standard deviation (not the mean) is tested so that an unknown bias
    does not matter; walking makes the hand sway at several deg/s.
    """
    return np.all(moving_std(gyro_radps, window_s, rate_hz) < threshold_radps, axis=1)


def initial_standstill(t_s: np.ndarray, gyro_radps: np.ndarray, first_step_t_s: float,
                       config: AttitudeConfig) -> np.ndarray:
    """Boolean mask of the last stretch of rest before the first step (at most ``bias_window_s``).

    Empty (all False) when the recording starts already walking.
    """
    rate_hz = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    rest = standstill_mask(gyro_radps, rate_hz, config.rest_window_s, config.rest_threshold_radps)
    rest_before_step = np.flatnonzero(rest & (t_s < first_step_t_s))
    if rest_before_step.size == 0:
        return np.zeros(len(t_s), dtype=bool)
    # The centred window already flags rest as ending half a window early; keep another half as margin.
    end = t_s[rest_before_step[-1]] - 0.5 * config.rest_window_s
    return rest & (t_s < end) & (t_s >= end - config.bias_window_s)


def relative_heading(t_s: np.ndarray, acc_mps2: np.ndarray, gyro_radps: np.ndarray, mag_ut: np.ndarray,
                     first_step_t_s: float, config: AttitudeConfig) -> HeadingEstimate:
    """Heading of the device relative to its heading just before the first step.

    Parameters
    ----------
    t_s : ndarray
        Uniform sample times, s.
    acc_mps2, gyro_radps, mag_ut : ndarray, shape (N, 3)
        IMU samples in the sensor frame (x right, y forward, z up).
    first_step_t_s : float
        Time of the first detected step, s: the rest before it calibrates the
        gyro bias and fixes the heading reference.
    config : AttitudeConfig
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    rate_hz = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    gyro_radps = np.asarray(gyro_radps, dtype=np.float64)
    still = initial_standstill(t_s, gyro_radps, first_step_t_s, config)
    bias = gyro_radps[still].mean(axis=0) if np.count_nonzero(still) >= MIN_REST_SAMPLES else np.zeros(3)
    mag = np.asarray(mag_ut, dtype=np.float64) if config.use_magnetometer else None
    ahrs_filter = Madgwick(gyr=gyro_radps - bias,
                           acc=np.asarray(acc_mps2, dtype=np.float64), mag=mag,
                           frequency=rate_hz, gain=config.gain)
    q_wxyz = ahrs_filter.Q
    forward = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]).apply(FORWARD_AXIS)
    # Earth frame x = north, y = west: clockwise-from-north heading is atan2(east, north).
    heading = np.unwrap(np.arctan2(-forward[:, 1], forward[:, 0]))
    # Reference: the heading over the last second of rest (or the first sample if there was none).
    last_second = still & (t_s >= t_s[still][-1] - 1.0) if np.any(still) else np.arange(len(t_s)) == 0
    reference = heading[last_second].mean()
    return HeadingEstimate(t_s=t_s, heading_rad=heading - reference, gyro_bias_radps=bias)
