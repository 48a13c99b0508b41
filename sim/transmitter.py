"""Pulse shaping of the DTMB symbol stream, evaluated at arbitrary times.

The transmitted baseband is ``s(u) = sum_n a_n p(u - n)`` with ``u`` the
transmitter time in symbol periods (u = 0 is the first symbol of frame 0, the
start of a superframe), ``a_n`` the symbols of :class:`sim.frames.FrameSource`
and ``p`` the square-root raised-cosine pulse of roll-off
``gb20600.SRRC_ROLLOFF`` (docs/dtmb.md §1), limited to ``+-span`` symbols the
way a transmitter's FIR filter is: the outer ``taper`` symbols of each side
are multiplied by a raised-cosine taper that falls smoothly to zero at
``+-span`` (:func:`shaping_pulse`). A hard cut would leave a step at the ends
whose spectrum decays only as 1/f; the taper makes the pulse's spectrum
negligible a little past the SRRC band edge, which is what lets
:mod:`sim.block_synthesis` work on a finite band of frequency bins
(:func:`pulse_spectrum`). Because ``s`` is evaluated at any real ``u``, a
receiver whose path delays change continuously (walking) or whose ADC clock
runs fast or slow (sampling offset), at any output rate, gets exactly the
samples it would record.

The pulse is tabulated on a fine grid (``oversampling`` points per symbol,
default T/512) and linearly interpolated; the table is scaled to unit energy,
so the shaped signal's mean power equals the mean symbol power (1 for the
body, ``header_power_ratio`` in the header).

Two numba kernels evaluate the model sample by sample, each with a
plain-numpy reference of the same arithmetic (``*_reference``) for the tests
and the benchmarks; they are the exact twin of the block synthesis
(``CaptureGenerator(synthesis="exact")``):

- :func:`shape_kernel` evaluates ``s(u_k)`` for an array of times;
- :func:`multipath_kernel` forms a received sample stream
  ``r_k = exp(j phi(t_k)) * sum_p c_p(t_k) s(u_p(t_k))``, with the per-path
  symbol time ``u_p``, complex path coefficient ``c_p`` and common phase
  ``phi`` given on a coarse uniform time grid and linearly interpolated
  between grid points (the geometry and the clock change slowly; see
  ``sim.rf``). Its cost is paths x (2 span) x samples multiply-adds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy.signal import fftconvolve

from dtmbnav_core import gb20600


def srrc_pulse(x: np.ndarray, rolloff: float = gb20600.SRRC_ROLLOFF) -> np.ndarray:
    """Square-root raised-cosine pulse at times ``x`` (in symbol periods).

    Normalised so that ``integral p(x)^2 dx = 1`` (x in symbols) and ``p * p``
    is a Nyquist raised cosine with value 1 at 0.
    """
    x = np.asarray(x, dtype=np.float64)
    b = rolloff
    out = np.empty_like(x)
    at_zero = np.abs(x) < 1e-12
    at_sing = np.abs(np.abs(x) - 1.0 / (4.0 * b)) < 1e-9
    regular = ~(at_zero | at_sing)
    xr = x[regular]
    out[regular] = ((np.sin(np.pi * xr * (1 - b)) + 4 * b * xr * np.cos(np.pi * xr * (1 + b)))
                    / (np.pi * xr * (1 - (4 * b * xr) ** 2)))
    out[at_zero] = 1 - b + 4 * b / np.pi
    out[at_sing] = b / np.sqrt(2) * ((1 + 2 / np.pi) * np.sin(np.pi / (4 * b))
                                     + (1 - 2 / np.pi) * np.cos(np.pi / (4 * b)))
    return out


#: Half-length of the transmit pulse, symbols.
PULSE_SPAN = 32
#: Symbols at each end of the pulse over which the raised-cosine taper falls to zero.
PULSE_TAPER = 12


def shaping_pulse(x: np.ndarray, span: int = PULSE_SPAN, taper: int = PULSE_TAPER,
                  rolloff: float = gb20600.SRRC_ROLLOFF) -> np.ndarray:
    """The transmit pulse at times ``x`` (symbol periods), before unit-energy scaling.

    :func:`srrc_pulse` times a window that is 1 for ``|x| <= span - taper``,
    falls as a raised cosine to 0 at ``|x| = span`` and is 0 beyond.
    """
    x = np.asarray(x, dtype=np.float64)
    edge = np.clip((np.abs(x) - (span - taper)) / taper, 0.0, 1.0) if taper > 0 else (np.abs(x) > span) * 1.0
    window = np.where(np.abs(x) <= span, 0.5 * (1.0 + np.cos(np.pi * edge)), 0.0)
    return srrc_pulse(x, rolloff) * window


@dataclass(frozen=True)
class PulseTable:
    """The transmit pulse tabulated for the kernels.

    Attributes
    ----------
    polyphase : ndarray, shape (oversampling + 1, 2 span)
        ``polyphase[i, j] = p(i / oversampling + span - 1 - j)``: row ``i``
        holds the 2 span taps for a time ``i / oversampling`` symbols past a
        symbol instant, contiguous so the tap loop reads memory in order.
        Scaled to unit pulse energy.
    oversampling : int
        Table points per symbol.
    span : int
        Half-length of the pulse, symbols.
    rolloff : float
        SRRC roll-off.
    taper : int
        Symbols of raised-cosine taper at each end (:func:`shaping_pulse`).
    scale : float
        Factor from :func:`shaping_pulse` to the unit-energy pulse of the table.
    lowpass : ndarray or None
        Impulse response (per symbol) of a low-pass filter that the tabulated
        pulse is the shaping pulse filtered by (the receiver front end's
        anti-alias filter, ``sim.frontend``), sampled on the table's grid of
        ``1 / oversampling`` symbols, odd length centred on 0, unit gain at DC
        (``sum(lowpass) / oversampling = 1``); None for the shaping pulse
        itself. ``span`` then includes the filter's half-length.
    """

    polyphase: np.ndarray
    oversampling: int
    span: int
    rolloff: float
    taper: int
    scale: float
    lowpass: np.ndarray | None = None

    @property
    def shaping_span(self) -> int:
        """Half-length of the shaping pulse before the low-pass filter, symbols."""
        if self.lowpass is None:
            return self.span
        return self.span - (len(self.lowpass) - 1) // (2 * self.oversampling)


def pulse_table(span: int = PULSE_SPAN, oversampling: int = 512, rolloff: float = gb20600.SRRC_ROLLOFF,
                taper: int = PULSE_TAPER, lowpass: np.ndarray | None = None) -> PulseTable:
    """Tabulate the pulse over ``[-span, span]`` symbols with ``oversampling`` points per symbol.

    With ``lowpass`` (:attr:`PulseTable.lowpass`, odd length
    ``2 h oversampling + 1`` for a whole number ``h`` of symbols) the table holds the
    shaping pulse convolved with that filter, over ``[-(span + h), span + h]``;
    its energy is what the filter lets through (no renormalisation).
    """
    if span < 2 or oversampling < 2 or not 0 <= taper <= span:
        raise ValueError(f"pulse table needs span >= 2, oversampling >= 2 and 0 <= taper <= span, "
                         f"got {span}, {oversampling}, {taper}")
    phase = np.arange(oversampling + 1)[:, None] / oversampling
    taps = span - 1 - np.arange(2 * span)[None, :]
    polyphase = shaping_pulse(phase + taps, span, taper, rolloff)
    # The window removes a little energy; restore unit energy so the signal power is exact.
    scale = 1.0 / np.sqrt(np.sum(polyphase[:-1] ** 2) / oversampling)
    polyphase *= scale
    if lowpass is not None:
        lowpass = np.asarray(lowpass, dtype=np.float64)
        half = (len(lowpass) - 1) // (2 * oversampling)
        if len(lowpass) != 2 * half * oversampling + 1:
            raise ValueError(f"pulse table: a low-pass of {len(lowpass)} taps is not 2 h {oversampling} + 1 long")
        fine = shaping_pulse(np.arange(-span * oversampling, span * oversampling + 1) / oversampling,
                             span, taper, rolloff) * scale
        filtered = fftconvolve(fine, lowpass) / oversampling          # x from -(span + half) symbols on
        span += half
        # polyphase[i, j] = q(i / oversampling + span - 1 - j), q[0] at x = -span.
        polyphase = filtered[np.arange(oversampling + 1)[:, None]
                             + (2 * span - 1 - np.arange(2 * span)[None, :]) * oversampling]
        lowpass = lowpass.copy()
        lowpass.flags.writeable = False
    polyphase.flags.writeable = False
    return PulseTable(polyphase, oversampling, span, rolloff, taper, float(scale), lowpass)


def pulse_spectrum(table: PulseTable, bins: np.ndarray, period_symbols: int,
                   points_per_symbol: int = 16) -> np.ndarray:
    """Fourier transform ``P(f) = integral p(x) exp(-j 2 pi f x) dx`` of the pulse at ``f = bins / period_symbols``.

    The frequencies are the harmonics of a ``period_symbols``-symbol period (cycles per symbol), which is what a
    DFT of that many symbols gives; ``P`` is real because the pulse is even.

    Parameters
    ----------
    table : PulseTable
    bins : ndarray of int
        Harmonic numbers (any sign; ``|bins| < period_symbols * points_per_symbol / 2``).
    period_symbols : int
        Period, symbols.
    points_per_symbol : int
        Sampling of the pulse for the integral. The tapered pulse is smooth and
        vanishes at its ends, so the sum over its samples converges like a
        trapezoid rule on a periodic function (spectrally); its error is the
        pulse's spectrum beyond ``points_per_symbol / 2`` cycles per symbol.

    With a low-pass (:attr:`PulseTable.lowpass`) the shaping pulse's spectrum
    is multiplied by the filter's response at the same frequencies, the
    transform of the convolution that the table holds.
    """
    if 2 * table.span >= period_symbols:
        raise ValueError(f"pulse spectrum: a {period_symbols}-symbol period is shorter than the pulse")
    bins = np.asarray(bins)
    length = period_symbols * points_per_symbol
    half = table.shaping_span * points_per_symbol
    samples = np.zeros(length)
    x = np.arange(-half, half + 1)
    samples[x % length] = (shaping_pulse(x / points_per_symbol, table.shaping_span, table.taper, table.rolloff)
                           * table.scale)
    spectrum = np.fft.fft(samples)[bins % length].real / points_per_symbol
    if table.lowpass is not None:
        # The filter's DTFT on its grid of 1 / oversampling symbols, at the harmonics of the period.
        length = period_symbols * table.oversampling
        taps = np.zeros(length)
        x = np.arange(len(table.lowpass)) - (len(table.lowpass) - 1) // 2
        taps[x % length] = table.lowpass
        spectrum *= np.fft.rfft(taps)[np.abs(bins)].real / table.oversampling
    return spectrum


def symbol_range(u_min: float, u_max: float, span: int) -> tuple[int, int]:
    """Symbols ``[first, stop)`` that contribute to ``s(u)`` for ``u_min <= u <= u_max``."""
    return int(np.floor(u_min)) - span + 1, int(np.floor(u_max)) + span + 1


# fastmath lets LLVM vectorise the tap sum; the loop has a fixed trip count, so every
# sample is still computed by the same instructions whatever the chunking.
@njit(cache=True, fastmath=True)
def _shaped_at(u: float, symbols: np.ndarray, first_symbol: int, polyphase: np.ndarray, oversampling: int) -> complex:
    """``sum_n a_n p(u - n)`` over the ``2 span`` symbols nearest ``u``."""
    n0 = int(np.floor(u))
    pos = (u - n0) * oversampling
    i0 = int(pos)
    w = pos - i0
    row0 = polyphase[i0]
    row1 = polyphase[i0 + 1]
    # Column j is symbol n0 - span + 1 + j at pulse time (u - n0) + span - 1 - j.
    base = n0 - first_symbol - (polyphase.shape[1] // 2) + 1
    acc_re = 0.0
    acc_im = 0.0
    for j in range(polyphase.shape[1]):
        p = row0[j] * (1.0 - w) + row1[j] * w
        a = symbols[base + j]
        acc_re += a.real * p
        acc_im += a.imag * p
    return complex(acc_re, acc_im)


@njit(cache=True, parallel=True)
def shape_kernel(u: np.ndarray, symbols: np.ndarray, first_symbol: int, polyphase: np.ndarray,
                 oversampling: int) -> np.ndarray:
    """Shaped signal ``s(u_k)`` at symbol times ``u`` (see the module docstring).

    Parameters
    ----------
    u : ndarray of float64
        Transmitter times, symbol periods.
    symbols : ndarray of complex128
        Symbols ``a_n`` for ``n = first_symbol, first_symbol + 1, ...``; must
        cover :func:`symbol_range` of ``u``.
    first_symbol : int
        Absolute index of ``symbols[0]``.
    polyphase, oversampling
        The fields of a :class:`PulseTable`.
    """
    out = np.empty(u.shape[0], dtype=np.complex128)
    for k in prange(u.shape[0]):
        out[k] = _shaped_at(u[k], symbols, first_symbol, polyphase, oversampling)
    return out


def shape_reference(u: np.ndarray, symbols: np.ndarray, first_symbol: int, table: PulseTable) -> np.ndarray:
    """Plain-numpy reference of :func:`shape_kernel` (same table interpolation)."""
    u = np.asarray(u, dtype=np.float64)
    n0 = np.floor(u).astype(np.int64)
    pos = (u - n0) * table.oversampling
    i0 = pos.astype(np.int64)
    w = (pos - i0)[:, None]
    taps = table.polyphase[i0] * (1.0 - w) + table.polyphase[i0 + 1] * w
    index = n0[:, None] - first_symbol - table.span + 1 + np.arange(2 * table.span)[None, :]
    return np.sum(symbols[index] * taps, axis=1)


@njit(cache=True, parallel=True)
def multipath_kernel(first_sample: int, count: int, sample_rate_hz: float, grid_first: int, grid_step_s: float,
                     path_u: np.ndarray, path_coef: np.ndarray, common_phase_rad: np.ndarray,
                     symbols: np.ndarray, first_symbol: int, polyphase: np.ndarray,
                     oversampling: int) -> np.ndarray:
    """Noise-free received samples of a multipath channel (module docstring).

    Sample ``k`` (absolute index ``first_sample + k``) is taken at receiver
    time ``tau_k = (first_sample + k) / sample_rate_hz``. Column ``g`` of the
    grid holds, at receiver time ``(grid_first + g) * grid_step_s``, each
    path's symbol time
    ``path_u[p, g]`` (symbols), its complex coefficient ``path_coef[p, g]`` and
    the common phase ``common_phase_rad[g]``; all three are interpolated
    linearly at ``tau_k``. The interpolation weight is computed from absolute
    indices only, so a sample's value does not depend on where a chunk starts.

    Returns
    -------
    ndarray of complex128, shape (count,)
    """
    out = np.empty(count, dtype=np.complex128)
    n_paths = path_u.shape[0]
    for k in prange(count):
        pos = (first_sample + k) / sample_rate_hz / grid_step_s
        g_abs = np.floor(pos)
        w = pos - g_abs
        g = int(g_abs) - grid_first
        acc = 0j
        for p in range(n_paths):
            u = path_u[p, g] + w * (path_u[p, g + 1] - path_u[p, g])
            c = path_coef[p, g] + w * (path_coef[p, g + 1] - path_coef[p, g])
            acc += c * _shaped_at(u, symbols, first_symbol, polyphase, oversampling)
        phi = common_phase_rad[g] + w * (common_phase_rad[g + 1] - common_phase_rad[g])
        out[k] = acc * complex(np.cos(phi), np.sin(phi))
    return out


def multipath_reference(first_sample: int, count: int, sample_rate_hz: float, grid_first: int, grid_step_s: float,
                        path_u: np.ndarray, path_coef: np.ndarray, common_phase_rad: np.ndarray,
                        symbols: np.ndarray, first_symbol: int, table: PulseTable) -> np.ndarray:
    """Plain-numpy reference of :func:`multipath_kernel`."""
    pos = (first_sample + np.arange(count)) / sample_rate_hz / grid_step_s
    g_abs = np.floor(pos)
    w = pos - g_abs
    g = g_abs.astype(np.int64) - grid_first
    acc = np.zeros(count, dtype=np.complex128)
    for p in range(path_u.shape[0]):
        u = path_u[p, g] + w * (path_u[p, g + 1] - path_u[p, g])
        c = path_coef[p, g] + w * (path_coef[p, g + 1] - path_coef[p, g])
        acc += c * shape_reference(u, symbols, first_symbol, table)
    phi = common_phase_rad[g] + w * (common_phase_rad[g + 1] - common_phase_rad[g])
    return acc * (np.cos(phi) + 1j * np.sin(phi))
