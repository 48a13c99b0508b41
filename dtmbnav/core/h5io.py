"""HDF5 helpers shared by every stage that writes or reads the project's files.

One schema for every file (``docs/schema.md``, names in :mod:`dtmbnav.core.schema`): a group per stage holding
equal-length 1-D datasets (N x 3 for vector sensors), one per column, with
parameters, units and versions as attributes. Files are written to a temporary
name and renamed into place only when complete, so an interrupted run never
leaves a file that looks finished.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from dtmbnav.core.schema import COMPLETE_ATTR, PACKAGE_VERSION_ATTR, SCHEMA_VERSION, SCHEMA_VERSION_ATTR


def package_version() -> str:
    """Installed dtmbnav version ("unknown" when running from a bare tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("dtmbnav")
    except PackageNotFoundError:
        return "unknown"


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike, mode: str = "w") -> Iterator[h5py.File]:
    """Open an HDF5 file for writing that only appears at ``path`` when complete.

    ``mode="w"`` writes a new file; ``mode="a"`` adds groups to a copy of an
    existing one. On an exception the partial file is removed and ``path`` is
    left as it was.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    if mode == "a" and path.exists():
        tmp.write_bytes(path.read_bytes())
    elif mode not in ("w", "a"):
        raise ValueError("mode must be 'w' or 'a'")
    try:
        with h5py.File(tmp, "a") as f:
            f.attrs[COMPLETE_ATTR] = False
            yield f
            f.attrs[COMPLETE_ATTR] = True
            f.attrs[PACKAGE_VERSION_ATTR] = package_version()
            f.attrs[SCHEMA_VERSION_ATTR] = SCHEMA_VERSION
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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

    ``parent`` may be an open group or a file path; a missing group or an
    incomplete file raises ``ValueError`` naming the file and the group.
    """
    if not isinstance(parent, h5py.Group):
        path = Path(parent)
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        with h5py.File(path, "r") as f:
            if not f.attrs.get(COMPLETE_ATTR, True):
                raise ValueError(f"{path}: file is incomplete (an interrupted run wrote it)")
            return read_columns(f, name)
    if name not in parent:
        raise ValueError(f"{parent.file.filename}: no group /{name.lstrip('/')}")
    group = parent[name]
    return {key: group[key][()] for key in group if isinstance(group[key], h5py.Dataset)}


def read_attrs(path: str | os.PathLike, name: str) -> dict[str, Any]:
    """Attributes of group ``name`` in file ``path``."""
    with h5py.File(path, "r") as f:
        if name not in f:
            raise ValueError(f"{path}: no group /{name.lstrip('/')}")
        return dict(f[name].attrs)
