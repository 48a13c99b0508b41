"""Streaming rational polyphase resampling to the DTMB symbol rate.

Any capture rate is brought to 7.56 Msps with an up/down rational ratio and a
Kaiser-windowed low-pass FIR (a windowed sinc, the design of
``scipy.signal.firwin``, written with numpy so that the receive path does
not import scipy), applied as a polyphase filter. Output sample ``n`` is computed at upsampled position
``n * down + D`` with ``D`` the filter's group delay, so it sits exactly at
input time ``n * down / up`` (input samples): the output index maps back to
the capture without an offset. Each output sample depends only on the input
samples it needs, whatever the chunking, so the stream is chunk-size invariant.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from numba import njit

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ

#: Largest up/down factor accepted before the ratio is approximated.
MAX_RATIO_TERM = 4096


def resampling_ratio(input_rate_hz: float, output_rate_hz: float = SYMBOL_RATE_HZ) -> tuple[int, int]:
    """``(up, down)`` with ``input_rate * up / down == output_rate``.

    Raises
    ------
    ValueError
        If the rate is not positive or no ratio with terms up to
        ``MAX_RATIO_TERM`` matches within 1 ppm (the residual would act as a
        sampling offset the tracker would have to absorb).
    """
    if not np.isfinite(input_rate_hz) or input_rate_hz <= 0:
        raise ValueError(f"sample_rate_hz must be a positive number, got {input_rate_hz!r}")
    ratio = Fraction(output_rate_hz / input_rate_hz).limit_denominator(MAX_RATIO_TERM)
    if ratio.numerator > MAX_RATIO_TERM or abs(float(ratio) * input_rate_hz / output_rate_hz - 1.0) > 1e-6:
        raise ValueError(f"sample_rate_hz {input_rate_hz} Hz: no rational ratio to {output_rate_hz} Hz "
                         f"with terms <= {MAX_RATIO_TERM}")
    return ratio.numerator, ratio.denominator


def design_filter(up: int, down: int, taps_per_phase: int = 12, beta: float = 8.0) -> np.ndarray:
    """Low-pass prototype for an up/down resampler (odd length, gain ``up``).

    The cutoff is the narrower of the input and output Nyquist frequencies.
    Length ``2 * taps_per_phase * max(up, down) + 1`` keeps the transition
    band a fixed fraction of the output band whatever the ratio. The taps are
    a sinc of that cutoff times a Kaiser window, scaled to unit gain at DC
    before the factor ``up`` (what ``scipy.signal.firwin(length, cutoff,
    window=("kaiser", beta))`` returns).
    """
    length = 2 * taps_per_phase * max(up, down) + 1
    cutoff = 1.0 / max(up, down)           # fraction of the upsampled Nyquist frequency
    lag = np.arange(length) - (length - 1) / 2
    h = cutoff * np.sinc(cutoff * lag) * np.kaiser(length, beta)
    return (up * h / np.sum(h)).astype(np.float32)


def polyphase_bank(h: np.ndarray, up: int) -> np.ndarray:
    """Filter ``h`` split into its ``up`` phases: ``bank[k, t] = h[k + t * up]`` (zero-padded).

    Each output sample is then one contiguous dot product of a bank row with
    the input, instead of a strided walk through ``h``.
    """
    n_taps = -(-len(h) // up)
    padded = np.zeros(n_taps * up, dtype=np.float32)
    padded[: len(h)] = h
    return np.ascontiguousarray(padded.reshape(n_taps, up).T)


@njit(cache=True, nogil=True)
def polyphase_kernel(x: np.ndarray, x_start: int, bank: np.ndarray, delay: int, up: int, down: int,
                     n_first: int, n_count: int) -> np.ndarray:
    """Output samples ``n_first .. n_first + n_count - 1`` of the resampler.

    ``x`` holds input samples with global indices ``x_start ..``; output n
    is ``sum_i x[i] h[n*down + D - i*up]`` over the taps inside the filter,
    ``D = delay = (len(h) - 1) // 2``, computed with the phase bank of
    :func:`polyphase_bank`. The caller guarantees the needed inputs are in
    ``x`` (indices below ``x_start`` count as zeros: the stream's start).
    """
    n_taps = bank.shape[1]
    out = np.empty(n_count, dtype=np.complex64)
    for j in range(n_count):
        u = (n_first + j) * down + delay
        i = u // up - x_start
        row = bank[u - (u // up) * up]
        acc_re = np.float32(0.0)
        acc_im = np.float32(0.0)
        stop = min(n_taps, i + 1)  # taps reaching before the stream start are zeros
        for t in range(stop):
            v = x[i - t]
            acc_re += row[t] * v.real
            acc_im += row[t] * v.imag
        out[j] = complex(acc_re, acc_im)
    return out


def polyphase_reference(x: np.ndarray, h: np.ndarray, up: int, down: int, n_count: int) -> np.ndarray:
    """Plain-numpy resampler of a whole signal starting at index 0 (for tests).

    Upsample by zero insertion, filter (FFT convolution), shift by the group
    delay, decimate.
    """
    from scipy.signal import fftconvolve   # tests and benchmark only: the receive path stays free of scipy

    delay = (len(h) - 1) // 2
    upsampled = np.zeros(len(x) * up, dtype=np.complex128)
    upsampled[::up] = x
    filtered = fftconvolve(upsampled, h.astype(np.float64))
    return filtered[delay: delay + n_count * down: down][:n_count].astype(np.complex64)


class StreamResampler:
    """Chunk-size-invariant resampler of a complex stream to 7.56 Msps.

    Parameters
    ----------
    input_rate_hz : float
        Capture sample rate, Hz.
    output_rate_hz : float
        Target rate, Hz (the DTMB symbol rate by default).

    Attributes
    ----------
    up, down : int
        The rational ratio; ``up == down == 1`` is a pass-through.
    """

    def __init__(self, input_rate_hz: float, output_rate_hz: float = SYMBOL_RATE_HZ) -> None:
        self.up, self.down = resampling_ratio(input_rate_hz, output_rate_hz)
        self.input_rate_hz = float(input_rate_hz)
        self.passthrough = self.up == 1 and self.down == 1
        self._h = design_filter(self.up, self.down) if not self.passthrough else np.ones(1, np.float32)
        self._bank = polyphase_bank(self._h, self.up)
        # Input samples each output needs behind the newest one it touches.
        self._history = len(self._h) // self.up + 2
        self._x = np.zeros(0, dtype=np.complex64)
        self._x_start = 0
        self._n_next = 0

    @property
    def noise_bandwidth_hz(self) -> float:
        """Equivalent noise bandwidth, Hz: white input noise of density N0 (per Hz) comes out at N0 times this per sample.

        Output sample n sums ``x[i - t]`` weighted by one phase of the filter;
        averaged over the ``up`` phases, white noise of variance ``sigma^2``
        comes out at ``sigma^2 sum(h^2) / up``, and its density (the filter's
        passband gain is 1) is ``sigma^2 / input_rate``. The pass-through has
        the whole 7.56 MHz band.
        """
        return self.input_rate_hz * float(np.sum(self._h.astype(np.float64) ** 2)) / self.up

    def input_index(self, n: np.ndarray) -> np.ndarray:
        """Input sample at or before output sample ``n`` (int64)."""
        return (np.asarray(n, dtype=np.int64) * self.down) // self.up

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """Feed input samples; return the output samples now complete."""
        chunk = np.asarray(chunk, dtype=np.complex64)
        if self.passthrough:
            return chunk
        self._x = np.concatenate([self._x, chunk])
        x_end = self._x_start + len(self._x)
        # Output n needs inputs up to floor((n*down + D) / up).
        delay = (len(self._h) - 1) // 2
        n_stop = (x_end * self.up - delay - 1) // self.down + 1 if x_end * self.up > delay else 0
        out = polyphase_kernel(self._x, self._x_start, self._bank, delay, self.up, self.down, self._n_next,
                               max(n_stop - self._n_next, 0))
        self._n_next = max(n_stop, self._n_next)
        keep_from = max((self._n_next * self.down + delay) // self.up - self._history, self._x_start)
        self._x = self._x[keep_from - self._x_start:]
        self._x_start = keep_from
        return out
