"""WT-UKF [WT-UKF]: the UKF with wavelet-estimated measurement noise.

[WT-UKF] estimates the unknown noise of each observation channel online: in a
sliding window of the last ``window`` observations, a discrete wavelet
transform splits the series into an approximation (the signal) and details
(the noise). Its eq. 15 takes the noise mean as ``mean(z) - mean(z*)`` with
``z*`` the series rebuilt from the approximation alone; its eq. 16 takes the
noise standard deviation as ``median(|finest detail coefficients|) / 0.6745``
(the MAD estimator). The mean is removed from the observation and the
variance replaces that channel's R.

Applied here by default to the range change only. In [WT-UKF] the PDR drives
the state and the only measurement is the external fix (GPS there, the DTMB
range here); our PDR heading and speed observations (eq. 18) are wide
pseudo-observations that hold the state near the PDR, and their error is the
PDR's drift, which a wavelet cannot see: estimating them too replaces the
wide heading sigma by its floor (a few degrees of fine-scale noise) and ties
the heading to a drifting gyro (``wavelet_rows=(0, 1, 2)`` does that). Until a channel's window is full, and below a floor
(``floor_fraction`` of the nominal sigma, so that a window that happens to be
smooth does not make the filter trust the channel without limit), the
nominal R of :mod:`fusion.model` applies. Note what the method can and
cannot see: white noise on a channel, yes; a slowly growing bias such as the
integrated range's oscillator drift or an NLOS reflection, no.
"""

from __future__ import annotations

import numpy as np
import pywt

from dtmbnav_core.records import FusedTrack
from fusion.driver import run_filter
from fusion.integrity import IntegrityConfig
from fusion.model import ClockModel, Geometry, KalmanObservation, ModelNoise
from fusion.observations import FilterEpochs
from fusion.ukf import RangePdrUkf

#: MAD-to-sigma factor of a Gaussian ([WT-UKF] eq. 16).
MAD_TO_SIGMA = 0.6745


def wavelet_noise_estimate(series: np.ndarray, wavelet: str = "db4", level: int = 2) -> tuple[float, float]:
    """Noise mean and standard deviation of a series ([WT-UKF] eq. 15-16).

    Parameters
    ----------
    series : ndarray
        The observations in the window.
    wavelet : str
        PyWavelets wavelet name.
    level : int
        Decomposition depth; the approximation at this level is the signal.

    Returns
    -------
    mean, sigma : float
        Noise mean (``mean(z) - mean(z*)``) and standard deviation
        (``median(|cD1|) / 0.6745``).
    """
    series = np.asarray(series, dtype=np.float64)
    coeffs = pywt.wavedec(series, wavelet, level=level, mode="periodization")
    approx_only = [coeffs[0]] + [np.zeros_like(c) for c in coeffs[1:]]
    rebuilt = pywt.waverec(approx_only, wavelet, mode="periodization")[: len(series)]
    mean = float(series.mean() - rebuilt.mean())
    sigma = float(np.median(np.abs(coeffs[-1])) / MAD_TO_SIGMA)
    return mean, sigma


class WaveletUkf(RangePdrUkf):
    """UKF whose observation noise comes from :func:`wavelet_noise_estimate` per channel.

    Parameters
    ----------
    epochs : FilterEpochs
        The whole observation history (the filter only looks back).
    window : int
        Sliding-window length, epochs.
    floor_fraction : float
        R is never below (floor_fraction * nominal sigma)^2.
    wavelet_rows : tuple of int
        Observation components (eq. 18: 0 range change, 1 PDR heading,
        2 PDR speed) whose noise the wavelet estimates; the others keep
        their nominal R.
    others
        As :class:`fusion.ukf.RangePdrUkf`.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise, epochs: FilterEpochs, window: int = 32,
                 floor_fraction: float = 0.3, wavelet_rows: tuple[int, ...] = (0,), clock: ClockModel = ClockModel(),
                 integrity: IntegrityConfig = IntegrityConfig()) -> None:
        super().__init__(geometry, noise, *epochs.initial_heading_speed(), clock, integrity)
        self.window = window
        self.floor_fraction = floor_fraction
        self.wavelet_rows = wavelet_rows
        self.channels = np.stack([epochs.range_change_m, np.unwrap(epochs.pdr_heading_rad), epochs.pdr_speed_mps],
                                 axis=1)

    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """Update with the window's wavelet noise estimates replacing the nominal R."""
        z = observation.z.copy()
        sigma = observation.sigma.copy()
        start = epoch + 1 - self.window
        if start >= 0:
            for i, row in enumerate(observation.rows):
                if row not in self.wavelet_rows:
                    continue
                history = self.channels[start: epoch + 1, row]
                if np.all(np.isfinite(history)):
                    mean, estimated = wavelet_noise_estimate(history)
                    z[i] -= mean
                    sigma[i] = max(estimated, self.floor_fraction * observation.sigma[i])
        self._update(z, np.diag(sigma**2), observation)


def run_wt_ukf(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(), window: int = 32,
               wavelet_rows: tuple[int, ...] = (0,), clock: ClockModel = ClockModel(),
               integrity: IntegrityConfig = IntegrityConfig()) -> FusedTrack:
    """Run the WT-UKF over all epochs (``wavelet_rows``: see :class:`WaveletUkf`)."""
    return run_filter(WaveletUkf(geometry, noise, epochs, window, wavelet_rows=wavelet_rows, clock=clock,
                                 integrity=integrity), epochs)
