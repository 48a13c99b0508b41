"""WGS84 latitude, longitude and height to and from the project's local ENU frame: files and command lines.

The ENU frame (x east, y north, z up, m; ``docs/conventions.md``) of an imported phone log is the
tangent plane at a geodetic origin stored on its ``/gnss`` group
(:data:`dtmbnav_core.schema.ORIGIN_ATTRS`); ``fuse --tower-ll`` puts a tower given by latitude and
longitude into the same frame, and ``fuse`` and ``report`` put the fused tracks and the towers back onto
WGS84 for maps. The pure conversions and :class:`GeodeticPoint` are :mod:`dtmbnav_core.geodetic`'s
(re-exported here); this module adds the parsing of ``LAT,LON[,H]`` and the reading of a file's origin.
"""

from __future__ import annotations

import os

import numpy as np

from dtmbnav_core.geodetic import GeodeticPoint, to_enu, to_geodetic
from dtmbnav_core.sensors import read_geodetic_origin

#: The conversions live in :mod:`dtmbnav_core.geodetic` (the simulator uses them too); importers of this
#: module get them here as well.
__all__ = ["GeodeticPoint", "parse_point", "read_origin", "to_enu", "to_geodetic", "tower_in_sensors_frame"]


def parse_point(text: str) -> GeodeticPoint:
    """``LAT,LON`` or ``LAT,LON,HEIGHT_M`` (deg, deg, m above the ellipsoid; the height None when not given);
    ValueError naming what is wrong."""
    parts = text.split(",")
    if len(parts) not in (2, 3):
        raise ValueError(f"expected LAT,LON[,HEIGHT_M], got {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"expected LAT,LON[,HEIGHT_M] as numbers, got {text!r}") from None
    return GeodeticPoint(*values)


def read_origin(path: str | os.PathLike) -> GeodeticPoint | None:
    """The geodetic origin of a sensors or results file's ENU frame (:func:`read_geodetic_origin`), None without."""
    origin = read_geodetic_origin(path)
    return None if origin is None else GeodeticPoint(*origin)


def tower_in_sensors_frame(sensors_path: str | os.PathLike, tower: GeodeticPoint) -> tuple[float, float, float]:
    """A tower given by latitude and longitude in the ENU frame of a sensors file.

    Returns
    -------
    x_m, y_m : float
        East and north of the tower about the file's origin, m.
    height_m : float
        The tower antenna's height above the receiver's antenna, m: its up coordinate (the origin is the
        phone's first fix, so its height is the antenna's) when the tower's height is given, else 0 (as
        ``--tower X,Y``).

    Raises
    ------
    ValueError
        The file has no geodetic origin (not an imported phone log).
    """
    origin = read_origin(sensors_path)
    if origin is None:
        raise ValueError(f"{sensors_path}: no geodetic origin (/gnss attributes origin_lat_deg, origin_lon_deg, "
                         "origin_height_m, written by 'dtmbnav sensors'); give the tower in its frame with --tower X,Y")
    height = tower.height_m if tower.height_m is not None else origin.height_m
    east, north, up = to_enu(np.array([tower.lat_deg]), np.array([tower.lon_deg]), np.array([height]), origin)
    return float(east[0]), float(north[0]), float(up[0]) if tower.height_m is not None else 0.0
