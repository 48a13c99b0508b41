"""``dtmbnav pdr --calibrate``: a walker's Weinberg gain from a walk of known length, and ``--walker`` (issue 59).

The tiny simulated walk is the calibration walk: its true length is the sum of its true steps. The profile
written from it must make ``pdr --walker`` walk that length again (within 2 %), whatever gain the sensors
file itself records; and the profile file must read back as written.
"""

from __future__ import annotations

import math
import tomllib

import h5py
import pytest
from conftest import TINY_WALK

from dtmbnav.cli import EXIT_OK, main
from dtmbnav.field.walker import WalkerProfile, read_walker_profile, write_walker_profile
from dtmbnav_core import schema
from dtmbnav_core.sensors import read_walk_truth
from sim.scenario import load_scenario, scenario_to_toml


def _run(capsys, *argv: str) -> str:
    code = main(list(argv))
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    return err


def _walked_m(path) -> float:
    with h5py.File(path, "r") as f:
        return float(f[schema.PDR]["step_length_m"][()].sum())


def test_a_calibrated_profile_walks_the_calibration_distance(tiny_walk_truth, tmp_path, capsys):
    distance_m = float(read_walk_truth(tiny_walk_truth).step_length_m.sum())
    walker = tmp_path / "walker.toml"
    err = _run(capsys, "pdr", str(tiny_walk_truth), "--calibrate", "--distance", f"{distance_m:.3f}", "-o", str(walker))
    profile = read_walker_profile(walker)
    assert f"Weinberg gain K = {profile.weinberg_k_m:.4f} m" in err
    assert profile.distance_m == pytest.approx(distance_m, abs=1e-3)
    assert profile.steps > 0 and profile.source == str(tiny_walk_truth) and profile.date.endswith("+00:00")
    # The profile's gain, not the one the sensors file records for the simulated walker, is the one used.
    _run(capsys, "pdr", str(tiny_walk_truth), "-o", str(tmp_path / "pdr.h5"), "--walker", str(walker))
    assert _walked_m(tmp_path / "pdr.h5") == pytest.approx(distance_m, rel=0.02)
    with h5py.File(tmp_path / "pdr.h5", "r") as f:
        assert f[schema.PDR].attrs["weinberg_k_m"] == profile.weinberg_k_m


def test_the_profile_reads_back_as_written(tmp_path):
    profile = WalkerProfile(weinberg_k_m=0.4712, distance_m=50.0, steps=68, source='walk "one".h5',
                            date="2026-12-07T05:00:00+00:00", k_by_carriage_m={"handheld": 0.47, "in pocket": 0.52})
    path = tmp_path / "walker.toml"
    write_walker_profile(path, profile)
    assert read_walker_profile(path) == profile
    doc = tomllib.loads(path.read_text())
    assert doc["weinberg_k_m"] == 0.4712 and doc["calibration"]["steps"] == 68


def test_a_profile_of_the_gain_alone_is_enough(tmp_path):
    path = tmp_path / "walker.toml"
    path.write_text("weinberg_k_m = 0.5\n")
    profile = read_walker_profile(path)
    assert profile.weinberg_k_m == 0.5 and math.isnan(profile.distance_m) and profile.k_by_carriage_m == {}


def test_each_carriage_keeps_its_own_gain(tiny_walk_truth, tmp_path, capsys):
    """Calibrating in the hand and in a trouser pocket builds one profile; each walk takes its carriage's gain."""
    pocket_toml = tmp_path / "pocket.toml"
    pocket_toml.write_text(scenario_to_toml(load_scenario(TINY_WALK).replace(imu={"carriage": "pocket"})))
    _run(capsys, "-q", "simulate", str(pocket_toml), "--no-iq", "-o", str(tmp_path / "pocket"))
    walks = {"steady": tiny_walk_truth, "swinging": tmp_path / "pocket" / "truth.h5"}
    distance_m = {name: float(read_walk_truth(path).step_length_m.sum()) for name, path in walks.items()}
    walker = tmp_path / "walker.toml"
    for name, path in walks.items():
        _run(capsys, "pdr", str(path), "--calibrate", "--distance", f"{distance_m[name]:.3f}", "-o", str(walker))
    profile = read_walker_profile(walker)
    assert set(profile.k_by_carriage_m) == {"steady", "swinging"}
    assert profile.weinberg_k_m == profile.k_by_carriage_m["swinging"]  # the latest calibration's
    # The pocket's swing moves the acceleration Weinberg's relation reads: one gain would not fit both
    # (the wrong one would miss by more than the 0.5 % below).
    assert abs(profile.k_by_carriage_m["swinging"] / profile.k_by_carriage_m["steady"] - 1.0) > 0.02
    for name, path in walks.items():
        _run(capsys, "pdr", str(path), "-o", str(tmp_path / f"{name}.h5"), "--walker", str(walker))
        assert _walked_m(tmp_path / f"{name}.h5") == pytest.approx(distance_m[name], rel=0.005)
        with h5py.File(tmp_path / f"{name}.h5", "r") as f:
            assert f[schema.PDR].attrs["carriage"] == name
            assert f[schema.PDR].attrs["weinberg_k_m"] == profile.k_by_carriage_m[name]


def test_calibrating_onto_a_file_that_is_no_profile_writes_nothing(tiny_walk_truth, tmp_path, capsys):
    other = tmp_path / "notes.toml"
    other.write_text('title = "not a walker"\n')
    assert main(["pdr", str(tiny_walk_truth), "--calibrate", "--distance", "12", "-o", str(other)]) != EXIT_OK
    assert "notes.toml" in capsys.readouterr().err
    assert other.read_text() == 'title = "not a walker"\n'
