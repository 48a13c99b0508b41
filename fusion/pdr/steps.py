"""Step detection from the acceleration norm (docs/method.md §3).

The norm of the specific force is orientation-free; its slowly varying part
(gravity, plus whatever bias and scale error the accelerometer has) is removed
with a long moving average, the rest is smoothed with a short moving average,
and a step is a local peak above an amplitude threshold at least a minimum
time after the previous step.

Each step also gets its window (from the previous peak or, for the first step
after standing still, from the last quiet sample before the peak) and the extremes
of the smoothed signal over that window, which feed Weinberg's step length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import find_peaks


@dataclass(frozen=True)
class StepDetectorConfig:
    """Thresholds of the step detector.

    Attributes
    ----------
    smoothing_s : float
        Moving-average window that smooths the acceleration norm, s.
    gravity_window_s : float
        Moving-average window that estimates gravity (and sensor bias) in the norm, s.
    peak_threshold_mps2 : float
        Least peak height of the smoothed norm above gravity, m/s^2.
    min_step_s : float
        Least time between two steps, s (a step takes 0.3-2 s).
    max_step_s : float
        A longer gap than this means the walker stood still in between, s.
    still_threshold_mps2 : float
        Below this the smoothed dynamic acceleration counts as standing still,
        m/s^2 (where a step after a standstill begins).
    """

    smoothing_s: float = 0.15
    gravity_window_s: float = 2.0
    peak_threshold_mps2: float = 0.6
    min_step_s: float = 0.3
    max_step_s: float = 2.0
    still_threshold_mps2: float = 0.15


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
        Samples not N x 3, fewer than two, or not uniformly increasing in time.
    """
    acc_mps2 = np.asarray(acc_mps2, dtype=np.float64)
    if acc_mps2.ndim != 2 or acc_mps2.shape[1] != 3 or len(acc_mps2) != len(t_s) or len(t_s) < 2:
        raise ValueError(f"acc_mps2 must be N x 3 with N = len(t_s) >= 2, got {acc_mps2.shape} and {len(t_s)}")
    dt = np.diff(t_s)
    if np.any(dt <= 0) or np.ptp(dt) > 1e-3 * dt.mean():
        raise ValueError("t_s must increase at a uniform rate")
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


def detect_steps(t_s: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig) -> DetectedSteps:
    """Detect steps: peaks of the smoothed dynamic acceleration (docs/method.md §3).

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
    peaks, _ = find_peaks(dyn, height=config.peak_threshold_mps2,
                          distance=max(1, round(config.min_step_s * rate_hz)))
    if peaks.size == 0:
        empty = np.zeros(0)
        return DetectedSteps(t_s=empty, start_t_s=empty, acc_max_mps2=empty, acc_min_mps2=empty)
    gap = np.diff(peaks, prepend=-np.iinfo(np.int64).max // 2)
    after_standstill = gap > config.max_step_s * rate_hz
    # A step after a standstill has no previous peak: it starts where the signal last was quiet.
    quiet = np.flatnonzero(np.abs(dyn) < config.still_threshold_mps2)
    last_quiet = quiet[np.maximum(np.searchsorted(quiet, peaks) - 1, 0)] if quiet.size else peaks * 0
    earliest = peaks - round(config.max_step_s * rate_hz)
    start = np.where(after_standstill, np.clip(last_quiet, np.maximum(earliest, 0), peaks - 1), peaks - gap)
    acc_max, acc_min = _window_extremes(dyn, start, peaks + 1)
    return DetectedSteps(t_s=t_s[peaks], start_t_s=t_s[start], acc_max_mps2=acc_max, acc_min_mps2=acc_min)
