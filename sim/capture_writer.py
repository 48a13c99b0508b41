"""Streaming IQ capture writers: SigMF, or raw interleaved samples + JSON sidecar.

Both write the data to a temporary name in the destination folder and rename
every file into place only when :meth:`CaptureWriter.close` succeeds, so an
interrupted simulation never leaves a capture that looks complete.

- ``container="sigmf"``: ``<stem>.sigmf-data`` and ``<stem>.sigmf-meta`` (the
  meta written by the ``sigmf`` package: ``core:datatype``,
  ``core:sample_rate``, author, description, one capture segment with
  ``core:frequency`` and ``core:datetime``, plus the project keys in the
  ``dtmbnav:`` namespace, e.g. ``dtmbnav:scenario`` and ``dtmbnav:seed``).
  A capture tuned beside the DTMB channel (``channel_hz`` given) records the
  channel too: ``dtmbnav:channel_hz`` and an annotation over the whole
  capture with the channel's ``core:freq_lower_edge``/``core:freq_upper_edge``
  (its 7.56 MHz band); ``core:frequency`` is the tuned centre.
- ``container="raw"``: ``<stem>.<format>`` and the sidecar
  ``<stem>.<format>.json`` with ``sample_rate_hz``, ``center_hz``,
  ``sample_format``, ``start_utc_unix_ns``, ``num_samples``, ``description``
  and the project keys under ``"dtmbnav"`` (with ``channel_hz`` for a capture
  tuned beside the channel).

``receiver.capture.open_capture`` reads both back.
"""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from sigmf import SigMFFile

from dtmbnav_core import gb20600
from dtmbnav_core.iqformat import get_format

CONTAINERS = ("sigmf", "raw")
#: Namespace of the project's keys in SigMF metadata.
SIGMF_NAMESPACE = "dtmbnav"


def capture_paths(stem: str | os.PathLike, container: str, sample_format: str) -> tuple[Path, Path]:
    """(data file, metadata file) that a capture with this stem is written to."""
    stem = Path(stem)
    if container == "sigmf":
        return stem.with_name(stem.name + ".sigmf-data"), stem.with_name(stem.name + ".sigmf-meta")
    if container == "raw":
        data = stem.with_name(f"{stem.name}.{get_format(sample_format).name}")
        return data, data.with_name(data.name + ".json")
    raise ValueError(f"unknown capture container {container!r}; expected one of {', '.join(CONTAINERS)}")


def _iso_utc(unix_ns: int) -> str:
    seconds, ns = divmod(int(unix_ns), 1_000_000_000)
    stamp = dt.datetime.fromtimestamp(seconds, tz=dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{stamp}.{ns // 1000:06d}Z"


class CaptureWriter:
    """Write one capture incrementally (use as a context manager).

    Parameters
    ----------
    stem : path
        Destination without extension (``out/park-loop`` -> ``out/park-loop.sigmf-meta`` ...).
    container : str
        ``"sigmf"`` or ``"raw"``.
    sample_format : str
        ``cu8``, ``ci8``, ``ci16`` or ``cf32``.
    sample_rate_hz, center_hz : float
        Sample rate, samples/s, and RF centre frequency, Hz.
    start_utc_unix_ns : int, optional
        UTC time of the first sample, ns since the Unix epoch.
    description : str
        Free text.
    project : dict, optional
        Project keys (scenario name, seed, ...): ``dtmbnav:<key>`` in SigMF,
        ``"dtmbnav": {...}`` in the sidecar.
    channel_hz : float, optional
        Centre of the DTMB channel, Hz, for a capture tuned beside it
        (``center_hz`` is then the tuned centre); None writes nothing of it.
    """

    def __init__(self, stem: str | os.PathLike, container: str, sample_format: str, sample_rate_hz: float,
                 center_hz: float, *, start_utc_unix_ns: int | None = None, description: str = "",
                 project: dict[str, Any] | None = None, channel_hz: float | None = None) -> None:
        self.format = get_format(sample_format)
        stem = Path(stem)
        self.data_path, self.meta_path = capture_paths(stem, container, sample_format)
        self.container = container
        self.sample_rate_hz = float(sample_rate_hz)
        self.center_hz = float(center_hz)
        self.start_utc_unix_ns = start_utc_unix_ns
        self.description = description
        self.project = dict(project or {})
        self.channel_hz = None if channel_hz is None else float(channel_hz)
        if self.channel_hz is not None:
            self.project["channel_hz"] = self.channel_hz
        self.num_samples = 0
        self._tmp_data = self.data_path.with_name(f".{self.data_path.name}.partial-{os.getpid()}")
        # The sigmf package appends ".sigmf-meta" to names without it, so the suffix stays last.
        self._tmp_meta = self.meta_path.with_name(f".{stem.name}.partial-{os.getpid()}{self.meta_path.suffix}")
        self._file = open(self._tmp_data, "wb")

    @property
    def capture_path(self) -> Path:
        """The path to hand to ``open_capture`` (the SigMF meta, or the raw data file)."""
        return self.meta_path if self.container == "sigmf" else self.data_path

    def write(self, rails: np.ndarray) -> None:
        """Append interleaved rails of the capture's format (``FrontEnd.quantise`` output)."""
        rails = np.asarray(rails)
        if rails.dtype != self.format.dtype:
            raise ValueError(f"{self.data_path}: got {rails.dtype} rails for a {self.format.name} capture")
        if rails.size % 2:
            raise ValueError(f"{self.data_path}: odd number of rails (half an IQ pair)")
        self._file.write(rails.tobytes())
        self.num_samples += rails.size // 2

    def _write_meta(self) -> None:
        if self.container == "sigmf":
            info = {"core:datatype": self.format.sigmf_datatype, "core:sample_rate": self.sample_rate_hz,
                    "core:author": "dtmbnav simulator", "core:description": self.description,
                    "core:extensions": [{"name": SIGMF_NAMESPACE, "version": "0.1.0", "optional": True}],
                    **{f"{SIGMF_NAMESPACE}:{k}": v for k, v in self.project.items()}}
            meta = SigMFFile(global_info=info, skip_checksum=True)
            capture = {"core:frequency": self.center_hz}
            if self.start_utc_unix_ns is not None:
                capture["core:datetime"] = _iso_utc(self.start_utc_unix_ns)
            meta.add_capture(0, metadata=capture)
            if self.channel_hz is not None:
                half = 0.5 * gb20600.SYMBOL_RATE_HZ
                meta.add_annotation(0, self.num_samples, metadata={
                    "core:freq_lower_edge": self.channel_hz - half, "core:freq_upper_edge": self.channel_hz + half,
                    "core:label": "DTMB channel"})
            meta.tofile(self._tmp_meta, overwrite=True)
        else:
            sidecar = {"sample_rate_hz": self.sample_rate_hz, "center_hz": self.center_hz,
                       "sample_format": self.format.name, "start_utc_unix_ns": self.start_utc_unix_ns,
                       "num_samples": self.num_samples, "description": self.description,
                       SIGMF_NAMESPACE: self.project}
            self._tmp_meta.write_text(json.dumps(sidecar, indent=2) + "\n")

    def close(self) -> None:
        """Finish: write the metadata and move both files into place."""
        self._file.close()
        try:
            self._write_meta()
            os.replace(self._tmp_data, self.data_path)
            os.replace(self._tmp_meta, self.meta_path)
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        """Drop the partial files."""
        self._file.close()
        self._tmp_data.unlink(missing_ok=True)
        self._tmp_meta.unlink(missing_ok=True)

    def __enter__(self) -> "CaptureWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
