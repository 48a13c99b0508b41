"""HDF5 helpers shared by every stage that writes or reads the project's files.

One schema for every file (``docs/schema.md``, names in :mod:`dtmbnav_core.schema`): a group per stage holding
equal-length 1-D datasets (N x 3 for vector sensors), one per column, with
parameters, units and versions as attributes. Files are written to a temporary
name and renamed into place only when complete, so an interrupted run never
leaves a file that looks finished.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from dtmbnav_core.records import FusedTrack, Track, with_unstated_error
from dtmbnav_core.schema import (
    COMPLETE_ATTR,
    FUSION_COVARIANCE_COLUMNS,
    PACKAGE_VERSION_ATTR,
    SCHEMA_VERSION,
    SCHEMA_VERSION_ATTR,
    TRACK_COLUMNS,
)
from dtmbnav_core.version import package_version


def partial_path(path: str | os.PathLike) -> Path:
    """The hidden temporary name a file is written under before it is renamed to ``path``."""
    path = Path(path)
    return path.with_name(f".{path.name}.partial-{os.getpid()}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path to write instead of ``path``, renamed to ``path`` only on success.

    The temporary file sits next to ``path`` (same folder, so the rename is
    atomic) under :func:`partial_path`'s hidden name. On any exception,
    including KeyboardInterrupt, it is removed and ``path`` is left as it was.
    """
    path = Path(path)
    tmp = partial_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary folder to write instead of folder ``path``; its files move into ``path`` only on success.

    For outputs made of several files (a report): on an exception the
    temporary folder is removed and ``path`` is neither created nor changed;
    on success ``path`` is created if missing and each file is renamed into
    it (files already there under other names are kept). Missing parent
    folders are created first (the temporary folder sits next to ``path``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.partial-", dir=path.parent))
    try:
        yield tmp
        path.mkdir(exist_ok=True)
        for item in sorted(tmp.iterdir()):
            os.replace(item, path / item.name)
        tmp.rmdir()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike, mode: str = "w") -> Iterator[h5py.File]:
    """Open an HDF5 file for writing that only appears at ``path`` when complete.

    ``mode="w"`` writes a new file; ``mode="a"`` adds groups to a copy of an
    existing one. On an exception the partial file is removed and ``path`` is
    left as it was.
    """
    if mode not in ("w", "a"):
        raise ValueError("mode must be 'w' or 'a'")
    path = Path(path)
    with atomic_path(path) as tmp:
        if mode == "a" and path.exists():
            tmp.write_bytes(path.read_bytes())
        with h5py.File(tmp, "a") as f:
            f.attrs[COMPLETE_ATTR] = False
            yield f
            f.attrs[COMPLETE_ATTR] = True
            f.attrs[PACKAGE_VERSION_ATTR] = package_version()
            f.attrs[SCHEMA_VERSION_ATTR] = SCHEMA_VERSION


@contextlib.contextmanager
def open_h5(path: str | os.PathLike) -> Iterator[h5py.File]:
    """Open an HDF5 file for reading, with errors that name it.

    Raises
    ------
    ValueError
        The path is missing, a folder, not an HDF5 file, or a file an
        interrupted run left incomplete.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    if not path.is_file():
        raise ValueError(f"{path}: not a file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        reason = str(exc).split("(", 1)[-1].rstrip(")") if "(" in str(exc) else str(exc)
        raise ValueError(f"{path}: not a readable HDF5 file ({reason})") from None
    with f:
        if not f.attrs.get(COMPLETE_ATTR, True):
            raise ValueError(f"{path}: file is incomplete (an interrupted run wrote it)")
        yield f


def _columns_of(record: Any) -> Mapping[str, np.ndarray]:
    if dataclasses.is_dataclass(record):
        return {f.name: getattr(record, f.name) for f in dataclasses.fields(record)}
    return record


def write_columns(parent: h5py.Group, name: str, record: Any, attrs: Mapping[str, Any] | None = None) -> h5py.Group:
    """Write a column record (dataclass of arrays, or mapping) as group ``name``.

    Parameters
    ----------
    parent : h5py.Group
        Where the group goes; an existing group of that name is replaced.
    name : str
        Group path relative to ``parent`` (e.g. ``"truth/frames"``).
    record : dataclass or mapping of str -> array
        Equal-length columns.
    attrs : mapping, optional
        Attributes (parameters, units, versions).
    """
    columns = _columns_of(record)
    lengths = {k: len(v) for k, v in columns.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"group {name}: columns differ in length: {lengths}")
    if name in parent:
        del parent[name]
    group = parent.create_group(name)
    for key, values in columns.items():
        group.create_dataset(key, data=np.asarray(values))
    for key, value in (attrs or {}).items():
        group.attrs[key] = value
    return group


def read_columns(parent: h5py.Group | str | os.PathLike, name: str) -> dict[str, np.ndarray]:
    """Read every dataset of group ``name`` into a dict of arrays.

    ``parent`` may be an open group or a file path (opened with :func:`open_h5`);
    a missing group raises ``ValueError`` naming the file and the group.
    """
    if not isinstance(parent, h5py.Group):
        with open_h5(parent) as f:
            return read_columns(f, name)
    if name not in parent:
        raise ValueError(f"{parent.file.filename}: no group /{name.lstrip('/')}")
    group = parent[name]
    return {key: group[key][()] for key in group if isinstance(group[key], h5py.Dataset)}


def read_attrs(path: str | os.PathLike, name: str) -> dict[str, Any]:
    """Attributes of group ``name`` in file ``path`` (ValueError naming a missing file or group)."""
    with open_h5(path) as f:
        if name not in f:
            raise ValueError(f"{path}: no group /{name.lstrip('/')}")
        return dict(f[name].attrs)


def read_fused_track(parent: h5py.Group | str | os.PathLike, name: str) -> FusedTrack:
    """The fused track of group ``name`` (``fusion/<filter>`` or its ``smoothed`` subgroup) with its stated error.

    A group written before the covariance columns existed (:data:`~dtmbnav_core.schema.FUSION_COVARIANCE_COLUMNS`)
    reads with NaN covariance: :meth:`~dtmbnav_core.records.FusedTrack.has_stated_error` is then False. A group
    with only some of them is a broken file (ValueError).
    """
    columns = read_columns(parent, name)
    track = Track(**{k: columns[k] for k in TRACK_COLUMNS})
    present = [k for k in FUSION_COVARIANCE_COLUMNS if k in columns]
    if not present:
        return with_unstated_error(track)
    if len(present) < len(FUSION_COVARIANCE_COLUMNS):
        where = parent.file.filename if isinstance(parent, h5py.Group) else parent
        raise ValueError(f"{where}: /{name.lstrip('/')} has {', '.join(present)} but not all of "
                         f"{', '.join(FUSION_COVARIANCE_COLUMNS)}")
    return FusedTrack(**track.columns(), **{k: columns[k] for k in FUSION_COVARIANCE_COLUMNS})
