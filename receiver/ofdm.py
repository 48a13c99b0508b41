"""The SI carriers of recovered frame bodies: a 3780-point DFT pruned to the 36 bins used.

The transform is a numba kernel over reused buffers: the body-recovery kernel
writes straight into :attr:`OfdmDemodulator.bodies` and nothing is allocated
per frame. Each :class:`OfdmDemodulator` owns its buffers, so threads that
demodulate different frames each use their own (the kernel releases the GIL).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dtmbnav_core import gb20600

#: Radix of the 36-point DFT's two stages (36 = 6 x 6).
RADIX = 6
#: Columns C of the split. A compile-time constant in :func:`si_dft_kernel`: with constant row
#: strides the compiler sees that the rows a loop stores do not overlap, and vectorises it.
COLUMNS = gb20600.BODY_LENGTH // (RADIX * RADIX)
#: sin(60 deg), the 3-point DFT's constant.
_SIN60 = np.float32(np.sqrt(3.0) / 2.0)


def si_carrier_numbers() -> np.ndarray:
    """Signed carrier number k (-18..17) of each SI carrier, SI order."""
    bins = np.asarray(gb20600.si_bins())
    return np.where(bins < gb20600.BODY_LENGTH // 2, bins, bins - gb20600.BODY_LENGTH)


def si_snr_db(si_carriers: np.ndarray, noise_power: np.ndarray) -> np.ndarray:
    """SNR on the SI carriers of each frame, dB.

    The unnormalised DFT puts ``3780 * noise_power`` of noise on every
    carrier, so the signal per carrier is the mean ``|Y_k|^2`` over the 36 SI
    carriers minus that, scaled back to per-sample units: with unit-power SI
    symbols this is the body SNR of :class:`receiver.body.ChannelEstimates`
    measured on the SI slice of the band only.

    Parameters
    ----------
    si_carriers : ndarray, complex, (B, 36)
        SI carriers from :meth:`OfdmDemodulator.si_carriers`.
    noise_power : ndarray, (B,)
        Noise power per received sample (``ChannelEstimates.noise_power``).
    """
    carrier_power = np.mean(si_carriers.real.astype(np.float64) ** 2 + si_carriers.imag.astype(np.float64) ** 2,
                            axis=1)
    noise = np.maximum(np.asarray(noise_power, dtype=np.float64), 1e-30)
    signal = np.maximum(carrier_power / gb20600.BODY_LENGTH - noise, 1e-30)
    return (10.0 * np.log10(signal / noise)).astype(np.float32)


class OfdmDemodulator:
    """The 36 SI carriers of recovered frame bodies: a 3780-point DFT pruned to the bins used.

    Only the SI carriers are used downstream, and they are exactly the
    carriers k = -18..17 (``gb20600.si_bins()``), whose residues mod 36 are
    all distinct. A Cooley-Tukey split of the same 3780-point DFT with
    ``N = R C`` (``R = 36`` rows, ``C = 105`` columns), ``n = C n1 + n2``::

        X[k] = sum_{n2 < C} W_N^(n2 k) Y[n2, k mod R],
        Y[n2, r] = sum_{n1 < R} x[C n1 + n2] W_R^(n1 r)

    evaluates it only where it is used: ``C`` R-point DFTs (one per column)
    and one length-C dot product per SI carrier. Each residue ``k mod R``
    picks out one SI carrier, because the 36 carriers span 36 consecutive k.
    The 36-point DFTs are split again, ``n1 = 6 a + b``, ``r = c + 6 d``::

        Y[n2, c + 6 d] = sum_b W_6^(b d) U[b, c, n2],
        U[b, c, n2] = W_36^(b c) sum_a W_6^(a c) x[C (6 a + b) + n2]

    (6-point DFTs, :func:`dft6`), computed for all C columns at once so that
    the loops over columns vectorise (:func:`si_dft_kernel`).

    The DFT is unnormalised: a carrier symbol X[k] sent through a channel
    H[k] comes out as ``sqrt(3780) H[k] X[k]`` (the transmitter's IDFT is
    unitary, docs/dtmb.md §3.3). :func:`si_carriers_reference` is the full
    ``np.fft`` equivalent.

    Parameters
    ----------
    batch : int
        Frames per call.
    """

    #: Rows R of the split (R-point DFTs); the SI carriers' residues mod R must be distinct.
    ROWS = gb20600.SI_LENGTH

    def __init__(self, batch: int) -> None:
        self.batch = batch
        n, rows = gb20600.BODY_LENGTH, self.ROWS
        cols = COLUMNS
        k = si_carrier_numbers()
        if rows != RADIX * RADIX or n != rows * cols or len(np.unique(k % rows)) != len(k):
            raise ValueError(f"the SI carriers' residues mod {rows} must be distinct and {RADIX}^2 x {cols} = {n}")
        self._bodies = np.zeros((batch, n), dtype=np.complex64)
        # U[b, c, :] of one frame, real and imaginary parts as separate rows: row 2 (RADIX b + c) + {0, 1}.
        self._work = np.empty(2 * rows * cols, dtype=np.float32)
        inner = np.exp(-2j * np.pi * np.outer(np.arange(RADIX), np.arange(RADIX)) / rows)      # W_36^(b c)
        self.inner_twiddles = np.stack([inner.real, inner.imag]).astype(np.float32)
        # twiddles[:, r, n2] = W_N^(n2 k) for the SI carrier k with k mod R = r; slot_of_si[s] = k_s mod R.
        carrier_of_residue = np.empty(rows, dtype=np.int64)
        carrier_of_residue[k % rows] = k
        outer = np.exp(-2j * np.pi * np.outer(carrier_of_residue, np.arange(cols)) / n)
        self.twiddles = np.stack([outer.real, outer.imag]).astype(np.float32)
        self.slot_of_si = (k % rows).astype(np.int64)
        self._unit_phases = np.ones(batch, dtype=np.complex64)

    @property
    def si_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:func:`si_dft_kernel`'s tables and scratch buffer: inner and outer twiddles, slot of each SI carrier,
        work row."""
        return self.inner_twiddles, self.twiddles, self.slot_of_si, self._work

    @property
    def bodies(self) -> np.ndarray:
        """The ``(batch, 3780)`` input buffer the body-recovery kernel fills."""
        return self._bodies

    def si_carriers(self, count: int, frame_phases: np.ndarray | None = None) -> np.ndarray:
        """SI carriers of the first ``count`` bodies, SI order, ``(count, 36)`` complex64.

        ``frame_phases`` (``(count,)`` complex64), when given, multiplies each
        frame's carriers (the constant phase the body kernel leaves out).
        """
        out = np.empty((count, len(self.slot_of_si)), dtype=np.complex64)
        phases = self._unit_phases if frame_phases is None else frame_phases
        inner_twiddles, twiddles, slot_of_si, work = self.si_tables
        si_dft_kernel(self._bodies, count, inner_twiddles, twiddles, slot_of_si, phases, work, out)
        return out


@njit(cache=True, fastmath=True, nogil=True)
def dft6(x0r: float, x0i: float, x1r: float, x1i: float, x2r: float, x2i: float, x3r: float, x3i: float,
         x4r: float, x4i: float, x5r: float, x5i: float) -> tuple:
    """6-point DFT ``X[c] = sum_a x[a] W_6^(a c)`` on real and imaginary parts (returns X0r, X0i, .., X5i).

    Good-Thomas split 6 = 2 x 3 (no twiddles): input ``a = (3 a1 + 2 a2) mod 6``,
    output ``c = (3 c1 + 4 c2) mod 6``; 2-point DFTs of the pairs (0, 3),
    (2, 5), (4, 1), then a 3-point DFT of the sums (outputs 0, 4, 2) and of
    the differences (outputs 3, 1, 5).
    """
    s0r, s0i, d0r, d0i = x0r + x3r, x0i + x3i, x0r - x3r, x0i - x3i
    s1r, s1i, d1r, d1i = x2r + x5r, x2i + x5i, x2r - x5r, x2i - x5i
    s2r, s2i, d2r, d2i = x4r + x1r, x4i + x1i, x4r - x1r, x4i - x1i
    # 3-point DFT (y0, y1, y2) -> (y0 + t, m - j h (y1 - y2), m + j h (y1 - y2)), t = y1 + y2, m = y0 - t / 2.
    tr, ti = s1r + s2r, s1i + s2i
    mr, mi = s0r - np.float32(0.5) * tr, s0i - np.float32(0.5) * ti
    ur, ui = _SIN60 * (s1i - s2i), _SIN60 * (s2r - s1r)
    x0r_, x0i_, x4r_, x4i_, x2r_, x2i_ = s0r + tr, s0i + ti, mr + ur, mi + ui, mr - ur, mi - ui
    tr, ti = d1r + d2r, d1i + d2i
    mr, mi = d0r - np.float32(0.5) * tr, d0i - np.float32(0.5) * ti
    ur, ui = _SIN60 * (d1i - d2i), _SIN60 * (d2r - d1r)
    x3r_, x3i_, x1r_, x1i_, x5r_, x5i_ = d0r + tr, d0i + ti, mr + ur, mi + ui, mr - ur, mi - ui
    return x0r_, x0i_, x1r_, x1i_, x2r_, x2i_, x3r_, x3i_, x4r_, x4i_, x5r_, x5i_


@njit(cache=True, fastmath=True, nogil=True)
def si_dft_kernel(bodies: np.ndarray, count: int, inner_twiddles: np.ndarray, twiddles: np.ndarray,
                  slot_of_si: np.ndarray, frame_phases: np.ndarray, work: np.ndarray, out: np.ndarray) -> None:
    """SI carriers of ``bodies[:count]`` by the split of :class:`OfdmDemodulator` (into ``out``, ``(count, 36)``).

    ``out[b, s] = frame_phases[b] X_b[k_s]`` with ``k_s mod 36 = slot_of_si[s]``.
    ``inner_twiddles`` is ``(2, 6, 6)`` (real, imaginary) ``W_36^(b c)``,
    ``twiddles`` ``(2, 36, C)`` ``W_N^(n2 k)`` per residue, ``work`` a
    ``72 C`` float32 scratch. Every loop over the C columns works on whole
    rows of one array (stage 1 stores, stage 2 only loads and accumulates),
    so both vectorise; sums are in float32.
    """
    cols = COLUMNS
    tw_re, tw_im = twiddles[0], twiddles[1]
    row = 2 * RADIX * cols          # stride between rows n1 and n1 + 6 of the body, in floats
    acc = np.empty(2 * RADIX * RADIX, dtype=np.float32)
    for f in range(count):
        x = bodies[f].view(np.float32)  # interleaved real, imaginary
        # Stage 1: U[b, c, :] for each b (6-point DFTs over a, then the W_36^(b c) twiddles).
        for b in range(RADIX):
            w1r, w1i = inner_twiddles[0, b, 1], inner_twiddles[1, b, 1]
            w2r, w2i = inner_twiddles[0, b, 2], inner_twiddles[1, b, 2]
            w3r, w3i = inner_twiddles[0, b, 3], inner_twiddles[1, b, 3]
            w4r, w4i = inner_twiddles[0, b, 4], inner_twiddles[1, b, 4]
            w5r, w5i = inner_twiddles[0, b, 5], inner_twiddles[1, b, 5]
            dst = 2 * RADIX * cols * b
            for n in range(cols):
                p = 2 * (b * cols + n)
                y = dft6(x[p], x[p + 1], x[p + row], x[p + row + 1], x[p + 2 * row], x[p + 2 * row + 1],
                         x[p + 3 * row], x[p + 3 * row + 1], x[p + 4 * row], x[p + 4 * row + 1],
                         x[p + 5 * row], x[p + 5 * row + 1])
                q = dst + n
                work[q] = y[0]
                work[q + cols] = y[1]
                work[q + 2 * cols] = y[2] * w1r - y[3] * w1i
                work[q + 3 * cols] = y[2] * w1i + y[3] * w1r
                work[q + 4 * cols] = y[4] * w2r - y[5] * w2i
                work[q + 5 * cols] = y[4] * w2i + y[5] * w2r
                work[q + 6 * cols] = y[6] * w3r - y[7] * w3i
                work[q + 7 * cols] = y[6] * w3i + y[7] * w3r
                work[q + 8 * cols] = y[8] * w4r - y[9] * w4i
                work[q + 9 * cols] = y[8] * w4i + y[9] * w4r
                work[q + 10 * cols] = y[10] * w5r - y[11] * w5i
                work[q + 11 * cols] = y[10] * w5i + y[11] * w5r
        # Stage 2 per c: Y[:, c + 6 d] (6-point DFTs over b), times W_N^(n2 k), summed over the columns.
        for c in range(RADIX):
            a0r = a0i = a1r = a1i = a2r = a2i = a3r = a3i = a4r = a4i = a5r = a5i = np.float32(0.0)
            src = 2 * cols * c
            step = 2 * RADIX * cols     # from U[b, c] to U[b + 1, c]
            t0r, t0i, t1r, t1i = tw_re[c], tw_im[c], tw_re[c + 6], tw_im[c + 6]
            t2r, t2i, t3r, t3i = tw_re[c + 12], tw_im[c + 12], tw_re[c + 18], tw_im[c + 18]
            t4r, t4i, t5r, t5i = tw_re[c + 24], tw_im[c + 24], tw_re[c + 30], tw_im[c + 30]
            for n in range(cols):
                q = src + n
                y = dft6(work[q], work[q + cols], work[q + step], work[q + step + cols],
                         work[q + 2 * step], work[q + 2 * step + cols], work[q + 3 * step], work[q + 3 * step + cols],
                         work[q + 4 * step], work[q + 4 * step + cols], work[q + 5 * step], work[q + 5 * step + cols])
                a0r += y[0] * t0r[n] - y[1] * t0i[n]
                a0i += y[0] * t0i[n] + y[1] * t0r[n]
                a1r += y[2] * t1r[n] - y[3] * t1i[n]
                a1i += y[2] * t1i[n] + y[3] * t1r[n]
                a2r += y[4] * t2r[n] - y[5] * t2i[n]
                a2i += y[4] * t2i[n] + y[5] * t2r[n]
                a3r += y[6] * t3r[n] - y[7] * t3i[n]
                a3i += y[6] * t3i[n] + y[7] * t3r[n]
                a4r += y[8] * t4r[n] - y[9] * t4i[n]
                a4i += y[8] * t4i[n] + y[9] * t4r[n]
                a5r += y[10] * t5r[n] - y[11] * t5i[n]
                a5i += y[10] * t5i[n] + y[11] * t5r[n]
            for d, (vr, vi) in enumerate(((a0r, a0i), (a1r, a1i), (a2r, a2i), (a3r, a3i), (a4r, a4i), (a5r, a5i))):
                acc[2 * (c + RADIX * d)] = vr
                acc[2 * (c + RADIX * d) + 1] = vi
        for s in range(slot_of_si.shape[0]):
            r = slot_of_si[s]
            out[f, s] = complex(acc[2 * r], acc[2 * r + 1]) * frame_phases[f]


def si_carriers_reference(bodies: np.ndarray) -> np.ndarray:
    """Plain-numpy equivalent of :class:`OfdmDemodulator` (``np.fft``, complex128)."""
    return np.fft.fft(bodies, axis=-1)[..., np.asarray(gb20600.si_bins())]
