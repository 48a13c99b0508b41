"""The SI carriers of recovered frame bodies: a 3780-point DFT pruned to the 36 bins used.

The FFTW plan is made once, on one thread, over aligned buffers that are
reused: the body-recovery kernel writes straight into
:attr:`OfdmDemodulator.bodies`. Nothing is allocated per frame.
"""

from __future__ import annotations

import numpy as np
import pyfftw
from numba import njit

from dtmbnav.core import gb20600


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

    evaluates it only where it is used: ``C`` strided R-point FFTs (one FFTW
    plan over the ``(batch, R, C)`` view of the bodies) and one length-C dot
    product per SI carrier (:func:`si_twiddle_kernel`), about 40 % of a full
    FFT's arithmetic. Each residue ``k mod R`` picks out one SI carrier,
    because the 36 carriers span 36 consecutive k.

    The DFT is unnormalised: a carrier symbol X[k] sent through a channel
    H[k] comes out as ``sqrt(3780) H[k] X[k]`` (the transmitter's IDFT is
    unitary, docs/dtmb.md §3.3). :func:`si_carriers_reference` is the full
    ``np.fft`` equivalent.

    Parameters
    ----------
    batch : int
        Frames per call.
    """

    #: Rows R of the split (R-point FFTs); the SI carriers' residues mod R must be distinct.
    ROWS = gb20600.SI_LENGTH

    def __init__(self, batch: int) -> None:
        self.batch = batch
        n, rows = gb20600.BODY_LENGTH, self.ROWS
        cols = n // rows
        k = si_carrier_numbers()
        if n % rows or len(np.unique(k % rows)) != len(k):
            raise ValueError(f"the SI carriers' residues mod {rows} must be distinct and {rows} must divide {n}")
        self._bodies = pyfftw.empty_aligned((batch, n), dtype=np.complex64)
        # Y stored as [b, n2, r]: the second stage then reads contiguous rows of R residues.
        self._columns = pyfftw.empty_aligned((batch, cols, rows), dtype=np.complex64)
        # FFTW_PATIENT: this short transform's plan tunes in ~0.2 s (once per batch size and process)
        # and runs ~35 % faster than FFTW_MEASURE's.
        self._plan = pyfftw.FFTW(self._bodies.reshape(batch, rows, cols), self._columns.transpose(0, 2, 1), axes=(1,),
                                 direction="FFTW_FORWARD", flags=("FFTW_PATIENT",), threads=1)
        self._bodies[:] = 0   # planning scribbles on the buffers
        # twiddles[n2, r] = W_N^(n2 k) for the SI carrier k with k mod R = r; slot_of_si[s] = k_s mod R.
        carrier_of_residue = np.empty(rows, dtype=np.int64)
        carrier_of_residue[k % rows] = k
        self.twiddles = np.exp(-2j * np.pi * np.outer(np.arange(cols), carrier_of_residue) / n).astype(np.complex64)
        self.slot_of_si = (k % rows).astype(np.int64)
        self._unit_phases = np.ones(batch, dtype=np.complex64)

    @property
    def bodies(self) -> np.ndarray:
        """The ``(batch, 3780)`` input buffer the body-recovery kernel fills."""
        return self._bodies

    def si_carriers(self, count: int, frame_phases: np.ndarray | None = None) -> np.ndarray:
        """SI carriers of the first ``count`` bodies, SI order, ``(count, 36)`` complex64.

        ``frame_phases`` (``(count,)`` complex64), when given, multiplies each
        frame's carriers (the constant phase the body kernel leaves out).
        """
        self._plan.execute()
        out = np.empty((count, len(self.slot_of_si)), dtype=np.complex64)
        phases = self._unit_phases if frame_phases is None else frame_phases
        si_twiddle_kernel(self._columns, self.twiddles, self.slot_of_si, phases, count, out)
        return out


@njit(cache=True, fastmath=True)
def si_twiddle_kernel(columns: np.ndarray, twiddles: np.ndarray, slot_of_si: np.ndarray, frame_phases: np.ndarray,
                      count: int, out: np.ndarray) -> None:
    """Second stage of the pruned DFT: ``out[b, s] = frame_phases[b] sum_n2 twiddles[n2, r] columns[b, n2, r]``.

    ``r = slot_of_si[s]``. The sums run over all R residues at once (the
    innermost loop is contiguous in r and vectorises); real and imaginary
    parts are accumulated separately in float32.
    """
    n_cols, rows = twiddles.shape
    acc_re = np.empty(rows, dtype=np.float32)
    acc_im = np.empty(rows, dtype=np.float32)
    for b in range(count):
        acc_re[:] = 0
        acc_im[:] = 0
        for c in range(n_cols):
            for r in range(rows):
                t, y = twiddles[c, r], columns[b, c, r]
                acc_re[r] += t.real * y.real - t.imag * y.imag
                acc_im[r] += t.real * y.imag + t.imag * y.real
        for s in range(slot_of_si.shape[0]):
            r = slot_of_si[s]
            out[b, s] = complex(acc_re[r], acc_im[r]) * frame_phases[b]


def si_twiddle_reference(columns: np.ndarray, twiddles: np.ndarray, slot_of_si: np.ndarray,
                         frame_phases: np.ndarray) -> np.ndarray:
    """Plain-numpy :func:`si_twiddle_kernel` (returns ``(B, 36)``, complex128)."""
    sums = np.einsum("bcr,cr->br", columns.astype(np.complex128), twiddles.astype(np.complex128))
    return sums[:, slot_of_si] * np.asarray(frame_phases)[:, None]


def si_carriers_reference(bodies: np.ndarray) -> np.ndarray:
    """Plain-numpy equivalent of :class:`OfdmDemodulator` (``np.fft``, complex128)."""
    return np.fft.fft(bodies, axis=-1)[..., np.asarray(gb20600.si_bins())]
