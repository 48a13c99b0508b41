"""The walker (sim/walk.py), the GNSS simulator (sim/gnss.py) and the walk's HDF5 groups (sim/walk_io.py).

Physics checked against the scenario: the path passes the waypoints with
rounded corners, velocity is continuous, the standing periods and pauses
hold the walker still, step lengths follow the pace and tile the path, and
everything is reproducible from the seed.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core.h5io import atomic_h5
from dtmbnav_core.sensors import read_gnss, read_imu, read_walk_truth
from sim.gnss import simulate_gnss, simulate_start_fix
from sim.imu import simulate_imu
from sim.scenario import Scenario, WalkConfig, load_scenario
from sim.walk import START_STOP_ACCEL_MPS2, build_path, simulate_walk
from sim.walk_io import write_walk_groups


def _scenario(seed: int = 7, **walk) -> Scenario:
    base = {"waypoints_m": [[0.0, 0.0], [0.0, 30.0], [25.0, 30.0], [25.0, 60.0]], "corner_radius_m": 2.0,
            "start_still_s": 5.0, "end_still_s": 3.0}
    return Scenario(seed=seed).replace(walk={**base, **walk})


@pytest.fixture(scope="module")
def park_walk():
    scenario = load_scenario("park-loop-cw")
    return scenario, simulate_walk(scenario)


def test_rounded_corner_geometry():
    # A 90 deg corner with radius r shortens the path by 2r - r*pi/2 and passes r(sqrt2 - 1) inside the corner.
    r = 3.0
    path = build_path([[0.0, 0.0], [0.0, 20.0], [20.0, 20.0]], closed=False, corner_radius_m=r)
    assert path.total_m == pytest.approx(40.0 - (2 * r - r * np.pi / 2), abs=1e-9)
    x, y, heading = path.evaluate(np.array([0.0, path.waypoint_s_m[1], path.total_m]))
    assert (x[0], y[0]) == pytest.approx((0.0, 0.0))
    assert (x[2], y[2]) == pytest.approx((20.0, 20.0))
    # The corner's midpoint is r (sqrt 2 - 1) from the sharp corner, on its diagonal.
    assert np.hypot(x[1] - 0.0, y[1] - 20.0) == pytest.approx(r * (np.sqrt(2) - 1), rel=1e-9)
    assert heading[1] == pytest.approx(np.pi / 4)  # halfway through a right turn from north to east


@settings(max_examples=40, deadline=None)
@given(points=st.lists(st.tuples(st.integers(-50, 50), st.integers(-50, 50)), min_size=2, max_size=7, unique=True),
       radius=st.floats(0.0, 5.0), closed=st.booleans())
def test_any_polyline_gives_a_continuous_path_through_its_ends(points, radius, closed):
    waypoints = [[float(x), float(y)] for x, y in points]
    if any(a == b for a, b in zip(waypoints[1:], waypoints[:-1])):
        return
    if closed and len(waypoints) < 3:
        return
    path = build_path(waypoints, closed=closed, corner_radius_m=radius)
    polyline = np.vstack([waypoints, waypoints[:1]] if closed else waypoints)
    assert path.total_m <= np.sum(np.hypot(*np.diff(polyline, axis=0).T)) + 1e-9
    assert np.all(path.length_m >= -1e-9)
    s = np.concatenate([path.s0_m, [path.total_m]])
    x, y, heading = path.evaluate(s)
    assert (x[0], y[0]) == pytest.approx(tuple(polyline[0]), abs=1e-9)
    assert (x[-1], y[-1]) == pytest.approx(tuple(polyline[-1]), abs=1e-6)
    # Continuity at every junction between pieces: the end of one piece is the start of the next.
    ends = path.evaluate(np.maximum(path.s0_m[1:] - 1e-9, 0.0))
    assert ends[0] == pytest.approx(path.x0_m[1:], abs=1e-6)
    assert ends[1] == pytest.approx(path.y0_m[1:], abs=1e-6)


def test_path_heading_is_direction_of_travel():
    path = build_path([[0.0, 0.0], [10.0, 5.0], [3.0, 12.0], [-4.0, 2.0]], closed=True, corner_radius_m=1.5)
    s = np.linspace(0.0, path.total_m, 20001)
    x, y, heading = path.evaluate(s)
    ds = np.hypot(np.diff(x), np.diff(y))
    assert ds == pytest.approx(np.diff(s), rel=1e-6)  # parametrised by arc length
    travel = np.arctan2(np.diff(x), np.diff(y))
    mid_heading = path.evaluate(0.5 * (s[1:] + s[:-1]))[2]
    assert np.max(np.abs(np.angle(np.exp(1j * (travel - mid_heading))))) < 1e-4
    assert (x[-1], y[-1]) == pytest.approx((0.0, 0.0), abs=1e-9)  # a loop closes


def test_track_is_smooth_and_speed_is_consistent(park_walk):
    _, walk = park_walk
    tr = walk.track
    dt = 1.0 / walk.rate_hz
    velocity = np.column_stack([np.diff(tr.x_m), np.diff(tr.y_m)]) / dt
    acceleration = np.linalg.norm(np.diff(velocity, axis=0), axis=1) / dt
    # Setting off/stopping at 0.8 m/s^2, corners of 2 m at 1.3 m/s: 0.85 m/s^2; no jumps in velocity.
    assert acceleration.max() < 1.2
    chord_speed = np.linalg.norm(velocity, axis=1)
    assert chord_speed == pytest.approx(0.5 * (tr.speed_mps[1:] + tr.speed_mps[:-1]), abs=5e-3)
    moving = tr.speed_mps > 0.5
    travel = np.arctan2(np.gradient(tr.x_m), np.gradient(tr.y_m))
    assert np.max(np.abs(np.angle(np.exp(1j * (travel - tr.heading_rad)))[moving])) < np.radians(1.0)


def test_loop_length_start_and_end_still(park_walk):
    scenario, walk = park_walk
    tr = walk.track
    assert walk.path.total_m == pytest.approx(116.0, abs=1.0)  # docs/scenarios.md: a loop of about 116 m
    assert tr.t_s[0] == 0.0
    assert walk.walk_start_t_s == pytest.approx(scenario.walk.start_still_s)
    assert tr.t_s[-1] == pytest.approx(walk.walk_end_t_s + scenario.walk.end_still_s, abs=1.0 / walk.rate_hz)
    standing = (tr.t_s <= walk.walk_start_t_s) | (tr.t_s >= walk.walk_end_t_s)
    assert np.all(tr.speed_mps[standing] == 0.0)
    assert np.all(tr.x_m[standing] == pytest.approx(0.0, abs=1e-9))
    assert np.all(tr.y_m[standing] == pytest.approx(0.0, abs=1e-9))
    # Cruise speed as configured.
    assert np.median(tr.speed_mps[~standing]) == pytest.approx(scenario.walk.speed_mps, rel=1e-6)


def test_steps_tile_the_path_with_configured_length_and_jitter(park_walk):
    scenario, walk = park_walk
    cfg = scenario.walk
    assert walk.step_length_m.sum() == pytest.approx(walk.path.total_m, rel=1e-9)
    assert np.all(np.diff(walk.step_t_s) > 0)
    cruise = walk.step_length_m[5:-5]
    nominal = cfg.speed_mps / cfg.step_frequency_hz
    assert cruise.mean() == pytest.approx(nominal, rel=0.02)
    assert cruise.std() / cruise.mean() == pytest.approx(cfg.step_length_jitter, rel=0.3)
    cadence = 1.0 / np.median(np.diff(walk.step_t_s))
    assert cadence == pytest.approx(cfg.step_frequency_hz, rel=0.03)
    # Truth step length = path distance between heel strikes.
    s_at_strike = np.interp(walk.step_t_s, walk.track.t_s, walk.distance_m)
    assert np.diff(s_at_strike) == pytest.approx(walk.step_length_m[1:], abs=0.02)


def test_pause_holds_the_walker_at_the_waypoint():
    scenario = _scenario(pauses=[{"at_waypoint": 2, "duration_s": 6.0}])
    walk = simulate_walk(scenario)
    tr = walk.track
    standing = (tr.speed_mps == 0.0) & (tr.t_s > walk.walk_start_t_s) & (tr.t_s < walk.walk_end_t_s)
    assert np.count_nonzero(standing) / walk.rate_hz == pytest.approx(6.0, abs=0.05)
    x, y = tr.x_m[standing], tr.y_m[standing]
    assert np.ptp(x) < 1e-9 and np.ptp(y) < 1e-9
    assert np.hypot(x[0] - 25.0, y[0] - 30.0) < 2.0  # at the (rounded) corner of waypoint 2
    # No step spans the pause: the step before it ends on arrival, the next starts on departure.
    t_pause = tr.t_s[standing]
    assert not np.any((walk.step_start_t_s < t_pause[0]) & (walk.step_t_s > t_pause[-1]))
    assert walk.first_of_leg.sum() == 2
    # Each constant-acceleration ramp costs v / (2a) against cruising through: stop + restart = v / a.
    without = simulate_walk(_scenario())
    ramp_cost = scenario.walk.speed_mps / START_STOP_ACCEL_MPS2
    assert walk.walk_end_t_s - without.walk_end_t_s == pytest.approx(6.0 + ramp_cost, abs=0.02)


def test_pace_change_changes_speed_and_cadence():
    scenario = _scenario(speed_mps=1.4, step_frequency_hz=1.9,
                         pace_changes=[{"after_m": 40.0, "speed_mps": 0.9, "step_frequency_hz": 1.5}])
    walk = simulate_walk(scenario)
    s_strike = np.interp(walk.step_t_s, walk.track.t_s, walk.distance_m)
    before = (s_strike > 5.0) & (s_strike < 35.0)
    after = (s_strike > 45.0) & (s_strike < 75.0)
    steps_dt = np.diff(walk.step_t_s, prepend=np.nan)
    assert 1.0 / np.median(steps_dt[before]) == pytest.approx(1.9, rel=0.05)
    assert 1.0 / np.median(steps_dt[after]) == pytest.approx(1.5, rel=0.05)
    assert np.median(walk.step_length_m[before]) == pytest.approx(1.4 / 1.9, rel=0.05)
    assert np.median(walk.step_length_m[after]) == pytest.approx(0.9 / 1.5, rel=0.05)


def test_step_phase():
    walk = simulate_walk(_scenario())
    index, phase = walk.step_phase(np.array([0.0, walk.step_t_s[3], 0.5 * (walk.step_t_s[3] + walk.step_t_s[4])]))
    assert index.tolist() == [-1, 4, 4]
    assert phase[0] == 0.0 and phase[1] == pytest.approx(0.0) and phase[2] == pytest.approx(0.5)


def test_deterministic_from_seed():
    a, b, c = (simulate_walk(_scenario(seed=s)) for s in (3, 3, 4))
    assert np.array_equal(a.track.x_m, b.track.x_m) and np.array_equal(a.step_length_m, b.step_length_m)
    assert not np.array_equal(a.step_length_m, c.step_length_m[: len(a.step_length_m)])


@pytest.mark.parametrize("walk, message", [
    ({"waypoints_m": [[0.0, 0.0], [0.0, 0.0], [5.0, 5.0]]}, "coincide"),
    ({"waypoints_m": [[0.0, 0.0]]}, "at least two"),
    ({"pauses": [{"at_waypoint": 0, "duration_s": 2.0}]}, "interior waypoint"),
    ({"speed_mps": 0.0}, "speed_mps"),
])
def test_bad_walk_raises(walk, message):
    with pytest.raises(ValueError, match=message):
        simulate_walk(_scenario(**walk))


def test_gnss_start_fix_and_blocked_sky():
    scenario = load_scenario("street-out")
    walk = simulate_walk(scenario)
    gnss = simulate_gnss(scenario, walk)
    assert np.all(np.diff(gnss.t_s) == pytest.approx(1.0 / scenario.gnss.rate_hz))
    # Beside the tall block on the west of the first street (x = -8 m, y < 175 m) the sky is cut.
    y_true = np.interp(gnss.t_s, walk.track.t_s, walk.track.y_m)
    x_true = np.interp(gnss.t_s, walk.track.t_s, walk.track.x_m)
    near_block = (x_true < 5.0) & (y_true > 20.0) & (y_true < 150.0)
    open_sky = x_true > 120.0
    drop = gnss.cn0_dbhz[open_sky].mean() - gnss.cn0_dbhz[near_block].mean()
    assert drop > 0.5 * scenario.gnss.blocked_cn0_drop_db
    error = np.hypot(gnss.x_m - x_true, gnss.y_m - y_true)
    assert np.sqrt(np.mean(error[near_block] ** 2)) > np.sqrt(np.mean(error[open_sky] ** 2))
    # The start fix, made of the standstill's own fixes, errs about the true start by its stated sigma per axis:
    # over seeds, the normalised error has unit spread and no bias.
    fixes = [simulate_start_fix(seeded, walk, simulate_gnss(seeded, walk))
             for seeded in (scenario.replace(seed=s) for s in range(400))]
    normalised = np.array([[(f.x_m - walk.track.x_m[0]) / f.sigma_m, (f.y_m - walk.track.y_m[0]) / f.sigma_m]
                           for f in fixes])
    assert normalised.std(axis=0) == pytest.approx([1.0, 1.0], rel=0.15)
    assert normalised.mean(axis=0) == pytest.approx([0.0, 0.0], abs=0.2)


def test_walk_groups_round_trip(tmp_path):
    scenario = _scenario()
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    gnss = simulate_gnss(scenario, walk)
    path = tmp_path / "truth.h5"
    with atomic_h5(path) as f:
        write_walk_groups(f, scenario, walk, imu, gnss)
    truth = read_walk_truth(path)
    assert np.array_equal(truth.track.x_m, walk.track.x_m)
    assert np.array_equal(truth.step_length_m, walk.step_length_m)
    assert truth.walk_start_t_s == walk.walk_start_t_s
    imu_back = read_imu(path)
    assert np.array_equal(imu_back.gyro_radps, imu.gyro_radps)
    gnss_back, fix = read_gnss(path)
    assert np.array_equal(gnss_back.cn0_dbhz, gnss.cn0_dbhz)
    assert fix == simulate_start_fix(scenario, walk, gnss) == truth.start_fix


def test_readers_name_missing_groups(tmp_path):
    path = tmp_path / "empty.h5"
    with atomic_h5(path) as f:
        f.create_group("other")
    for reader, group in ((read_walk_truth, "truth/trajectory"), (read_imu, "imu"), (read_gnss, "gnss")):
        with pytest.raises(ValueError, match=group):
            reader(path)


def test_walk_config_defaults_make_a_walk():
    walk = simulate_walk(Scenario(walk=WalkConfig()))
    assert walk.path.total_m == pytest.approx(50.0)
