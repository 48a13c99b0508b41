"""Stage dumps: the receiver's intermediate outputs, frame by frame, in an HDF5 file.

Like GNSS-SDR's per-block dumps, every stage of the receiver can hand on what
it computed (:attr:`receiver.pipeline.ReceiverConfig.inspect`); a
:class:`StageDump` is such a hook that appends each stage's arrays, one row
per frame, to ``/<stage>/<name>`` datasets (resizable along the first axis,
chunked, so memory stays flat however long the capture). It is what
``dtmbnav receive --dump FILE`` writes; ``docs/cli.md`` lists the
stages and their arrays. Every stage's arrays include ``window_start``, the
frame's window start in 7.56 Msps stream samples, which places its rows in
the capture and selects them for a time window.

A 0-d array (a constant of the lock, such as the first lag of the path
tracker's span) is stored as an attribute of its stage's group, updated as
the receiver re-acquires. The file is marked ``complete`` when closed after
a run that ended normally.

Sizes per frame (PN420, complex64): ``channel`` about 1 kB, ``paths`` 1.4
kB (165 lags), ``body`` 30 kB: a minute of capture is 108 000 frames, so
dump the bodies over a window.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping

import h5py
import numpy as np

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from receiver.delay_doppler import DelayDopplerMap, delay_doppler_map
from receiver.pipeline import INSPECT_STAGES
#: Stages dumped unless others are asked for (the bodies are large: module docstring).
DEFAULT_DUMP_STAGES = ("channel", "tracking", "paths")
#: Frames per HDF5 chunk of a dumped array.
CHUNK_FRAMES = 1024


class StageDump:
    """An inspect hook (:attr:`receiver.pipeline.ReceiverConfig.inspect`) that writes the stages to HDF5.

    Parameters
    ----------
    path : path
        HDF5 file to write (replaced if it exists).
    stages : iterable of str
        Stages to keep, from :data:`receiver.pipeline.INSPECT_STAGES`.
    window_s : (float, float) or None
        Keep only frames whose window starts within ``[start, stop)`` seconds
        of the 7.56 Msps stream (the capture's time from its first sample);
        None keeps every frame.
    """

    def __init__(self, path: str | os.PathLike, stages: Iterable[str] = DEFAULT_DUMP_STAGES,
                 window_s: tuple[float, float] | None = None) -> None:
        self.stages = frozenset(stages)
        unknown = sorted(self.stages - set(INSPECT_STAGES))
        if unknown or not self.stages:
            raise ValueError(f"dump stages must be some of {', '.join(INSPECT_STAGES)}, got {sorted(self.stages)}")
        if window_s is not None and not (0.0 <= window_s[0] < window_s[1]):
            raise ValueError(f"dump window must be 0 <= start < stop seconds, got {window_s}")
        self._window = None if window_s is None else (window_s[0] * SYMBOL_RATE_HZ, window_s[1] * SYMBOL_RATE_HZ)
        self._file = h5py.File(path, "w")
        self._file.attrs["stages"] = ",".join(s for s in INSPECT_STAGES if s in self.stages)
        if window_s is not None:
            self._file.attrs["window_s"] = np.asarray(window_s, dtype=np.float64)
        self._file.attrs["complete"] = False

    def __call__(self, stage: str, arrays: Mapping[str, np.ndarray]) -> None:
        """Append one batch of ``stage``'s arrays (first axis: frames; ``window_start`` among them)."""
        if stage not in self.stages:
            return
        keep = slice(None)
        if self._window is not None:
            start = np.asarray(arrays["window_start"])
            keep = (start >= self._window[0]) & (start < self._window[1])
            if not keep.any():
                return
        group = self._file.require_group(stage)
        for name, value in arrays.items():
            value = np.asarray(value)
            if value.ndim == 0:
                group.attrs[name] = value
                continue
            rows = value[keep]
            if name not in group:
                group.create_dataset(name, shape=(0, *rows.shape[1:]), maxshape=(None, *rows.shape[1:]),
                                     dtype=rows.dtype, chunks=(CHUNK_FRAMES, *rows.shape[1:]))
            dataset = group[name]
            end = dataset.shape[0] + len(rows)
            dataset.resize(end, axis=0)
            dataset[end - len(rows):] = rows

    def close(self, complete: bool = True) -> None:
        """Close the file; ``complete`` marks a run that ended normally."""
        if self._file.id.valid:
            self._file.attrs["complete"] = complete
            self._file.close()


def read_stage(path: str | os.PathLike, stage: str, window_s: tuple[float, float] | None = None
               ) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """A dumped stage's arrays (the frames whose window starts within ``window_s`` seconds) and its attributes.

    Raises
    ------
    ValueError
        If the file has no such stage, or no frame of it lies in the window.
    """
    with h5py.File(path, "r") as f:
        if stage not in f:
            raise ValueError(f"{path}: no stage {stage!r} in this dump (it has {', '.join(f) or 'none'}; "
                             f"dtmbnav receive --dump-stages names them)")
        group = f[stage]
        start = group["window_start"][()]
        keep = np.ones(len(start), dtype=bool) if window_s is None else \
            (start >= window_s[0] * SYMBOL_RATE_HZ) & (start < window_s[1] * SYMBOL_RATE_HZ)
        if not keep.any():
            raise ValueError(f"{path}: no {stage} frame in {window_s} s (the dump's window starts span "
                             f"{start.min() / SYMBOL_RATE_HZ:.2f}-{start.max() / SYMBOL_RATE_HZ:.2f} s)"
                             if len(start) else f"{path}: the {stage} stage holds no frame")
        index = np.flatnonzero(keep)
        arrays = {name: group[name][index[0]:index[-1] + 1][keep[index[0]:index[-1] + 1]] for name in group}
        return arrays, dict(group.attrs)


def map_from_dump(path: str | os.PathLike, at_s: float, seconds: float, delays: np.ndarray | None = None,
                  oversample: int = 4) -> DelayDopplerMap:
    """The delay-Doppler map of a stage dump's ``paths`` frames within ``seconds`` centred on ``at_s``.

    ``delays`` (samples after the first of those frames' window start)
    default to the strongest lag of their mean CIR, from 4 before to 8 after.
    """
    arrays, attrs = read_stage(path, "paths", (max(at_s - seconds / 2.0, 0.0), at_s + seconds / 2.0))
    start, index, taps = arrays["window_start"], arrays["frame_index"], arrays["taps"]
    steps = np.diff(start) / np.maximum(np.diff(index), 1)
    frame_length = int(np.rint(np.median(steps))) if len(steps) else 0
    lag0 = int(attrs["lag0"])
    if delays is None:
        peak = lag0 + int(np.argmax(np.mean(np.abs(taps) ** 2, axis=0)))
        delays = np.arange(peak - 4, peak + 9)
    return delay_doppler_map(taps, start, index, lag0, frame_length, delays, oversample)
