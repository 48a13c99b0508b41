"""Writing receiver results: HDF5 ``/receiver/frames`` (via receiver.h5io) and CSV.

The HDF5 group holds one dataset per :class:`~receiver.records.FrameBatch`
column and the receiver's parameters as attributes (``pn_mode``,
``si_index``, ``sample_rate_hz``, ``clock_offset_hz`` = the f_s used,
``carrier_hz``, the resampling ratio, versions); the file is written
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

from receiver.h5io import atomic_h5, package_version, write_columns
from receiver.records import FrameBatch

#: HDF5 group of the per-frame results.
FRAMES_GROUP = "receiver/frames"

#: Unit of each column (written as ``units`` attribute, "column:unit" pairs).
COLUMN_UNITS = {
    "t_s": "s", "sample_index": "input sample", "frame_index": "frame", "pn_phase": "chip", "cfo_hz": "Hz",
    "cfo_pn_hz": "Hz", "doppler_hz": "Hz", "velocity_mps": "m/s (positive closing)",
    "range_change_m": "m since first frame", "snr_db": "dB", "peak_metric": "0..1", "flags": "FrameFlag bits",
}


def frame_attributes(receiver_attrs: Mapping[str, Any]) -> dict[str, Any]:
    """Group attributes: the receiver's parameters plus versions and units."""
    attrs = dict(receiver_attrs)
    attrs["dtmbnav_version"] = package_version()
    attrs["numpy_version"] = np.__version__
    attrs["h5py_version"] = h5py.__version__
    attrs["units"] = ", ".join(f"{k}:{v}" for k, v in COLUMN_UNITS.items())
    return attrs


def write_frames_h5(path: str | os.PathLike, frames: FrameBatch, attrs: Mapping[str, Any], mode: str = "w") -> None:
    """Write ``frames`` as ``/receiver/frames`` of ``path`` (atomically).

    Parameters
    ----------
    mode : {"w", "a"}
        New file, or add the group to a copy of an existing file.
    """
    with atomic_h5(path, mode) as f:
        write_columns(f, FRAMES_GROUP, frames, frame_attributes(attrs))


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
