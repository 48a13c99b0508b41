"""Open an IQ capture and read it in chunks with flat memory.

Accepted inputs (``docs/conventions.md``):

- **SigMF**: ``name.sigmf-meta`` or ``name.sigmf-data`` (either file name);
  the metadata (read with the ``sigmf`` package) gives the datatype, sample
  rate, centre frequency and start time of the first capture segment.
- **Raw + sidecar**: a raw interleaved file ``name.<fmt>`` with the project's
  JSON sidecar ``name.<fmt>.json`` (``sample_rate_hz``, ``sample_format``,
  ``center_hz``, ``start_utc_unix_ns``).

The centre of the DTMB channel, when the capture was tuned beside it
(``docs/schema.md``), is the project key ``channel_hz`` (``dtmbnav:channel_hz``
in SigMF, ``"dtmbnav": {"channel_hz": ...}`` in a sidecar) or, in SigMF
without it, the centre of an annotation's ``core:freq_lower_edge`` /
``core:freq_upper_edge`` that lies within one sample rate of the capture's
centre; :attr:`CaptureSource.channel_hz` holds it (None: not recorded).
- **Plain raw**: any file, given ``sample_format`` and ``sample_rate_hz``.
- ``"-"``: a binary stream on stdin, given ``sample_format`` and ``sample_rate_hz``.

Values given on the command line must agree with the file's metadata (a
mismatch is an error, never a silent choice). Every problem (unknown
datatype, missing or malformed metadata, a file that is empty or ends in half
an IQ pair, NaN/inf samples) raises ``ValueError`` naming the file;
:class:`MissingCaptureOptions` (a ``ValueError``) says that the caller must
give the sample format or rate.

A stream is read as its data arrives, so everything read before an
interruption has been handed on, and a stop request
(:class:`dtmbnav_core.interrupt.DeferredStop`) ends a wait for data; a
stream that ends inside an IQ pair (a ``head -c`` that cut a sample) yields
every whole sample and then raises :class:`TruncatedStream`, which a caller
may treat as the end of the stream.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import select
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from numba import njit

from dtmbnav_core.interrupt import stop_requested
from dtmbnav_core.iqformat import IqFormat, decode, from_sigmf_datatype, get_format

#: Key of the project's metadata: ``dtmbnav:<key>`` in a SigMF global object, a ``dtmbnav`` object in a
#: raw capture's sidecar (``sim.capture_writer`` writes them).
PROJECT_NAMESPACE = "dtmbnav"


class MissingCaptureOptions(ValueError):
    """The capture does not say its sample format or rate, and the caller did not give them."""


class TruncatedStream(ValueError):
    """A stream ended inside an IQ pair; every whole sample before it was yielded.

    Attributes
    ----------
    samples : int
        Whole samples read before the cut.
    """

    def __init__(self, message: str, samples: int) -> None:
        super().__init__(message)
        self.samples = samples


@dataclass
class CaptureSource:
    """An opened capture (see :func:`open_capture`).

    Attributes
    ----------
    path : str
        Data file path, or ``"-"`` for stdin.
    sample_rate_hz : float
        Samples/s.
    center_hz : float or None
        RF centre frequency, Hz, when known.
    sample_format : str
        ``cu8``, ``ci8``, ``ci16`` or ``cf32``.
    num_samples : int or None
        Complex samples in the file; None for a stream.
    start_utc_unix_ns : int or None
        UTC time of the first sample, ns since the Unix epoch, when known.
    metadata : dict
        The file's metadata as read (SigMF global object or the sidecar).
    header_bytes : int
        Bytes to skip at the start of the data file (SigMF ``core:header_bytes``).
    channel_hz : float or None
        Centre of the DTMB channel, Hz, when the metadata records it (module
        docstring); None otherwise.
    """

    path: str
    sample_rate_hz: float
    center_hz: float | None
    sample_format: str
    num_samples: int | None
    start_utc_unix_ns: int | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    header_bytes: int = 0
    channel_hz: float | None = None

    @property
    def format(self) -> IqFormat:
        """The :class:`dtmbnav_core.iqformat.IqFormat` of the samples."""
        return get_format(self.sample_format)

    @property
    def is_stream(self) -> bool:
        """True for stdin: it cannot be read twice, and its length is unknown."""
        return self.path == "-"

    def project_value(self, key: str) -> Any:
        """A project key of the metadata (``scenario``, ``seed``, ...), None when absent."""
        if f"{PROJECT_NAMESPACE}:{key}" in self.metadata:
            return self.metadata[f"{PROJECT_NAMESPACE}:{key}"]
        project = self.metadata.get(PROJECT_NAMESPACE)
        return project.get(key) if isinstance(project, dict) else None

    def chunks(self, chunk_samples: int) -> Iterator[np.ndarray]:
        """Yield the samples as complex64 arrays of at most ``chunk_samples``.

        A file gives full chunks (the last may be shorter); a stream gives
        what has arrived, up to ``chunk_samples`` at a time.

        Raises
        ------
        ValueError
            Truncated data (half an IQ pair at the end of a file), NaN/inf in
            cf32, an empty input.
        TruncatedStream
            A stream ended inside an IQ pair (after yielding every whole sample).
        """
        if chunk_samples <= 0:
            raise ValueError(f"chunk_samples must be positive, got {chunk_samples}")
        if self.is_stream:
            yield from self._read(sys.stdin.buffer, chunk_samples, _read_available)
            return
        with open(self.path, "rb") as stream:
            stream.seek(self.header_bytes)
            yield from self._read(stream, chunk_samples, _read_exactly)

    def _read(self, stream: IO[bytes], chunk_samples: int,
              read: Callable[[IO[bytes], int], bytes | None]) -> Iterator[np.ndarray]:
        fmt = self.format
        want = chunk_samples * fmt.bytes_per_sample
        position = 0
        carry = b""  # the bytes of a sample split across two reads
        blocks = _BlockPool(chunk_samples)
        while True:
            data = read(stream, want - len(carry))
            if data is None:  # a stop was requested while waiting: what was read has been yielded
                return
            if not data:
                break
            data = carry + data
            whole = len(data) - len(data) % fmt.bytes_per_sample
            carry = data[whole:]
            if whole:
                yield _decode_block(np.frombuffer(data, np.uint8, whole), fmt, blocks,
                                    where=f"{self.path} (block from sample {position})")
                position += whole // fmt.bytes_per_sample
        if carry:
            message = (f"{self.path}: truncated data: the last {len(carry)} byte(s) after sample {position} are "
                       f"half an IQ pair of {fmt.name}")
            if self.is_stream:
                raise TruncatedStream(message, position)
            raise ValueError(message)
        if position == 0:
            raise ValueError(f"{self.path}: no samples (empty capture)")


#: Decoded blocks a reader keeps for reuse (when all are still in use downstream, more are allocated).
POOLED_BLOCKS = 8


class _BlockPool:
    """complex64 blocks handed out again once nothing downstream refers to them.

    The receiver holds the blocks it is given by reference until it has
    processed them (:class:`receiver.pipeline.SampleQueue`), so a block is
    reused only when the pool holds the last reference to it, as CPython's
    reference count tells (a numpy view of a block refers to the block).
    Reuse keeps the memory mapped: a fresh block of this size costs page
    faults every time.
    """

    def __init__(self, block_samples: int) -> None:
        self._block_samples = block_samples
        self._blocks: list[np.ndarray] = []

    def take(self, samples: int) -> np.ndarray:
        """A complex64 array of ``samples`` (<= the block size) that nothing else uses."""
        for block in self._blocks:
            if sys.getrefcount(block) == 3:   # the list, this loop's name and getrefcount's argument
                return block[:samples]
        block = np.empty(self._block_samples, dtype=np.complex64)
        if len(self._blocks) < POOLED_BLOCKS:
            self._blocks.append(block)
        return block[:samples]


def _decode_block(raw: np.ndarray, fmt: IqFormat, blocks: _BlockPool, where: str) -> np.ndarray:
    """One block of raw bytes (whole IQ pairs) as complex64: :func:`rails_to_samples` into a pooled block for
    the integer formats, :func:`dtmbnav_core.iqformat.decode` (which also rejects NaN and inf) for cf32."""
    if not fmt.is_integer:
        return decode(raw, fmt, where=where, out=blocks.take(len(raw) // fmt.bytes_per_sample))
    out = blocks.take(len(raw) // fmt.bytes_per_sample)
    rails_to_samples(raw.view(fmt.dtype), np.float32(fmt.decode_offset), np.float32(1.0 / fmt.scale), out.view(np.float32))
    return out


@njit(cache=True, nogil=True)
def rails_to_samples(rails: np.ndarray, offset: float, inv_scale: float, out: np.ndarray) -> None:
    """``out[i] = (rails[i] - offset) * inv_scale`` in float32: integer IQ rails to the interleaved floats of complex64.

    The arithmetic of :func:`dtmbnav_core.iqformat.decode` (its reference
    twin; full scales are powers of two, so the reciprocal is exact) in one
    vectorised pass, without numpy's buffered mixed-type loop.
    """
    for i in range(rails.shape[0]):
        out[i] = (np.float32(rails[i]) - offset) * inv_scale


def _read_exactly(stream: IO[bytes], size: int) -> bytes:
    """Read ``size`` bytes, fewer only at the end of the file."""
    parts = []
    remaining = size
    while remaining:
        part = stream.read(remaining)
        if not part:
            break
        parts.append(part)
        remaining -= len(part)
    return b"".join(parts)


#: Seconds a stream reader waits for data before it checks for a stop request (SIGINT, SIGTERM).
STOP_POLL_S = 0.25


def _read_available(stream: IO[bytes], size: int) -> bytes | None:
    """Read up to ``size`` bytes of what a stream has, waiting only while nothing has arrived.

    Returns None, having read nothing, when a stop is requested while it waits
    (:func:`dtmbnav_core.interrupt.stop_requested`): an idle pipe must not hold
    up Ctrl-C, and a signal must not interrupt a read whose data would be lost.
    """
    read1 = getattr(stream, "read1", stream.read)
    try:
        fd = stream.fileno()
    except (AttributeError, OSError):  # an in-memory stream never blocks
        return read1(size)
    while not stop_requested():
        try:
            ready, _, _ = select.select([fd], [], [], STOP_POLL_S)
        except (OSError, ValueError):  # a descriptor select cannot wait on: read, blocking
            return read1(size)
        if ready:
            return read1(size)
    return None


def _number(where: str, key: str, value: Any, *, positive: bool = True) -> float | None:
    """A metadata value that must be a finite (positive) number; None stays None."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: {key} must be a number, got {value!r}")
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{where}: {key} must be a finite{' positive' if positive else ''} number, got {value!r}")
    return float(value)


def _agree(where: str, what: str, from_file: Any, given: Any) -> Any:
    """The file's value, after checking that a given one matches it."""
    if from_file is None:
        return given
    if given is not None:
        same = (math.isclose(float(from_file), float(given), rel_tol=1e-9) if isinstance(given, (int, float))
                else str(from_file) == str(given))
        if not same:
            raise ValueError(f"{where}: {what} in the metadata is {from_file} but {given} was given")
    return from_file


def parse_utc(where: str, text: Any) -> int:
    """ISO 8601 time (``core:datetime``, ``receive --start-time``; without a zone: UTC) -> ns since the Unix epoch."""
    try:
        stamp = dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"{where}: bad ISO 8601 time {text!r}") from None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=dt.timezone.utc)
    delta = stamp - dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc)
    return (delta.days * 86400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000


def _file_samples(path: Path, fmt: IqFormat, header_bytes: int = 0) -> int:
    if not path.is_file():
        raise ValueError(f"{path}: no such capture file")
    size = path.stat().st_size - header_bytes
    if size <= 0:
        raise ValueError(f"{path}: no samples (empty capture)")
    if size % fmt.bytes_per_sample:
        raise ValueError(f"{path}: {size} bytes is not a whole number of {fmt.name} IQ pairs "
                         f"({fmt.bytes_per_sample} bytes each): truncated data (half an IQ pair at the end)")
    return size // fmt.bytes_per_sample


def _open_sigmf(path: Path, sample_format: str | None, sample_rate_hz: float | None,
                center_hz: float | None) -> CaptureSource:
    from sigmf import SigMFFile

    base = path.with_suffix("")
    meta_path, data_path = base.with_suffix(".sigmf-meta"), base.with_suffix(".sigmf-data")
    for file, what in ((meta_path, "metadata"), (data_path, "data")):
        if not file.exists():
            raise ValueError(f"{file}: SigMF {what} file not found")
        if not file.is_file():
            raise ValueError(f"{file}: SigMF {what} path is not a file")
    try:
        meta = json.loads(meta_path.read_text())
        # Schema check only: SigMFFile.fromfile would also map the data, which must
        # first pass this module's own size checks.
        SigMFFile(metadata=meta, skip_checksum=True).validate()
    except Exception as exc:  # json and the sigmf package raise their own error types
        raise ValueError(f"{meta_path}: invalid SigMF metadata: {str(exc).splitlines()[0]}") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("global", {}), dict):
        raise ValueError(f"{meta_path}: invalid SigMF metadata: expected a JSON object with a 'global' object")
    info = meta.get("global", {})
    where = str(meta_path)
    if "core:datatype" not in info or "core:sample_rate" not in info:
        raise ValueError(f"{where}: core:datatype and core:sample_rate are required")
    try:
        fmt = from_sigmf_datatype(info["core:datatype"])
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if info.get("core:num_channels", 1) != 1:
        raise ValueError(f"{where}: {info['core:num_channels']} channels; only single-channel captures are read")
    _agree(where, "sample format", fmt.name, get_format(sample_format).name if sample_format else None)
    rate = _agree(where, "sample rate", _number(where, "core:sample_rate", info["core:sample_rate"]), sample_rate_hz)
    captures = meta.get("captures") or [{}]
    first = captures[0]
    centre = _agree(where, "centre frequency", _number(where, "core:frequency", first.get("core:frequency")),
                    center_hz)
    start = parse_utc(where, first["core:datetime"]) if "core:datetime" in first else None
    header = int(_number(where, "core:header_bytes", first.get("core:header_bytes", 0), positive=False) or 0)
    channel = _number(where, f"{PROJECT_NAMESPACE}:channel_hz", info.get(f"{PROJECT_NAMESPACE}:channel_hz"))
    if channel is None and centre is not None:
        channel = _annotated_channel(where, meta.get("annotations"), float(centre), float(rate))
    return CaptureSource(str(data_path), rate, None if centre is None else float(centre), fmt.name,
                         _file_samples(data_path, fmt, header), start, info, header, channel)


def _annotated_channel(where: str, annotations: Any, centre_hz: float, rate_hz: float) -> float | None:
    """Centre of the first SigMF annotation with both frequency edges that lies within ``rate_hz`` of the
    capture's centre, Hz (the channel a capture tuned beside it records); None without one."""
    if not isinstance(annotations, list):
        return None
    for note in annotations:
        if not isinstance(note, dict) or "core:freq_lower_edge" not in note or "core:freq_upper_edge" not in note:
            continue
        low = _number(where, "core:freq_lower_edge", note["core:freq_lower_edge"])
        high = _number(where, "core:freq_upper_edge", note["core:freq_upper_edge"])
        middle = 0.5 * (low + high)
        if abs(middle - centre_hz) < rate_hz:
            return middle
    return None


def _open_raw(path: Path, sample_format: str | None, sample_rate_hz: float | None,
              center_hz: float | None) -> CaptureSource:
    sidecar_path = path.with_name(path.name + ".json")
    meta: dict[str, Any] = {}
    where = str(path)
    if sidecar_path.is_file():
        where = str(sidecar_path)
        try:
            meta = json.loads(sidecar_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{where}: invalid JSON sidecar: {exc}") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{where}: invalid JSON sidecar: expected an object, got {type(meta).__name__}")
        for key in ("sample_rate_hz", "sample_format"):
            if key not in meta:
                raise ValueError(f"{where}: sidecar lacks {key!r}")
        start = meta.get("start_utc_unix_ns")
        if start is not None and (isinstance(start, bool) or not isinstance(start, int)):
            raise ValueError(f"{where}: start_utc_unix_ns must be a whole number of ns, got {start!r}")
    fmt_name = _agree(where, "sample format", meta.get("sample_format"), sample_format)
    rate = _agree(where, "sample rate", _number(where, "sample_rate_hz", meta.get("sample_rate_hz")), sample_rate_hz)
    centre = _agree(where, "centre frequency", _number(where, "center_hz", meta.get("center_hz")), center_hz)
    if fmt_name is None or rate is None:
        raise MissingCaptureOptions(f"{path}: raw capture without a sidecar ({sidecar_path.name}): give the sample "
                                    "format and the sample rate")
    try:
        fmt = get_format(fmt_name)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    _number(where, "sample rate", rate)
    project = meta.get(PROJECT_NAMESPACE)
    channel = _number(where, f"{PROJECT_NAMESPACE}.channel_hz",
                      project.get("channel_hz") if isinstance(project, dict) else None)
    return CaptureSource(str(path), float(rate), None if centre is None else float(centre), fmt.name,
                         _file_samples(path, fmt), meta.get("start_utc_unix_ns"), meta, channel_hz=channel)


def open_capture(path: str | Path, *, sample_format: str | None = None, sample_rate_hz: float | None = None,
                 center_hz: float | None = None) -> CaptureSource:
    """Open a capture (module docstring for the accepted kinds).

    Parameters
    ----------
    path : str or Path
        SigMF meta/data file, raw file (with or without sidecar), or ``"-"`` for stdin.
    sample_format : str, optional
        ``cu8``, ``ci8``, ``ci16`` or ``cf32``; required for plain raw files and stdin.
    sample_rate_hz : float, optional
        Samples/s; required for plain raw files and stdin.
    center_hz : float, optional
        RF centre frequency, Hz.

    Raises
    ------
    MissingCaptureOptions
        Plain raw file or stdin without ``sample_format`` and ``sample_rate_hz``.
    ValueError
        Missing, unknown, malformed or inconsistent metadata, missing or empty
        file, a folder, truncated data (the message names the file).
    """
    if str(path) == "-":
        if sample_format is None or sample_rate_hz is None:
            raise MissingCaptureOptions("stdin capture: give the sample format and the sample rate")
        _number("stdin capture", "sample rate", sample_rate_hz)
        return CaptureSource("-", float(sample_rate_hz), center_hz, get_format(sample_format).name, None)
    path = Path(path)
    if path.suffix in (".sigmf-meta", ".sigmf-data"):
        return _open_sigmf(path, sample_format, sample_rate_hz, center_hz)
    if not path.exists():
        raise ValueError(f"{path}: no such capture file")
    if not path.is_file():
        raise ValueError(f"{path}: not a file (a folder?); give the capture file")
    return _open_raw(path, sample_format, sample_rate_hz, center_hz)


def capture_files(path: str | Path) -> tuple[Path, ...]:
    """The files a capture path stands for: both SigMF files, or the raw file and its sidecar (none for stdin).

    For checking that an output path does not name one of them.
    """
    if str(path) == "-":
        return ()
    path = Path(path)
    if path.suffix in (".sigmf-meta", ".sigmf-data"):
        base = path.with_suffix("")
        return base.with_suffix(".sigmf-meta"), base.with_suffix(".sigmf-data")
    return path, path.with_name(path.name + ".json")
