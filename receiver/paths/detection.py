"""Path detection: new paths in what the tracked paths leave unexplained (:mod:`receiver.paths`).

What the paths' pulses and their delay derivatives leave unexplained (so a
slightly mis-delayed strong path leaves nothing behind), as power per lag
over a batch of F frames, divided by the noise floor (the lags outside the
span), is ``Gamma(F, 1/F)`` distributed where there is only noise
(:func:`detection_threshold`); a lag above the threshold with false-alarm
probability ``false_alarm`` per lag and batch, above ``relative_floor_db`` of
the strongest path and standing out of its surroundings like a pulse
(:func:`detect_paths`) is a new path: the strongest such peak per batch, and
none next to a path whose delay loop is still settling (that residual is its
fitting error). The next batch fits it with the others, so the residual
stays exact and a strong path's sidelobes are never taken for paths.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: Lags (from, to) on either side of a residual peak whose median is its local background (detect_paths).
RING = (3, 10)


def erlang_log_survival(x: float, shape: int) -> float:
    """log P(X > x) for X the sum of ``shape`` independent unit-mean exponential variables.

    For a whole-number shape the survival function of the Gamma (Erlang)
    distribution is the finite sum ``exp(-x) * sum_{k < shape} x**k / k!``,
    evaluated here in the log domain.
    """
    if x <= 0.0:
        return 0.0
    k = np.arange(shape)
    log_terms = k * math.log(x) - x - np.array([math.lgamma(i + 1.0) for i in range(shape)])
    peak = log_terms.max()
    return float(peak + math.log(np.exp(log_terms - peak).sum()))


@lru_cache(maxsize=64)
def detection_threshold(frames: int, false_alarm: float) -> float:
    """Residual power over the noise floor that noise alone exceeds with probability ``false_alarm``.

    The mean of ``frames`` exponential variables (the power of a complex
    Gaussian tap, unit mean) is ``Gamma(frames, 1 / frames)``; its inverse
    survival function is found by bisection on :func:`erlang_log_survival`.
    Written out rather than taken from ``scipy.stats.gamma.isf``, which gives
    the same value but whose import would be a large part of the run time of
    every ``dtmbnav receive`` of a short capture.
    """
    target = math.log(false_alarm)
    low, high = 0.0, float(frames)
    while erlang_log_survival(high, frames) > target:
        low, high = high, 2.0 * high
    for _ in range(200):  # bisection to the float's resolution
        middle = 0.5 * (low + high)
        if middle in (low, high):
            break
        if erlang_log_survival(middle, frames) > target:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high) / frames


def detect_paths(power: np.ndarray, lag0: int, limit: float, existing: np.ndarray, settled: np.ndarray,
                 min_separation: float, settle_guard: float, max_births: int) -> list[float]:
    """New paths in the residual power of a batch: its strongest peaks above ``limit``.

    A path is a pulse about a chip wide: its peak must stand above the
    residual around it (the median over ``RING`` lags on either side) by the
    factor the threshold stands above the noise floor. Interference spread
    over the lags (a tone, a DC offset: their header correlation is a smooth
    function of the lag) raises the floor and the ring alike and is never
    taken for a path. A peak next to a path that is still settling (its
    delay not yet converged) is that path's fitting error, not a path: no
    birth within ``settle_guard`` of one. Peaks are taken strongest first,
    one chip apart.

    Parameters
    ----------
    power : (L,) ndarray
        Mean residual power per lag over the noise floor.
    lag0 : int
        Lag of ``power[0]``.
    limit : float
        Detection threshold (noise and relative floor).
    existing : ndarray
        Lags of the paths already tracked.
    settled : ndarray of bool
        Which of them have settled.
    min_separation, settle_guard : float
        Closest allowed to a settled / a settling path, samples.
    max_births : int
        Most paths returned.

    Returns
    -------
    list of float
        Fractional lags of the new paths (parabolic interpolation of the peak).
    """
    p = np.asarray(power, dtype=np.float64)
    if len(p) < 3:
        return []
    inner = np.arange(1, len(p) - 1)
    peaks = inner[(p[inner] > limit) & (p[inner] >= p[inner - 1]) & (p[inner] >= p[inner + 1])]
    found: list[float] = []
    for peak in peaks[np.argsort(p[peaks])[::-1]]:
        ring = np.concatenate([p[max(peak - RING[1], 0): max(peak - RING[0] + 1, 0)], p[peak + RING[0]: peak + RING[1] + 1]])
        if len(ring) and p[peak] <= limit * np.median(ring):
            continue
        left, centre, right = p[peak - 1: peak + 2]
        curvature = left - 2.0 * centre + right
        lag = lag0 + peak + (float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5)) if curvature < 0 else 0.0)
        distance = np.abs(np.asarray(existing, dtype=np.float64) - lag)
        guard = np.where(settled, min_separation, settle_guard)
        if np.all(distance >= guard) and all(abs(lag - f) >= 1.0 for f in found):
            found.append(lag)
            if len(found) >= max_births:
                break
    return found
