"""The live positions' line formats: CSV rows and GeoJSON lines, written as each position comes.

``dtmbnav live`` writes every position when the fusion gives it, so that another program can follow the
file as it grows (``tail -f``). Each line is complete when written and the file is flushed after each batch:
a reader never sees half a row, and a walk cut short keeps every row up to the cut.

- CSV (:data:`LIVE_CSV_COLUMNS`): a header row, then one row per position: walk time (s on the phone's
  clock), UTC (ISO 8601), the filter, the stage (``heading`` while the initial heading is not yet
  confident, ``filtered`` after), latitude and longitude (deg, WGS84), the 95 % accuracy radius (m: the
  radius of the circle that bounds the stated 95 % error ellipse,
  :meth:`dtmbnav_core.records.FusedTrack.accuracy_radius_m`), the local east/north position (m) and the
  stated east/north covariance (m^2).
- GeoJSON lines: one RFC 7946 Feature per line (newline-delimited), a Point (longitude, latitude) with
  the same fields as properties.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import IO

import numpy as np

from dtmbnav_core.geodetic import GeodeticPoint, to_geodetic
from dtmbnav_core.records import FusedTrack

#: Columns of the live CSV file, in order.
LIVE_CSV_COLUMNS = ("t_s", "utc", "filter", "stage", "lat_deg", "lon_deg", "accuracy_m", "east_m", "north_m",
                    "var_x_m2", "var_y_m2", "cov_xy_m2")
#: Decimal places of latitude and longitude (1e-9 deg is 0.1 mm on the ground or less).
LAT_LON_DECIMALS = 9


@dataclass(frozen=True)
class GeoPositions:
    """Positions of one filter put on WGS84, ready for the line formats.

    Attributes
    ----------
    filter_name : str
    stage : ndarray of str
        Per row, ``heading`` or ``filtered``.
    track : FusedTrack
        The rows in the local east/north frame with their stated covariance.
    lat_deg, lon_deg : ndarray
        The same positions on WGS84, deg.
    utc_ns : ndarray of int64
        Each row's time, ns since the Unix epoch.
    """

    filter_name: str
    stage: np.ndarray
    track: FusedTrack
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    utc_ns: np.ndarray

    @classmethod
    def from_track(cls, filter_name: str, stage: np.ndarray, track: FusedTrack, origin: GeodeticPoint,
                   t0_utc_ns: int) -> GeoPositions:
        """``track`` (local frame about ``origin``, times since ``t0_utc_ns``) on WGS84."""
        lat, lon = to_geodetic(track.x_m, track.y_m, 0.0, origin)
        utc_ns = t0_utc_ns + np.round(np.asarray(track.t_s) * 1e9).astype(np.int64)
        return cls(filter_name, np.asarray(stage), track, np.atleast_1d(lat), np.atleast_1d(lon), utc_ns)

    def rows(self) -> list[dict[str, object]]:
        """One dict per position, keyed by :data:`LIVE_CSV_COLUMNS`."""
        t = self.track
        accuracy = t.accuracy_radius_m()
        return [{"t_s": round(float(t.t_s[k]), 3), "utc": _iso_utc(int(self.utc_ns[k])),
                 "filter": self.filter_name, "stage": str(self.stage[k]),
                 "lat_deg": round(float(self.lat_deg[k]), LAT_LON_DECIMALS),
                 "lon_deg": round(float(self.lon_deg[k]), LAT_LON_DECIMALS),
                 "accuracy_m": _number(accuracy[k]), "east_m": _number(t.x_m[k]), "north_m": _number(t.y_m[k]),
                 "var_x_m2": _number(t.var_x_m2[k]), "var_y_m2": _number(t.var_y_m2[k]),
                 "cov_xy_m2": _number(t.cov_xy_m2[k])}
                for k in range(len(t))]


def _number(value: float) -> float | None:
    """A finite value rounded to 1 mm (or 1 mm^2), None otherwise (JSON has no NaN)."""
    return round(float(value), 3) if np.isfinite(value) else None


def _iso_utc(unix_ns: int) -> str:
    """ISO 8601 UTC with milliseconds."""
    return datetime.fromtimestamp(unix_ns / 1e9, tz=timezone.utc).isoformat(timespec="milliseconds")


class LivePositionWriter:
    """Writes positions to a CSV file and/or a GeoJSON-lines file as they come (module docstring).

    Parameters
    ----------
    csv_path, geojson_path : path or None
        Where to write (None: not written); an existing file is replaced.
    """

    def __init__(self, csv_path: str | os.PathLike | None = None,
                 geojson_path: str | os.PathLike | None = None) -> None:
        self._streams: list[IO[str]] = []
        self._csv = self._geojson = None
        self.rows = 0
        try:
            if csv_path is not None:
                stream = open(csv_path, "w", newline="")
                self._streams.append(stream)
                self._csv = csv.DictWriter(stream, LIVE_CSV_COLUMNS)
                self._csv.writeheader()
                stream.flush()
            if geojson_path is not None:
                self._geojson = open(geojson_path, "w")
                self._streams.append(self._geojson)
        except BaseException:
            self.close()
            raise

    def write(self, positions: GeoPositions) -> None:
        """Append the rows of ``positions`` and flush."""
        rows = positions.rows()
        if self._csv is not None:
            self._csv.writerows({key: "" if value is None else value for key, value in row.items()} for row in rows)
        if self._geojson is not None:
            for row in rows:
                feature = {"type": "Feature", "geometry": {"type": "Point",
                                                           "coordinates": [row["lon_deg"], row["lat_deg"]]},
                           "properties": row}
                self._geojson.write(json.dumps(feature, allow_nan=False) + "\n")
        for stream in self._streams:
            stream.flush()
        self.rows += len(rows)

    def close(self) -> None:
        """Close the files (what was written stays)."""
        for stream in self._streams:
            stream.close()
        self._streams = []

    def __enter__(self) -> LivePositionWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
