"""Typed per-frame records of the receiver.

A :class:`FrameBatch` is a dataclass of equal-length numpy columns, one row per
received signal frame; its field names are the ``/receiver/frames`` schema of
``conventions.md``. The receiver yields frames as a stream of such batches.

Columns
-------
- ``t_s``: frame start (first header sample of the main path) on the capture's
  clock, s: the frame's first sample index in the 7.56 Msps stream divided by
  7.56e6 (the resampler aligns that stream's sample n with input time
  ``n / 7.56e6``), never accumulated.
- ``sample_index``: index in the INPUT stream (before resampling) of the
  input sample at or just before the frame start, so rows can be matched
  to the capture file.
- ``frame_index``: the receiver's frame counter. With a rotating header it is
  congruent to the frame's place in the superframe (modulo the frames per
  superframe); it keeps counting across gaps (frame periods elapsed).
- ``pn_phase``: cyclic phase of the frame's header (dtmb.md §2.3).
- ``cfo_hz``: total carrier offset (coarse + SI estimate, eq. 5-8) measured
  between this frame and the previous one; NaN on the first frame of a lock.
- ``cfo_pn_hz``: the independent estimate from the PN headers, same pair.
- ``doppler_hz``: ``cfo_hz - f_s`` (eq. 9); ``velocity_mps``: eq. 10,
  positive when closing on the tower.
- ``range_change_m``: eq. 11, range since the first frame, m (shrinks when
  closing); continued across a gap with the last velocity (flagged).
- ``snr_db``: header-based SNR (over the whole band); ``si_snr_db``: SNR on
  the 36 SI carriers (a 72 kHz slice at the band centre), which fades where
  paths with different delays cancel there, and which the CFO estimate
  (eq. 5-8) lives on; ``peak_metric``: share of the header-window power
  captured by the channel taps (0 on noise, ~1 on a clean signal).
- ``flags``: :class:`FrameFlag` bits.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntFlag

import numpy as np


class FrameFlag(IntFlag):
    """Per-frame quality bits (``flags`` column)."""

    #: First frame of a lock (acquisition or re-acquisition): no CFO pair.
    LOCK_START = 1
    #: First frame after a loss of lock: the samples before it were not tracked.
    GAP = 2
    #: Header correlation below the lock threshold (frame kept, not trusted).
    LOW_QUALITY = 4
    #: Frame inside the static window used to estimate the clock offset f_s.
    CALIBRATION = 8


@dataclass
class FrameBatch:
    """Per-frame receiver results (one row per frame, columns as above)."""

    t_s: np.ndarray
    sample_index: np.ndarray
    frame_index: np.ndarray
    pn_phase: np.ndarray
    cfo_hz: np.ndarray
    cfo_pn_hz: np.ndarray
    doppler_hz: np.ndarray
    velocity_mps: np.ndarray
    range_change_m: np.ndarray
    snr_db: np.ndarray
    si_snr_db: np.ndarray
    peak_metric: np.ndarray
    flags: np.ndarray

    def __post_init__(self) -> None:
        lengths = {f.name: len(getattr(self, f.name)) for f in fields(self)}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"FrameBatch: columns differ in length: {lengths}")

    def __len__(self) -> int:
        return len(self.t_s)

    def select(self, rows: slice | np.ndarray) -> "FrameBatch":
        """The rows picked by a slice, index array or boolean mask, as a new batch."""
        return FrameBatch(**{name: values[rows] for name, values in self.columns().items()})

    def columns(self) -> dict[str, np.ndarray]:
        """The columns by name, in field order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def empty(cls) -> "FrameBatch":
        """A batch with no rows (typed columns)."""
        return cls.concatenate([])

    @classmethod
    def concatenate(cls, batches: list["FrameBatch"]) -> "FrameBatch":
        """Rows of ``batches`` in order, as one batch."""
        dtypes = COLUMN_DTYPES
        if not batches:
            return cls(**{name: np.empty(0, dtype=dt) for name, dt in dtypes.items()})
        return cls(**{name: np.concatenate([getattr(b, name) for b in batches]).astype(dt, copy=False)
                      for name, dt in dtypes.items()})


#: Storage type of each column.
COLUMN_DTYPES: dict[str, type] = {
    "t_s": np.float64, "sample_index": np.int64, "frame_index": np.int64, "pn_phase": np.int32,
    "cfo_hz": np.float64, "cfo_pn_hz": np.float64, "doppler_hz": np.float64, "velocity_mps": np.float64,
    "range_change_m": np.float64, "snr_db": np.float32, "si_snr_db": np.float32,
    "peak_metric": np.float32, "flags": np.uint8,
}
