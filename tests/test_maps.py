"""Map output of the fused tracks: the geodetic origin carried by ``fuse``, and the report's map files.

A results file with a known origin and known ENU tracks is written through the schema; the report's
``tracks.geojson``, ``tracks.gpx`` and ``map.html`` must hold every track, converted back to ENU
with pymap3d, within 1 mm. A results file without an origin gets no map files unless ``--origin``
places it; ``fuse`` on a sensors file with an origin writes each track's latitude and longitude.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import geojson
import gpxpy
import h5py
import numpy as np
import pymap3d
import pytest

from dtmbnav.cli import EXIT_OK, main
from dtmbnav.field.maps import (GEOJSON_NAME, GPX_NAME, HTML_NAME, KIND_FILTER, KIND_FIX, KIND_PDR, KIND_TOWER,
                          KIND_TRUTH)
from dtmbnav.chain.report import NO_MAP_NOTE
from dtmbnav_core import schema
from dtmbnav_core.h5io import atomic_h5, read_attrs, read_columns, write_columns
from dtmbnav_core.records import PdrSteps
from fusion.metrics import PDR_AT_FIX, place_pdr

ORIGIN = (30.5123456, 114.3654321, 25.0)
MAP_FILES = (GEOJSON_NAME, GPX_NAME, HTML_NAME)
#: Tower sites of the written results file: east, north, m; height above the receiver's antenna, m.
TOWERS = ((2400.0, -1300.0, 180.0), (-900.0, 3100.0, 120.0))
START_XY_M = (100.0, 50.0)
HEADING_RAD = 0.3
TOLERANCE_M = 1e-3


def _loop(n: int, radius_m: float, shift_m: float) -> dict[str, np.ndarray]:
    """A loop about the start, ``shift_m`` east of it, as track columns."""
    a = np.linspace(0.0, 2.0 * np.pi, n)
    return {"t_s": np.linspace(10.0, 130.0, n), "x_m": START_XY_M[0] + shift_m + radius_m * np.sin(a),
            "y_m": START_XY_M[1] - radius_m + radius_m * np.cos(a), "heading_rad": a % (2 * np.pi),
            "speed_mps": np.full(n, 1.3)}


FILTER_TRACKS = {"ukf": _loop(180, 150.0, 0.0), "pf": _loop(180, 148.0, 2.5)}


def _pdr() -> dict[str, np.ndarray]:
    n = 180
    t = np.linspace(10.0, 130.0, n)
    a = np.linspace(0.0, 2.0 * np.pi, n)
    return {"t_s": t, "x_m": 140.0 * np.sin(a), "y_m": 140.0 * (np.cos(a) - 1.0), "heading_rad": a,
            "speed_mps": np.full(n, 1.2), "step_length_m": np.full(n, 0.7)}


def write_results(path: Path, origin: tuple[float, float, float] | None) -> Path:
    """A results file with two filter tracks; with ``origin`` also ``/gnss`` and the towers, as ``fuse`` writes."""
    t = np.arange(0.0, 140.0, 0.5)
    frames = {"t_s": t, "range_change_m": -0.5 * t, "snr_db": np.full(len(t), 20.0, np.float32),
              "flags": np.zeros(len(t), np.uint8)}
    with atomic_h5(path) as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, frames, {"pn_mode": "PN420"})
        write_columns(h5, schema.PDR, _pdr(), {"step_model": "frequency"})
        for name, track in FILTER_TRACKS.items():
            write_columns(h5, schema.fusion_group(name), track, {
                schema.INITIAL_HEADING_ATTR: HEADING_RAD, **dict(zip(schema.FUSION_START_ATTRS, START_XY_M))})
        if origin is not None:
            fixes = {"t_s": np.arange(0.0, 130.0, 10.0)}
            fixes.update(x_m=START_XY_M[0] + 3.0 * np.sin(fixes["t_s"]), y_m=START_XY_M[1] + 0.2 * fixes["t_s"],
                         cn0_dbhz=np.full(len(fixes["t_s"]), 35.0))
            write_columns(h5, schema.GNSS, fixes, {
                **dict(zip(schema.ORIGIN_ATTRS, origin)),
                **dict(zip(schema.START_FIX_ATTRS, (0.0, *START_XY_M, 3.0)))})
            sites = np.array(TOWERS)
            for name, values in zip(schema.FUSION_TOWER_ATTRS, sites.T):
                h5[schema.FUSION].attrs[name] = values
    return path


def _enu(lat, lon, origin) -> tuple[np.ndarray, np.ndarray]:
    """East and north of WGS84 points (at the origin's height) about ``origin``, m."""
    east, north, _ = pymap3d.geodetic2enu(np.asarray(lat), np.asarray(lon), origin[2], *origin)
    return np.asarray(east), np.asarray(north)


def expected_tracks() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every track the map must show, ENU m: the filters' and the PDR placed at the start fix."""
    pdr = place_pdr(PdrSteps(**_pdr()), *START_XY_M, HEADING_RAD)
    return {PDR_AT_FIX: (pdr.x_m, pdr.y_m), **{n: (t["x_m"], t["y_m"]) for n, t in FILTER_TRACKS.items()}}


def _assert_within_mm(name, lat, lon, origin, expected) -> None:
    east, north = _enu(lat, lon, origin)
    error = np.hypot(east - expected[0], north - expected[1])
    assert len(east) == len(expected[0]) and error.max() < TOLERANCE_M, f"{name}: {error.max()} m"


@pytest.fixture(scope="module")
def geo_report(tmp_path_factory) -> Path:
    """The report folder of a results file with a geodetic origin."""
    folder = tmp_path_factory.mktemp("geo")
    results = write_results(folder / "results.h5", ORIGIN)
    assert main(["-q", "report", str(results), "-o", str(folder / "report")]) == EXIT_OK
    return folder / "report"


def test_the_geojson_holds_every_track_within_a_millimetre(geo_report):
    text = (geo_report / GEOJSON_NAME).read_text()
    parsed = geojson.loads(text)
    assert parsed.is_valid, parsed.errors()
    assert isinstance(parsed, geojson.FeatureCollection)
    # The coordinates as written: geojson.loads rounds them to its default 6 decimal places (0.1 m).
    collection = json.loads(text)
    lines = {f["properties"]["name"]: f for f in collection["features"] if f["geometry"]["type"] == "LineString"}
    assert set(lines) == set(expected_tracks())
    for name, expected in expected_tracks().items():
        assert lines[name]["properties"]["kind"] == (KIND_PDR if name == PDR_AT_FIX else KIND_FILTER)
        lon, lat = np.array(lines[name]["geometry"]["coordinates"]).T
        _assert_within_mm(name, lat, lon, ORIGIN, expected)
    points = [f for f in collection["features"] if f["geometry"]["type"] == "Point"]
    towers = [f for f in points if f["properties"]["kind"] == KIND_TOWER]
    fixes = [f for f in points if f["properties"]["kind"] == KIND_FIX]
    assert [f["properties"]["name"] for f in towers] == ["tower 0", "tower 1"]
    assert len(fixes) == 13
    # The towers at their height above the receiver: back to ENU at that height, they land where they were.
    for feature, (x, y, up) in zip(towers, TOWERS):
        lon, lat = feature["geometry"]["coordinates"]
        east, north, _ = pymap3d.geodetic2enu(lat, lon, ORIGIN[2] + up, *ORIGIN)
        assert np.hypot(east - x, north - y) < TOLERANCE_M


def test_the_gpx_holds_every_track_within_a_millimetre(geo_report):
    gpx = gpxpy.parse((geo_report / GPX_NAME).read_text())
    tracks = {t.name: t for t in gpx.tracks}
    assert set(tracks) == set(expected_tracks())
    for name, expected in expected_tracks().items():
        points = [p for segment in tracks[name].segments for p in segment.points]
        _assert_within_mm(name, [p.latitude for p in points], [p.longitude for p in points], ORIGIN, expected)
    assert sorted(w.name for w in gpx.waypoints if w.type == KIND_TOWER) == ["tower 0", "tower 1"]


def test_the_html_map_has_a_polyline_per_track(geo_report):
    html = (geo_report / HTML_NAME).read_text()
    for name in expected_tracks():
        assert name in html
    assert len(re.findall(r"L\.polyline\(", html)) == len(expected_tracks())
    assert "L.control.layers" in html
    summary = json.loads((geo_report / "summary.json").read_text())
    assert summary["map_files"] == list(MAP_FILES)


def test_no_origin_no_map_files_unless_given(tmp_path):
    results = write_results(tmp_path / "results.h5", None)
    assert main(["-q", "report", str(results), "-o", str(tmp_path / "plain")]) == EXIT_OK
    assert not [name for name in MAP_FILES if (tmp_path / "plain" / name).exists()]
    summary = json.loads((tmp_path / "plain" / "summary.json").read_text())
    assert summary["map"] == NO_MAP_NOTE and summary["map_files"] == []
    # --origin places the local frame (height 0 m when not given).
    assert main(["-q", "report", str(results), "-o", str(tmp_path / "placed"),
                 "--origin=-33.9,18.4"]) == EXIT_OK
    gpx = gpxpy.parse((tmp_path / "placed" / GPX_NAME).read_text())
    ukf = [p for s in next(t for t in gpx.tracks if t.name == "ukf").segments for p in s.points]
    _assert_within_mm("ukf", [p.latitude for p in ukf], [p.longitude for p in ukf], (-33.9, 18.4, 0.0),
                      expected_tracks()["ukf"])
    # No fixes or towers are known for it: tracks only.
    assert not gpx.waypoints


def test_a_simulated_walk_placed_with_its_truth_shows_the_truth_fixes_and_tower(tiny_results, tiny_walk_truth,
                                                                              tmp_path):
    out = tmp_path / "report"
    assert main(["-q", "report", str(tiny_results), "--truth", str(tiny_walk_truth), "-o", str(out),
                 "--origin", "48.85,2.35,35"]) == EXIT_OK
    features = json.loads((out / GEOJSON_NAME).read_text())["features"]
    kinds = {}
    for feature in features:
        kinds.setdefault(feature["properties"]["kind"], []).append(feature["properties"]["name"])
    assert kinds[KIND_TRUTH] == ["truth"] and kinds[KIND_PDR] == [PDR_AT_FIX]
    assert sorted(kinds[KIND_FILTER]) == ["pf", "ukf"]
    assert kinds[KIND_TOWER] == ["tower 0"]
    assert len(kinds[KIND_FIX]) == len(read_columns(tiny_walk_truth, schema.GNSS)["t_s"])
    tower = next(f for f in features if f["properties"]["kind"] == KIND_TOWER)
    east, north = _enu(tower["geometry"]["coordinates"][1], tower["geometry"]["coordinates"][0], (48.85, 2.35, 35.0))
    x, y = (read_attrs(tiny_walk_truth, schema.TRUTH_TRAJECTORY)[n] for n in (schema.TOWER_X_ATTR,
                                                                               schema.TOWER_Y_ATTR))
    assert np.hypot(east - x, north - y) < TOLERANCE_M
    assert "map: tracks.geojson, tracks.gpx, map.html" in (out / "summary.md").read_text()


def test_report_origin_is_checked_at_parse_time(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["report", str(tmp_path / "r.h5"), "-o", str(tmp_path / "out"), "--origin", "95,10"])
    assert exc.value.code == 2
    assert "latitude 95.0 deg is out of range" in capsys.readouterr().err


@pytest.fixture(scope="module")
def geo_sensors(tiny_walk_truth, tmp_path_factory) -> Path:
    """The tiny walk's truth file with a geodetic origin on ``/gnss``, as ``dtmbnav sensors`` stores it."""
    path = tmp_path_factory.mktemp("geo-sensors") / "sensors.h5"
    shutil.copyfile(tiny_walk_truth, path)
    with h5py.File(path, "a") as f:
        for name, value in zip(schema.ORIGIN_ATTRS, ORIGIN):
            f[schema.GNSS].attrs[name] = value
    return path


def test_fuse_writes_latitude_and_longitude_with_an_origin(tiny_results, geo_sensors, tmp_path):
    receiver = tiny_results.parent / "exact-receiver.h5"
    out = tmp_path / "fused.h5"
    assert main(["-q", "fuse", "--receiver", str(receiver), "--sensors", str(geo_sensors), "-o", str(out),
                 "--filters", "ukf"]) == EXIT_OK
    track = read_columns(out, schema.fusion_group("ukf"))
    lat, lon, _ = pymap3d.enu2geodetic(track["x_m"], track["y_m"], 0.0, *ORIGIN)
    np.testing.assert_allclose(track["lat_deg"], lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(track["lon_deg"], lon, rtol=0, atol=1e-12)
    # The origin travels with the fixes (/gnss copied), and the tower used is recorded on /fusion.
    assert read_columns(out, schema.GNSS)["x_m"].tolist() == read_columns(geo_sensors, schema.GNSS)["x_m"].tolist()
    assert tuple(read_attrs(out, schema.GNSS)[n] for n in schema.ORIGIN_ATTRS) == ORIGIN
    fusion = read_attrs(out, schema.FUSION)
    tower = read_attrs(geo_sensors, schema.TRUTH_TRAJECTORY)
    assert fusion["towers_x_m"].tolist() == [tower[schema.TOWER_X_ATTR]]
    assert fusion["towers_y_m"].tolist() == [tower[schema.TOWER_Y_ATTR]]
    lat, lon, _ = pymap3d.enu2geodetic(fusion["towers_x_m"], fusion["towers_y_m"], fusion["towers_height_m"],
                                       *ORIGIN)
    np.testing.assert_allclose(fusion["towers_lat_deg"], lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fusion["towers_lon_deg"], lon, rtol=0, atol=1e-12)


def test_fuse_without_an_origin_writes_the_old_layout(tiny_results):
    """A simulation's results: no /gnss, no latitude or longitude columns, no tower attributes (only the
    time offset's, from the simulation's record)."""
    with h5py.File(tiny_results, "r") as f:
        assert schema.GNSS not in f
        attrs = f[schema.FUSION].attrs
        assert all(key.startswith("time_offset_") for key in attrs)
        assert attrs["time_offset_source"] == "simulation record" and attrs["time_offset_sigma_s"] == 0.0
        for name in f[schema.FUSION]:
            assert set(f[schema.fusion_group(name)]) == {*schema.TRACK_COLUMNS, *schema.FUSION_COVARIANCE_COLUMNS,
                                                         schema.SMOOTHED}
