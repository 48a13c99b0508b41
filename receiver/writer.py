"""Writing receiver results: HDF5 ``/receiver/frames`` and ``/receiver/paths`` (via receiver.h5io) and CSV.

The HDF5 group holds one dataset per :class:`~dtmbnav_core.records.FrameBatch`
column and the receiver's parameters as attributes (``pn_mode``,
``si_index``, ``sample_rate_hz``, ``clock_offset_hz`` = the f_s used,
``carrier_hz``, the resampling ratio, versions); ``/receiver/paths`` holds
one dataset per :class:`~dtmbnav_core.records.PathBatch` column (the path
tracker's rows, written as they come, like the frames). Both files are
written atomically (a hidden temporary name renamed when complete), so a
failed run never leaves a file that looks complete; a run that keeps what it
received before an interruption finishes them normally and says so in the
``ended_early`` attribute (``docs/schema.md``).
"""

from __future__ import annotations

import contextlib
import csv
import os
import sys
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import h5py
import numpy as np

from dtmbnav_core import schema
from dtmbnav_core.h5io import atomic_h5, atomic_path, package_version
from dtmbnav_core.records import FRAME_COLUMN_DTYPES, PATH_COLUMN_DTYPES, FrameBatch, FrameFlag, PathBatch

#: Unit of each column (written as ``units`` attribute, "column:unit" pairs).
COLUMN_UNITS = {
    "t_s": "s", "sample_index": "input sample", "frame_index": "frame", "pn_phase": "chip", "cfo_hz": "Hz",
    "cfo_pn_hz": "Hz", "doppler_hz": "Hz", "velocity_mps": "m/s (positive closing)",
    "range_change_m": "m since first frame", "snr_db": "dB", "si_snr_db": "dB", "peak_metric": "0..1", "flags": "FrameFlag bits",
    "segment_id": "lock segment",
    "first_path_cfo_hz": "Hz", "first_path_range_change_m": "m since first frame", "first_path_delay_s": "s after t_s",
    "first_path_snr_db": "dB", "first_path_id": "path id", "tower_count": "towers",
    "range_difference_change_1_m": "m since both tracked", "range_difference_change_2_m": "m since both tracked",
}
#: Unit of each ``/receiver/paths`` column.
PATH_COLUMN_UNITS = {
    "t_s": "s", "frame_index": "frame", "path_id": "id", "tower_id": "id", "delay_s": "s after t_s",
    "delay_rate": "s/s", "cfo_hz": "Hz", "doppler_hz": "Hz", "range_change_m": "m since the path's first row",
    "snr_db": "dB", "flags": "PathFlag bits",
}
#: Rows gathered before they are appended to the HDF5 columns. Growing the resizable datasets has a
#: fixed cost per call that is large next to a receiver batch's rows, so rows go in blocks of this
#: many (about 18 s of PN420 frames, a few MB: memory stays flat), not batch by batch.
WRITE_ROWS = 1 << 15


def frame_attributes(receiver_attrs: Mapping[str, Any], units: Mapping[str, str] = COLUMN_UNITS) -> dict[str, Any]:
    """Group attributes: the receiver's parameters plus versions and units."""
    attrs = dict(receiver_attrs)
    attrs[schema.PACKAGE_VERSION_ATTR] = package_version()
    attrs["numpy_version"] = np.__version__
    attrs["h5py_version"] = h5py.__version__
    attrs["units"] = ", ".join(f"{k}:{v}" for k, v in units.items())
    return attrs


@contextlib.contextmanager
def open_csv(path: str | os.PathLike) -> Iterator[IO[str]]:
    """A text stream for a CSV file that appears at ``path`` only when complete (``"-"``: stdout)."""
    if str(path) == "-":
        yield sys.stdout
        sys.stdout.flush()
        return
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as stream:
        yield stream


def write_csv(path: str | os.PathLike, columns: Mapping[str, np.ndarray]) -> None:
    """Write equal-length columns as CSV with a header row (``"-"`` writes to stdout), atomically."""
    with open_csv(path) as stream:
        writer = csv.writer(stream)
        writer.writerow(columns)
        writer.writerows(zip(*(np.asarray(c).tolist() for c in columns.values())))


class FrameSink:
    """Writes frame batches as they come: HDF5 ``/receiver/frames`` (and ``/receiver/paths``) and/or CSV, memory flat.

    The HDF5 columns are resizable datasets that grow batch by batch inside an
    :func:`~dtmbnav_core.h5io.atomic_h5` file and the CSV rows go to a hidden
    temporary file, so both appear only at :meth:`close`, which also sets the
    attributes; :meth:`abort` removes them. HDF5 rows are appended in blocks
    of :data:`WRITE_ROWS` (and the rest at :meth:`close`). Counts of frames
    and gaps and the time span are kept for a summary.

    Parameters
    ----------
    h5_path, csv_path : path or None
        Where to write (None: not written). ``csv_path`` ``"-"`` is stdout.
    """

    def __init__(self, h5_path: str | os.PathLike | None, csv_path: str | os.PathLike | None = None) -> None:
        self.h5_path = None if h5_path is None else Path(h5_path)
        self.frames = 0
        self.paths = 0
        self.gaps = 0
        self.first_t_s = float("nan")
        self.last_t_s = float("nan")
        self._files = contextlib.ExitStack()
        self._h5 = None
        self._csv = None
        self._pending: list[FrameBatch] = []
        self._pending_rows = 0
        self._written = 0
        self._pending_paths: list[PathBatch] = []
        self._pending_path_rows = 0
        self._paths_written = 0
        try:
            if h5_path is not None:
                self._h5 = self._files.enter_context(atomic_h5(h5_path))
                group = self._h5.create_group(schema.RECEIVER_FRAMES)
                for name, dtype in FRAME_COLUMN_DTYPES.items():
                    group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(4096,))
            if csv_path is not None:
                self._csv = csv.writer(self._files.enter_context(open_csv(csv_path)))
                self._csv.writerow(FRAME_COLUMN_DTYPES)
        except BaseException as exc:
            self.abort(exc)
            raise

    def append(self, batch: FrameBatch) -> None:
        """Write the rows of one batch."""
        n = len(batch)
        if n == 0:
            return
        if self._h5 is not None:
            self._pending.append(batch)
            self._pending_rows += n
            if self._pending_rows >= WRITE_ROWS:
                self._write_pending()
        if self._csv is not None:
            self._csv.writerows(zip(*(c.tolist() for c in batch.columns().values())))
        if self.frames == 0:
            self.first_t_s = float(batch.t_s[0])
        self.last_t_s = float(batch.t_s[-1])
        self.frames += n
        self.gaps += int(np.count_nonzero(batch.flags & FrameFlag.GAP))

    def append_paths(self, rows: PathBatch) -> None:
        """Write path-tracker rows (HDF5 only; the group is made on the first call), in blocks like the frames."""
        if self._h5 is None or len(rows) == 0:
            return
        self._pending_paths.append(rows)
        self._pending_path_rows += len(rows)
        self.paths += len(rows)
        if self._pending_path_rows >= WRITE_ROWS:
            self._write_pending_paths()

    def _write_pending(self) -> None:
        """Append the gathered frame rows to the HDF5 columns."""
        self._written = _append_rows(self._h5[schema.RECEIVER_FRAMES], FRAME_COLUMN_DTYPES, self._pending,
                                     self._written)
        self._pending, self._pending_rows = [], 0

    def _write_pending_paths(self) -> None:
        """Append the gathered path rows to the ``/receiver/paths`` columns."""
        self._paths_written = _append_rows(self._paths_group(), PATH_COLUMN_DTYPES, self._pending_paths,
                                           self._paths_written)
        self._pending_paths, self._pending_path_rows = [], 0

    def _paths_group(self) -> h5py.Group:
        if schema.RECEIVER_PATHS not in self._h5:
            group = self._h5.create_group(schema.RECEIVER_PATHS)
            for name, dtype in PATH_COLUMN_DTYPES.items():
                group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(8192,))
        return self._h5[schema.RECEIVER_PATHS]

    def close(self, attrs: Mapping[str, Any], path_attrs: Mapping[str, Any] | None = None) -> None:
        """Finish the files and move them into place; ``attrs`` become the frames group's attributes,
        ``path_attrs`` the paths group's.

        With ``path_attrs`` the paths group is written even when no path was found.
        """
        if self._h5 is not None:
            self._write_pending()
            for key, value in frame_attributes(attrs).items():
                self._h5[schema.RECEIVER_FRAMES].attrs[key] = value
            if self._pending_paths or path_attrs is not None:
                group = self._paths_group()
                self._write_pending_paths()
                for key, value in frame_attributes(path_attrs or {}, PATH_COLUMN_UNITS).items():
                    group.attrs[key] = value
        self._h5 = self._csv = None
        self._files.close()

    def abort(self, exc: BaseException) -> None:
        """Drop the partial files (the target paths are left as they were)."""
        self._pending, self._pending_rows = [], 0
        self._pending_paths, self._pending_path_rows = [], 0
        self._h5 = self._csv = None
        try:
            self._files.__exit__(type(exc), exc, exc.__traceback__)
        except BaseException:  # a failure while cleaning up must not hide the error that caused it
            pass


def _append_rows(group: h5py.Group, columns: Iterable[str], batches: list[Any], written: int) -> int:
    """Append the rows of ``batches`` (records with the ``columns``) to a group's resizable datasets.

    Returns the group's row count afterwards.
    """
    rows = sum(len(b) for b in batches)
    if not rows:
        return written
    end = written + rows
    for name in columns:
        group[name].resize((end,))
        group[name][written:] = np.concatenate([getattr(b, name) for b in batches])
    return end
