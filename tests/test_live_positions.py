"""The live positions' line formats (dtmbnav.field.live_positions): rows on WGS84, complete lines, no NaN."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from dtmbnav_core.geodetic import GeodeticPoint, to_enu
from dtmbnav_core.records import ELLIPSE_95_CHI2, FusedTrack, Track
from dtmbnav.field.live_positions import LIVE_CSV_COLUMNS, GeoPositions, LivePositionWriter

ORIGIN = GeodeticPoint(31.2, 121.5, 10.0)
T0_UTC_NS = 1_765_000_000_000_000_000


def _positions(first: int, count: int, stated: bool = True) -> GeoPositions:
    k = np.arange(first, first + count, dtype=np.float64)
    track = Track(0.5 * k, 3.0 * k, -2.0 * k, np.zeros(count), np.ones(count))
    cov = np.array([[[4.0 + j, 1.0], [1.0, 2.0]] for j in k]) if stated else np.full((count, 2, 2), np.nan)
    stage = np.where(k < 3, "heading", "filtered")
    return GeoPositions.from_track("pf", stage, FusedTrack.from_track(track, cov), ORIGIN, T0_UTC_NS)


def test_rows_go_back_to_the_local_frame_and_state_the_95_radius(tmp_path) -> None:
    with LivePositionWriter(tmp_path / "live.csv", tmp_path / "live.geojsonl") as writer:
        writer.write(_positions(0, 4))
        writer.write(_positions(4, 3))
    rows = list(csv.DictReader(open(tmp_path / "live.csv")))
    features = [json.loads(line) for line in open(tmp_path / "live.geojsonl")]
    assert tuple(rows[0]) == LIVE_CSV_COLUMNS and len(rows) == len(features) == 7
    lat = np.array([float(r["lat_deg"]) for r in rows])
    lon = np.array([float(r["lon_deg"]) for r in rows])
    east, north, _ = to_enu(lat, lon, np.full(7, ORIGIN.height_m), ORIGIN)
    np.testing.assert_allclose(east, 3.0 * np.arange(7), atol=1e-3)
    np.testing.assert_allclose(north, -2.0 * np.arange(7), atol=1e-3)
    # The 95 % radius bounds the ellipse: sqrt(chi2 * largest eigenvalue).
    largest = np.linalg.eigvalsh(np.array([[4.0 + 5, 1.0], [1.0, 2.0]]))[-1]
    assert float(rows[5]["accuracy_m"]) == pytest.approx(np.sqrt(ELLIPSE_95_CHI2 * largest), abs=1e-3)
    assert [r["stage"] for r in rows[:4]] == ["heading"] * 3 + ["filtered"]
    assert rows[2]["utc"] == "2025-12-06T05:46:41.000+00:00"
    assert features[6]["geometry"]["coordinates"] == [float(rows[6]["lon_deg"]), float(rows[6]["lat_deg"])]


def test_a_position_without_a_stated_error_is_empty_not_nan(tmp_path) -> None:
    with LivePositionWriter(tmp_path / "live.csv", tmp_path / "live.geojsonl") as writer:
        writer.write(_positions(0, 2, stated=False))
    assert list(csv.DictReader(open(tmp_path / "live.csv")))[0]["accuracy_m"] == ""
    assert json.loads(open(tmp_path / "live.geojsonl").readline())["properties"]["accuracy_m"] is None


def test_each_batch_is_on_disk_when_written(tmp_path) -> None:
    writer = LivePositionWriter(tmp_path / "live.csv")
    writer.write(_positions(0, 2))
    assert len(open(tmp_path / "live.csv").read().splitlines()) == 3   # flushed: a follower sees the rows now
    writer.close()
