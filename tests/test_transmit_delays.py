"""SFN transmit delay offsets: the simulator's per-walk draw, the code difference as a receiver sees it, and the
fusion's three ways of taking the offsets out (plan, exact, estimated at the start fix) against truth."""

import dataclasses

import numpy as np
import pytest
from fusion_synth import exact_paths, park_like_walk

from dtmbnav.evaluation.evaluate import load_evaluation_scenario, scenario_transmit_delays, with_transmit_delays
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from fusion.observations import aggregate_paths, epoch_times
from fusion.run import FusionConfig
from fusion.transmit_delays import TransmitDelays, start_difference_gradient_m, tie_code_differences
from sim.scenario import load_scenario

SECOND_TOWER = ((-1560.0, -4285.0, 120.0),)
#: c (tx_1 - tx_0) of the synthetic network, m: 0.5 us.
OFFSET_M = 0.5e-6 * SPEED_OF_LIGHT_MPS


def coded_walk(code_noise_m: float = 0.3, seed: int = 5, late_s: float | None = None):
    """The synthetic park walk in a two-tower SFN whose difference carries the code a receiver measures: the true
    range difference, the transmit delay offsets' difference and noise. ``late_s``: the difference is not
    tracked before that time."""
    walk = park_like_walk(seed=0, other_towers=SECOND_TOWER)
    g = walk.geometry
    paths = exact_paths(walk, first_path=False)
    difference = paths.differences[1]
    x, y = (np.interp(difference.t_s, walk.truth.t_s, v) for v in (walk.truth.x_m, walk.truth.y_m))
    rng = np.random.default_rng(seed)
    code = g.range_m(x, y, 1) - g.range_m(x, y, 0) + OFFSET_M + code_noise_m * rng.standard_normal(len(x))
    valid = difference.valid.copy()
    if late_s is not None:
        valid &= difference.t_s >= late_s
    coded = dataclasses.replace(difference, code_range_m=code, valid=valid)
    return walk, dataclasses.replace(paths, differences={1: coded})


def tied(walk, paths, geometry, known):
    config = FusionConfig()
    t = epoch_times(walk.pdr.t_s, 0.0, config.standstills)
    return tie_code_differences(aggregate_paths(paths, t, geometry.n_towers), geometry, known,
                                float(walk.pdr.t_s[0]), 1.5)


def test_known_offsets_are_taken_out_with_their_sigma():
    walk, paths = coded_walk()
    plan = TransmitDelays((0.2e-6, 0.7e-6), (100e-9, 100e-9), "plan")
    epochs, offsets = tied(walk, paths, walk.geometry, plan)
    assert offsets.source == ("plan",)
    assert offsets.offset_m[0] == pytest.approx(OFFSET_M)
    assert offsets.sigma_m[0] == pytest.approx(np.sqrt(2.0) * 100e-9 * SPEED_OF_LIGHT_MPS)
    np.testing.assert_array_equal(epochs.range_difference_code_sigma_m[:, 0], offsets.sigma_m[0])
    # What is left is the range difference at the epochs, to the code's noise.
    g = walk.geometry
    x, y = (np.interp(epochs.t_s, walk.truth.t_s, v) for v in (walk.truth.x_m, walk.truth.y_m))
    left = epochs.range_difference_code_m[:, 0] - (g.range_m(x, y, 1) - g.range_m(x, y, 0))
    assert np.nanmax(np.abs(left)) < 0.5
    with pytest.raises(ValueError, match="one per tower"):
        tied(walk, paths, walk.geometry, TransmitDelays((0.0,), (0.0,)))


@pytest.mark.parametrize("fix_error_m", [(0.0, 0.0), (2.0, -1.0), (-1.5, 1.5)])
def test_the_start_fix_estimate_is_off_by_the_fix_error_seen_along_the_hyperbola(fix_error_m):
    """Unknown offsets, estimated while the walker stands at the fix: the estimate's error is the fix's error
    projected on the gradient of r_1 - r_0, and the stated sigma (fix sigma times the gradient's norm) holds it."""
    walk, paths = coded_walk()
    g = walk.geometry
    at_fix = dataclasses.replace(g, start_x_m=g.start_x_m + fix_error_m[0], start_y_m=g.start_y_m + fix_error_m[1])
    _, offsets = tied(walk, paths, at_fix, None)
    assert offsets.source == ("start fix",)
    projected = (at_fix.start_range_m(1) - at_fix.start_range_m(0)) - (g.start_range_m(1) - g.start_range_m(0))
    assert offsets.offset_m[0] == pytest.approx(OFFSET_M - projected, abs=0.05)
    assert offsets.sigma_m[0] == pytest.approx(1.5 * start_difference_gradient_m(at_fix, 1), rel=0.01)
    assert abs(offsets.offset_m[0] - OFFSET_M) <= 3.0 * offsets.sigma_m[0] + 1e-9
    assert 0.0 < start_difference_gradient_m(g, 1) <= 2.0


def test_a_difference_first_tracked_after_the_first_step_stays_unknown():
    walk, paths = coded_walk(late_s=None)
    first_step = float(walk.pdr.t_s[0])
    walk_late, late = coded_walk(late_s=first_step + 5.0)
    epochs, offsets = tied(walk_late, late, walk_late.geometry, None)
    assert offsets.source == ("unknown",) and np.isnan(offsets.offset_m[0]) and np.isinf(offsets.sigma_m[0])
    assert np.isinf(epochs.range_difference_code_sigma_m).all()
    assert "unknown" in offsets.describe()
    _, on_time = tied(walk, paths, walk.geometry, None)
    assert "start fix" in on_time.describe()


def test_the_simulator_draws_each_walks_offsets_about_the_plan():
    """Each site's offset is the plan's plus its own N(0, plan_error_s) draw, a function of the walk's seed alone:
    over 400 seeds the draws spread by plan_error_s about the plan, two sites' draws are uncorrelated (so their
    difference, what a receiver sees of an SFN, spreads by sqrt(2) plan_error_s), and the same walk with another
    receiver, or asked again, keeps its offsets."""
    scenario = load_scenario("sfn-park")
    sigma = scenario.network.plan_error_s
    plan = np.array([site.transmit_delay_s for site in scenario.sites])
    assert sigma > 0.0 and len(plan) == 2
    draws = np.array([scenario.replace(seed=seed).transmit_delays_s() - plan for seed in range(400)])
    assert np.std(draws) == pytest.approx(sigma, rel=0.1)
    assert abs(np.mean(draws)) < 3.0 * sigma / np.sqrt(draws.size)
    # 400 uncorrelated pairs keep |r| below 3 / sqrt(400); one draw shared by both sites would give r = 1 and a
    # difference exactly the plan's.
    assert abs(np.corrcoef(draws[:, 0], draws[:, 1])[0, 1]) < 0.15
    assert np.std(draws[:, 1] - draws[:, 0]) == pytest.approx(np.sqrt(2.0) * sigma, rel=0.1)
    walk = scenario.replace(seed=7)
    offsets = walk.transmit_delays_s()
    np.testing.assert_array_equal(walk.replace(receiver={"cn_db": 3.0, "sample_rate_hz": 10e6}).transmit_delays_s(),
                                  offsets)
    np.testing.assert_array_equal(walk.transmit_delays_s(), offsets)
    assert not np.array_equal(scenario.replace(seed=8).transmit_delays_s(), offsets)
    exact = scenario.replace(network={"plan_error_s": 0.0})
    np.testing.assert_array_equal(exact.transmit_delays_s(), plan)


def test_what_the_fusion_is_given_follows_the_scenarios_network_knowledge():
    scenario = load_scenario("sfn-park").replace(seed=4)
    assert scenario.network.known == "unknown" and scenario_transmit_delays(scenario) is None
    plan = scenario_transmit_delays(with_transmit_delays(scenario, "plan"))
    assert plan.delays_s == tuple(site.transmit_delay_s for site in scenario.sites)
    assert plan.sigmas_s == (scenario.network.plan_error_s,) * 2
    exact = with_transmit_delays(scenario, "exact")
    assert exact.name == "sfn-park (delays exact)"
    assert scenario_transmit_delays(exact).delays_s == tuple(scenario.transmit_delays_s())
    assert scenario_transmit_delays(load_scenario("park-loop-cw")) is None          # one tower
    named = load_evaluation_scenario("sfn-park (delays plan)")                    # a results table's row name
    assert named.name == "sfn-park (delays plan)" and named.network.known == "plan"
    assert load_evaluation_scenario("sfn-park") == load_scenario("sfn-park")
    with pytest.raises(ValueError, match="network.known"):
        scenario.replace(network={"known": "guess"})


def test_the_observation_model_codes_hold_the_true_offsets():
    """The observation model's tower difference code, like a receiver's, is the range difference plus
    c (tx_1 - tx_0) of the walk's true offsets (not the plan's)."""
    from sim.obs_paths import simulate_obs_paths
    from sim.walk import simulate_walk

    scenario = load_scenario("sfn-park").replace(seed=301104, network={"plan_error_s": 1e-6})
    truth = simulate_walk(scenario).track
    paths = simulate_obs_paths(scenario, truth)
    difference = paths.differences[1]
    sites = scenario.sites
    x, y = (np.interp(difference.t_s, truth.t_s, v) for v in (truth.x_m, truth.y_m))
    antenna = scenario.channel.antenna_height_m

    def distance(k):
        return np.sqrt((x - sites[k].x_m) ** 2 + (y - sites[k].y_m) ** 2 + (sites[k].height_m - antenna) ** 2)

    true = scenario.transmit_delays_s()
    left = difference.code_range_m - (distance(1) - distance(0))
    offset_m = SPEED_OF_LIGHT_MPS * (true[1] - true[0])
    assert np.nanmedian(left) == pytest.approx(offset_m, abs=1.0)
    plan_m = SPEED_OF_LIGHT_MPS * (sites[1].transmit_delay_s - sites[0].transmit_delay_s)
    assert abs(offset_m - plan_m) > 5.0          # the draw moved it, so the test can tell the two apart
