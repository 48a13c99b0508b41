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
are unknown. The same attitude gives the walking direction
(:mod:`fusion.pdr.walking_direction`) where the phone does not point along the walk.
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


def gyro_bias_at_rest(t_s: np.ndarray, gyro_radps: np.ndarray, first_step_t_s: float,
                      config: AttitudeConfig) -> tuple[np.ndarray, np.ndarray]:
    """The gyro's static bias (rad/s, shape (3,)) and the rest mask it was measured over.

    The bias is the mean rate over :func:`initial_standstill`, or zero with
    fewer than :data:`MIN_REST_SAMPLES` rest samples.
    """
    still = initial_standstill(t_s, gyro_radps, first_step_t_s, config)
    bias = gyro_radps[still].mean(axis=0) if np.count_nonzero(still) >= MIN_REST_SAMPLES else np.zeros(3)
    return bias, still


def madgwick_attitude(gyro_radps: np.ndarray, acc_mps2: np.ndarray, mag_ut: np.ndarray | None, rate_hz: float,
                      gain: float, initial: tuple[np.ndarray, np.ndarray | None] | None = None) -> Rotation:
    """Sensor-to-earth rotation at every sample from the Madgwick filter (earth x north, y west, z up).

    Parameters
    ----------
    gyro_radps, acc_mps2 : ndarray, shape (N, 3)
        Bias-corrected angular rate (rad/s) and specific force (m/s^2), sensor frame.
    mag_ut : ndarray, shape (N, 3), or None
        Magnetic field, uT (None: gyro and accelerometer only).
    rate_hz : float
        Sample rate, Hz.
    gain : float
        Madgwick ``beta``.
    initial : (ndarray, ndarray or None), optional
        Specific force and field (sensor frame) to start from in place of the
        first sample's: ``ahrs`` starts from its first sample, so these are fed as
        one extra, motionless sample ahead of the record and its attitude dropped.
        A mean over a stride gives a better start than a walking instant.
    """
    if initial is not None:
        acc_mps2 = np.vstack([initial[0], acc_mps2])
        gyro_radps = np.vstack([np.zeros(3), gyro_radps])
        mag_ut = None if mag_ut is None else np.vstack([initial[1], mag_ut])
    q_wxyz = Madgwick(gyr=gyro_radps, acc=acc_mps2, mag=mag_ut, frequency=rate_hz, gain=gain).Q
    rotation = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]])
    return rotation if initial is None else rotation[1:]


def forward_heading(t_s: np.ndarray, attitude: Rotation, still: np.ndarray) -> np.ndarray:
    """Heading of the sensor's forward axis projected on the horizontal, relative to its rest value, rad.

    Clockwise from north, unwrapped; ``attitude`` from :func:`madgwick_attitude`,
    ``still`` the rest mask of :func:`gyro_bias_at_rest`.
    """
    forward = attitude.apply(FORWARD_AXIS)
    # Earth frame x = north, y = west: clockwise-from-north heading is atan2(east, north).
    heading = np.unwrap(np.arctan2(-forward[:, 1], forward[:, 0]))
    return heading - rest_reference(t_s, heading, still)


def rest_reference(t_s: np.ndarray, angle_rad: np.ndarray, still: np.ndarray) -> float:
    """Mean of an angle over the last second of rest (or its first sample if there was none), rad."""
    last_second = still & (t_s >= t_s[still][-1] - 1.0) if np.any(still) else np.arange(len(t_s)) == 0
    return float(angle_rad[last_second].mean())
