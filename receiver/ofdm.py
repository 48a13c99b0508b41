"""Planned, batched FFTs (pyfftw) and the 3780-point demodulation of frame bodies.

FFTW plans are made once per (batch, length, direction) with ``FFTW_MEASURE``
on one thread, over aligned buffers that are reused: callers write the input
rows in place (the body-recovery kernel writes straight into
:attr:`BatchFft.input`), run :meth:`BatchFft.execute`, and read
:attr:`BatchFft.output`. Nothing is allocated per frame.
"""

from __future__ import annotations

import numpy as np
import pyfftw

from receiver import gb20600


class BatchFft:
    """A 1-D complex64 FFT of every row of a ``(batch, n)`` buffer.

    Parameters
    ----------
    batch : int
        Rows per call.
    n : int
        Transform length.
    inverse : bool
        Backward transform (unnormalised, like FFTW) instead of forward.
    """

    def __init__(self, batch: int, n: int, inverse: bool = False) -> None:
        self.input = pyfftw.empty_aligned((batch, n), dtype=np.complex64)
        self.output = pyfftw.empty_aligned((batch, n), dtype=np.complex64)
        self.input[:] = 0
        direction = "FFTW_BACKWARD" if inverse else "FFTW_FORWARD"
        self._plan = pyfftw.FFTW(self.input, self.output, axes=(1,), direction=direction,
                                 flags=("FFTW_MEASURE",), threads=1)
        self.input[:] = 0

    def execute(self) -> np.ndarray:
        """Transform :attr:`input` into :attr:`output` (returned)."""
        self._plan.execute()
        return self.output


class OfdmDemodulator:
    """3780-point FFT of recovered frame bodies and extraction of the SI carriers.

    The forward FFT is unnormalised: a carrier symbol X[k] sent through a
    channel H[k] comes out as ``sqrt(3780) H[k] X[k]`` (the transmitter's IDFT
    is unitary, dtmb.md §3.3).

    Parameters
    ----------
    batch : int
        Frames per call.
    """

    def __init__(self, batch: int) -> None:
        self.fft = BatchFft(batch, gb20600.BODY_LENGTH)
        self.si_bins = np.asarray(gb20600.si_bins())

    @property
    def bodies(self) -> np.ndarray:
        """The ``(batch, 3780)`` input buffer the body-recovery kernel fills."""
        return self.fft.input

    def si_carriers(self, count: int) -> np.ndarray:
        """FFT the first ``count`` bodies; their 36 SI carriers, SI order, ``(count, 36)``."""
        spectrum = self.fft.execute()
        return spectrum[:count, self.si_bins]


def si_carriers_reference(bodies: np.ndarray) -> np.ndarray:
    """Plain-numpy equivalent of :class:`OfdmDemodulator` (``np.fft``, complex128)."""
    return np.fft.fft(bodies, axis=-1)[..., np.asarray(gb20600.si_bins())]
