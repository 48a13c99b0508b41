"""Delay-Doppler map of the PN-header CIR over a few hundred to a few thousand frames (``docs/paths.md``).

Paths closer than a chip merge in one frame's CIR (the delay fit of
:mod:`receiver.paths` separates them only down to about a third of a chip);
over many frames they separate by their Doppler, the rate of their carrier
phase. For frames ``n = 0..N-1`` and a grid of physical delays ``d``, the CIR
is read at lag ``d - o_n`` (``o_n``: how far frame n's window start has moved
from the nominal frame grid, so a path at a fixed delay stays in one column),
Hann-windowed along the frames and Fourier transformed: each path becomes a
line at its Doppler (plus the receiver's common carrier offset), at its
delay. :func:`doppler_lines` lists the lines.

This is the diagnostic behind issue 14's street analysis (``docs/paths.md``,
"Separating paths by Doppler"); ``dtmbnav doppler-map`` runs it on a stage
dump (``dtmbnav receive --dump``, stage ``paths``). The receiver's ranging does
not use it yet.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from dtmbnav.core.gb20600 import SYMBOL_RATE_HZ
from receiver.dump import read_stage


@dataclass(frozen=True)
class DelayDopplerMap:
    """The CIR's spectrum along the frames at each delay.

    Attributes
    ----------
    doppler_hz : ndarray, (K,)
        Frequency of each row, Hz (the path's Doppler plus the receiver's
        carrier offset left in the CIR; increasing).
    delay_samples : ndarray of int, (L,)
        Physical delay of each column, 7.56 Msps samples after the first
        frame's window start.
    spectrum : ndarray of complex, (K, L)
        Windowed DFT along the frames, normalised so that a constant tap of
        amplitude ``a`` gives ``|a|`` at 0 Hz.
    """

    doppler_hz: np.ndarray
    delay_samples: np.ndarray
    spectrum: np.ndarray

    @property
    def power(self) -> np.ndarray:
        """``|spectrum|^2``, (K, L)."""
        return np.abs(self.spectrum) ** 2


@dataclass(frozen=True)
class DopplerLine:
    """A peak of the map's power summed over the delays.

    Attributes
    ----------
    doppler_hz : float
        Its frequency, Hz.
    power_db : float
        Its delay-summed power relative to the strongest line, dB.
    delay_samples : int
        The delay of its strongest column.
    profile_db : ndarray, (L,)
        Its power at each delay of the map, dB relative to its strongest column.
    """

    doppler_hz: float
    power_db: float
    delay_samples: int
    profile_db: np.ndarray


def delay_doppler_map(taps: np.ndarray, window_start: np.ndarray, frame_index: np.ndarray, lag0: int,
                      frame_length: int, delays: np.ndarray, oversample: int = 4) -> DelayDopplerMap:
    """Delay-Doppler map of consecutive frames' CIRs (module docstring).

    Parameters
    ----------
    taps : (N, M) complex
        CIR of each frame over lags ``lag0 .. lag0 + M - 1`` (the ``paths``
        stage of a dump: :meth:`receiver.channel_estimate.ChannelEstimator.span_taps`).
    window_start : (N,) int
        Window start of each frame, stream samples (7.56 Msps).
    frame_index : (N,) int
        Frame counter (consecutive frames differ by 1; a gap is refused).
    lag0 : int
        Lag of ``taps``' first column.
    frame_length : int
        Nominal frame length, samples (PN420: 4200).
    delays : (L,) int
        Physical delays to map, samples after the first frame's window start.
    oversample : int
        Zero-padding factor of the DFT (interpolates the frequency axis).

    Returns
    -------
    DelayDopplerMap

    Raises
    ------
    ValueError
        If the frames are not consecutive, or a delay falls outside the CIR
        span in some frame.
    """
    taps = np.asarray(taps)
    n = len(taps)
    frame_index = np.asarray(frame_index, dtype=np.int64)
    if n < 2 or np.any(np.diff(frame_index) != 1):
        raise ValueError("delay_doppler_map: needs two or more consecutive frames (frame_index step 1)")
    offsets = (np.asarray(window_start, dtype=np.int64) - int(window_start[0])) - (frame_index - frame_index[0]) * \
        frame_length
    delays = np.asarray(delays, dtype=np.int64)
    columns = delays[None, :] - offsets[:, None] - lag0
    if columns.min() < 0 or columns.max() >= taps.shape[1]:
        raise ValueError(f"delay_doppler_map: delays {delays.min()}..{delays.max()} leave the CIR span "
                         f"{lag0}..{lag0 + taps.shape[1] - 1} in some frame (window offsets "
                         f"{offsets.min()}..{offsets.max()})")
    x = taps[np.arange(n)[:, None], columns]
    window = np.hanning(n)
    size = oversample * n
    spectrum = np.fft.fftshift(np.fft.fft(x * window[:, None], size, axis=0), axes=0) / window.sum()
    doppler = np.fft.fftshift(np.fft.fftfreq(size, frame_length / SYMBOL_RATE_HZ))
    return DelayDopplerMap(doppler, delays, spectrum)


def doppler_lines(dd_map: DelayDopplerMap, floor_db: float = -25.0, max_lines: int = 8) -> list[DopplerLine]:
    """The map's lines: local maxima of the delay-summed power within ``floor_db`` of the strongest, strongest first."""
    total = dd_map.power.sum(axis=1)
    strongest = total.max()
    inner = np.arange(1, len(total) - 1)
    peaks = inner[(total[inner] >= total[inner - 1]) & (total[inner] > total[inner + 1])
                  & (total[inner] >= strongest * 10.0 ** (floor_db / 10.0))]
    lines = []
    for k in peaks[np.argsort(-total[peaks])][:max_lines]:
        profile = dd_map.power[k]
        lines.append(DopplerLine(float(dd_map.doppler_hz[k]), float(10.0 * np.log10(total[k] / strongest)),
                                 int(dd_map.delay_samples[np.argmax(profile)]),
                                 10.0 * np.log10(np.maximum(profile, 1e-300) / profile.max())))
    return lines


def map_from_dump(path: str | os.PathLike, at_s: float, seconds: float, delays: np.ndarray | None = None,
                  oversample: int = 4) -> DelayDopplerMap:
    """The delay-Doppler map of a stage dump's ``paths`` frames within ``seconds`` centred on ``at_s``.

    ``delays`` (samples after the first of those frames' window start)
    default to the strongest lag of their mean CIR, from 4 before to 8 after.
    """
    arrays, attrs = read_stage(path, "paths", (max(at_s - seconds / 2.0, 0.0), at_s + seconds / 2.0))
    start, index, taps = arrays["window_start"], arrays["frame_index"], arrays["taps"]
    steps = np.diff(start) / np.maximum(np.diff(index), 1)
    frame_length = int(np.rint(np.median(steps))) if len(steps) else 0
    lag0 = int(attrs["lag0"])
    if delays is None:
        peak = lag0 + int(np.argmax(np.mean(np.abs(taps) ** 2, axis=0)))
        delays = np.arange(peak - 4, peak + 9)
    return delay_doppler_map(taps, start, index, lag0, frame_length, delays, oversample)
