"""Map files of fused tracks: GeoJSON, GPX and an HTML map (folium).

Tracks and points come in on WGS84 (latitude and longitude, deg; :func:`dtmbnav_core.geodetic.to_geodetic`
puts the ENU frame there), each with a name and a kind, and go out as:

- ``tracks.geojson``: a FeatureCollection, one LineString per track and one Point per point, with the
  properties ``name`` and ``kind`` (RFC 7946 order: longitude, latitude); a track that states its error
  also has ``accuracy_m``, one value per coordinate of its line (null where none is stated);
- ``tracks.gpx``: GPX 1.1, one ``<trk>`` per track (``<name>``, ``<type>`` = kind) and one ``<wpt>``
  per point; a point of a track that states its error has ``<extensions><dtmbnav:accuracy_m>``;
- ``map.html``: a folium (Leaflet) map, every track a PolyLine in its own layer, the GNSS fixes as
  circle markers and the towers as markers, with a layer control. The page loads its map tiles when
  opened; writing it needs no network.

Points that are not finite (a filter that diverged) are left out of every file.

A point's accuracy is the radius of the circle that bounds the 95 % ellipse of the error the filter states,
m (:meth:`dtmbnav_core.records.FusedTrack.accuracy_radius_m`): the ellipse's semi-major axis, so the
circle holds at least 95 % of a Gaussian error of that covariance.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import folium
import geojson
import gpxpy.gpx
import numpy as np

#: Decimal places of latitude and longitude in the GeoJSON file: 1e-9 deg is 0.1 mm on the ground or less.
GEOJSON_PRECISION = 9
#: Kinds of tracks and points (the ``kind`` property, the GPX ``<type>``).
KIND_FILTER = "filter"
KIND_SMOOTHED = "smoothed"
KIND_PDR = "pdr"
KIND_TRUTH = "truth"
KIND_FIX = "gnss_fix"
KIND_TOWER = "tower"
#: XML namespace of the GPX extension element ``accuracy_m`` (the 95 % radius of a track point, m).
GPX_NAMESPACE = "urn:dtmbnav:gpx:1"
#: File names of the map files in a report folder.
GEOJSON_NAME = "tracks.geojson"
GPX_NAME = "tracks.gpx"
HTML_NAME = "map.html"
#: Line colours of the filter tracks, in turn; the PDR and the truth have their own.
FILTER_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#e377c2", "#8c564b")
KIND_COLOURS = {KIND_PDR: "#7f7f7f", KIND_TRUTH: "#000000", KIND_FIX: "#ff7f0e", KIND_TOWER: "red"}


@dataclass(frozen=True)
class MapTrack:
    """A track on WGS84.

    Attributes
    ----------
    name : str
        What the map calls it (a filter's name, ``pdr@fix``, ``truth``).
    kind : str
        :data:`KIND_FILTER`, :data:`KIND_SMOOTHED` (a filter's smoothed track), :data:`KIND_PDR` or
        :data:`KIND_TRUTH`.
    lat_deg, lon_deg : ndarray
        Latitude and longitude of each point, deg.
    accuracy_m : ndarray or None
        Each point's accuracy (module docstring), m; NaN where not stated; None: a track that states none.
    """

    name: str
    kind: str
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    accuracy_m: np.ndarray | None = None

    def _finite_rows(self) -> np.ndarray:
        lat, lon = np.asarray(self.lat_deg, dtype=np.float64), np.asarray(self.lon_deg, dtype=np.float64)
        return np.isfinite(lat) & np.isfinite(lon)

    def finite(self) -> tuple[np.ndarray, np.ndarray]:
        """Latitude and longitude of the finite points, deg."""
        ok = self._finite_rows()
        return np.asarray(self.lat_deg, dtype=np.float64)[ok], np.asarray(self.lon_deg, dtype=np.float64)[ok]

    def finite_accuracy(self) -> list[float | None] | None:
        """The accuracy of the finite points, m (None where not stated); None for a track that states none."""
        if self.accuracy_m is None:
            return None
        accuracy = np.asarray(self.accuracy_m, dtype=np.float64)[self._finite_rows()]
        return [float(a) if np.isfinite(a) else None for a in accuracy]


@dataclass(frozen=True)
class MapPoint:
    """A point on WGS84: a GNSS fix or a tower.

    Attributes
    ----------
    name : str
        What the map calls it (``GNSS fix 3``, ``tower 0``).
    kind : str
        :data:`KIND_FIX` or :data:`KIND_TOWER`.
    lat_deg, lon_deg : float
        Latitude and longitude, deg.
    """

    name: str
    kind: str
    lat_deg: float
    lon_deg: float

    def is_finite(self) -> bool:
        return bool(np.isfinite(self.lat_deg) and np.isfinite(self.lon_deg))


def _lon_lat(lat: np.ndarray, lon: np.ndarray) -> list[tuple[float, float]]:
    return [(float(x), float(y)) for y, x in zip(lat, lon)]


def tracks_to_geojson(tracks: list[MapTrack], points: list[MapPoint]) -> geojson.FeatureCollection:
    """Tracks as LineStrings and points as Points, each a Feature with properties ``name`` and ``kind``.

    A track with fewer than two finite points (no line) is a Point where it has one, else left out.
    """
    features = []
    for track in tracks:
        coords = _lon_lat(*track.finite())
        if not coords:
            continue
        geometry = (geojson.LineString(coords, precision=GEOJSON_PRECISION) if len(coords) >= 2
                    else geojson.Point(coords[0], precision=GEOJSON_PRECISION))
        properties = {"name": track.name, "kind": track.kind}
        accuracy = track.finite_accuracy()
        if accuracy is not None:
            properties["accuracy_m"] = [None if a is None else round(a, 3) for a in accuracy]
        features.append(geojson.Feature(geometry=geometry, properties=properties))
    for point in points:
        if point.is_finite():
            geometry = geojson.Point((float(point.lon_deg), float(point.lat_deg)), precision=GEOJSON_PRECISION)
            features.append(geojson.Feature(geometry=geometry, properties={"name": point.name, "kind": point.kind}))
    return geojson.FeatureCollection(features)


def tracks_to_gpx(tracks: list[MapTrack], points: list[MapPoint]) -> gpxpy.gpx.GPX:
    """GPX 1.1: one track (one segment) per track, named, its kind as ``<type>``; one waypoint per point."""
    gpx = gpxpy.gpx.GPX()
    gpx.creator = "dtmbnav"
    gpx.nsmap["dtmbnav"] = GPX_NAMESPACE
    for track in tracks:
        lat, lon = track.finite()
        segment = gpxpy.gpx.GPXTrackSegment([gpxpy.gpx.GPXTrackPoint(float(y), float(x)) for y, x in zip(lat, lon)])
        for point, accuracy in zip(segment.points, track.finite_accuracy() or ()):
            if accuracy is not None:
                element = ElementTree.Element(f"{{{GPX_NAMESPACE}}}accuracy_m")
                element.text = f"{accuracy:.3f}"
                point.extensions.append(element)
        trk = gpxpy.gpx.GPXTrack(name=track.name)
        trk.type = track.kind
        trk.segments.append(segment)
        gpx.tracks.append(trk)
    for point in points:
        if point.is_finite():
            gpx.waypoints.append(gpxpy.gpx.GPXWaypoint(float(point.lat_deg), float(point.lon_deg), name=point.name,
                                                       type=point.kind))
    return gpx


def tracks_to_html_map(tracks: list[MapTrack], points: list[MapPoint]) -> folium.Map:
    """A folium map: each track a PolyLine in its own layer, the fixes and the towers in a layer each.

    The view fits every track and point; the layer control switches each layer on and off.
    """
    lines = [(track, _lon_lat(*track.finite())) for track in tracks]
    lines = [(track, coords) for track, coords in lines if coords]
    shown = [p for p in points if p.is_finite()]
    everything = [(y, x) for _, coords in lines for x, y in coords] + [(p.lat_deg, p.lon_deg) for p in shown]
    centre = np.mean(everything, axis=0).tolist() if everything else [0.0, 0.0]
    fmap = folium.Map(location=centre, zoom_start=17, control_scale=True)
    colours = itertools.cycle(FILTER_COLOURS)
    for track, coords in lines:
        colour = KIND_COLOURS.get(track.kind) or next(colours)
        layer = folium.FeatureGroup(name=track.name)
        folium.PolyLine([(y, x) for x, y in coords], color=colour, weight=3 if track.kind == KIND_FILTER else 2,
                        dash_array="6 6" if track.kind == KIND_PDR else None, tooltip=track.name).add_to(layer)
        layer.add_to(fmap)
    fixes = [p for p in shown if p.kind == KIND_FIX]
    if fixes:
        layer = folium.FeatureGroup(name="GNSS fixes")
        for p in fixes:
            folium.CircleMarker((p.lat_deg, p.lon_deg), radius=3, color=KIND_COLOURS[KIND_FIX], fill=True,
                                tooltip=p.name).add_to(layer)
        layer.add_to(fmap)
    towers = [p for p in shown if p.kind != KIND_FIX]
    if towers:
        layer = folium.FeatureGroup(name="towers")
        for p in towers:
            folium.Marker((p.lat_deg, p.lon_deg), tooltip=p.name, popup=p.name,
                          icon=folium.Icon(color=KIND_COLOURS[KIND_TOWER], icon="signal")).add_to(layer)
        layer.add_to(fmap)
    if len(everything) >= 2:
        lat, lon = np.array(everything).T
        fmap.fit_bounds([(float(lat.min()), float(lon.min())), (float(lat.max()), float(lon.max()))])
    folium.LayerControl(collapsed=False).add_to(fmap)
    return fmap


def write_geojson(path: str | os.PathLike, tracks: list[MapTrack], points: list[MapPoint]) -> Path:
    """:func:`tracks_to_geojson` written to ``path``; returns it."""
    Path(path).write_text(geojson.dumps(tracks_to_geojson(tracks, points)) + "\n")
    return Path(path)


def write_gpx(path: str | os.PathLike, tracks: list[MapTrack], points: list[MapPoint]) -> Path:
    """:func:`tracks_to_gpx` written to ``path``; returns it."""
    Path(path).write_text(tracks_to_gpx(tracks, points).to_xml())
    return Path(path)


def write_html_map(path: str | os.PathLike, tracks: list[MapTrack], points: list[MapPoint]) -> Path:
    """:func:`tracks_to_html_map` written to ``path``; returns it."""
    tracks_to_html_map(tracks, points).save(str(path))
    return Path(path)


def write_map_files(folder: str | os.PathLike, tracks: list[MapTrack], points: list[MapPoint]) -> list[Path]:
    """``tracks.geojson``, ``tracks.gpx`` and ``map.html`` in ``folder``; returns their paths."""
    folder = Path(folder)
    return [write_geojson(folder / GEOJSON_NAME, tracks, points), write_gpx(folder / GPX_NAME, tracks, points),
            write_html_map(folder / HTML_NAME, tracks, points)]
