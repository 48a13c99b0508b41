"""The PDR chain: IMU log -> steps -> step lengths -> heading -> positions (docs/method.md §3).

The Weinberg gain K is never assumed: either the caller passes one calibrated
beforehand with :func:`calibrate_weinberg_k_from_walk` (a walk of known
length by the same person and device), or chooses the linear frequency model,
which needs no calibration.

What a phone gives is taken as it comes: samples at uneven times (a phone's
time stamps scatter, and runs of samples go missing) are linearly resampled
onto a uniform grid at their mean rate (:mod:`dtmbnav_core.resampling`), and
the jitter and gaps found are reported in the result; a log without a
magnetometer (``mag_ut`` all zeros, the convention of
:func:`dtmbnav_core.sensors.read_has_magnetometer`) gets the attitude from the
gyro and accelerometer alone. Each such choice is said in ``PdrResult.notes``.

The heading a step moves along comes from the phone's forward axis or from
the walking direction (:mod:`fusion.pdr.walking_direction`): a phone held in
front points along the walk, one in a pocket or a swinging hand does not, and
a change of carriage would otherwise be taken for a turn.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from dtmbnav_core.records import ImuLog, PdrSteps, Track
from dtmbnav_core.resampling import SampleTiming, check_increasing, interpolate, is_uniform, sample_timing, uniform_grid
from fusion.pdr.attitude import AttitudeConfig, forward_heading, gyro_bias_at_rest, madgwick_attitude
from fusion.pdr.dead_reckoning import dead_reckon, mean_heading_over_windows, resample_steps
from fusion.pdr.step_length import calibrate_weinberg_k, frequency_length, weinberg_length
from fusion.pdr.steps import DetectedSteps, StepDetectorConfig, detect_steps
from fusion.pdr.walking_direction import WalkingConfig, WalkingDirection, walking_direction

STEP_MODELS = ("weinberg", "frequency")
#: Carriages the PDR tells apart (by the attitude's median swing over a stride, ``WalkingConfig.swing_deg``),
#: and what they mean for the user.
CARRIAGE_CLASSES = {
    "steady": "held steady (in the hand, texting, at the ear, in a bag): heading from the phone's yaw",
    "swinging": "on a swinging limb (a trouser pocket, a swinging hand): heading from the walking direction",
}
HEADING_SOURCES = ("phone", "walking", "auto")


@dataclass(frozen=True)
class PdrConfig:
    """Settings of the PDR chain.

    Attributes
    ----------
    step_model : str
        ``"weinberg"`` (needs ``weinberg_k_m``) or ``"frequency"`` (L = 0.4 f - 0.01).
    weinberg_k_m : float or None
        Calibrated Weinberg gain, m.
    weinberg_k_by_carriage_m : mapping of str to float
        Weinberg gains calibrated for a carriage (keys of :data:`CARRIAGE_CLASSES`), m; the
        walk's carriage takes its own where there is one, else ``weinberg_k_m``. The
        swing of a pocket or a hand moves the acceleration that Weinberg's relation
        reads, so one gain does not fit every carriage.
    output_rate_hz : float
        Rate of the resampled track, Hz.
    heading_source : str
        ``"phone"``: the heading of the phone's forward axis; ``"walking"``: the
        phone's yaw plus the smoothed phone-to-walk offset
        (:mod:`fusion.pdr.walking_direction`); ``"auto"``: the walking direction
        where the phone's attitude swings over a stride (pocket, swinging hand)
        or its carriage changes, else the phone's heading.
    steps : StepDetectorConfig
    attitude : AttitudeConfig
    walking : WalkingConfig
    """

    step_model: str = "weinberg"
    weinberg_k_m: float | None = None
    weinberg_k_by_carriage_m: Mapping[str, float] = field(default_factory=dict)
    output_rate_hz: float = 10.0
    heading_source: str = "auto"
    steps: StepDetectorConfig = field(default_factory=StepDetectorConfig)
    attitude: AttitudeConfig = field(default_factory=AttitudeConfig)
    walking: WalkingConfig = field(default_factory=WalkingConfig)


@dataclass(frozen=True)
class PdrResult:
    """PDR output: one row per step, and the same resampled at ``output_rate_hz``.

    Both are in the PDR frame: start at (0, 0), heading relative to the initial one.

    Attributes
    ----------
    steps : PdrSteps
    track : Track
    timing : SampleTiming or None
        Rate, jitter and gaps of the IMU's sample times (None where not measured).
    notes : tuple of str
        What the PDR did in place of its settings, for the user: resampled
        uneven times, bridged gaps, no magnetometer, a change of carriage.
    walking : WalkingDirection or None
        Per step: the phone-to-walk offset, the changes of carriage found and
        the attitude's swing (None where no step was detected).
    walking_used : bool
        Whether the steps' heading is the walking direction's (else the phone's).
    carriage : str
        How the phone rode over most of the walk, from its attitude's swing over a
        stride: a key of :data:`CARRIAGE_CLASSES`, or ``"unknown"`` without steps.
    """

    steps: PdrSteps
    track: Track
    timing: SampleTiming | None = None
    notes: tuple[str, ...] = ()
    walking: WalkingDirection | None = None
    walking_used: bool = False
    carriage: str = "unknown"

    @property
    def carriage_changes(self) -> int:
        """Changes of carriage found during the walk."""
        return 0 if self.walking is None else int(np.count_nonzero(self.walking.carriage_change))


def check_imu(imu: ImuLog) -> None:
    """Raise ValueError unless the IMU's three sensors are N x 3 and finite."""
    for name in ("acc_mps2", "gyro_radps", "mag_ut"):
        values = getattr(imu, name)
        if values.ndim != 2 or values.shape[1] != 3:
            raise ValueError(f"imu.{name} must be N x 3, got shape {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"imu.{name} contains NaN or inf")


def check_config(config: PdrConfig) -> None:
    """Raise ValueError for an unknown step model or heading source, the Weinberg model without a
    gain, or a non-positive output rate."""
    if config.step_model not in STEP_MODELS:
        raise ValueError(f"PdrConfig.step_model: unknown {config.step_model!r}; known: {STEP_MODELS}")
    if config.step_model == "weinberg" and config.weinberg_k_m is None:
        raise ValueError("PdrConfig.weinberg_k_m is required by the Weinberg model; calibrate it with "
                         "calibrate_weinberg_k_from_walk on a walk of known length, or use step_model='frequency'")
    if config.heading_source not in HEADING_SOURCES:
        raise ValueError(f"PdrConfig.heading_source: unknown {config.heading_source!r}; known: {HEADING_SOURCES}")
    if config.output_rate_hz <= 0:
        raise ValueError(f"PdrConfig.output_rate_hz must be > 0, got {config.output_rate_hz}")


def uniform_imu(imu: ImuLog) -> tuple[ImuLog, SampleTiming, tuple[str, ...]]:
    """The IMU log on a uniform time grid, the timing of its samples, and notes for the user.

    A log already on a uniform grid (:func:`~dtmbnav_core.resampling.is_uniform`)
    is returned as it is. Otherwise every axis is linearly interpolated onto a grid
    from the first sample at the mean rate of the intervals that are no gap
    (:func:`~dtmbnav_core.resampling.sample_timing`); a gap is bridged by a straight
    line, so a step inside it may go uncounted, and each is noted.

    Raises
    ------
    ValueError
        Times that do not strictly increase (a repeated or decreasing time stamp).
    """
    check_increasing(imu.t_s, "imu.t_s")
    timing = sample_timing(imu.t_s)
    if is_uniform(imu.t_s):
        return imu, timing, ()
    grid = uniform_grid(float(imu.t_s[0]), float(imu.t_s[-1]), timing.rate_hz)
    resampled = ImuLog(t_s=grid, **{name: interpolate(imu.t_s, getattr(imu, name), grid)
                                    for name in ("acc_mps2", "gyro_radps", "mag_ut")})
    notes = [(f"imu: uneven sample times ({timing.describe()}): resampled onto a uniform grid at "
              f"{timing.rate_hz:.2f} Hz")]
    notes += [(f"imu: no samples for {end - start:.3f} s from {start:.3f} s: bridged by interpolation (a step "
               "there may go uncounted)") for start, end in timing.gaps_s]
    return resampled, timing, tuple(notes)


def has_magnetometer(imu: ImuLog) -> bool:
    """Whether the log holds magnetometer samples (all zeros stands for none, as in an imported log)."""
    return bool(np.any(imu.mag_ut != 0.0))


def run_pdr(imu: ImuLog, config: PdrConfig) -> PdrResult:
    """Run pedestrian dead reckoning on an IMU log.

    Parameters
    ----------
    imu : ImuLog
        Accelerometer, gyro and magnetometer, sensor frame x right, y forward,
        z up; uneven sample times are resampled (:func:`uniform_imu`), and a
        magnetometer of all zeros (none) makes the attitude gyro-and-accelerometer.
    config : PdrConfig

    Returns
    -------
    PdrResult

    Raises
    ------
    ValueError
        Malformed IMU data (including sample times that do not strictly
        increase), an unknown step model, or the Weinberg model without a gain.
    """
    check_imu(imu)
    check_config(config)
    imu, timing, notes = uniform_imu(imu)
    attitude = config.attitude
    if attitude.use_magnetometer and not has_magnetometer(imu):
        attitude = dataclasses.replace(attitude, use_magnetometer=False)
        notes += (("imu: no magnetometer (mag_ut all zeros): the attitude comes from the gyro and accelerometer "
                   "alone, and the heading drifts with the gyro's bias"),)
    detected = detect_steps(imu.t_s, imu.acc_mps2, config.steps)
    step_heading, walking, walking_used = _step_heading(imu, detected, attitude, config)
    if walking is not None and walking.carriage_change.any():
        notes += tuple(f"pdr: the phone changed carriage (its attitude moved by more than "
                       f"{config.walking.change_deg:g} deg) before the step at {t:.2f} s: the phone-to-walk "
                       "offset was estimated afresh after it" + ("" if walking_used else
                       ", but the heading is the phone's (heading_source='phone'), so it may turn there")
                       for t in detected.t_s[walking.carriage_change])
    carriage = "unknown" if walking is None else (
        "swinging" if np.median(walking.swing_rad) > np.radians(config.walking.swing_deg) else "steady")
    if config.step_model == "weinberg":
        lengths = weinberg_length(detected.acc_max_mps2, detected.acc_min_mps2, weinberg_gain(config, carriage))
    else:
        lengths = frequency_length(1.0 / detected.duration_s)
    steps = dead_reckon(detected.t_s, detected.start_t_s, lengths, step_heading)
    n_out = int(np.floor((imu.t_s[-1] - imu.t_s[0]) * config.output_rate_hz)) + 1
    track = resample_steps(steps, detected.start_t_s, imu.t_s[0] + np.arange(n_out) / config.output_rate_hz)
    return PdrResult(steps=steps, track=track, timing=timing, notes=notes, walking=walking,
                     walking_used=walking_used, carriage=carriage)


def weinberg_gain(config: PdrConfig, carriage: str) -> float | None:
    """The Weinberg gain for a walk in ``carriage``: its own calibrated one, else the general one, m."""
    return config.weinberg_k_by_carriage_m.get(carriage, config.weinberg_k_m)


def _step_heading(imu: ImuLog, detected: DetectedSteps, attitude: AttitudeConfig,
                  config: PdrConfig) -> tuple[np.ndarray, WalkingDirection | None, bool]:
    """Each step's relative heading (rad), the walking-direction estimate, and whether the heading is its.

    ``imu`` is on a uniform grid; one AHRS run serves the phone's heading and the walking direction.
    """
    first_step = detected.t_s[0] if len(detected.t_s) else imu.t_s[-1]
    rate_hz = (len(imu.t_s) - 1) / (imu.t_s[-1] - imu.t_s[0])
    bias, still = gyro_bias_at_rest(imu.t_s, imu.gyro_radps, first_step, attitude)
    mag = imu.mag_ut if attitude.use_magnetometer else None
    gyro = imu.gyro_radps - bias
    rotation = madgwick_attitude(gyro, imu.acc_mps2, mag, rate_hz, attitude.gain)
    heading = forward_heading(imu.t_s, rotation, still)
    phone = mean_heading_over_windows(imu.t_s, heading, detected.start_t_s, detected.t_s)
    if len(detected.t_s) == 0:
        return phone, None, False
    walking = walking_direction(imu.t_s, imu.acc_mps2, gyro, rotation, still, detected.t_s,
                                detected.start_t_s, attitude.gain, config.walking)
    use = config.heading_source == "walking" or (config.heading_source == "auto" and (
        walking.carriage_change.any() or np.median(walking.swing_rad) > np.radians(config.walking.swing_deg)))
    return (walking.heading_rad if use else phone), walking, bool(use)


def calibrate_weinberg_k_from_walk(imu: ImuLog, distance_m: float, config: PdrConfig | None = None) -> float:
    """Weinberg gain K from a recording of a walk of known length (same person and device), m.

    Every step detected in ``imu`` is assumed to belong to the ``distance_m``
    walked; the detector settings of ``config`` are used so that K matches
    the smoothing that :func:`run_pdr` will apply.
    """
    check_imu(imu)
    detector = (config or PdrConfig()).steps
    imu, _, _ = uniform_imu(imu)
    detected = detect_steps(imu.t_s, imu.acc_mps2, detector)
    return calibrate_weinberg_k(detected.acc_max_mps2, detected.acc_min_mps2, distance_m)
