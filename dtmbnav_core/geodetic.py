"""WGS84 latitude, longitude and height to and from a local ENU frame, through ``pymap3d``.

The project's ENU frame (x east, y north, z up, m; ``docs/conventions.md``) is the tangent plane at a
geodetic origin: an imported phone log's first fix (or one given), a simulated scenario's
``[origin]``. The conversions are pure functions, shared by the simulator (which writes the walk's
fixes and the towers as latitude and longitude) and the real-data path (which reads them back), with
the helpers of files and command lines: ``LAT,LON[,H]`` parsed, a sensors file's origin read, a tower
given by latitude and longitude put into a sensors file's frame (``fuse --tower-ll``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pymap3d

from dtmbnav_core.sensors import read_geodetic_origin


@dataclass(frozen=True)
class GeodeticPoint:
    """A point on WGS84.

    Attributes
    ----------
    lat_deg, lon_deg : float
        Latitude (-90..90) and longitude (-180..180), deg.
    height_m : float or None
        Height above the WGS84 ellipsoid, m; None where not given (see :meth:`with_height`).
    """

    lat_deg: float
    lon_deg: float
    height_m: float | None = None

    def __post_init__(self) -> None:
        values = (self.lat_deg, self.lon_deg) + (() if self.height_m is None else (self.height_m,))
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"latitude, longitude and height must be finite numbers, got {values}")
        if abs(self.lat_deg) > 90.0:
            raise ValueError(f"latitude {self.lat_deg} deg is out of range (-90..90)")
        if abs(self.lon_deg) > 180.0:
            raise ValueError(f"longitude {self.lon_deg} deg is out of range (-180..180)")

    def with_height(self, default_m: float) -> GeodeticPoint:
        """This point, its height ``default_m`` where none was given."""
        return self if self.height_m is not None else GeodeticPoint(self.lat_deg, self.lon_deg, float(default_m))


def _known_height(origin: GeodeticPoint) -> float:
    if origin.height_m is None:
        raise ValueError("the ENU origin needs a height")
    return origin.height_m


def to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, height_m: np.ndarray,
           origin: GeodeticPoint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """East, north and up of WGS84 points about ``origin`` (whose height must be known), m (``pymap3d.geodetic2enu``)."""
    east, north, up = pymap3d.geodetic2enu(np.asarray(lat_deg, dtype=np.float64), np.asarray(lon_deg, dtype=np.float64),
                                           np.asarray(height_m, dtype=np.float64), origin.lat_deg, origin.lon_deg,
                                           _known_height(origin))
    return np.asarray(east, dtype=np.float64), np.asarray(north, dtype=np.float64), np.asarray(up, dtype=np.float64)


def to_lat_lon_height(east_m: np.ndarray, north_m: np.ndarray, up_m: np.ndarray | float,
                      origin: GeodeticPoint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """WGS84 latitude and longitude, deg, and height above the ellipsoid, m, of ENU points about ``origin``
    (whose height must be known) (``pymap3d.enu2geodetic``; east, north and up in m; ``up_m`` broadcast)."""
    east = np.asarray(east_m, dtype=np.float64)
    up = np.broadcast_to(np.asarray(up_m, dtype=np.float64), east.shape)
    lat, lon, height = pymap3d.enu2geodetic(east, np.asarray(north_m, dtype=np.float64), up, origin.lat_deg,
                                            origin.lon_deg, _known_height(origin))
    return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64), np.asarray(height, dtype=np.float64)


def to_geodetic(east_m: np.ndarray, north_m: np.ndarray, up_m: np.ndarray | float,
                origin: GeodeticPoint) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 latitude and longitude, deg, of ENU points about ``origin`` (:func:`to_lat_lon_height` without
    the height)."""
    lat, lon, _ = to_lat_lon_height(east_m, north_m, up_m, origin)
    return lat, lon


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


def tower_in_frame(origin: GeodeticPoint, tower: GeodeticPoint) -> tuple[float, float, float]:
    """A tower given by latitude and longitude in the ENU frame about ``origin`` (the phone's first fix).

    Returns
    -------
    x_m, y_m : float
        East and north of the tower about the origin, m.
    height_m : float
        The tower antenna's height above the receiver's antenna, m: its up coordinate (the origin is the
        phone's first fix, so its height is the antenna's) when the tower's height is given, else 0 (as
        ``--tower X,Y``).
    """
    height = tower.height_m if tower.height_m is not None else origin.height_m
    east, north, up = to_enu(np.array([tower.lat_deg]), np.array([tower.lon_deg]), np.array([height]), origin)
    return float(east[0]), float(north[0]), float(up[0]) if tower.height_m is not None else 0.0


def required_origin(sensors_path: str | os.PathLike) -> GeodeticPoint:
    """A sensors file's geodetic origin (:func:`read_origin`).

    Raises
    ------
    ValueError
        The file has no geodetic origin (not an imported phone log).
    """
    origin = read_origin(sensors_path)
    if origin is None:
        raise ValueError(f"{sensors_path}: no geodetic origin (/gnss attributes origin_lat_deg, origin_lon_deg, "
                         "origin_height_m, written by 'dtmbnav sensors'); give the tower in its frame with --tower X,Y")
    return origin


def tower_in_sensors_frame(sensors_path: str | os.PathLike, tower: GeodeticPoint) -> tuple[float, float, float]:
    """:func:`tower_in_frame` about a sensors file's origin (ValueError without one: :func:`required_origin`)."""
    return tower_in_frame(required_origin(sensors_path), tower)
