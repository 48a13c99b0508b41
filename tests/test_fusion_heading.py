"""Initial heading from the range constraint (eq. 14-15) against walks with a known heading."""

import numpy as np
import pytest
from fusion_synth import make_pdr, park_like_walk, polyline_truth
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fusion.heading_init import COST_FLOOR_M, predicted_range_change, rotate_pdr, solve_initial_heading
from fusion.metrics import heading_error_rad
from fusion.model import Geometry

GEOMETRY = Geometry(0.0, 0.0, 2000.0, 2200.0, 150.0)
#: An SFN: GEOMETRY's tower and a second one at another bearing.
SFN = Geometry(0.0, 0.0, 2000.0, 2200.0, 150.0, other_towers=((-1560.0, -4285.0, 120.0),))


def drifting_clock_m(t_s):
    """A free-running TCXO's drift, integrated: a range error common to every tower's range, m."""
    return 0.05 * (t_s - t_s[0]) ** 1.5


def measured_range(walk_or_pdr_xy, heading_rad, geometry=GEOMETRY, scale=1.0):
    """Exact range change of a relative track placed at P0 with a heading and scale."""
    x, y = walk_or_pdr_xy
    return predicted_range_change(heading_rad, scale * x, scale * y, geometry)


def test_rotate_pdr_follows_the_clockwise_convention():
    # A step north in the PDR frame becomes a step east after a +90 deg (clockwise) rotation.
    x, y = rotate_pdr(np.array([0.0]), np.array([1.0]), np.pi / 2)
    np.testing.assert_allclose([x[0], y[0]], [1.0, 0.0], atol=1e-12)


@given(st.floats(0.0, 2 * np.pi - 1e-3))
@example(0.703125)  # 0.3 deg from a grid point: the refinement once stalled on the grid point
@settings(max_examples=25, deadline=None)
def test_recovers_any_heading_from_an_error_free_pdr(true_heading):
    walk = park_like_walk()
    pdr = walk.pdr
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured_range((pdr.x_m, pdr.y_m), true_heading),
                                GEOMETRY, scale_bounds=None, max_duration_s=None)
    assert heading_error_rad(sol.heading_rad, true_heading) < np.deg2rad(0.05)
    assert sol.costs_m[0] < 1e-3


@given(st.floats(0.0, 2 * np.pi - 1e-3))
@settings(max_examples=15, deadline=None)
def test_a_tower_difference_gives_the_heading_where_a_drifting_clock_ruins_the_range(true_heading):
    """SFN (docs/paths.md): the difference of two towers' ranges carries no receiver clock; eq. 15 on it."""
    pdr = park_like_walk().pdr
    x, y = pdr.x_m, pdr.y_m
    difference = predicted_range_change(true_heading, x, y, SFN, difference_tower=1)
    clock_m = drifting_clock_m(pdr.t_s)
    sol = solve_initial_heading(pdr.t_s, x, y, difference, SFN, difference_tower=1, max_duration_s=None)
    assert heading_error_rad(sol.heading_rad, true_heading) < np.deg2rad(0.1)
    # The same difference from the two ranges, each with the clock in it, equals the clock-free one ...
    one = predicted_range_change(true_heading, x, y, SFN) + clock_m
    moved = rotate_pdr(x, y, true_heading)
    other = SFN.range_m(moved[0], moved[1], 1) - SFN.start_range_m(1) + clock_m
    np.testing.assert_allclose(other - one, difference, atol=1e-9)
    # ... while no heading explains the first tower's range with the clock in it (the fit's rms
    # residual is metres; the difference's is nil). How far off its heading lands depends on the
    # heading (the bias passes through zero near 170 deg): the next test measures that.
    biased = solve_initial_heading(pdr.t_s, x, y, one, SFN, max_duration_s=None)
    assert sol.costs_m[0] < 1e-3
    assert biased.costs_m[0] > 5.0


def test_a_drifting_clock_throws_the_single_tower_heading_off():
    """Over 24 headings round the circle the clock-drifted range's eq. 15 heading is > 2 deg off at nearly all."""
    pdr = park_like_walk().pdr
    clock_m = drifting_clock_m(pdr.t_s)
    headings = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    errors = [heading_error_rad(solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m,
                                                      predicted_range_change(h, pdr.x_m, pdr.y_m, SFN) + clock_m,
                                                      SFN, max_duration_s=None).heading_rad, h)
              for h in headings]
    assert np.median(errors) > np.deg2rad(10.0)
    assert np.mean(np.asarray(errors) > np.deg2rad(2.0)) > 0.9


def test_symmetric_walk_reports_both_mirror_minima():
    """A straight walk: headings beta and 2*theta_b - beta give the same range change."""
    truth = polyline_truth([[0, 0], [0, 60]])
    pdr, _ = make_pdr(truth, 10.0)
    bearing = np.arctan2(2000.0, 2200.0)  # tower bearing from P0, clockwise from north
    flat = Geometry(0.0, 0.0, 2000.0, 2200.0, 0.0)
    true_heading = bearing + np.deg2rad(50.0)
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured_range((pdr.x_m, pdr.y_m), true_heading, flat),
                                flat, scale_bounds=None, max_duration_s=None)
    mirror = 2 * bearing - true_heading
    best_two = sol.minima_rad[:2]
    assert min(heading_error_rad(best_two, true_heading)) < np.deg2rad(0.1)
    assert min(heading_error_rad(best_two, mirror)) < np.deg2rad(0.1)
    assert sol.confidence < 0.05


def test_asymmetric_loop_is_confident():
    walk = park_like_walk()
    pdr = walk.pdr
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured_range((pdr.x_m, pdr.y_m), 1.0), GEOMETRY,
                                max_duration_s=None)
    assert sol.confidence > 0.5


def test_joint_scale_removes_the_step_gain_bias():
    """PDR steps 15 % too long: the literal eq. 15 is biased, the scale-aware solve is not."""
    walk = park_like_walk(gain=1.15)
    pdr = walk.pdr
    true_heading = walk.initial_heading_rad
    measured = measured_range((walk.pdr.x_m / 1.15, walk.pdr.y_m / 1.15), true_heading)
    literal = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, scale_bounds=None,
                                    max_duration_s=None)
    joint = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=None)
    assert heading_error_rad(literal.heading_rad, true_heading) > np.deg2rad(3.0)
    assert heading_error_rad(joint.heading_rad, true_heading) < np.deg2rad(0.2)
    assert joint.scales[0] == pytest.approx(1 / 1.15, rel=0.01)


def test_missing_ranges_are_skipped_and_window_limits_epochs():
    walk = park_like_walk()
    pdr = walk.pdr
    measured = measured_range((pdr.x_m, pdr.y_m), 2.0)
    measured[::3] = np.nan
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=30.0)
    assert heading_error_rad(sol.heading_rad, 2.0) < np.deg2rad(0.1)
    within = (pdr.t_s <= pdr.t_s[0] + 30.0) & np.isfinite(measured)
    assert sol.n_used == within.sum()


def test_straight_start_widens_the_window_until_the_mirror_is_resolved():
    """80 m straight (about a minute) before the first turn: 45 s of it fit the mirror as well as the truth."""
    truth = polyline_truth([[0, 0], [0, 80], [60, 80], [60, 120]])
    pdr, _ = make_pdr(truth, 10.0)
    flat = Geometry(0.0, 0.0, 2000.0, 2200.0, 0.0)
    true_heading = np.arctan2(2000.0, 2200.0) + np.deg2rad(50.0)
    measured = measured_range((pdr.x_m, pdr.y_m), true_heading, flat)
    first = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, flat, max_duration_s=45.0, min_confidence=0.0)
    assert first.confidence < 0.05                                   # a straight leg: truth and mirror tie
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, flat, max_duration_s=45.0)
    assert sol.confidence >= 0.3 and sol.n_used > first.n_used
    assert heading_error_rad(sol.heading_rad, true_heading) < np.deg2rad(0.2)


def test_mirror_and_truth_both_within_the_noise_floor_tie():
    """A straight leg walked across the line to the tower, its range over the first 45 s the mirror's (a few cm off
    the truth's, as a PDR's wobble and the range noise make it on a street): mirror 0.00 m, truth 0.02 m. Both are
    below the cost floor, so they tie and the window widens to the turn; read as a confidence of 0.42 they chose
    the mirror, 180 deg off (street-out tuning walk 107)."""
    truth = polyline_truth([[0, 0], [0.12, 40], [0, 80], [60, 80], [60, 120]])
    pdr, _ = make_pdr(truth, 10.0)
    flat = Geometry(0.0, 0.0, 2000.0, 2200.0, 0.0)
    across = np.arctan2(2000.0, 2200.0) + np.pi / 2
    exact = measured_range((pdr.x_m, pdr.y_m), across, flat)
    mirror_error = measured_range((pdr.x_m, pdr.y_m), across - np.pi, flat) - exact
    early = pdr.t_s <= pdr.t_s[0] + 45.0
    measured = exact + np.where(early, mirror_error, mirror_error[early][-1])
    first = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, flat, max_duration_s=45.0, min_confidence=0.0)
    assert first.costs_m[1] < COST_FLOOR_M and first.confidence == 0.0
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, flat, max_duration_s=45.0)
    assert sol.n_used > first.n_used
    assert heading_error_rad(sol.heading_rad, across) < np.deg2rad(0.5)


def test_a_range_jump_across_a_gap_gets_a_free_offset():
    """After a stretch without range the range returns 10 m off: the later run's offset is free, the fit exact."""
    walk = park_like_walk()
    pdr = walk.pdr
    measured = measured_range((pdr.x_m, pdr.y_m), 2.0)
    gap = (pdr.t_s > 40.0) & (pdr.t_s < 50.0)
    measured[gap] = np.nan
    measured[pdr.t_s >= 50.0] += 10.0
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=None)
    assert heading_error_rad(sol.heading_rad, 2.0) < np.deg2rad(0.1)
    assert sol.costs_m[0] < 1e-3


def test_bad_input_raises():
    with pytest.raises(ValueError, match="differ in length"):
        solve_initial_heading(np.zeros(5), np.zeros(5), np.zeros(4), np.zeros(5), GEOMETRY)
    with pytest.raises(ValueError, match="does not constrain the heading"):
        solve_initial_heading(np.arange(5.0), np.zeros(5), np.zeros(5), np.full(5, np.nan), GEOMETRY)


def isolated_epochs(t_s, every=15):
    """True at every ``every``-th epoch only: each a run of one after a gap (a range that comes and goes)."""
    return np.arange(len(t_s)) % every == every // 2


def test_isolated_epochs_after_gaps_do_not_make_a_heading():
    """Each epoch after a gap has a free offset, so single ones fit every heading: no heading at all."""
    walk = park_like_walk()
    pdr = walk.pdr
    measured = measured_range((pdr.x_m, pdr.y_m), 2.0)
    measured[~isolated_epochs(pdr.t_s)] = np.nan
    with pytest.raises(ValueError, match="does not constrain the heading"):
        solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=None)


def test_a_window_of_isolated_epochs_widens_to_the_first_run_that_constrains():
    walk = park_like_walk()
    pdr = walk.pdr
    measured = measured_range((pdr.x_m, pdr.y_m), 2.0)
    later = pdr.t_s >= pdr.t_s[0] + 60.0
    measured[~(isolated_epochs(pdr.t_s) | later)] = np.nan
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=45.0)
    assert heading_error_rad(sol.heading_rad, 2.0) < np.deg2rad(0.1)
    assert sol.n_used > np.count_nonzero(isolated_epochs(pdr.t_s) & ~later)


def test_a_window_fitted_exactly_by_heading_and_scale_is_not_confident():
    """Two pairs of epochs after gaps: two constraints for two unknowns, a perfect fit at a wrong heading.

    (Street-out tuning walk 108: five epochs in three runs over its first 45 s gave a heading 67 deg off
    with confidence 1; the range of the walk's second half gives it to 17 deg.)
    """
    walk = park_like_walk()
    pdr = walk.pdr
    measured = measured_range((pdr.x_m, pdr.y_m), 2.0) + np.random.default_rng(3).normal(0.0, 0.1, len(pdr))
    pairs = np.zeros(len(pdr), dtype=bool)
    for i in (20, 50):
        pairs[i:i + 2] = True
    later = pdr.t_s >= pdr.t_s[0] + 60.0
    measured[~(pairs | later)] = np.nan
    first = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=45.0,
                                  min_confidence=0.0)
    assert first.n_used == 4 and first.confidence == 0.0
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, measured, GEOMETRY, max_duration_s=45.0)
    assert sol.n_used > 4
    assert heading_error_rad(sol.heading_rad, 2.0) < np.deg2rad(1.0)


def test_a_walker_who_has_hardly_moved_gives_no_heading():
    """Centimetres of PDR motion move the predicted range by less than its noise: the cost is flat, no minimum
    of it is a heading (without the flatness check its rounding made one)."""
    t = np.arange(20.0)
    x, y = 0.002 * np.sin(t), 0.002 * np.cos(t)
    measured = np.random.default_rng(1).normal(0.0, 0.05, len(t))
    measured[0] = 0.0
    with pytest.raises(ValueError, match="does not constrain the heading"):
        solve_initial_heading(t, x, y, measured, GEOMETRY, max_duration_s=None)


def test_heading_sigma_holds_the_scatter_of_white_range_noise():
    """With white range noise alone, eq. 15's sigma matches the scatter of the solved heading over noise draws."""
    walk = park_like_walk()
    pdr = walk.pdr
    true_heading = np.deg2rad(70.0)
    clean = measured_range((pdr.x_m, pdr.y_m), true_heading)
    rng = np.random.default_rng(5)
    errors, sigmas = [], []
    for _ in range(40):
        noisy = clean + rng.laplace(0.0, 0.3, clean.shape)
        sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, noisy, GEOMETRY, scale_bounds=None, max_duration_s=20.0)
        errors.append(heading_error_rad(sol.heading_rad, true_heading))
        sigmas.append(sol.sigma_rad)
    scatter = np.sqrt(np.mean(np.square(errors)))
    assert 0.6 < np.mean(sigmas) / scatter < 1.7


def test_heading_sigma_grows_with_the_start_fix_error_and_the_pdr_drift():
    """The fix's error and the PDR heading's drift move the minimum as a whole: each widens the sigma."""
    pdr = park_like_walk().pdr
    true_heading = np.deg2rad(200.0)
    rc = measured_range((pdr.x_m, pdr.y_m), true_heading) + np.random.default_rng(1).laplace(0.0, 0.1, len(pdr.t_s))

    def sigma(**kw):
        return solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, rc, GEOMETRY, **kw).sigma_rad

    alone = sigma()
    assert sigma(start_sigma_m=3.0) > alone
    assert sigma(heading_rate_sigma_radps=np.deg2rad(0.05)) > alone
    # A P0 off by the stated sigma moves the minimum by no more than a few of the sigma it claims.
    shifted = Geometry(3.0, 0.0, GEOMETRY.tower_x_m, GEOMETRY.tower_y_m, GEOMETRY.tower_height_m)
    sol = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, rc, shifted, start_sigma_m=3.0)
    assert heading_error_rad(sol.heading_rad, true_heading) < 3.0 * sol.sigma_rad


def test_an_uncertain_heading_says_so_and_widens_the_filters_start():
    from fusion.heading_init import HeadingSolution
    from fusion.run import FusionConfig, with_heading_spread
    config = FusionConfig()
    sure = HeadingSolution(np.array([1.0]), np.array([0.1]), np.array([1.0]), 1.0, 1.0, 50, np.deg2rad(0.5))
    vague = HeadingSolution(np.array([1.0]), np.array([0.1]), np.array([1.0]), 1.0, 1.0, 50, np.deg2rad(8.0))
    mirror = HeadingSolution(np.array([1.0, 2.0]), np.array([0.1, 0.11]), np.ones(2), 1.0, 0.1, 50, np.deg2rad(0.5))
    assert not sure.uncertain() and "WARNING" not in sure.describe()
    assert vague.uncertain() and "WARNING" in vague.describe()
    assert mirror.uncertain() and "WARNING" in mirror.describe()
    assert with_heading_spread(config, sure) is config
    assert with_heading_spread(config, vague).noise.initial_heading_rad == pytest.approx(np.deg2rad(8.0))
