"""Test signals for the receiver tests, built on the symbol-rate frame source.

:func:`make_signal` turns :class:`sim.frames.FrameSource` symbols into a
received 7.56 Msps stream with the impairments the receiver must handle: a
bulk CFO (phase ramp), a delay that drifts linearly (sampling offset, applied
with a windowed-sinc fractional-delay interpolator), an optional echo and
complex white noise at a given SNR (relative to the unit body power).

:func:`make_paths_signal` builds a multipath stream with the transmitter's
SRRC pulse (``sim.transmitter.srrc_pulse``): paths with fixed fractional
delays, complex gains, Dopplers of their own and optional extra phase
(e.g. a forced cycle slip), for the path tracker's tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.signal import oaconvolve

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from sim.frames import FrameConfig, FrameSource
from sim.transmitter import srrc_pulse

#: Half-length of the fractional-delay interpolator, samples.
_HALF_TAPS = 24


def fractional_delay(source: FrameSource, n: np.ndarray, delay: np.ndarray) -> np.ndarray:
    """Samples ``s(n - delay)`` of the band-limited symbol stream (Hann-windowed sinc)."""
    pos = n - delay
    base = np.floor(pos).astype(np.int64)
    k = base[:, None] + np.arange(-_HALF_TAPS + 1, _HALF_TAPS + 1)[None, :]
    x = pos[:, None] - k
    taps = np.sinc(x) * (0.5 + 0.5 * np.cos(np.pi * x / _HALF_TAPS))
    lo = int(k.min())
    sym = source.symbols(max(lo, 0), int(k.max()) + 1)
    sym = np.concatenate([np.zeros(max(-lo, 0), complex), sym])
    return np.sum(taps * sym[k - min(lo, 0) - max(lo, 0)], axis=1)


def make_signal(n_samples: int, *, pn_mode: PnMode = PnMode.PN420, rotating: bool = True, si_index: int = 15,
                start_symbol: int = 10_000, cfo_hz: float = 0.0, cfo_rate_hz_per_s: float = 0.0,
                sampling_offset_ppm: float = 0.0, echo: tuple[float, complex] | None = None,
                snr_db: float | None = 20.0, seed: int = 1, first_sample: int = 0,
                block: int = 1 << 16) -> np.ndarray:
    """A received stream (complex64) of ``n_samples`` at 7.56 Msps.

    Parameters
    ----------
    start_symbol : int
        Transmitted symbol at receiver sample 0 (so the capture starts mid-frame).
    cfo_hz, cfo_rate_hz_per_s : float
        Carrier offset at sample 0 and its linear drift (Doppler ramp).
    sampling_offset_ppm : float
        Receiver clock fast by this much: transmitted time advances
        ``1 / (1 + ppm * 1e-6)`` symbols per sample.
    echo : (delay_samples, gain) or None
        A second path.
    snr_db : float or None
        Body SNR; None for no noise.
    first_sample : int
        Index of the first sample produced (a later piece of the same stream;
        the noise differs between pieces).
    block : int
        Samples interpolated at once (bounds memory).
    """
    source = FrameSource(FrameConfig(pn_mode=pn_mode, rotating_phase=rotating, si_index=si_index, seed=seed))
    n = first_sample + np.arange(n_samples, dtype=np.float64)
    u = start_symbol + n / (1.0 + sampling_offset_ppm * 1e-6)
    x = np.empty(n_samples, dtype=np.complex128)
    for a in range(0, n_samples, block):
        part = u[a: a + block]
        x[a: a + block] = fractional_delay(source, part, np.zeros_like(part))
        if echo is not None:
            x[a: a + block] += echo[1] * fractional_delay(source, part, np.full_like(part, echo[0]))
    t = n / SYMBOL_RATE_HZ
    x = x * np.exp(2j * np.pi * (cfo_hz * t + 0.5 * cfo_rate_hz_per_s * t ** 2))
    if snr_db is not None:
        rng = np.random.default_rng([seed, first_sample])
        sigma = np.sqrt(10 ** (-snr_db / 10) / 2)
        x = x + sigma * (rng.standard_normal(n_samples) + 1j * rng.standard_normal(n_samples))
    return x.astype(np.complex64)


def frame_start_samples(pn_mode: PnMode, start_symbol: int, n_samples: int, sampling_offset_ppm: float = 0.0) -> np.ndarray:
    """Receiver sample positions (fractional) of every transmitted frame start in the stream."""
    flen = pn_mode.value.frame_length
    first = -(-start_symbol // flen)
    frames = np.arange(first, first + n_samples // flen + 2)
    pos = (frames * flen - start_symbol) * (1.0 + sampling_offset_ppm * 1e-6)
    return pos[pos < n_samples]


@dataclass(frozen=True)
class SignalPath:
    """One propagation path of :func:`make_paths_signal`.

    Attributes
    ----------
    delay : float
        Delay, samples (chips) after the direct arrival grid of ``start_symbol``.
    gain : complex
        Amplitude relative to a unit-power body.
    doppler_hz : float
        Carrier frequency of the path, Hz.
    extra_cycles : callable or None
        Extra carrier phase in cycles as a function of time (s), e.g. a forced cycle slip.
    """

    delay: float
    gain: complex
    doppler_hz: float = 0.0
    extra_cycles: Callable[[np.ndarray], np.ndarray] | None = None


def make_paths_signal(n_samples: int, paths: list[SignalPath], *, pn_mode: PnMode = PnMode.PN420,
                      snr_db: float | None = 15.0, start_symbol: int = 10_000, seed: int = 1,
                      span: int = 48) -> np.ndarray:
    """A multipath stream (complex64, 7.56 Msps) of SRRC-shaped DTMB frames.

    Receiver sample n sees path p's transmitted stream at symbol time
    ``start_symbol + n - delay_p``, times ``gain_p exp(j 2 pi (doppler_p t + extra_p(t)))``
    with ``t = n / 7.56e6``; the pulse is truncated to ``+-span`` chips and
    noise is added at ``snr_db`` relative to the unit body power.
    """
    source = FrameSource(FrameConfig(pn_mode=pn_mode, seed=seed))
    reach = span + int(np.ceil(max(abs(p.delay) for p in paths))) + 1
    first = start_symbol - reach
    symbols = source.symbols(first, start_symbol + n_samples + reach)
    t = np.arange(n_samples) / SYMBOL_RATE_HZ
    x = np.zeros(n_samples, dtype=np.complex128)
    for path in paths:
        k0 = int(np.floor(path.delay)) - span
        taps = srrc_pulse(k0 + np.arange(2 * span + 1) - path.delay)
        shaped = oaconvolve(symbols, taps)[start_symbol - k0 - first + np.arange(n_samples)]
        cycles = path.doppler_hz * t + (path.extra_cycles(t) if path.extra_cycles is not None else 0.0)
        x += path.gain * shaped * np.exp(2j * np.pi * cycles)
    if snr_db is not None:
        rng = np.random.default_rng([seed, 7])
        sigma = np.sqrt(10 ** (-snr_db / 10) / 2)
        x += sigma * (rng.standard_normal(n_samples) + 1j * rng.standard_normal(n_samples))
    return x.astype(np.complex64)
