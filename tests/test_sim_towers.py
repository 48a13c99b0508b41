"""Several towers (a single-frequency network) in the simulator: the scenario format, every tower's
paths in the channel, and the per-path truth (``/truth/paths``)."""

import tomllib

import numpy as np
import pytest

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import Track
from sim.channel import DIFFUSE, DIRECT, GROUND, PATH_KINDS, WALL, Channel
from sim.path_truth import PATH_TRUTH_RATE_HZ, path_truth
from sim.rf import CaptureGenerator
from sim.scenario import TowerSite, load_scenario, scenario_from_dict, scenario_to_toml
from sim.walk import simulate_walk

TOWERS = [{"x_m": -300.0, "y_m": 3000.0}, {"x_m": 4000.0, "y_m": -1000.0, "height_m": 100.0, "power_db": -6.0,
                                            "transmit_delay_s": 2e-6}]


def straight_walk(seconds=20.0, speed_mps=1.3, rate_hz=100.0):
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    return Track(t, np.zeros(len(t)), speed_mps * t, np.zeros(len(t)), np.full(len(t), speed_mps))


def two_tower_scene(**channel):
    return load_scenario("park-loop-cw").replace(towers=TOWERS, channel={"rician_k_db": None, **channel})


def test_towers_table_parses_round_trips_and_sets_the_first_site():
    scn = load_scenario("sfn-park")
    assert len(scn.sites) == 2 and scn.tower.x_m == scn.sites[0].x_m and scn.tower.y_m == scn.sites[0].y_m
    assert scn.sites[1].transmit_delay_s == 0.5e-6 and scn.receiver.clock.preset == "free-running"
    assert scenario_from_dict(tomllib.loads(scenario_to_toml(scn))) == scn
    # The single-tower format is unchanged: one site, from [tower].
    single = load_scenario("street-out")
    assert single.towers == [] and single.sites == [TowerSite(-2600.0, 1500.0, 150.0)]
    assert "[[towers]]" not in scenario_to_toml(single)
    assert scenario_from_dict(tomllib.loads(scenario_to_toml(single))) == single


def test_a_site_given_twice_or_a_bad_tower_is_an_error():
    with pytest.raises(ValueError, match=r"\[tower\].*x_m.*\[\[towers\]\]"):
        scenario_from_dict({"tower": {"x_m": 1.0}, "towers": [{"x_m": 2.0, "y_m": 3.0}]})
    with pytest.raises(ValueError, match="unknown key"):
        scenario_from_dict({"towers": [{"x_m": 2.0, "gain": 3.0}]})
    with pytest.raises(ValueError, match="transmit_delay_s"):
        scenario_from_dict({"towers": [{"x_m": 2.0, "transmit_delay_s": -1e-6}]})
    with pytest.raises(ValueError, match="towers"):
        load_scenario("sfn-park").replace(tower={"x_m": 0.0})


def test_every_tower_has_its_own_paths_with_power_and_transmit_delay():
    track = straight_walk()
    scn = two_tower_scene(ground_reflection=True, walls=[{"start_m": [20.0, -100.0], "end_m": [20.0, 400.0],
                                                          "gain_db": -3.0}])
    channel = Channel(scn, track, np.random.default_rng(0))
    assert channel.num_towers == 2
    assert list(channel.path_tower) == [0, 0, 0, 1, 1, 1]
    assert [PATH_KINDS[k] for k in channel.path_kind] == ["direct", "ground", "wall"] * 2
    t = track.t_s[::100]
    state = channel.state(t)
    b = TOWERS[1]
    length_b = np.hypot(np.hypot(b["x_m"] - 0.0, b["y_m"] - track.y_m[::100]), b["height_m"] - 1.2)
    np.testing.assert_allclose(state.delay_s[3], length_b / SPEED_OF_LIGHT_MPS + 2e-6, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.abs(state.coef[3]), 10 ** (-6.0 / 20))
    # The same wall reflects each tower by its own image (tower B east of the wall: no reflection).
    assert np.all(np.abs(state.coef[2]) > 0.5) and np.all(state.coef[5] == 0.0)
    np.testing.assert_allclose(channel.direct(t, tower=1).range_m, length_b, rtol=0, atol=1e-6)
    # Tower A's paths are exactly the single-tower scenario's.
    single = Channel(scn.replace(towers=[TOWERS[0]]), track, np.random.default_rng(0)).state(t)
    np.testing.assert_array_equal(state.delay_s[:3], single.delay_s)
    np.testing.assert_array_equal(state.coef[:3], single.coef)


def test_blockage_attenuates_each_towers_direct_path_by_its_own_line_of_sight():
    # A block to the NW cuts the line to tower A (NNW) until the line passes the block's corner
    # (-40, 420), 23.08 m into the walk; tower B (ESE) stays in view.
    block = {"polygon_m": [[-45.0, 0.0], [-40.0, 0.0], [-40.0, 420.0], [-45.0, 420.0]], "attenuation_db": 18.0}
    scn = two_tower_scene(ground_reflection=False, buildings=[block])
    track = straight_walk()
    state = Channel(scn, track, np.random.default_rng(0)).state(track.t_s)
    a, b = np.abs(state.coef[0]), np.abs(state.coef[1])
    assert np.all(b == pytest.approx(10 ** (-6.0 / 20)))
    # Blocked, not removed: 18 dB down, still there.
    np.testing.assert_allclose(20 * np.log10(a), np.where(track.y_m < 20.0 / (1.0 - 40.0 / 300.0), -18.0, 0.0), atol=1e-9)


def test_path_truth_matches_the_frame_truth_and_the_geometry():
    scn = load_scenario("street-out-sfn")
    walk = simulate_walk(scn)
    gen = CaptureGenerator(scn, walk.track, start_s=40.0, seconds=1.0)
    truth = path_truth(gen)
    n_paths = gen.num_paths
    assert len(truth) == n_paths * round(PATH_TRUTH_RATE_HZ)
    assert set(truth.tower_id) == {0, 1} and set(truth.kind) >= {DIRECT, GROUND, WALL, DIFFUSE}
    direct0 = (truth.tower_id == 0) & (truth.kind == DIRECT)
    frames = gen.frame_truth()
    # The first tower's direct path is the frame truth's (Doppler and range, interpolated to its epochs).
    np.testing.assert_allclose(truth.doppler_hz[direct0], np.interp(truth.t_s[direct0], frames.t_s, frames.doppler_hz),
                               atol=2e-3)
    np.testing.assert_allclose(truth.range_m[direct0], np.interp(truth.t_s[direct0], frames.t_s, frames.range_m),
                               atol=1e-3)
    # Tower B is about 1.6 km farther: 41 chips later, 4 dB weaker, and in view.
    direct1 = (truth.tower_id == 1) & (truth.kind == DIRECT)
    lag = (truth.delay_s[direct1] - truth.delay_s[direct0]) * 7.56e6
    assert np.all((lag > 38) & (lag < 44)) and np.all(np.abs(truth.power_db[direct1] + 4.0) < 1e-4)
    # The Doppler is the rate of the path length.
    for path in range(n_paths):
        rows = truth.path_index == path
        rate = np.gradient(truth.range_m[rows], truth.t_s[rows])
        np.testing.assert_allclose(-truth.doppler_hz[rows][1:-1] * SPEED_OF_LIGHT_MPS / gen.carrier_hz,
                                   rate[1:-1], atol=0.02)
