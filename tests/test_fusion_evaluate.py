"""Monte Carlo evaluation: the table's numbers against a chain with known PDR errors."""

import json

import numpy as np
import pytest
from fusion_synth import make_pdr, polyline_truth

from dtmbnav.evaluation import evaluate as ev
from fusion.metrics import error_stats, interpolate_track, place_pdr, position_errors_m, true_initial_heading_rad
from fusion.run import FusionConfig


def synthetic_chain(scenario, range_source, foot_imu=False):
    """Truth along the scenario's waypoints; PDR 15 % long with 2 deg heading noise; exact start fix."""
    walk = scenario.walk
    truth = polyline_truth(walk.waypoints_m + ([walk.waypoints_m[0]] if walk.closed else []),
                           speed_mps=walk.speed_mps, still_s=walk.start_still_s)
    pdr, _ = make_pdr(truth, walk.start_still_s, gain=1.15, heading_noise_rad=np.deg2rad(2.0), length_noise=0.03,
                      seed=scenario.seed)
    return ev.ChainOutput(truth=truth, pdr=pdr, start_fix_xy_m=(0.0, 0.0), walk_start_t_s=walk.start_still_s,
                          ranges=range_source(scenario, truth).ranges)


@pytest.fixture(scope="module")
def park_rows():
    """Two walks on the scenario file's layout (whose geometry the assertions below rely on)."""
    return ev.evaluate("park-loop-ccw", seeds=2, filters=("pf", "ukf"), config=FusionConfig(n_particles=500),
                       chain=synthetic_chain, vary_geometry=False)


def test_rows_hold_pdr_then_filters_with_paper_figures(park_rows):
    assert [r.filter for r in park_rows] == ["pdr", "pdr@fix", "pf", "ukf"]
    pdr, at_fix, pf, ukf = park_rows
    assert at_fix.reduction_95 is None and at_fix.paper_p95_m is None
    assert pdr.reduction_95 is None and pdr.paper_p95_m == 9.19
    assert pf.paper_p95_m == 5.41 and pf.paper_reduction_95 == 0.41
    assert ukf.paper_p95_m is None
    assert pf.reduction_95 == pytest.approx(1 - pf.p95_m / pdr.p95_m)
    assert pf.reduction_95_vs_fix == pytest.approx(1 - pf.p95_m / at_fix.p95_m)
    assert at_fix.reduction_95_vs_fix is None
    assert all(r.seeds == 2 and r.p68_m <= r.p95_m <= r.max_m for r in park_rows)


def test_pdr_row_is_the_true_start_true_heading_baseline(park_rows):
    scn = ev.load_scenario("park-loop-ccw")
    p95 = []
    for k in range(2):
        out = synthetic_chain(ev.seed_scenario(scn, k, vary_geometry=False), ev.obs_range_source)
        placed = place_pdr(out.pdr, 0.0, 0.0, true_initial_heading_rad(out.truth, out.walk_start_t_s))
        p95.append(error_stats(position_errors_m(placed, out.truth)).p95_m)
    assert park_rows[0].p95_m == pytest.approx(np.mean(p95))


def test_fusion_beats_the_pdr_on_a_gain_error(park_rows):
    pdr, _, pf, _ = park_rows
    assert pf.reduction_95 > 0.3
    assert pf.heading_error_median_deg < 5.0


def test_exact_level_feeds_the_true_range():
    """``level="exact"``: the range source is the direct path's range change, no error."""
    scn = ev.seed_scenario(ev.load_scenario("park-loop-ccw"), 0, vary_geometry=False)
    walk = scn.walk
    truth = polyline_truth(walk.waypoints_m + [walk.waypoints_m[0]], speed_mps=walk.speed_mps,
                           still_s=walk.start_still_s)
    ranges = ev.level_range_source("exact")(scn, truth).ranges
    tower = scn.tower
    at = interpolate_track(truth, ranges.t_s)
    r = np.hypot(np.hypot(at.x_m - tower.x_m, at.y_m - tower.y_m), tower.height_m - scn.channel.antenna_height_m)
    # The channel interpolates the track with a cubic spline: a millimetre from linear at the corners.
    np.testing.assert_allclose(ranges.range_change_m, r - r[0], atol=2e-3)
    rows = ev.evaluate("park-loop-ccw", seeds=1, filters=("pf",), config=FusionConfig(n_particles=500),
                       chain=synthetic_chain, vary_geometry=False, level="exact")
    assert rows[-1].level == "exact" and rows[-1].reduction_95 > 0.3


def test_walks_come_from_the_reporting_seeds_with_their_own_layout(park_rows):
    scn = ev.load_scenario("park-loop-ccw")
    assert ev.monte_carlo_seed(scn.seed, 1) == 1000 * scn.seed + ev.REPORTING_SEEDS.start + 1
    walk = ev.seed_scenario(scn, 1)
    assert walk.seed == ev.monte_carlo_seed(scn.seed, 1) and walk.tower != scn.tower
    assert walk.walk.waypoints_m[0] == scn.walk.waypoints_m[0] and walk.walk.waypoints_m != scn.walk.waypoints_m
    assert ev.seed_scenario(scn, 1, vary_geometry=False) == scn.replace(seed=walk.seed)
    assert all(r.first_seed == ev.REPORTING_SEEDS.start and r.level == "obs" and not r.geometry_varied
               for r in park_rows)


def test_table_and_json(park_rows):
    table = ev.format_table(park_rows)
    assert "park-loop-ccw" in table and "9.19" in table and "41%" in table
    first, last = ev.REPORTING_SEEDS.start, ev.REPORTING_SEEDS[-1]
    assert table.splitlines()[0].startswith(f"Monte Carlo indices {first}-{first + 1} (reporting range; "
                                            f"reporting range {first}-{last}, tuning range "
                                            f"{ev.TUNING_SEEDS.start}-{ev.TUNING_SEEDS[-1]}), obs level, "
                                            "the scenario file's layout")
    # Reductions carry a decimal: a 40.5 % cut must not print as the paper's 41 %.
    assert f"{100 * park_rows[2].reduction_95:5.1f}%" in table
    decoded = json.loads(ev.rows_to_json(park_rows))
    assert decoded[2]["filter"] == "pf" and decoded[2]["p95_m"] == pytest.approx(park_rows[2].p95_m)
    assert decoded[2]["first_seed"] == first and decoded[2]["level"] == "obs"
    assert decoded[2]["geometry_varied"] is False


def test_arguments_are_checked():
    with pytest.raises(ValueError, match="level"):
        ev.evaluate("park-loop-cw", seeds=1, level="rf")
    with pytest.raises(ValueError, match="seeds"):
        ev.evaluate("park-loop-cw", seeds=0)
    with pytest.raises(ValueError, match="Monte Carlo index"):
        ev.evaluate("park-loop-cw", seeds=2, first_seed=999)
    assert ev.expand_scenarios(["street", "x.toml"]) == ["street-out", "street-back", "x.toml"]
    assert ev.paper_figures("street-back").reduction_95 == 0.30 and ev.paper_figures("custom") is None


def test_worst_walk_against_its_own_pdr_at_the_fix():
    """worst@fix: the largest per-walk ratio of a filter's 95 % to that walk's pdr@fix 95 %, minus one."""
    def walk(pdr_m, at_fix_m, pf_m):
        errors = {"pdr": np.full(10, pdr_m), "pdr@fix": np.full(10, at_fix_m), "pf": np.full(10, pf_m)}
        return ev.SeedResult(truth=None, tracks={}, errors_m=errors, heading_error_rad=0.0)

    # Walk 1: the PF halves its PDR; walk 2: it is 25 % worse than its PDR. The mean hides walk 2.
    rows = ev.summarise("park-loop-cw", [walk(3.0, 2.0, 1.0), walk(3.0, 4.0, 5.0)])
    pdr, at_fix, pf = rows
    assert pf.worst_vs_fix == pytest.approx(0.25)
    assert pf.reduction_95_vs_fix == pytest.approx(0.0)
    assert pdr.worst_vs_fix is None and at_fix.worst_vs_fix is None
    assert "+25.0%" in ev.format_table(rows)
