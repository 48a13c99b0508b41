"""Typed readers and writers of the sensor and truth groups (``docs/schema.md``).

``/imu``, ``/gnss``, ``/truth/trajectory`` and ``/truth/steps`` as the
records of :mod:`dtmbnav_core.records`. The simulator writes these groups, the
real-data path (``dtmbnav pdr``, ``fuse``, ``report``) reads them: both go
through this module, so reading a sensors file never imports the simulator.

The start fix P0 is stored as attributes (:data:`~dtmbnav_core.schema.START_FIX_ATTRS`)
on both ``/truth/trajectory`` and ``/gnss``: the fusion side reads it from
``/gnss``, an evaluation from the truth.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import h5py
import numpy as np

from dtmbnav_core import schema
from dtmbnav_core.h5io import open_h5, read_attrs, read_columns, write_columns
from dtmbnav_core.records import GnssLog, ImuLog, StartFix, Track, WalkTruth


def start_fix_attrs(fix: StartFix) -> dict[str, float]:
    """The start fix as the attributes stored with ``/truth/trajectory`` and ``/gnss``."""
    return dict(zip(schema.START_FIX_ATTRS, (fix.t_s, fix.x_m, fix.y_m, fix.sigma_m)))


def _start_fix_from(attrs: Mapping[str, Any], where: str) -> StartFix:
    try:
        t_s, x_m, y_m, sigma_m = (float(attrs[name]) for name in schema.START_FIX_ATTRS)
    except KeyError as exc:
        raise ValueError(f"{where}: no start-fix attribute {exc}") from exc
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: malformed start-fix attribute ({exc})") from exc
    return StartFix(t_s=t_s, x_m=x_m, y_m=y_m, sigma_m=sigma_m)


def _need(columns: Mapping[str, np.ndarray], names: tuple[str, ...], where: str) -> None:
    missing = [n for n in names if n not in columns]
    if missing:
        raise ValueError(f"{where}: missing column(s) {missing}")


def write_truth_trajectory(h5file: h5py.File, track: Track, step_t_s: np.ndarray, step_length_m: np.ndarray,
                           fix: StartFix, attrs: Mapping[str, Any]) -> None:
    """Write ``/truth/trajectory`` (with the start fix) and ``/truth/steps``.

    Parameters
    ----------
    h5file : h5py.File
        Open for writing (e.g. by :func:`dtmbnav_core.h5io.atomic_h5`).
    track : Track
        Truth trajectory.
    step_t_s, step_length_m : ndarray
        Heel-strike times, s, and truth step lengths, m.
    fix : StartFix
        The GNSS start fix P0.
    attrs : mapping
        Further ``/truth/trajectory`` attributes (tower, walk start and end, scenario text).
    """
    write_columns(h5file, schema.TRUTH_TRAJECTORY, track, attrs={**attrs, **start_fix_attrs(fix)})
    write_columns(h5file, schema.TRUTH_STEPS, {"t_s": step_t_s, "step_length_m": step_length_m},
                  attrs={"definition": "heel strike ending each step; length = path distance from the previous one"})


def write_imu(h5file: h5py.File, imu: ImuLog, attrs: Mapping[str, Any]) -> None:
    """Write ``/imu`` with its attributes (rate, sensor frame, units, calibrated Weinberg K)."""
    write_columns(h5file, schema.IMU, imu, attrs=attrs)


def write_gnss(h5file: h5py.File, gnss: GnssLog, fix: StartFix | None, attrs: Mapping[str, Any],
               extra_columns: Mapping[str, np.ndarray] | None = None) -> None:
    """Write ``/gnss`` and the start fix P0 as its attributes (none where ``fix`` is None: a phone log without fixes).

    ``extra_columns`` are further columns of the same length (an imported phone log's
    :data:`~dtmbnav_core.schema.GNSS_GEODETIC_COLUMNS`); readers take only the columns they know.
    """
    columns = {**gnss.columns(), **(extra_columns or {})}
    write_columns(h5file, schema.GNSS, columns, attrs={**attrs, **(start_fix_attrs(fix) if fix else {})})


def read_walk_truth(path: str | os.PathLike) -> WalkTruth:
    """Read ``/truth/trajectory`` and ``/truth/steps`` of a truth file.

    Raises
    ------
    ValueError
        Missing file, group, column or attribute (the message names it).
    """
    traj = read_columns(path, schema.TRUTH_TRAJECTORY)
    _need(traj, schema.TRACK_COLUMNS, f"{path}: /{schema.TRUTH_TRAJECTORY}")
    steps = read_columns(path, schema.TRUTH_STEPS)
    _need(steps, schema.STEP_COLUMNS, f"{path}: /{schema.TRUTH_STEPS}")
    attrs = read_attrs(path, schema.TRUTH_TRAJECTORY)
    if schema.WALK_START_ATTR not in attrs:
        raise ValueError(f"{path}: /{schema.TRUTH_TRAJECTORY} has no {schema.WALK_START_ATTR} attribute")
    return WalkTruth(track=Track(**{k: traj[k] for k in schema.TRACK_COLUMNS}),
                     step_t_s=steps["t_s"], step_length_m=steps["step_length_m"],
                     walk_start_t_s=float(attrs[schema.WALK_START_ATTR]),
                     start_fix=_start_fix_from(attrs, f"{path}: /{schema.TRUTH_TRAJECTORY}"))


def read_imu(path: str | os.PathLike) -> ImuLog:
    """Read ``/imu`` of a file as an :class:`ImuLog` (ValueError naming what is missing or malformed)."""
    cols = read_columns(path, schema.IMU)
    _need(cols, schema.IMU_COLUMNS, f"{path}: /{schema.IMU}")
    for name in schema.IMU_COLUMNS[1:]:
        if cols[name].ndim != 2 or cols[name].shape[1] != 3:
            raise ValueError(f"{path}: /{schema.IMU}/{name} must be N x 3, got shape {cols[name].shape}")
    return ImuLog(**{k: cols[k] for k in schema.IMU_COLUMNS})


def read_gnss(path: str | os.PathLike) -> tuple[GnssLog, StartFix]:
    """Read ``/gnss`` of a file: the per-epoch fixes and the start fix P0."""
    cols = read_columns(path, schema.GNSS)
    _need(cols, schema.GNSS_COLUMNS, f"{path}: /{schema.GNSS}")
    fix = _start_fix_from(read_attrs(path, schema.GNSS), f"{path}: /{schema.GNSS}")
    return GnssLog(**{k: cols[k] for k in schema.GNSS_COLUMNS}), fix


def read_fix_count(path: str | os.PathLike) -> int:
    """How many fixes the file's ``/gnss`` holds: 0 without ``/gnss`` or for a phone log without fixes (whose
    ``/gnss`` has no rows and no start fix)."""
    with open_h5(path) as f:
        return len(f[schema.GNSS]["t_s"]) if schema.GNSS in f and "t_s" in f[schema.GNSS] else 0


def read_geodetic_origin(path: str | os.PathLike) -> tuple[float, float, float] | None:
    """The geodetic origin of the file's ENU frame (latitude, longitude, deg; ellipsoidal height, m), from the
    ``/gnss`` attributes of an imported phone log (or of a results file fused from one); None when the file has
    none (a simulation's) or has no ``/gnss`` (a results file of a simulation)."""
    with open_h5(path) as f:
        if schema.GNSS not in f:
            return None
    attrs = read_attrs(path, schema.GNSS)
    if not all(name in attrs for name in schema.ORIGIN_ATTRS):
        return None
    try:
        lat, lon, height = (float(attrs[name]) for name in schema.ORIGIN_ATTRS)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: /{schema.GNSS}: malformed origin attributes {schema.ORIGIN_ATTRS}") from None
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and np.isfinite(height)):
        raise ValueError(f"{path}: /{schema.GNSS}: origin {lat}, {lon}, {height} out of range")
    return lat, lon, height


def read_weinberg_k_m(path: str | os.PathLike) -> float | None:
    """The Weinberg gain calibrated for the walker and device (``/imu`` attribute), m; None if absent."""
    value = read_attrs(path, schema.IMU).get(schema.WEINBERG_K_ATTR)
    if value is None:
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: /{schema.IMU} attribute {schema.WEINBERG_K_ATTR} is not a number: "
                         f"{value!r}") from None


def read_tower(path: str | os.PathLike) -> tuple[float, float, float]:
    """Tower position (x, y, m) and height above the antenna (m) from ``/truth/trajectory``."""
    attrs = read_attrs(path, schema.TRUTH_TRAJECTORY)
    try:
        return (float(attrs[schema.TOWER_X_ATTR]), float(attrs[schema.TOWER_Y_ATTR]),
                float(attrs.get(schema.TOWER_HEIGHT_ATTR, 0.0)))
    except KeyError:
        raise ValueError(f"{path}: no tower position in /{schema.TRUTH_TRAJECTORY}; give --tower X,Y") from None


def read_capture_start_s(path: str | os.PathLike) -> float:
    """Where a simulated capture starts on the sensors file's clock, s (0 if not recorded)."""
    with h5py.File(path, "r") as f:
        if schema.TRUTH_FRAMES in f:
            return float(f[schema.TRUTH_FRAMES].attrs.get(schema.CAPTURE_START_ATTR, 0.0))
    return 0.0


def read_has_magnetometer(path: str | os.PathLike) -> bool:
    """Whether the file's ``/imu`` holds magnetometer samples: False where an imported log had none
    (attribute ``has_magnetometer``; ``/imu/mag_ut`` then holds zeros), True otherwise."""
    return bool(read_attrs(path, schema.IMU).get(schema.HAS_MAGNETOMETER_ATTR, True))
