"""Moving-window statistics of a uniformly sampled signal.

:func:`moving_std` is how the project tells rest from motion: the phone-log importer finds the start
of a walk where the accelerometer magnitude's moving standard deviation rises
(``dtmbnav/field/sensors_import.py``), the PDR's attitude filter finds rest where every gyro axis's
stays low (``fusion/pdr/attitude.py``). Both stand on this layer, so the one definition sits here.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d


def moving_std(x: np.ndarray, window_s: float, rate_hz: float, axis: int = 0) -> np.ndarray:
    """Standard deviation of ``x`` over a centred window, at every sample, in ``x``'s unit.

    Parameters
    ----------
    x : ndarray
        Samples on a uniform grid of ``rate_hz`` (Hz) along ``axis``.
    window_s : float
        Window length, s: ``window_s * rate_hz`` samples, rounded, at least 2.
    rate_hz : float
        Sample rate, Hz.
    axis : int
        The time axis of ``x``.

    Returns
    -------
    ndarray
        The population standard deviation (ddof 0) over each sample's window, same shape as ``x``;
        windows at the ends repeat the edge sample (scipy's ``mode="nearest"``).

    Notes
    -----
    Computed as sqrt(mean(x^2) - mean(x)^2) from two moving averages (``uniform_filter1d``), in a time
    independent of the window's length; the difference is clipped at 0, which rounding can undercut for
    a constant signal.
    """
    width = max(2, round(window_s * rate_hz))
    mean = uniform_filter1d(x, width, axis=axis, mode="nearest")
    mean_sq = uniform_filter1d(x**2, width, axis=axis, mode="nearest")
    return np.sqrt(np.maximum(mean_sq - mean**2, 0.0))
