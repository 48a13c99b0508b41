"""Observation-level range simulator: its errors against the true geometry, scene by scene."""

import numpy as np
import pytest
from fusion_synth import polyline_truth

from dtmbnav.core.gb20600 import PnMode
from fusion.metrics import interpolate_track
from fusion.model import Geometry
from sim.channel import segment_crosses_polygon
from sim.obs_range import ObsRangeConfig, si_phase_steps_kernel, si_phase_steps_reference, simulate_obs_range
from sim.scenario import load_scenario


def true_range_change(scenario, truth, t_s):
    at = interpolate_track(truth, t_s)
    tower = scenario.tower
    g = Geometry(truth.x_m[0], truth.y_m[0], tower.x_m, tower.y_m, tower.height_m - scenario.channel.antenna_height_m)
    return g.range_m(at.x_m, at.y_m) - g.start_range_m()


@pytest.fixture(scope="module")
def park():
    scn = load_scenario("park-loop-cw")
    truth = polyline_truth(scn.walk.waypoints_m + [scn.walk.waypoints_m[0]], still_s=scn.walk.start_still_s)
    return scn, truth, simulate_obs_range(scn, truth)


def test_line_of_sight_range_follows_the_geometry(park):
    scn, truth, rs = park
    err = rs.range_change_m - true_range_change(scn, truth, rs.t_s)
    still = rs.t_s < scn.walk.start_still_s
    assert np.abs(err[still]).max() < 0.05      # calibrated f_s: no drift while standing
    assert np.abs(err).max() < 0.5              # LOS: centimetre ripple + sub-metre clock wander
    assert rs.valid.mean() > 0.95
    assert np.median(rs.snr_db) == pytest.approx(scn.receiver.cn_db, abs=1.5)


def test_walking_towards_the_tower_shrinks_the_range():
    scn = load_scenario("park-loop-cw")
    bearing = np.arctan2(scn.tower.x_m, scn.tower.y_m)
    end = 40.0 * np.array([np.sin(bearing), np.cos(bearing)])
    truth = polyline_truth([[0.0, 0.0], end.tolist()], still_s=10.0)
    rs = simulate_obs_range(scn, truth)
    assert rs.range_change_m[-1] == pytest.approx(-40.0 * np.cos(np.arctan2(150.0 - 1.2, 2973.0)), abs=0.3)


def test_sample_rate_is_the_frame_rate_over_the_decimation(park):
    scn, truth, rs = park
    frame_s = PnMode.PN420.value.frame_duration_s
    np.testing.assert_allclose(np.diff(rs.t_s), 8 * frame_s)
    short = polyline_truth([[0, 0], [0, 3]], still_s=scn.walk.start_still_s)
    full = simulate_obs_range(scn, short, ObsRangeConfig(decimation=1))
    assert 1.0 / np.median(np.diff(full.t_s)) == pytest.approx(1800.0)


def test_same_seed_same_output_and_seed_matters(park):
    scn, truth, rs = park
    again = simulate_obs_range(scn, truth)
    other = simulate_obs_range(scn.replace(seed=scn.seed + 1), truth)
    assert np.array_equal(rs.range_change_m, again.range_change_m)
    assert not np.array_equal(rs.range_change_m, other.range_change_m)


def test_free_running_clock_breaks_the_method(park):
    scn, truth, _ = park
    free = scn.replace(receiver={"clock": {"preset": "free-running"}})
    rs = simulate_obs_range(free, truth)
    err = rs.range_change_m - true_range_change(free, truth, rs.t_s)
    assert np.abs(err).max() > 5.0


def test_blocked_line_of_sight_biases_range_and_lowers_snr():
    scn = load_scenario("street-out")
    truth = polyline_truth(scn.walk.waypoints_m, still_s=scn.walk.start_still_s)
    rs = simulate_obs_range(scn, truth)
    err = rs.range_change_m - true_range_change(scn, truth, rs.t_s)
    at = interpolate_track(truth, rs.t_s)
    blocked = np.zeros(len(rs.t_s), bool)
    for b in scn.channel.buildings:
        blocked |= segment_crosses_polygon(at.x_m, at.y_m, scn.tower.x_m, scn.tower.y_m, b.polygon_m)
    assert blocked.mean() > 0.3 and (~blocked).mean() > 0.05
    assert np.median(rs.snr_db[blocked]) < np.median(rs.snr_db[~blocked]) - 5.0
    # The range drifts while a reflection sets the phase: far larger than the LOS ripple.
    assert np.abs(err[blocked]).max() > 2.0


def test_si_phase_kernel_matches_reference():
    rng = np.random.default_rng(0)
    coef = rng.normal(size=(4, 300)) + 1j * rng.normal(size=(4, 300))
    delay = 1e-5 + rng.uniform(0, 2e-6, (4, 300))
    baseband = np.linspace(-36e3, 36e3, 36)
    for a, b in zip(si_phase_steps_kernel(coef, delay, baseband), si_phase_steps_reference(coef, delay, baseband)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_segment_polygon_crossing():
    square = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
    ax = np.array([-1.0, -1.0, 2.0])
    ay = np.array([0.5, 2.0, 0.5])
    assert segment_crosses_polygon(ax, ay, 3.0, 0.5, square).tolist() == [True, False, False]


def test_bad_config_raises(park):
    scn, truth, _ = park
    with pytest.raises(ValueError, match="decimation"):
        simulate_obs_range(scn, truth, ObsRangeConfig(decimation=0))
    with pytest.raises(ValueError, match="calibration window"):
        simulate_obs_range(scn, polyline_truth([[0, 0], [0, 3]], still_s=2.0))
    with pytest.raises(ValueError, match="preset"):
        simulate_obs_range(scn.replace(receiver={"clock": {"preset": "atomic"}}), truth)
