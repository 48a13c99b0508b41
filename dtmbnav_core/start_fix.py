"""The start fix P0 from every fix of the standstill before the walk, and the correlation its sigma respects.

A phone logs a fix every second or so while its user stands still before walking. Each fix's error is the
sum of slow terms (multipath off the nearby walls, the atmosphere's residual, the satellites' geometry) that
a stationary single-frequency receiver shows as strongly correlated over time: a first-order Gauss-Markov
(Ornstein-Uhlenbeck) process describes such a position series better than white noise (Soundy et al.,
"Comparison of Enhanced Noise Model Performance Based on Analysis of Civilian GPS Data", Sensors 20(21)
6050, 2020). Per axis the error of fix i is ``sigma_i z(t_i)``, ``z`` a unit-variance process with the
autocorrelation ``exp(-|dt| / FIX_ERROR_TAU_S)``; the simulator draws its fixes so (``sim/gnss.py``) and
the importer assumes it of a phone's (``dtmbnav/field/sensors_import.py``).

The rule (:func:`standstill_start_fix`): every fix of the standstill, from when the walker is known to stand
still to the walk's start (or, with a window, those of its last ``window_s`` seconds up to its last fix), is
combined into their inverse-variance weighted mean, ``w_i = sigma_i^-2 / sum_j sigma_j^-2``, the weights a
stated accuracy gives when errors are taken as independent. Its sigma is not the independent-error ``(sum_j sigma_j^-2)^-1/2`` but the exact standard
deviation of that mean under the Gauss-Markov model,

    sigma^2 = sum_ij w_i w_j sigma_i sigma_j exp(-|t_i - t_j| / tau),

so a run of fixes a few seconds apart counts for hardly more than one fix. The fixes' effective number,
``n_eff = N sigma_ind^2 / sigma^2`` with ``sigma_ind^2 = (sum_j sigma_j^-2)^-1``, is the number of
independent fixes of their mean inverse variance that would give that sigma: N for independent errors, 1 for
equal fixes at one moment (Cauchy-Schwarz keeps it within 1..N); for equal sigmas over a window
``T`` sampled densely it tends to Bayley and Hammersley's effective number of independent observations of
an exponentially autocorrelated series (J. R. Stat. Soc. Suppl. 8(2), 184-197, 1946),
``(T / tau)^2 / (2 (T / tau - 1 + exp(-T / tau)))``: 1 for ``T << tau``, ``T / (2 tau)`` for ``T >> tau``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dtmbnav_core.records import StartFix

#: Correlation time of a phone fix's position error, s (first-order Gauss-Markov, per axis). An assumption of
#: the order the literature describes for single-frequency receivers standing still (module docstring): their
#: errors wander over tens of seconds to minutes. The simulator draws its fixes with it and the start fix's
#: sigma assumes it.
FIX_ERROR_TAU_S = 30.0


@dataclass(frozen=True)
class CombinedFix:
    """A start fix combined from several fixes, and how many went into it.

    Attributes
    ----------
    fix : StartFix
        Weighted mean position, stamped at the last fix combined; its sigma per axis under the
        Gauss-Markov model (module docstring), m.
    n_fixes : int
        Fixes combined.
    n_effective : float
        Their effective number of independent fixes (1 <= n_effective <= n_fixes).
    """

    fix: StartFix
    n_fixes: int
    n_effective: float


def correlated_mean_variance(t_s: np.ndarray, a: np.ndarray, tau_s: float) -> float:
    """``sum_ij a_i a_j exp(-|t_i - t_j| / tau_s)`` for times ``t_s`` in non-decreasing order, O(N).

    The exponential kernel is Markov: ``r_i = sum_{j<i} a_j exp(-(t_i - t_j) / tau)`` obeys
    ``r_i = exp(-(t_i - t_{i-1}) / tau) (r_{i-1} + a_{i-1})``, so a long standstill at a high fix rate
    needs no N x N matrix.
    """
    decay = np.exp(-np.diff(t_s) / tau_s)
    cross = 0.0
    r = 0.0
    for i in range(1, len(a)):
        r = decay[i - 1] * (r + a[i - 1])
        cross += a[i] * r
    return float(np.sum(a**2) + 2.0 * cross)


def correlated_weighted_mean(t_s: np.ndarray, values: np.ndarray, sigma_m: np.ndarray, tau_s: float
                             ) -> tuple[np.ndarray | float, float, float]:
    """Inverse-variance weighted mean of ``values`` whose errors are ``sigma_i z(t_i)`` (module docstring), its
    variance under that correlation and the effective number of independent values, unchecked.

    Parameters
    ----------
    t_s : ndarray
        Times, s, non-decreasing.
    values : ndarray
        (N,) or (N, k) values, averaged along the first axis.
    sigma_m : ndarray
        Each value's stated 1-sigma error (> 0).
    tau_s : float
        Correlation time of the errors, s.

    Returns
    -------
    mean : float or ndarray
        ``sum_i w_i values_i`` with ``w_i`` proportional to ``sigma_i^-2``.
    variance : float
        ``sum_ij w_i w_j sigma_i sigma_j exp(-|t_i - t_j| / tau_s)`` (per column).
    n_effective : float
        ``N sigma_ind^2 / variance`` with ``sigma_ind^2 = (sum_j sigma_j^-2)^-1``.
    """
    inverse = sigma_m**-2.0
    w = inverse / inverse.sum()
    variance = correlated_mean_variance(t_s, w * sigma_m, tau_s)
    return w @ values, variance, float(len(t_s) / (inverse.sum() * variance))


def combine_fixes(t_s: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, sigma_m: np.ndarray,
                  tau_s: float = FIX_ERROR_TAU_S) -> CombinedFix:
    """Inverse-variance weighted mean of fixes and its sigma under Gauss-Markov errors (module docstring).

    Parameters
    ----------
    t_s : ndarray
        Fix times, s, non-decreasing.
    x_m, y_m : ndarray
        Fixed east and north positions, m.
    sigma_m : ndarray
        Each fix's stated 1-sigma error per axis, m (> 0).
    tau_s : float
        Correlation time of the errors, s.

    Raises
    ------
    ValueError
        No fix, times out of order, a sigma not positive and finite, or tau not positive.
    """
    t = np.asarray(t_s, dtype=np.float64)
    sigma = np.asarray(sigma_m, dtype=np.float64)
    if t.size == 0:
        raise ValueError("combine_fixes: no fix to combine")
    if np.any(np.diff(t) < 0):
        raise ValueError("combine_fixes: fix times must be in non-decreasing order")
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ValueError("combine_fixes: every fix's sigma must be positive and finite")
    if not tau_s > 0:
        raise ValueError(f"combine_fixes: the correlation time must be > 0, got {tau_s}")
    mean, variance, n_effective = correlated_weighted_mean(
        t, np.column_stack([np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)]), sigma, tau_s)
    # The weights are positive, so the variance lies between the independent and the fully correlated one;
    # the clamp only keeps rounding from taking n_eff past its bounds.
    n_effective = min(float(t.size), max(1.0, n_effective))
    fix = StartFix(t_s=float(t[-1]), x_m=float(mean[0]), y_m=float(mean[1]), sigma_m=math.sqrt(variance))
    return CombinedFix(fix=fix, n_fixes=int(t.size), n_effective=n_effective)


def standstill_fixes(t_s: np.ndarray, standstill_start_s: float, walk_start_s: float,
                     window_s: float | None = None) -> np.ndarray:
    """Indices of the fixes the start fix combines: those from ``standstill_start_s`` to ``walk_start_s``
    (both included); with ``window_s``, only those within ``window_s`` seconds before the last of them (0: the
    last alone). Empty when the standstill holds no fix.

    Raises
    ------
    ValueError
        A negative window.
    """
    if window_s is not None and not window_s >= 0:
        raise ValueError(f"the start fix's window must be >= 0 s, got {window_s}")
    t = np.asarray(t_s, dtype=np.float64)
    chosen = np.flatnonzero((t >= standstill_start_s) & (t <= walk_start_s))
    if chosen.size and window_s is not None:
        chosen = chosen[t[chosen] >= t[chosen[-1]] - window_s]
    return chosen


def standstill_start_fix(t_s: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, sigma_m: np.ndarray,
                         standstill_start_s: float, walk_start_s: float, window_s: float | None = None,
                         tau_s: float = FIX_ERROR_TAU_S) -> CombinedFix | None:
    """The start fix from the standstill's fixes (:func:`standstill_fixes`, :func:`combine_fixes`); None when
    the standstill holds no fix. Times in non-decreasing order."""
    chosen = standstill_fixes(t_s, standstill_start_s, walk_start_s, window_s)
    if chosen.size == 0:
        return None
    return combine_fixes(np.asarray(t_s)[chosen], np.asarray(x_m)[chosen], np.asarray(y_m)[chosen],
                         np.asarray(sigma_m)[chosen], tau_s)
