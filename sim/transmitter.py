"""Pulse shaping of the DTMB symbol stream, evaluated at arbitrary times.

The transmitted baseband is ``s(u) = sum_n a_n p(u - n)`` with ``u`` the
transmitter time in symbol periods (u = 0 is the first symbol of frame 0, the
start of a superframe), ``a_n`` the symbols of :class:`sim.frames.FrameSource`
and ``p`` the square-root raised-cosine pulse of roll-off
``gb20600.SRRC_ROLLOFF`` (docs/dtmb.md §1), truncated to ``+-span`` symbols.
Because ``s`` is evaluated at any real ``u``, a receiver whose path delays
change continuously (walking) or whose ADC clock runs fast or slow (sampling
offset), at any output rate, gets exactly the samples it would record.

The pulse is tabulated on a fine grid (``oversampling`` points per symbol,
default T/512) and linearly interpolated; the table is scaled to unit energy,
so the shaped signal's mean power equals the mean symbol power (1 for the
body, ``header_power_ratio`` in the header).

Two numba kernels do the work, each with a plain-numpy reference of the same
arithmetic (``*_reference``) for the tests and the benchmarks:

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

from dtmbnav.core import gb20600


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


@dataclass(frozen=True)
class PulseTable:
    """A truncated SRRC tabulated for the kernels.

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
        Half-length of the truncated pulse, symbols.
    rolloff : float
        SRRC roll-off.
    """

    polyphase: np.ndarray
    oversampling: int
    span: int
    rolloff: float


def pulse_table(span: int = 16, oversampling: int = 512, rolloff: float = gb20600.SRRC_ROLLOFF) -> PulseTable:
    """Tabulate the SRRC over ``[-span, span]`` symbols with ``oversampling`` points per symbol."""
    if span < 2 or oversampling < 2:
        raise ValueError(f"pulse table needs span >= 2 and oversampling >= 2, got {span}, {oversampling}")
    phase = np.arange(oversampling + 1)[:, None] / oversampling
    taps = span - 1 - np.arange(2 * span)[None, :]
    polyphase = srrc_pulse(phase + taps, rolloff)
    # Truncation loses a little energy; restore unit energy so the signal power is exact.
    polyphase /= np.sqrt(np.sum(polyphase[:-1] ** 2) / oversampling)
    polyphase.flags.writeable = False
    return PulseTable(polyphase, oversampling, span, rolloff)


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
