"""FFTW plans for the simulator, reproducible and safe to make from several threads.

Plans are made with ``FFTW_ESTIMATE``: the planner picks the algorithm from
the problem alone, without timing runs, so every run and every thread
computes a transform with the same arithmetic and the simulator's output is
the same to the bit. FFTW would also use wisdom that other code in the
process (the receiver's measured plans) left for the same problem or one of
its sub-problems, so the simulator plans with the wisdom set aside and puts
it back afterwards. Plans are made under one lock (executing them is
thread-safe, and pyfftw releases the GIL while a plan runs).
"""

from __future__ import annotations

import threading

import numpy as np
import pyfftw

_PLAN_LOCK = threading.Lock()


def fftw_plan(rows: int, length: int, direction: str, dtype: type = np.complex128) -> pyfftw.FFTW:
    """An out-of-place plan of ``rows`` transforms of ``length`` points over its own aligned buffers.

    Parameters
    ----------
    rows, length : int
        Batch shape; the transform runs along the last axis.
    direction : str
        ``"FFTW_FORWARD"`` (``X[k] = sum_n x[n] exp(-j 2 pi k n / N)``) or
        ``"FFTW_BACKWARD"`` (the same with ``+j``, unnormalised).
    dtype : type
        ``np.complex128`` or ``np.complex64``.

    Returns
    -------
    pyfftw.FFTW
        Fill ``plan.input_array``, call ``plan.execute()``, read ``plan.output_array``.
    """
    with _PLAN_LOCK:
        source = pyfftw.empty_aligned((rows, length), dtype=dtype)
        target = pyfftw.empty_aligned((rows, length), dtype=dtype)
        source[:] = 0
        wisdom = pyfftw.export_wisdom()
        pyfftw.forget_wisdom()
        try:
            return pyfftw.FFTW(source, target, axes=(1,), direction=direction, flags=("FFTW_ESTIMATE",), threads=1)
        finally:
            pyfftw.forget_wisdom()
            pyfftw.import_wisdom(wisdom)
