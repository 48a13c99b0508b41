"""Carrier derotation of sample segments by the coarse CFO (before channel estimation and body recovery).

The tracked coarse CFO is removed from each frame's header window and body
window on the 7.56 Msps stream: ``out[k, i] = buf[start_k + i] exp(-j 2 pi f
(start_k + i) / 7.56e6)``, with the phase of every sample taken from its
absolute index, so a frame's result never depends on where a batch begins.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ


@njit(cache=True, fastmath=True, nogil=True)
def derotate_segments(buf: np.ndarray, buf_start: int, seg_starts: np.ndarray, length: int,
                      cfo_cycles_per_sample: float, rot: np.ndarray, out: np.ndarray) -> None:
    """Copy ``length`` samples from each segment start, removing the coarse CFO.

    ``out[b, i] = buf[s_b + i] * exp(-j 2 pi f T (s_b + i))`` with ``s_b`` global
    stream indices (``buf[0]`` is index ``buf_start``). The phase of the first
    sample is computed in float64 from the absolute index (no accumulated
    drift); ``rot[i] = exp(-j 2 pi f T i)`` carries it along the segment.
    """
    for b in range(seg_starts.shape[0]):
        s = seg_starts[b]
        cycles = cfo_cycles_per_sample * s
        cycles -= np.floor(cycles)
        base = np.complex64(np.exp(-2j * np.pi * cycles))
        # 1-D slices with non-negative loop indices: the loop vectorises (no wraparound checks).
        src, dst = buf[s - buf_start: s - buf_start + length], out[b]
        for i in range(length):
            dst[i] = src[i] * rot[i] * base


def derotate_segments_reference(buf: np.ndarray, buf_start: int, seg_starts: np.ndarray, length: int,
                                cfo_cycles_per_sample: float) -> np.ndarray:
    """Plain-numpy :func:`derotate_segments` (returns the ``(B, length)`` array)."""
    n = seg_starts[:, None] + np.arange(length)[None, :]
    return buf[n - buf_start] * np.exp(-2j * np.pi * cfo_cycles_per_sample * n)


def rotation_table(cfo_hz: float, length: int) -> np.ndarray:
    """``exp(-j 2 pi f T i)``, ``i < length`` (complex64), for :func:`derotate_segments`."""
    return np.exp(-2j * np.pi * cfo_hz / SYMBOL_RATE_HZ * np.arange(length)).astype(np.complex64)
