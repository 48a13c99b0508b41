"""The live web page (dtmbnav.field.live_page): its state route, its ellipses, and the page in a real headless browser."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
import urllib.error
import urllib.request

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core.records import ELLIPSE_95_CHI2
from dtmbnav.field.live_page import LiveView, ViewRow, ViewScene, ellipse_95

CHROMIUM = next((shutil.which(name) for name in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(name)), None)


def _rows(first: int, stop: int) -> list[ViewRow]:
    """Positions on a 20 m circle, the first ten before the heading is confident."""
    rows = []
    for k in range(first, stop):
        east, north = 20.0 * np.cos(k / 10), 20.0 * np.sin(k / 10)
        major, minor, angle = ellipse_95(4.0 + 0.1 * k, 1.0, 0.5)
        rows.append(ViewRow(0.5 * k, east, north, 31.0 + north / 1.1e5, 121.0 + east / 0.95e5, major, minor, angle,
                            "heading" if k < 10 else "filtered"))
    return rows


def _get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as reply:
        return json.loads(reply.read())


@settings(max_examples=50, deadline=None)
@given(sx=st.floats(0.01, 100.0), sy=st.floats(0.01, 100.0), rho=st.floats(-0.99, 0.99))
def test_ellipse_95_holds_the_covariance(sx: float, sy: float, rho: float) -> None:
    """The ellipse's axes are the covariance's principal sigmas times sqrt(chi2_95), along its eigenvectors."""
    cov = np.array([[sx**2, rho * sx * sy], [rho * sx * sy, sy**2]])
    major, minor, angle = ellipse_95(cov[0, 0], cov[1, 1], cov[0, 1])
    u = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    v = np.array([-u[1], u[0]])
    assert major >= minor >= 0.0
    assert u @ cov @ u * ELLIPSE_95_CHI2 == pytest.approx(major**2, rel=1e-6)
    assert v @ cov @ v * ELLIPSE_95_CHI2 == pytest.approx(minor**2, rel=1e-6, abs=1e-9)
    assert np.trace(cov) * ELLIPSE_95_CHI2 == pytest.approx(major**2 + minor**2, rel=1e-6)


def test_state_route_gives_only_new_rows_and_no_nan() -> None:
    with LiveView() as view:
        view.set_scene(ViewScene(1.0, 2.0, float("nan"), [45.0], [4000.0]))
        view.set_status(lock="yes", snr_db=float("nan"))
        view.add_rows(_rows(0, 5))
        first = _get(view.url + "state.json")
        view.add_rows(_rows(5, 8))
        later = _get(view.url + "state.json?since=5")
        assert first["total"] == 5 and len(first["rows"]) == 5
        assert later["total"] == 8 and [r["t_s"] for r in later["rows"]] == [2.5, 3.0, 3.5]
        assert first["scene"]["start_sigma_m"] is None and first["status"]["snr_db"] is None
        assert later["revision"] == first["revision"] == 0
        # Rows that revise the track from t = 1.0 s on (the fusion re-sending a stretch, filtered) replace it.
        view.add_rows([dataclasses.replace(row, stage="filtered") for row in _rows(2, 4)])
        view.set_head(_rows(8, 10))
        revised = _get(view.url + "state.json")
        assert revised["revision"] == 1 and revised["total"] == 4
        assert [r["stage"] for r in revised["rows"]] == ["heading", "heading", "filtered", "filtered"]
        assert [r["t_s"] for r in revised["head"]] == [4.0, 4.5]
        with pytest.raises(urllib.error.HTTPError) as bad:
            _get(view.url + "state.json?since=x")
        assert bad.value.code == 400


def _browse(url: str, *options: str) -> str:
    """Open ``url`` in headless Chromium, let its scripts run for 3 s of virtual time, return its stdout."""
    command = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=800,600",
               "--virtual-time-budget=3000", *options, url]
    return subprocess.run(command, capture_output=True, text=True, timeout=120, check=True).stdout


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium on this machine (the distribution's `chromium` package)")
def test_page_draws_the_track_as_it_grows(tmp_path) -> None:
    """In a real browser: the page loads, polls, and the track has grown between two screenshots."""
    with LiveView() as view:
        view.set_scene(ViewScene(0.0, 0.0, 2.0, [45.0], [4000.0]))
        view.add_rows(_rows(0, 20))
        first = _browse(view.url, "--dump-dom")
        _browse(view.url, f"--screenshot={tmp_path / 'first.png'}")
        view.add_rows(_rows(20, 60))
        view.set_head(_rows(60, 64))
        later = _browse(view.url, "--dump-dom")
        _browse(view.url, f"--screenshot={tmp_path / 'later.png'}")
        view.add_rows([dataclasses.replace(row, stage="filtered") for row in _rows(50, 55)])
        revised = _browse(view.url, "--dump-dom")   # the page takes the whole track again on a revision
    assert re.search(r'id="track"[^>]*data-rows="20"', first)
    assert re.search(r'id="track"[^>]*data-rows="60"', later)
    last = _rows(63, 64)[0]   # the head's end is the newest position
    assert f"{last.lat_deg:.6f}, {last.lon_deg:.6f}" in later
    assert f"{last.ellipse_major_m:.1f} m" in later
    assert later.count("<ellipse") == 60
    assert len(re.search(r'id="head"[^>]*points="([^"]*)"', later).group(1).split()) == 5   # track end + 4
    assert re.search(r'id="track"[^>]*data-rows="55"', revised) and revised.count("<ellipse") == 55
    shots = [(tmp_path / name).read_bytes() for name in ("first.png", "later.png")]
    assert shots[0][:8] == b"\x89PNG\r\n\x1a\n" and shots[0] != shots[1]
