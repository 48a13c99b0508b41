"""Frequency shift of the input stream: a capture tuned beside the DTMB channel, moved back onto it.

A zero-IF SDR (HackRF, PlutoSDR, RTL-SDR) is often tuned beside the channel
to keep its LO leakage (the spike at DC) out of the band; the channel then
sits at ``channel_offset_hz`` (channel centre minus capture centre, Hz) from
DC in the capture. The receiver multiplies the input by

``exp(-j 2 pi channel_offset_hz n / fs_in)``

with ``n`` the absolute input sample index, before resampling to 7.56 Msps,
which puts the channel back at DC. The phase is a function of ``n`` alone
(float64, reduced to whole cycles per table block), so any chunking of the
stream gives the same samples.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Samples per block of the phasor table: phasor(n) = block phasor(n // MIX_BLOCK) * table[n % MIX_BLOCK].
MIX_BLOCK = 4096
#: Guard between the SI carriers' edge (+-36 kHz, a little more with a tuner offset) and fs / 2, Hz.
SI_BAND_GUARD_HZ = 40e3


def max_channel_offset_hz(sample_rate_hz: float) -> float:
    """Largest ``|channel_offset_hz|`` at which the recorded band still holds the SI carriers, Hz."""
    return sample_rate_hz / 2.0 - SI_BAND_GUARD_HZ


def check_channel_offset(channel_offset_hz: float, sample_rate_hz: float) -> None:
    """Raise ValueError when the shift moves the SI carriers out of the recorded band (or is not finite)."""
    if not np.isfinite(channel_offset_hz):
        raise ValueError(f"channel offset must be a finite frequency, got {channel_offset_hz!r}")
    limit = max_channel_offset_hz(sample_rate_hz)
    if abs(channel_offset_hz) > limit:
        raise ValueError(f"the DTMB channel lies {channel_offset_hz / 1e3:+.1f} kHz from the capture's centre, "
                         f"outside the recorded band: at {sample_rate_hz / 1e6:g} Msps the SI carriers need "
                         f"|channel - centre| <= {limit / 1e3:.1f} kHz")


@njit(cache=True, nogil=True)
def _phasor(cycles: float) -> complex:
    """``exp(-j 2 pi cycles)`` with ``cycles`` first reduced to [0, 1)."""
    frac = cycles - np.floor(cycles)
    return complex(np.cos(2.0 * np.pi * frac), -np.sin(2.0 * np.pi * frac))


@njit(cache=True, nogil=True)
def mix_kernel(x: np.ndarray, first_index: int, cycles_per_sample: float, table: np.ndarray,
               out: np.ndarray) -> None:
    """``out[i] = x[i] * exp(-j 2 pi cycles_per_sample (first_index + i))`` (complex64 in and out).

    Parameters
    ----------
    x : complex64 ndarray
        Input samples; ``x[i]`` is absolute sample ``first_index + i``.
    first_index : int
        Absolute index of ``x[0]``.
    cycles_per_sample : float
        ``channel_offset_hz / fs_in``.
    table : complex128 ndarray
        ``exp(-j 2 pi cycles_per_sample k)`` for ``k < MIX_BLOCK`` (:func:`phasor_table`).
    out : complex64 ndarray
        Output, same length as ``x`` (may be ``x``).
    """
    n = first_index
    stop = first_index + x.shape[0]
    i = 0
    while n < stop:
        block = n // MIX_BLOCK
        k = n - block * MIX_BLOCK
        # Cycles of the block start, reduced in float64: (block * MIX_BLOCK * f) mod 1, without an
        # integer product that could overflow.
        base = _phasor((block * (MIX_BLOCK * cycles_per_sample)) % 1.0)
        take = min(MIX_BLOCK - k, stop - n)
        for j in range(take):
            p = base * table[k + j]
            v = x[i + j]
            re = v.real * p.real - v.imag * p.imag
            im = v.real * p.imag + v.imag * p.real
            out[i + j] = complex(np.float32(re), np.float32(im))
        n += take
        i += take


def phasor_table(cycles_per_sample: float) -> np.ndarray:
    """``exp(-j 2 pi cycles_per_sample k)``, ``k = 0 .. MIX_BLOCK - 1`` (complex128)."""
    k = np.arange(MIX_BLOCK, dtype=np.float64)
    cycles = (k * cycles_per_sample) % 1.0
    return np.exp(-2j * np.pi * cycles)


class StreamMixer:
    """Shift a stream by ``-channel_offset_hz``, chunk by chunk (module docstring).

    Parameters
    ----------
    channel_offset_hz : float
        Channel centre minus capture centre, Hz.
    sample_rate_hz : float
        Input rate, samples/s.
    """

    def __init__(self, channel_offset_hz: float, sample_rate_hz: float) -> None:
        check_channel_offset(channel_offset_hz, sample_rate_hz)
        self.channel_offset_hz = float(channel_offset_hz)
        self.cycles_per_sample = self.channel_offset_hz / float(sample_rate_hz)
        self._table = phasor_table(self.cycles_per_sample)
        #: Absolute index of the next input sample.
        self.position = 0

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """The next input samples, shifted (a new complex64 array: the caller's chunk is left as it is)."""
        x = np.ascontiguousarray(chunk, dtype=np.complex64)
        out = np.empty(len(x), dtype=np.complex64)
        mix_kernel(x, self.position, self.cycles_per_sample, self._table, out)
        self.position += len(x)
        return out
