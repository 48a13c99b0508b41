"""Step-length models (docs/method.md §3): Weinberg with a calibrated gain, and the linear frequency model.

Weinberg: ``L = K (a_max - a_min)^(1/4)`` with the extremes of the vertical
(here: gravity-free norm) acceleration over the step. K depends on the person,
the carriage and the smoothing, so it is calibrated from a walk of known
length: ``K = D / sum_i (a_max,i - a_min,i)^(1/4)``.

Linear frequency model ([CN0-KF]): ``L = 0.4 f - 0.01`` m for a cadence
0.5 < f < 3 Hz, else 0.7 m.
"""

from __future__ import annotations

import numpy as np

#: Validity range of the linear frequency model, Hz, and its fallback length, m.
FREQUENCY_MODEL_RANGE_HZ = (0.5, 3.0)
FREQUENCY_MODEL_FALLBACK_M = 0.7


def weinberg_length(acc_max_mps2: np.ndarray, acc_min_mps2: np.ndarray, k_m: float) -> np.ndarray:
    """Weinberg step length ``K (a_max - a_min)^(1/4)``, m."""
    if k_m <= 0:
        raise ValueError(f"Weinberg gain k_m must be > 0, got {k_m}")
    return k_m * np.maximum(np.asarray(acc_max_mps2) - np.asarray(acc_min_mps2), 0.0) ** 0.25


def calibrate_weinberg_k(acc_max_mps2: np.ndarray, acc_min_mps2: np.ndarray, distance_m: float) -> float:
    """Weinberg gain that makes the given steps add up to a known walked distance, m.

    Raises
    ------
    ValueError
        No steps, or a non-positive distance.
    """
    if distance_m <= 0:
        raise ValueError(f"calibration distance must be > 0, got {distance_m}")
    unit_lengths = weinberg_length(acc_max_mps2, acc_min_mps2, 1.0)
    if unit_lengths.size == 0 or unit_lengths.sum() <= 0:
        raise ValueError("calibration walk: no steps detected")
    return float(distance_m / unit_lengths.sum())


def frequency_length(step_frequency_hz: np.ndarray) -> np.ndarray:
    """Linear step-frequency model ``0.4 f - 0.01`` m (0.7 m outside 0.5-3 Hz)."""
    f = np.asarray(step_frequency_hz, dtype=np.float64)
    lo, hi = FREQUENCY_MODEL_RANGE_HZ
    return np.where((f > lo) & (f < hi), 0.4 * f - 0.01, FREQUENCY_MODEL_FALLBACK_M)
