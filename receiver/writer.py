"""Writing receiver results: HDF5 ``/receiver/frames`` and ``/receiver/paths`` (via receiver.h5io) and CSV.

The HDF5 group holds one dataset per :class:`~dtmbnav.core.records.FrameBatch`
column and the receiver's parameters as attributes (``pn_mode``,
``si_index``, ``sample_rate_hz``, ``clock_offset_hz`` = the f_s used,
``carrier_hz``, the resampling ratio, versions); ``/receiver/paths`` holds
one dataset per :class:`~dtmbnav.core.records.PathBatch` column (the path
tracker's rows, written as they come, like the frames). The file is written
atomically, so an interrupted run never leaves a file that looks complete.
"""

from __future__ import annotations

import csv
import os
import sys
from collections.abc import Mapping
from typing import Any

import h5py
import numpy as np

from dtmbnav.core import schema
from dtmbnav.core.h5io import atomic_h5, package_version
from dtmbnav.core.records import (
    FRAME_COLUMN_DTYPES,
    PATH_COLUMN_DTYPES,
    FrameBatch,
    FrameFlag,
    PathBatch,
)

#: Unit of each column (written as ``units`` attribute, "column:unit" pairs).
COLUMN_UNITS = {
    "t_s": "s", "sample_index": "input sample", "frame_index": "frame", "pn_phase": "chip", "cfo_hz": "Hz",
    "cfo_pn_hz": "Hz", "doppler_hz": "Hz", "velocity_mps": "m/s (positive closing)",
    "range_change_m": "m since first frame", "snr_db": "dB", "si_snr_db": "dB", "peak_metric": "0..1", "flags": "FrameFlag bits",
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


def frame_attributes(receiver_attrs: Mapping[str, Any], units: Mapping[str, str] = COLUMN_UNITS) -> dict[str, Any]:
    """Group attributes: the receiver's parameters plus versions and units."""
    attrs = dict(receiver_attrs)
    attrs[schema.PACKAGE_VERSION_ATTR] = package_version()
    attrs["numpy_version"] = np.__version__
    attrs["h5py_version"] = h5py.__version__
    attrs["units"] = ", ".join(f"{k}:{v}" for k, v in units.items())
    return attrs


def write_csv(path: str | os.PathLike, columns: Mapping[str, np.ndarray]) -> None:
    """Write equal-length columns as CSV with a header row (``"-"`` writes to stdout)."""
    stream = sys.stdout if str(path) == "-" else open(path, "w", newline="")
    try:
        writer = csv.writer(stream)
        writer.writerow(columns)
        writer.writerows(zip(*(np.asarray(c).tolist() for c in columns.values())))
    finally:
        if stream is not sys.stdout:
            stream.close()


class FrameSink:
    """Writes frame batches as they come: HDF5 ``/receiver/frames`` (and ``/receiver/paths``) and/or CSV, memory flat.

    The HDF5 columns are resizable datasets that grow batch by batch inside an
    :func:`~dtmbnav.core.h5io.atomic_h5` file, so the file appears only when
    complete; the attributes are set at :meth:`close`. Counts of frames and
    gaps and the time span are kept for a summary.

    Parameters
    ----------
    h5_path, csv_path : path or None
        Where to write (None: not written). ``csv_path`` ``"-"`` is stdout.
    """

    def __init__(self, h5_path: str | os.PathLike | None, csv_path: str | os.PathLike | None = None) -> None:
        self.frames = 0
        self.paths = 0
        self.gaps = 0
        self.first_t_s = float("nan")
        self.last_t_s = float("nan")
        self._h5_context = atomic_h5(h5_path) if h5_path is not None else None
        self._h5 = self._h5_context.__enter__() if self._h5_context is not None else None
        if self._h5 is not None:
            group = self._h5.create_group(schema.RECEIVER_FRAMES)
            for name, dtype in FRAME_COLUMN_DTYPES.items():
                group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(4096,))
        self._csv_stream = None
        if csv_path is not None:
            self._csv_stream = sys.stdout if str(csv_path) == "-" else open(csv_path, "w", newline="")
            self._csv = csv.writer(self._csv_stream)
            self._csv.writerow(FRAME_COLUMN_DTYPES)

    def append(self, batch: FrameBatch) -> None:
        """Write the rows of one batch."""
        n = len(batch)
        if n == 0:
            return
        if self._h5 is not None:
            group = self._h5[schema.RECEIVER_FRAMES]
            for name, values in batch.columns().items():
                group[name].resize((self.frames + n,))
                group[name][self.frames:] = values
        if self._csv_stream is not None:
            self._csv.writerows(zip(*(c.tolist() for c in batch.columns().values())))
        if self.frames == 0:
            self.first_t_s = float(batch.t_s[0])
        self.last_t_s = float(batch.t_s[-1])
        self.frames += n
        self.gaps += int(np.count_nonzero(batch.flags & FrameFlag.GAP))

    def append_paths(self, rows: PathBatch) -> None:
        """Write path-tracker rows (HDF5 only; the group is made on the first call)."""
        if self._h5 is None:
            return
        group = self._paths_group()
        n = len(rows)
        for name, values in rows.columns().items():
            group[name].resize((self.paths + n,))
            group[name][self.paths:] = values
        self.paths += n

    def _paths_group(self) -> h5py.Group:
        if schema.RECEIVER_PATHS not in self._h5:
            group = self._h5.create_group(schema.RECEIVER_PATHS)
            for name, dtype in PATH_COLUMN_DTYPES.items():
                group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(8192,))
        return self._h5[schema.RECEIVER_PATHS]

    def close(self, attrs: Mapping[str, Any], path_attrs: Mapping[str, Any] | None = None) -> None:
        """Finish the files; ``attrs`` become the frames group's attributes, ``path_attrs`` the paths group's.

        With ``path_attrs`` the paths group is written even when no path was found.
        """
        if self._h5 is not None:
            for key, value in frame_attributes(attrs).items():
                self._h5[schema.RECEIVER_FRAMES].attrs[key] = value
            if path_attrs is not None:
                group = self._paths_group()
                for key, value in frame_attributes(path_attrs, PATH_COLUMN_UNITS).items():
                    group.attrs[key] = value
            self._h5_context.__exit__(None, None, None)
            self._h5 = None
        self._close_csv()

    def abort(self, exc: BaseException) -> None:
        """Drop the partial HDF5 file (the target path is left as it was)."""
        if self._h5 is not None:
            try:
                self._h5_context.__exit__(type(exc), exc, exc.__traceback__)
            except BaseException:
                pass
            self._h5 = None
        self._close_csv()

    def _close_csv(self) -> None:
        if self._csv_stream is not None and self._csv_stream is not sys.stdout:
            self._csv_stream.close()
        self._csv_stream = None
