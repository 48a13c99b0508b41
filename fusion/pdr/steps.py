"""Step detection from the acceleration norm with an adaptive threshold (docs/method.md §3).

The norm of the specific force is orientation-free; its slowly varying part
(gravity, plus whatever bias and scale error the accelerometer has) is removed
with a long moving average, the rest is smoothed with a short moving average,
and a step is a local peak above an amplitude threshold at least a minimum
time after a higher one.

The threshold adapts to the walker's own acceleration level, as in Zhao's
pedometer (N. Zhao, "Full-featured pedometer design realized with 3-axis
digital accelerometer", Analog Dialogue 44-06, 2010: the dynamic threshold is
the mid-level of the recent signal), because that level varies several-fold
with the carriage and the pace (Brajdic & Harle, "Walk detection and step
counting on unconstrained smartphones", UbiComp 2013): a phone held to text
during a slow walk sees a small fraction of what a pocket sees at a brisk
pace. Here the level is a running high percentile of the dynamic acceleration
over a few seconds, the threshold a fixed fraction of it, and a low absolute
floor keeps sensor noise from counting while the walker stands still.

Each step also gets its window (from the previous peak or, for the first step
after standing still, as long as the walker's next step) and the extremes of
the smoothed signal over that window, which feed Weinberg's step length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import percentile_filter, uniform_filter1d
from scipy.signal import find_peaks

from dtmbnav_core.resampling import UNIFORM_SPREAD, is_uniform


@dataclass(frozen=True)
class StepDetectorConfig:
    """Settings of the step detector.

    Attributes
    ----------
    smoothing_s : float
        Moving-average window that smooths the acceleration norm, s.
    gravity_window_s : float
        Moving-average window that estimates gravity (and sensor bias) in the norm, s.
    amplitude_window_s : float
        Centred window over which the walker's acceleration level is taken, s
        (a few steps even at a slow pace).
    amplitude_percentile : float
        Percentile of the dynamic acceleration over that window that measures the level (0-100).
    threshold_fraction : float
        Least peak height of a step as a fraction of the level.
    floor_mps2 : float
        Least peak height of a step whatever the level, m/s^2 (above sensor noise and tremor at rest).
    min_step_s : float
        Least time between two steps, s (a step takes 0.3-2 s).
    max_step_s : float
        A longer gap than this means the walker stood still in between, s.
    """

    smoothing_s: float = 0.15
    gravity_window_s: float = 2.0
    amplitude_window_s: float = 4.0
    amplitude_percentile: float = 90.0
    threshold_fraction: float = 0.25
    floor_mps2: float = 0.2
    min_step_s: float = 0.3
    max_step_s: float = 2.0


@dataclass(frozen=True)
class DetectedSteps:
    """Steps found in an acceleration record.

    Attributes
    ----------
    t_s : ndarray
        Time of each step's peak, s.
    start_t_s : ndarray
        Start of each step's window, s.
    acc_max_mps2, acc_min_mps2 : ndarray
        Extremes of the smoothed, gravity-free norm over the window, m/s^2.
    """

    t_s: np.ndarray
    start_t_s: np.ndarray
    acc_max_mps2: np.ndarray
    acc_min_mps2: np.ndarray

    @property
    def duration_s(self) -> np.ndarray:
        """Duration of each step, s."""
        return self.t_s - self.start_t_s


def dynamic_acceleration(t_s: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig) -> np.ndarray:
    """Smoothed acceleration norm with gravity removed, m/s^2 (one value per sample).

    Raises
    ------
    ValueError
        Samples not N x 3, fewer than two, or not on a uniform time grid (intervals
        within :data:`~dtmbnav_core.resampling.UNIFORM_SPREAD` of their mean:
        :func:`fusion.pdr.pipeline.run_pdr` resamples uneven ones).
    """
    acc_mps2 = np.asarray(acc_mps2, dtype=np.float64)
    if acc_mps2.ndim != 2 or acc_mps2.shape[1] != 3 or len(acc_mps2) != len(t_s) or len(t_s) < 2:
        raise ValueError(f"acc_mps2 must be N x 3 with N = len(t_s) >= 2, got {acc_mps2.shape} and {len(t_s)}")
    dt = np.diff(t_s)
    if np.any(dt <= 0) or not is_uniform(t_s):
        raise ValueError(f"t_s must increase at a uniform rate (interval spread at most {UNIFORM_SPREAD:g} of the "
                         f"mean interval, got {np.ptp(dt) / abs(dt.mean()):.3g}); resample uneven times first "
                         "(run_pdr does)")
    rate_hz = 1.0 / dt.mean()
    norm = np.linalg.norm(acc_mps2, axis=1)
    gravity = uniform_filter1d(norm, max(1, round(config.gravity_window_s * rate_hz)), mode="nearest")
    return uniform_filter1d(norm - gravity, max(1, round(config.smoothing_s * rate_hz)), mode="nearest")


def _window_extremes(signal: np.ndarray, start: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Max and min of ``signal[start[i]:stop[i]]`` for each i (non-empty windows, start ascending)."""
    # reduceat over the interleaved bounds [s0, e0, s1, e1, ...]: the even results are the windows.
    bounds = np.column_stack([start, stop]).ravel()
    padded = np.append(signal, signal[-1])  # a window may end at the last sample
    return np.maximum.reduceat(padded, bounds)[::2], np.minimum.reduceat(padded, bounds)[::2]


def step_threshold(dyn_mps2: np.ndarray, rate_hz: float, config: StepDetectorConfig) -> np.ndarray:
    """Least height of a step's peak at each sample: a fraction of the walker's own level, m/s^2.

    The level is a running percentile (``amplitude_percentile``) of the dynamic
    acceleration over a centred window of ``amplitude_window_s``: close to the
    height of the step peaks in it, whatever the carriage and the pace, and
    unmoved by a few outlying samples. The threshold is ``threshold_fraction`` of
    it, but never below ``floor_mps2``, which keeps sensor noise and a still
    hand's tremor from counting as steps.
    """
    width = max(1, round(config.amplitude_window_s * rate_hz))
    level = percentile_filter(dyn_mps2, config.amplitude_percentile, size=width, mode="nearest")
    return np.maximum(config.threshold_fraction * level, config.floor_mps2)


def detect_steps(t_s: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig) -> DetectedSteps:
    """Detect steps: peaks of the smoothed dynamic acceleration above an adaptive threshold (docs/method.md §3).

    A step is a local peak of :func:`dynamic_acceleration` above
    :func:`step_threshold` and at least ``min_step_s`` after a higher one. Its
    window runs from the previous step's peak; a step more than ``max_step_s``
    after the previous one (the first after a standstill) has no previous peak,
    and gets the duration of the walker's next step, clipped to
    ``[min_step_s, max_step_s]`` (or the median step duration of the record when
    the next step is not part of the same walk), so that its speed and length
    are those of a real step.

    Parameters
    ----------
    t_s : ndarray
        Uniformly spaced sample times, s.
    acc_mps2 : ndarray, shape (N, 3)
        Accelerometer specific force, m/s^2, any sensor frame.
    config : StepDetectorConfig

    Returns
    -------
    DetectedSteps
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    dyn = dynamic_acceleration(t_s, acc_mps2, config)
    rate_hz = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    peaks, _ = find_peaks(dyn, height=step_threshold(dyn, rate_hz, config),
                          distance=max(1, round(config.min_step_s * rate_hz)))
    if peaks.size == 0:
        empty = np.zeros(0)
        return DetectedSteps(t_s=empty, start_t_s=empty, acc_max_mps2=empty, acc_min_mps2=empty)
    gap = np.diff(peaks, prepend=-np.iinfo(np.int64).max // 2)
    after_standstill = gap > config.max_step_s * rate_hz
    start = peaks - np.where(after_standstill, _first_step_samples(gap, after_standstill, rate_hz, config), gap)
    start = np.maximum(start, 0)
    acc_max, acc_min = _window_extremes(dyn, start, peaks + 1)
    return DetectedSteps(t_s=t_s[peaks], start_t_s=t_s[start], acc_max_mps2=acc_max, acc_min_mps2=acc_min)


def _first_step_samples(gap: np.ndarray, after_standstill: np.ndarray, rate_hz: float,
                        config: StepDetectorConfig) -> np.ndarray:
    """Window length, in samples, of every step if it were the first after a standstill.

    A step from a standstill lasts about as long as the next one (the cadence
    settles within a step or two); where the next step is itself after a
    standstill (or there is none) the median duration of the steps that do
    follow another stands in, or ``max_step_s`` when there are none.
    """
    lo, hi = round(config.min_step_s * rate_hz), round(config.max_step_s * rate_hz)
    walking = gap[~after_standstill]
    fallback = int(np.median(walking)) if walking.size else hi
    next_gap = np.append(gap[1:], 0)
    next_walking = np.append(~after_standstill[1:], False)
    return np.clip(np.where(next_walking, next_gap, fallback), lo, hi)
