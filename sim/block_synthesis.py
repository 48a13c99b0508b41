"""Block synthesis: the received multipath stream computed a block of samples at a time in the frequency domain.

This is the default synthesis of :class:`sim.rf.CaptureGenerator`; its exact
twin evaluates the same model sample by sample
(:func:`sim.transmitter.multipath_kernel`, ``synthesis="exact"``).

**Model.** The received sample ``j`` of block ``b`` (absolute sample
``b B + j``, ``0 <= j < B``) is

``r(j) = exp(j phi(j)) sum_p c_p(j) s(u_p(j))``

with ``s`` the shaped symbol stream (:mod:`sim.transmitter`), and the path
symbol times ``u_p``, path coefficients ``c_p`` and common phase ``phi``
linear in ``j`` between their values at the block's ends (sim.rf's grid is
the block boundaries): ``u_p(j) = u_p0 + sigma_p j``,
``c_p(j) = C_p + C'_p delta``, ``phi(j) = phi_0 + phi' j``, with
``delta = j - j_c`` the offset from the block centre ``j_c = (B - 1) / 2``.

**Delay slope, first order.** An FFT evaluates ``s`` on a uniform grid of
``rho = N / M`` symbols per sample (N symbols in, M samples out). Each path's
slope ``sigma_p`` differs from ``rho`` by ``eps_p``: the sampling-clock
offset, the path's Doppler (its delay changes by picoseconds per frame at
walking speed) and the rounding of the rate to ``N / M``; blocks are short
enough that ``|eps_p| B`` stays below ``MAX_BLOCK_DRIFT_SYMBOLS``
(:func:`choose_layout`). Around the block centre

``c_p(j) s(u_p(j)) = C_p s(x_p(j)) + delta [C'_p s(x_p(j)) + eps_p C_p s'(x_p(j))] + O(delta^2)``

with ``x_p(j) = u_p(j) - eps_p delta`` on the FFT grid. The neglected terms
are ``C_p (eps_p delta)^2 s'' / 2`` and ``C'_p eps_p delta^2 s'``: with the
grid rule of sim.rf (a path's phase turns by at most
``MAX_GRID_PHASE_STEP_RAD`` per block) and ``|eps_p delta|`` at most half of
``MAX_BLOCK_DRIFT_SYMBOLS`` they stay far below the -50 dB bound that the
tests hold the synthesis to.

**Frequency domain (overlap-save).** Paths whose ``x_p`` lie within
``layout.spread_symbols`` of each other share a window of N symbols
``a[n0 .. n0 + N)``; ``A = DFT_N(a)``. On the window's period the shaped
signal is ``s(n0 + x) = (1/N) sum_k A[k mod N] P(k / N) exp(j 2 pi k x / N)``
(``P`` the pulse spectrum, :func:`sim.transmitter.pulse_spectrum`, through
the front end's anti-alias filter below the symbol rate), exact
where the pulse does not wrap, ``span <= x <= N - span``. At
``x = E_p + rho j`` the factor ``exp(j 2 pi k rho j / N)`` is
``exp(j 2 pi k j / M)``, so

``Y0[k mod M] = sum_p A[k] P(k/N) C_p exp(j 2 pi k E_p / N)``
``Y1[k mod M] = sum_p A[k] P(k/N) exp(j 2 pi k E_p / N) (C'_p + j 2 pi (k / N) eps_p C_p)``

and ``r(j) = exp(j phi(j)) (y0(j) + delta y1(j))``, ``y = IDFT_M(Y) / N``
(unnormalised inverse). The fractional delay of each path is its linear
phase over the bins, the derivative ``s'`` a factor ``j 2 pi k / N``, the
sampling at any rate ``fs = M Rs / N`` a fold of the bins modulo M (aliasing
included, as sampling gives it). Bins stop at ``|k / N| <= BAND_EDGE``; the
tapered pulse has less than -70 dB of its energy beyond. The transforms and
the bin sums run in single precision (rounding about -140 dB of the signal).

Every block is a pure function of its index; blocks are computed in batches
of ``layout.batch_blocks`` that start at absolute multiples of the batch, so
the FFT sizes and batch shapes (and the rounding) never depend on how a
caller chunks the stream. The numba kernels release the GIL, so batches can
run on several threads (``dtmbnav simulate --jobs N``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyfftw
from numba import njit

from dtmbnav_core import gb20600
from sim.fft import fftw_plan
from sim.transmitter import PulseTable, pulse_spectrum

#: Highest frequency carried, cycles per symbol (the tapered pulse's energy beyond is below -70 dB).
BAND_EDGE = 0.6
#: Least spread of path positions that one symbol window holds, symbols.
MIN_SPREAD_SYMBOLS = 32
#: Largest drift over a block from rounding the rate to N / M, symbols.
RATE_TOLERANCE_SYMBOLS = 1e-3
#: Largest drift over a block of a path's delay against the FFT grid (clock offset and Doppler), symbols.
MAX_BLOCK_DRIFT_SYMBOLS = 0.02
#: Blocks per batch (one FFT call per batch).
BATCH_BLOCKS = 32
#: Bins per chunk of the path loop in :func:`path_spectrum_kernel` (its phase tables).
_CHUNK_BINS = 64


def _is_smooth(n: int) -> bool:
    """True when n has no prime factor above 7 (the sizes FFTW transforms fastest)."""
    for p in (2, 3, 5, 7):
        while n % p == 0:
            n //= p
    return n == 1


@dataclass(frozen=True)
class BlockLayout:
    """Sizes of the block synthesis at one output rate.

    Attributes
    ----------
    block_samples : int
        Output samples per block, B.
    window_symbols : int
        Symbols per window (forward DFT length), N.
    output_bins : int
        Inverse DFT length, M; ``rho = N / M`` symbols per output sample.
    spread_symbols : float
        Largest spread of path positions that share a window, symbols.
    first_bin : int
        Lowest harmonic carried, ``-floor(BAND_EDGE * N)``.
    pulse : ndarray of float32
        ``P(k / N)`` for ``k = first_bin .. -first_bin``.
    batch_blocks : int
        Blocks per batch.
    span : int
        Pulse half-length, symbols.
    """

    block_samples: int
    window_symbols: int
    output_bins: int
    spread_symbols: float
    first_bin: int
    pulse: np.ndarray
    batch_blocks: int
    span: int

    @property
    def rho(self) -> float:
        """Symbols per output sample on the FFT grid, N / M."""
        return self.window_symbols / self.output_bins

    @property
    def batch_samples(self) -> int:
        """Output samples per batch."""
        return self.block_samples * self.batch_blocks


def choose_layout(sample_rate_hz: float, max_block_s: float, max_rate_error: float, pulse: PulseTable,
                  batch_blocks: int = BATCH_BLOCKS) -> BlockLayout:
    """Block and DFT sizes for an output rate.

    Parameters
    ----------
    sample_rate_hz : float
        Output rate, samples/s.
    max_block_s : float
        Longest block, s (sim.rf's grid rule).
    max_rate_error : float
        Bound of any path's fractional rate error ``|sigma_p / rho - 1|``
        (clock frequency offset plus Doppler over carrier). The block is short
        enough that the delay drifts by at most ``MAX_BLOCK_DRIFT_SYMBOLS``
        against the FFT grid, which keeps the first-order term's remainder
        below -80 dB.
    pulse : PulseTable
        Transmit pulse.
    batch_blocks : int
        Blocks per batch.

    Notes
    -----
    N must hold a block's ``rho (B - 1)`` symbols, the pulse (``2 span``) and
    a path spread of at least ``MIN_SPREAD_SYMBOLS``. Among the windows up
    to twice that size, the smallest N whose ``M = round(N fs / Rs)`` keeps
    the rate error over a block below ``RATE_TOLERANCE_SYMBOLS`` is taken,
    sizes with no prime factor above 7 first (standard rates such as 7.56,
    10, 12.5, 16 and 20 Msps have exact such pairs); failing that, the pair
    with the smallest error (the first-order term carries what remains).
    """
    if sample_rate_hz <= 0 or max_block_s <= 0:
        raise ValueError(f"block layout needs a positive rate and block length, got {sample_rate_hz}, {max_block_s}")
    rho_nominal = gb20600.SYMBOL_RATE_HZ / sample_rate_hz
    if max_rate_error > 0:
        max_block_s = min(max_block_s, MAX_BLOCK_DRIFT_SYMBOLS / (max_rate_error * gb20600.SYMBOL_RATE_HZ))
    block = max(int(np.floor(max_block_s * sample_rate_hz)), 1)
    n_min = int(np.ceil(rho_nominal * (block - 1))) + 2 * pulse.span + MIN_SPREAD_SYMBOLS + 2
    candidates = np.arange(n_min, 2 * n_min + 1)
    bins = np.maximum(np.rint(candidates / rho_nominal).astype(np.int64), 1)
    drift = np.abs(candidates / bins - rho_nominal) * block
    within = drift <= RATE_TOLERANCE_SYMBOLS
    smooth = np.array([_is_smooth(int(n)) and _is_smooth(int(m)) for n, m in zip(candidates, bins)])
    if np.any(within & smooth):
        pick = int(np.argmax(within & smooth))
    elif np.any(within):
        pick = int(np.argmax(within))
    else:
        pick = int(np.argmin(drift))
    n, m = int(candidates[pick]), int(bins[pick])
    spread = n - 2 * pulse.span - n / m * (block - 1) - 1.0
    k_max = int(np.floor(BAND_EDGE * n))
    harmonics = np.arange(-k_max, k_max + 1)
    spectrum = pulse_spectrum(pulse, harmonics, n).astype(np.float32)
    spectrum.flags.writeable = False
    return BlockLayout(block, n, m, spread, -k_max, spectrum, batch_blocks, pulse.span)


@njit(cache=True, nogil=True)
def window_plan_kernel(path_u: np.ndarray, coef: np.ndarray, rho: float, block_samples: int, span: int,
                       window_symbols: int, spread_symbols: float, window_first: np.ndarray,
                       window_of_path: np.ndarray, phase_cycles: np.ndarray, c0: np.ndarray, c1: np.ndarray,
                       c_rate: np.ndarray) -> int:
    """Per block and path: the symbol window and the coefficients of the bin sums (module docstring).

    Parameters
    ----------
    path_u : (P, nb + 1) float64
        Path symbol times at the block boundaries.
    coef : (P, nb + 1) complex128
        Path coefficients at the block boundaries.
    rho, block_samples, span, window_symbols, spread_symbols
        The layout.
    window_first : (>= nb P,) int64, out
        Absolute index of each window's first symbol.
    window_of_path : (nb, P) int64, out
        Window row of each path in each block, -1 for a path that is silent
        over the whole block (zero coefficient at both ends).
    phase_cycles : (nb, P) float64, out
        ``E_p / N``: the path's delay phase per harmonic, cycles.
    c0, c1 : (nb, P) complex128, out
        ``C_p`` and ``C'_p``.
    c_rate : (nb, P) complex128, out
        ``2 pi eps_p C_p / N`` (times ``j k`` in bin k).

    Returns
    -------
    int
        Number of windows.
    """
    n_paths, nb = path_u.shape[0], path_u.shape[1] - 1
    centre = (block_samples - 1) / 2.0
    start = np.empty(n_paths)
    order = np.empty(n_paths, dtype=np.int64)
    windows = 0
    for b in range(nb):
        active = 0
        for p in range(n_paths):
            window_of_path[b, p] = -1
            slope = (path_u[p, b + 1] - path_u[p, b]) / block_samples
            eps = slope - rho
            dc = coef[p, b + 1] - coef[p, b]
            c0[b, p] = coef[p, b] + dc * (centre / block_samples)
            c1[b, p] = dc / block_samples
            c_rate[b, p] = 2.0 * np.pi * eps / window_symbols * c0[b, p]
            # Where the FFT grid of this path starts (sample 0 on the grid of slope rho).
            start[p] = path_u[p, b] + eps * centre
            if coef[p, b] != 0 or coef[p, b + 1] != 0:
                # Insertion sort of the active paths by grid start.
                i = active
                while i > 0 and start[order[i - 1]] > start[p]:
                    order[i] = order[i - 1]
                    i -= 1
                order[i] = p
                active += 1
        first = 0.0
        for i in range(active):
            p = order[i]
            if i == 0 or start[p] - first > spread_symbols:
                window_first[windows] = np.int64(np.floor(start[p])) - span
                first = start[p]
                windows += 1
            window_of_path[b, p] = windows - 1
            phase_cycles[b, p] = (start[p] - window_first[windows - 1]) / window_symbols
    return windows


def window_plan_reference(path_u: np.ndarray, coef: np.ndarray, layout: BlockLayout):
    """Plain-numpy reference of :func:`window_plan_kernel`; returns its outputs as a tuple."""
    n_paths, nb = path_u.shape[0], path_u.shape[1] - 1
    b_len = layout.block_samples
    centre = (b_len - 1) / 2.0
    eps = np.diff(path_u, axis=1) / b_len - layout.rho
    dc = np.diff(coef, axis=1)
    c0 = (coef[:, :-1] + dc * (centre / b_len)).T
    c1 = (dc / b_len).T
    c_rate = (2.0 * np.pi * eps.T / layout.window_symbols) * c0
    start = (path_u[:, :-1] + eps * centre).T
    active = ((coef[:, :-1] != 0) | (coef[:, 1:] != 0)).T
    window_first, window_of_path = [], np.full((nb, n_paths), -1, dtype=np.int64)
    phase_cycles = np.zeros((nb, n_paths))
    for b in range(nb):
        first = None
        for p in sorted(np.flatnonzero(active[b]), key=lambda q: start[b, q]):
            if first is None or start[b, p] - first > layout.spread_symbols:
                window_first.append(int(np.floor(start[b, p])) - layout.span)
                first = start[b, p]
            window_of_path[b, p] = len(window_first) - 1
            phase_cycles[b, p] = (start[b, p] - window_first[-1]) / layout.window_symbols
    return np.array(window_first, dtype=np.int64), window_of_path, phase_cycles, c0, c1, c_rate


# fastmath lets LLVM vectorise the bin loops; every block runs the same instructions whatever the
# chunking or the thread, so the output stays reproducible to the bit. The sums are single precision
# (rounding near -140 dB of the signal); phases are reduced in double precision first.
@njit(cache=True, nogil=True, fastmath=True)
def path_spectrum_kernel(spectra: np.ndarray, window_of_path: np.ndarray, phase_cycles: np.ndarray,
                         c0: np.ndarray, c1: np.ndarray, c_rate: np.ndarray, pulse: np.ndarray, first_bin: int,
                         out: np.ndarray) -> None:
    """The bin sums ``Y0`` and ``Y1`` of every block (module docstring).

    Parameters
    ----------
    spectra : (W, N) complex64
        DFT of each symbol window.
    window_of_path, phase_cycles, c0, c1, c_rate : (nb, P)
        From :func:`window_plan_kernel`.
    pulse : (K,) float32
        ``P(k / N)`` for ``k = first_bin .. first_bin + K - 1``.
    first_bin : int
    out : (2 nb, M) complex64
        Row ``2 b``: ``Y0`` of block b; row ``2 b + 1``: ``Y1``.
    """
    nb, n_paths = window_of_path.shape
    n_sym = spectra.shape[1]
    m_out = out.shape[1]
    n_bins = pulse.shape[0]
    lo_re = np.empty((n_paths, _CHUNK_BINS), dtype=np.float32)
    lo_im = np.empty((n_paths, _CHUNK_BINS), dtype=np.float32)
    hi_re = np.empty(n_paths)
    hi_im = np.empty(n_paths)
    step_re = np.empty(n_paths)
    step_im = np.empty(n_paths)
    a0r = np.empty(_CHUNK_BINS, dtype=np.float32)
    a0i = np.empty(_CHUNK_BINS, dtype=np.float32)
    a1r = np.empty(_CHUNK_BINS, dtype=np.float32)
    a1i = np.empty(_CHUNK_BINS, dtype=np.float32)
    a2r = np.empty(_CHUNK_BINS, dtype=np.float32)
    a2i = np.empty(_CHUNK_BINS, dtype=np.float32)
    for b in range(nb):
        out[2 * b, :] = 0.0
        out[2 * b + 1, :] = 0.0
        last_window = -1
        for p in range(n_paths):
            w = window_of_path[b, p]
            last_window = max(last_window, w)
            if w >= 0:
                # exp(j 2 pi k E / N) = hi (at the chunk's first bin) * lo[i]; hi steps by a chunk per
                # chunk, lo by a bin per bin: two complex recurrences in double precision (their
                # rounding grows like the number of steps, about 1e-14).
                cycles = phase_cycles[b, p]
                turns = cycles * first_bin
                ph = 2.0 * np.pi * (turns - np.floor(turns))
                hi_re[p], hi_im[p] = np.cos(ph), np.sin(ph)
                turns = cycles * _CHUNK_BINS
                ph = 2.0 * np.pi * (turns - np.floor(turns))
                step_re[p], step_im[p] = np.cos(ph), np.sin(ph)
                ph = 2.0 * np.pi * (cycles - np.floor(cycles))
                dr, di = np.cos(ph), np.sin(ph)
                zr, zi = 1.0, 0.0
                for i in range(_CHUNK_BINS):
                    lo_re[p, i] = zr
                    lo_im[p, i] = zi
                    zr, zi = zr * dr - zi * di, zr * di + zi * dr
        for w in range(last_window + 1):
            used = False
            for p in range(n_paths):
                used = used or window_of_path[b, p] == w
            if not used:
                continue
            for h in range(0, n_bins, _CHUNK_BINS):
                n = min(_CHUNK_BINS, n_bins - h)
                a0r[:] = 0.0
                a0i[:] = 0.0
                a1r[:] = 0.0
                a1i[:] = 0.0
                a2r[:] = 0.0
                a2i[:] = 0.0
                for p in range(n_paths):
                    if window_of_path[b, p] != w:
                        continue
                    hr, hi = np.float32(hi_re[p]), np.float32(hi_im[p])
                    hi_re[p], hi_im[p] = (hi_re[p] * step_re[p] - hi_im[p] * step_im[p],
                                          hi_re[p] * step_im[p] + hi_im[p] * step_re[p])
                    cr, ci = np.float32(c0[b, p].real), np.float32(c0[b, p].imag)
                    dr, di = np.float32(c1[b, p].real), np.float32(c1[b, p].imag)
                    er, ei = np.float32(c_rate[b, p].real), np.float32(c_rate[b, p].imag)
                    lr = lo_re[p]
                    li = lo_im[p]
                    for i in range(_CHUNK_BINS):
                        zr = hr * lr[i] - hi * li[i]
                        zi = hr * li[i] + hi * lr[i]
                        a0r[i] += cr * zr - ci * zi
                        a0i[i] += cr * zi + ci * zr
                        a1r[i] += dr * zr - di * zi
                        a1i[i] += dr * zi + di * zr
                        a2r[i] += er * zr - ei * zi
                        a2i[i] += er * zi + ei * zr
                k0 = first_bin + h
                kn0 = k0 % n_sym
                km0 = k0 % m_out
                if kn0 + n <= n_sym and km0 + n <= m_out:
                    # The chunk's bins are contiguous in the window's DFT and in the output (no wrap).
                    src = spectra[w, kn0: kn0 + n]
                    y0 = out[2 * b, km0: km0 + n]
                    y1 = out[2 * b + 1, km0: km0 + n]
                    for i in range(n):
                        a = src[i] * pulse[h + i]
                        kf = np.float32(k0 + i)
                        # Y1's bin factor: C'_p + j k (2 pi eps_p C_p / N).
                        y0[i] += a * complex(a0r[i], a0i[i])
                        y1[i] += a * complex(a1r[i] - kf * a2i[i], a1i[i] + kf * a2r[i])
                else:
                    for i in range(n):
                        k = k0 + i
                        a = spectra[w, k % n_sym] * pulse[h + i]
                        kf = np.float32(k)
                        out[2 * b, k % m_out] += a * complex(a0r[i], a0i[i])
                        out[2 * b + 1, k % m_out] += a * complex(a1r[i] - kf * a2i[i], a1i[i] + kf * a2r[i])


def path_spectrum_reference(spectra: np.ndarray, window_of_path: np.ndarray, phase_cycles: np.ndarray,
                            c0: np.ndarray, c1: np.ndarray, c_rate: np.ndarray, pulse: np.ndarray, first_bin: int,
                            output_bins: int) -> np.ndarray:
    """Plain-numpy reference of :func:`path_spectrum_kernel`; returns ``out``."""
    nb, n_paths = window_of_path.shape
    k = first_bin + np.arange(len(pulse))
    out = np.zeros((2 * nb, output_bins), dtype=np.complex128)
    spectra = spectra.astype(np.complex128)
    pulse = pulse.astype(np.float64)
    for b in range(nb):
        for p in range(n_paths):
            w = window_of_path[b, p]
            if w < 0:
                continue
            term = spectra[w, k % spectra.shape[1]] * pulse * np.exp(2j * np.pi * phase_cycles[b, p] * k)
            np.add.at(out[2 * b], k % output_bins, c0[b, p] * term)
            np.add.at(out[2 * b + 1], k % output_bins, (c1[b, p] + 1j * k * c_rate[b, p]) * term)
    return out


@njit(cache=True, nogil=True, fastmath=True)
def combine_kernel(inverse: np.ndarray, block_samples: int, phase: np.ndarray, scale: float, out: np.ndarray) -> None:
    """``out[b B + j] = scale exp(j phi(j)) (y0(j) + (j - j_c) y1(j))`` for every block of a batch.

    Parameters
    ----------
    inverse : (2 nb, M) complex64
        Unnormalised inverse DFTs of ``Y0`` (even rows) and ``Y1`` (odd rows).
    block_samples : int
    phase : (nb + 1,) float64
        Common phase at the block boundaries, rad.
    scale : float
        ``1 / N``.
    out : (nb B,) complex128
    """
    nb = inverse.shape[0] // 2
    centre = (block_samples - 1) / 2.0
    lo_re = np.empty(_CHUNK_BINS)
    lo_im = np.empty(_CHUNK_BINS)
    for b in range(nb):
        step = (phase[b + 1] - phase[b]) / block_samples
        # exp(j phi(j)) = hi (at the chunk's first sample) * lo[i], both by complex recurrences.
        dr, di = np.cos(step), np.sin(step)
        zr, zi = 1.0, 0.0
        for i in range(_CHUNK_BINS):
            lo_re[i] = zr
            lo_im[i] = zi
            zr, zi = zr * dr - zi * di, zr * di + zi * dr
        dr, di = np.cos(step * _CHUNK_BINS), np.sin(step * _CHUNK_BINS)
        hr, hi = scale * np.cos(phase[b]), scale * np.sin(phase[b])
        for h in range(0, block_samples, _CHUNK_BINS):
            for i in range(min(_CHUNK_BINS, block_samples - h)):
                j = h + i
                rot = complex(hr * lo_re[i] - hi * lo_im[i], hr * lo_im[i] + hi * lo_re[i])
                y0 = complex(inverse[2 * b, j].real, inverse[2 * b, j].imag)
                y1 = complex(inverse[2 * b + 1, j].real, inverse[2 * b + 1, j].imag)
                out[b * block_samples + j] = rot * (y0 + (j - centre) * y1)
            hr, hi = hr * dr - hi * di, hr * di + hi * dr


def combine_reference(inverse: np.ndarray, block_samples: int, phase: np.ndarray, scale: float) -> np.ndarray:
    """Plain-numpy reference of :func:`combine_kernel`; returns ``out``."""
    nb = inverse.shape[0] // 2
    j = np.arange(block_samples)
    step = np.diff(phase) / block_samples
    rot = scale * np.exp(1j * (phase[:-1, None] + step[:, None] * j))
    inverse = inverse.astype(np.complex128)
    body = inverse[0::2, :block_samples] + (j - (block_samples - 1) / 2.0) * inverse[1::2, :block_samples]
    return (rot * body).reshape(nb * block_samples)


class BlockSynthesizer:
    """FFT plans and buffers of one layout; one per thread (a plan's buffers are its own).

    Parameters
    ----------
    layout : BlockLayout
    """

    def __init__(self, layout: BlockLayout) -> None:
        self.layout = layout
        self._inverse = fftw_plan(2 * layout.batch_blocks, layout.output_bins, "FFTW_BACKWARD", np.complex64)
        self._forward: dict[int, pyfftw.FFTW] = {}

    def _forward_plan(self, rows: int) -> pyfftw.FFTW:
        """Forward DFT of ``rows`` windows (plans cached by row count)."""
        if rows not in self._forward:
            self._forward[rows] = fftw_plan(rows, self.layout.window_symbols, "FFTW_FORWARD", np.complex64)
        return self._forward[rows]

    def synthesize(self, path_u: np.ndarray, coef: np.ndarray, phase: np.ndarray, symbols) -> np.ndarray:
        """Noise-free samples of one batch.

        Parameters
        ----------
        path_u, coef : (P, batch_blocks + 1)
            Path symbol times and coefficients at the batch's block boundaries.
        phase : (batch_blocks + 1,) float64
            Common phase at the boundaries, rad.
        symbols : callable
            ``symbols(start, stop, out)`` writes the transmitted symbols
            ``[start, stop)`` into ``out`` (:meth:`sim.frames.FrameSource.symbols`).

        Returns
        -------
        ndarray of complex128, shape (batch_blocks * block_samples,)
        """
        lay = self.layout
        nb = path_u.shape[1] - 1
        n_paths = path_u.shape[0]
        if nb != lay.batch_blocks:
            raise ValueError(f"block synthesis: got {nb} blocks for a batch of {lay.batch_blocks}")
        window_first = np.empty(nb * n_paths, dtype=np.int64)
        window_of_path = np.empty((nb, n_paths), dtype=np.int64)
        phase_cycles = np.zeros((nb, n_paths))
        c0 = np.empty((nb, n_paths), dtype=np.complex128)
        c1 = np.empty_like(c0)
        c_rate = np.empty_like(c0)
        n_windows = window_plan_kernel(path_u, coef, lay.rho, lay.block_samples, lay.span, lay.window_symbols,
                                       lay.spread_symbols, window_first, window_of_path, phase_cycles, c0, c1, c_rate)
        forward = self._forward_plan(max(n_windows, 1))
        for w in range(n_windows):
            symbols(int(window_first[w]), int(window_first[w]) + lay.window_symbols, forward.input_array[w])
        forward.execute()
        path_spectrum_kernel(forward.output_array, window_of_path, phase_cycles, c0, c1, c_rate, lay.pulse,
                             lay.first_bin, self._inverse.input_array)
        self._inverse.execute()
        out = np.empty(nb * lay.block_samples, dtype=np.complex128)
        combine_kernel(self._inverse.output_array, lay.block_samples, np.ascontiguousarray(phase, dtype=np.float64),
                       1.0 / lay.window_symbols, out)
        return out
