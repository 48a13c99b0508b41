"""The walker's step period from the acceleration itself: a running autocorrelation (docs/method.md §3).

Walking is periodic, and its period is what makes one step one count whatever
the carriage: a slow texting step that gives two peaks, a trouser pocket whose
leg dominates every other step, a swinging arm whose pendulum adds its own
humps. The period is taken as in the autocorrelation step counters of Rai et al.
("Zee: zero-effort crowdsourcing for indoor localization", MobiCom 2012) and
Brajdic & Harle ("Walk detection and step counting on unconstrained
smartphones", UbiComp 2013): over a window of a few steps, the normalised
autocorrelation of the dynamic acceleration peaks at the stride (one cycle of
both legs, which repeats exactly) and, where the two legs look alike, at the
step. The highest peak is taken; it is a stride, not a step, when the
autocorrelation half-way to it is positive above a small fraction of it (at
half a stride the other leg's step correlates; at half a step the signal is in
antiphase and the correlation is negative).

The windows hop by a fraction of a second, and the signal is first decimated to
a rate that still resolves the period finely (the dynamic acceleration is
already smoothed well below that rate's Nyquist frequency), so that an
hour-long log costs a few FFTs per second of walking and memory stays flat:
the windows are processed in blocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks

#: Rate at which the period is estimated, Hz (resolution 1/rate before interpolation).
PERIOD_RATE_HZ = 50.0
#: Windows processed at once (bounds the memory whatever the log's length).
WINDOWS_PER_BLOCK = 2048


@dataclass(frozen=True)
class StepPeriod:
    """The step period at regularly spaced times.

    Attributes
    ----------
    t_s : ndarray
        Centre of each window, s.
    period_s : ndarray
        Step period there, s (NaN where the window shows no period in range).
    strength : ndarray
        Normalised autocorrelation at that period (1: perfectly periodic; 0 where none).
    """

    t_s: np.ndarray
    period_s: np.ndarray
    strength: np.ndarray

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Period (s) and strength at the given times, linearly interpolated.

        Where no window has a period, the period is NaN.
        """
        known = np.isfinite(self.period_s)
        period = (np.interp(t_s, self.t_s[known], self.period_s[known]) if known.any()
                  else np.full(np.shape(t_s), np.nan))
        return period, np.interp(t_s, self.t_s, self.strength)


def _window_autocorrelation(windows: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised, unbiased autocorrelation of each row for lags 0..max_lag (row 0 of a flat window is 0)."""
    centred = windows - windows.mean(axis=1, keepdims=True)
    n = centred.shape[1]
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(centred, nfft, axis=1)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), nfft, axis=1)[:, :max_lag + 1]
    power = acf[:, :1]
    acf = np.divide(acf, power, out=np.zeros_like(acf), where=power > 0)
    return acf * (n / (n - np.arange(max_lag + 1)))


def _period_of(acf: np.ndarray, min_lag: int, stride_ratio: float) -> tuple[float, float]:
    """Step period (in lags) and its strength from one autocorrelation.

    The highest peak is refined by a parabola through it. Where it is a stride, the
    step period is half of it: a stride is a left and a right step, so its half is
    the mean step however unlike the two legs are, and the stride's lag is the
    sharper of the two (the half-way peak of a lopsided gait is low and broad).
    """
    peaks, _ = find_peaks(acf)
    peaks = peaks[peaks >= min_lag]
    if peaks.size == 0:
        return np.nan, 0.0
    best = int(peaks[np.argmax(acf[peaks])])
    lag = float(best)
    if best < len(acf) - 1:
        left, right = acf[best - 1], acf[best + 1]
        curvature = left - 2.0 * acf[best] + right
        if curvature < 0:
            lag += 0.5 * (left - right) / curvature
    half = acf[int(0.4 * best):int(0.6 * best) + 1]
    if half.size and best // 2 >= min_lag and half.max() > stride_ratio * acf[best]:
        return 0.5 * lag, float(acf[best])  # a stride
    return lag, float(acf[best])


def step_period(t_s: np.ndarray, dyn_mps2: np.ndarray, window_s: float, hop_s: float, min_period_s: float,
                max_period_s: float, stride_ratio: float) -> StepPeriod:
    """The step period over running windows of the dynamic acceleration.

    Parameters
    ----------
    t_s : ndarray
        Uniformly spaced sample times, s.
    dyn_mps2 : ndarray
        Smoothed, gravity-free acceleration norm, m/s^2 (:func:`fusion.pdr.steps.dynamic_acceleration`).
    window_s : float
        Length of each window, s (a few strides at the slowest cadence).
    hop_s : float
        Spacing of the windows' centres, s.
    min_period_s, max_period_s : float
        Shortest and longest lag searched, s: the step period of the slowest walk, and a
        stride of a normal one (which is then halved).
    stride_ratio : float
        The highest autocorrelation peak is a stride when the autocorrelation half-way
        to it exceeds this fraction of it.

    Returns
    -------
    StepPeriod
    """
    rate_hz = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    factor = max(1, int(rate_hz // PERIOD_RATE_HZ))
    signal = dyn_mps2[::factor]
    rate_hz /= factor
    width = max(4, round(window_s * rate_hz))
    hop = max(1, round(hop_s * rate_hz))
    max_lag = min(round(max_period_s * rate_hz), width - 2)
    min_lag = max(1, round(min_period_s * rate_hz))
    padded = np.pad(signal, width // 2, mode="reflect" if len(signal) > width // 2 else "edge")
    starts = np.arange(0, len(signal), hop)
    period = np.full(len(starts), np.nan)
    strength = np.zeros(len(starts))
    for block in range(0, len(starts), WINDOWS_PER_BLOCK):
        first = starts[block:block + WINDOWS_PER_BLOCK]
        windows = padded[first[:, None] + np.arange(width)]
        for i, acf in enumerate(_window_autocorrelation(windows, max_lag), start=block):
            lag, strength[i] = _period_of(acf, min_lag, stride_ratio)
            period[i] = lag / rate_hz
    return StepPeriod(t_s=t_s[0] + starts / rate_hz, period_s=period, strength=strength)
