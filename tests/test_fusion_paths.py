"""Path observations (first-path ranges, tower differences): model, aggregation, standstill epochs, filters."""

import numpy as np
import pytest
from fusion_synth import clock_range_m, exact_paths, exact_ranges, park_like_walk, path_series

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import PathRangeSeries, RangeSeries
from fusion import HEADING_RANGES, SI_RANGE_USES
from fusion.metrics import error_stats, heading_error_rad, place_pdr, position_errors_m
from fusion.model import (CLOCK_STATE_SIZE, ClockModel, EpochObservation, Geometry, ModelNoise, ObservationLayout,
                          StepControl, observation_jacobian, observe, propagate, transition_jacobian)
from fusion.observations import FilterEpochs, PathAggregationConfig, PathEpochs, RangeEpochs, StandstillConfig, aggregate_path, aggregate_paths, aggregate_ranges, build_epochs, epoch_times, si_range_epochs, standstill_times
from dtmbnav_core.records import PathRanges
from fusion.transmit_delays import TransmitDelays, tie_code_differences
from fusion.run import FILTERS, FusionConfig, fuse

SFN = Geometry(3.0, -2.0, 2000.0, 2200.0, 150.0, other_towers=((-1800.0, 1500.0, 100.0), (500.0, -2500.0, 60.0)))
SECOND_TOWER = ((-1800.0, 1500.0, 100.0),)
FREE_TCXO = {"clock_model": "free-running", "clock_allan_deviation": 1.6e-9, "clock_allan_tau_s": 100.0}


# --- the model --------------------------------------------------------------------------------

def test_observation_model_of_every_channel():
    layout = ObservationLayout(SFN.n_towers)
    x, y = 40.0, 25.0
    state = np.array([x, y, 0.0, 1.0, 1.3, 2.5, 0.1])  # with the clock: 2.5 m integrated, 0.1 m/s
    z = observe(state, SFN, SFN.start_range_m())  # a scalar origin: the SI range's; the others at P0
    ranges = [SFN.range_m(x, y, k) - SFN.range_m(SFN.start_x_m, SFN.start_y_m, k) for k in range(3)]
    rows = layout.rows()
    np.testing.assert_allclose(z[rows[0]], ranges[0] + 2.5)                       # SI carriers: range + clock
    np.testing.assert_allclose(z[rows[1:4]], np.array(ranges) + 2.5)              # first paths: range + clock
    np.testing.assert_allclose(z[rows[4:]], [ranges[1] - ranges[0], ranges[2] - ranges[0]])  # differences: no clock
    np.testing.assert_allclose(z[[1, 2]], [1.0, 1.3])


@pytest.mark.parametrize("size", [5, CLOCK_STATE_SIZE])
def test_jacobians_match_finite_differences(size):
    x = np.array([40.0, 25.0, 0.01, 1.0, 1.3, 2.5, 0.1])[:size]
    control = StepControl(0.55, 0.1, 1.05, interval_s=0.8)
    eps = 1e-6
    numeric_f = np.column_stack([(propagate(x + eps * e, control) - propagate(x - eps * e, control)) / (2 * eps)
                                 for e in np.eye(size)])
    np.testing.assert_allclose(transition_jacobian(x, control), numeric_f, atol=1e-6)
    np.testing.assert_allclose(transition_jacobian(np.stack([x, x]), control)[1], numeric_f, atol=1e-6)
    numeric_h = np.column_stack([(observe(x + eps * e, SFN, 0.0) - observe(x - eps * e, SFN, 0.0)) / (2 * eps)
                                 for e in np.eye(size)])
    np.testing.assert_allclose(observation_jacobian(x, SFN), numeric_h, atol=1e-6)


def test_epoch_observation_orders_and_pads_the_channels():
    obs = EpochObservation(0, 1.0, 0.2, 0.5, 1.3, first_path_range_m=np.array([2.0, np.nan]),
                           first_path_sigma_m=np.array([0.1, 0.1]), first_path_new_origin=np.array([True, True]),
                           range_difference_m=np.array([4.0]), range_difference_sigma_m=np.array([0.3]),
                           range_difference_new_origin=np.array([False]))
    z, sigma, new_origin = obs.range_channels(3)
    np.testing.assert_array_equal(z, [1.0, 2.0, np.nan, np.nan, 4.0, np.nan])
    np.testing.assert_array_equal(sigma, [0.2, 0.1, np.nan, np.nan, 0.3, np.nan])
    assert new_origin.tolist() == [False, True, False, False, False, False]  # no data: no new origin
    # A new lock segment makes the SI range channel (0) a new origin, only where it has a range.
    assert EpochObservation(0, 1.0, 0.2, 0.5, 1.3, range_new_origin=True).range_channels(1)[2].tolist() == [True, False]
    assert not EpochObservation(0, np.nan, np.nan, 0.5, 1.3, range_new_origin=True).range_channels(1)[2].any()
    kalman = obs.kalman(ModelNoise(), 3, use=np.array([True, False, True, True, True, True]))
    assert kalman.rows.tolist() == [0, 1, 2, 6]  # the first path to tower 0 left out; difference 1 is row 6
    with pytest.raises(ValueError, match="the geometry has 1"):
        obs.range_channels(1)
    with pytest.raises(ValueError, match="height_m"):
        Geometry(0.0, 0.0, 1.0, 1.0, 0.0, other_towers=((1.0, 2.0),))


# --- aggregation of the path channels ---------------------------------------------------------

def ramp_path(duration_s=20.0, rate_hz=200.0):
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    return path_series(t, -1.0 * t)


def test_a_slip_drops_its_epoch_and_makes_the_next_a_new_origin():
    series = ramp_path()
    slip = series.slip.copy()
    slip[np.argmin(np.abs(series.t_s - 5.0))] = True
    jumped = np.where(series.t_s >= 5.0, series.range_change_m + 0.45, series.range_change_m)
    series = PathRangeSeries(series.t_s, jumped, series.snr_db, series.valid, slip, series.path_age_s)
    value, sigma, new_origin, _ = aggregate_path(series, np.array([4.0, 5.0, 6.0, 7.0]))
    assert np.isnan(value[1]) and np.isnan(sigma[1])
    assert new_origin.tolist() == [False, False, True, False]
    assert value[2] == pytest.approx(-6.0 + 0.45, abs=1.0 / 200.0)  # the window mean of a sampled ramp: to a frame


def test_a_reacquired_path_is_a_new_origin_and_a_young_path_is_held_back():
    series = ramp_path()
    age = np.where(series.t_s < 8.0, series.path_age_s, series.t_s - 8.0)  # path lost and found at 8 s
    series = PathRangeSeries(series.t_s, series.range_change_m, series.snr_db, series.valid, series.slip, age)
    config = PathAggregationConfig()
    _, sigma, new_origin, _ = aggregate_path(series, np.array([7.0, 8.2, 9.0, 18.0]), config)
    assert np.isnan(sigma[1])                                 # younger than min_path_age_s
    assert new_origin.tolist() == [False, False, True, False]
    young = config.base_sigma_m * np.sqrt(1.0 + config.path_settle_s / 1.0)
    assert sigma[2] == pytest.approx(young, rel=0.01)         # one second old
    assert sigma[3] == pytest.approx(config.base_sigma_m * np.sqrt(1.0 + config.path_settle_s / 10.0), rel=0.01)


def test_path_sigma_grows_like_one_over_snr():
    series = ramp_path()
    weak = PathRangeSeries(series.t_s, series.range_change_m, np.full(len(series), 0.0), series.valid, series.slip,
                           series.path_age_s)
    config = PathAggregationConfig(good_snr_db=10.0)
    ratio = aggregate_path(weak, np.array([15.0]), config)[1] / aggregate_path(series, np.array([15.0]), config)[1]
    assert ratio[0] == pytest.approx(np.sqrt(10.0), rel=1e-6)


def test_the_code_range_is_averaged_across_a_slip_and_absent_without_one():
    series = ramp_path()
    slip = series.slip.copy()
    slip[np.argmin(np.abs(series.t_s - 5.0))] = True
    coded = PathRangeSeries(series.t_s, series.range_change_m, series.snr_db, series.valid, slip, series.path_age_s,
                            code_range_m=100.0 - 1.0 * series.t_s)
    value, _, _, code = aggregate_path(coded, np.array([4.0, 5.0, 6.0]))
    assert np.isnan(value[1])                                 # the carrier's window holds the slip
    np.testing.assert_allclose(code, 100.0 - np.array([4.0, 5.0, 6.0]), atol=1.0 / 200.0)
    assert np.isnan(aggregate_path(series, np.array([4.0]))[3]).all()   # no code range given: none


def test_aggregate_paths_rejects_a_tower_outside_the_geometry():
    with pytest.raises(ValueError, match="differences: tower 0"):
        aggregate_paths(PathRanges(differences={0: ramp_path()}), np.array([5.0]), 2)


# --- standstill epochs ------------------------------------------------------------------------

def test_standstill_epochs_fill_the_pauses_and_give_no_track_rows():
    walk = park_like_walk(pauses=((30.0, 10.0),))
    config = StandstillConfig()
    still = standstill_times(walk.pdr.t_s, 0.0, config)
    gaps = np.diff(np.concatenate([[0.0], walk.pdr.t_s]))
    assert np.count_nonzero(gaps > config.min_gap_s) == 2    # before the first step, and the pause
    assert np.all(np.min(np.abs(still[:, None] - walk.pdr.t_s[None]), axis=1) >= config.margin_s - 1e-9)
    t = epoch_times(walk.pdr.t_s, 0.0, config)
    epochs = build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), t), walk.initial_heading_rad)
    assert len(epochs) == len(walk.pdr) + len(still)
    np.testing.assert_array_equal(epochs.t_s[epochs.is_step], walk.pdr.t_s)
    n = int(np.flatnonzero(~epochs.is_step)[-1])
    assert epochs.control(n).dt_s == 0.0 and epochs.control(n).interval_s > 0.0
    assert np.isnan(epochs.observation(n).pdr_heading_rad)
    assert epochs.initial_heading_speed() == (walk.pdr.heading_rad[0] + walk.initial_heading_rad, walk.pdr.speed_mps[0])
    for name, runner in FILTERS.items():
        track = runner(epochs, walk.geometry, FusionConfig(n_particles=300, **FREE_TCXO))
        np.testing.assert_array_equal(track.t_s, walk.pdr.t_s)
        assert np.isfinite(track.x_m).all(), name


def test_build_epochs_rejects_ranges_off_the_step_times():
    walk = park_like_walk()
    with pytest.raises(ValueError, match="not aggregated at the PDR step times"):
        build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s[1:]), 0.0)


# --- the filters on path observations -------------------------------------------------------

def fused_p95(walk, epochs, name, config):
    return error_stats(position_errors_m(FILTERS[name](epochs, walk.geometry, config), walk.truth)).p95_m


@pytest.mark.parametrize("noise_m", [0.0, 0.05])
def test_every_filter_converges_on_first_path_ranges_to_two_towers(noise_m):
    """No SI-carrier range at all: exact or noisy first-path ranges of two towers correct a drifting PDR."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=1, other_towers=SECOND_TOWER)
    paths = exact_paths(walk)
    rng = np.random.default_rng(3)
    for series in paths.first_path.values():
        series.range_change_m = series.range_change_m + noise_m * rng.standard_normal(len(series))
    no_si = exact_ranges(walk)
    no_si = RangeSeries(no_si.t_s, no_si.range_change_m, no_si.snr_db, np.zeros(len(no_si), bool))
    epochs = build_epochs(walk.pdr, aggregate_ranges(no_si, walk.pdr.t_s), walk.initial_heading_rad,
                          aggregate_paths(paths, walk.pdr.t_s, walk.geometry.n_towers))
    assert np.isnan(epochs.range_change_m).all()
    pdr95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk.truth)).p95_m
    for name in FILTERS:
        assert fused_p95(walk, epochs, name, FusionConfig(n_particles=1000)) < 0.5 * pdr95, name


def test_a_range_difference_corrects_a_heading_error_under_a_free_running_clock():
    """The SI-carrier range drifts with a TCXO; the clock-free tower difference still fixes an 8 deg heading error."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=0, laps=2, other_towers=SECOND_TOWER)
    ranges = exact_ranges(walk)
    drifting = RangeSeries(ranges.t_s, ranges.range_change_m + clock_range_m(ranges.t_s, 1.6e-9, 100.0, seed=0),
                           ranges.snr_db, ranges.valid)
    heading = walk.initial_heading_rad + np.deg2rad(8.0)
    pdr_at_fix95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, heading), walk.truth)).p95_m
    config = FusionConfig(n_particles=1000, **FREE_TCXO)
    t = epoch_times(walk.pdr.t_s, 0.0, config.standstills)
    with_difference = aggregate_paths(exact_paths(walk, first_path=False), t, walk.geometry.n_towers)
    for name in ("pf", "ukf"):
        si_only = fused_p95(walk, build_epochs(walk.pdr, aggregate_ranges(drifting, t), heading), name, config)
        both = fused_p95(walk, build_epochs(walk.pdr, aggregate_ranges(drifting, t), heading, with_difference), name,
                         config)
        assert both < 0.4 * pdr_at_fix95, (name, both, pdr_at_fix95)
        assert si_only > 0.6 * pdr_at_fix95, (name, si_only, pdr_at_fix95)


def test_heading_range_first_path_solves_eq_15_where_the_si_range_follows_a_reflection():
    """A disciplined clock, the SI range bent by a reflection's Doppler, the first path exact: eq. 15 on each."""
    walk = park_like_walk(gain=1.1, seed=2)
    ranges = exact_ranges(walk)
    bent = RangeSeries(ranges.t_s, ranges.range_change_m + 0.6 * np.clip(ranges.t_s - 10.0, 0.0, None),
                       ranges.snr_db, ranges.valid)   # 0.6 m/s from the first step on
    tower = (walk.geometry.tower_x_m, walk.geometry.tower_y_m)
    errors = {}
    for heading_range in HEADING_RANGES:
        result = fuse(walk.pdr, bent, (0.0, 0.0), tower, ("ukf",), tower_height_m=walk.geometry.tower_height_m,
                      paths=exact_paths(walk), config=FusionConfig(heading_range=heading_range))
        errors[heading_range] = abs(np.rad2deg(heading_error_rad(result.heading.heading_rad,
                                                                 walk.initial_heading_rad)))
    assert errors["first-path"] < 3.0
    assert errors["si"] > 3.0 * errors["first-path"]
    with pytest.raises(ValueError, match="heading_range"):
        FusionConfig(heading_range="gnss")


def test_si_range_is_kept_only_where_no_first_path_is_observed():
    t = np.arange(8.0)
    nan = np.nan
    si_range = np.where(t == 6.0, nan, t)                     # the SI range itself dropped at 6
    si = RangeEpochs(t, si_range, np.where(np.isfinite(si_range), 0.3, nan), np.full(8, 20.0), np.full(8, 10.0),
                     np.array([True, False, False, True, False, False, False, False]))
    first = np.array([[nan, nan], [nan, 1.0], [2.0, nan], [3.0, 3.0], [4.0, nan], [nan, nan], [nan, nan], [nan, nan]])
    paths = PathEpochs(t, first, np.where(np.isfinite(first), 0.2, nan), np.zeros((8, 2), bool), np.empty((8, 0)),
                       np.empty((8, 0)), np.empty((8, 0), bool), np.full((8, 2), np.nan), np.empty((8, 0)),
                       np.empty((8, 0)))
    kept = si_range_epochs(si, paths, "without-first-path")
    np.testing.assert_array_equal(np.isfinite(kept.range_change_m), [True, False, False, False, False, True, False, True])
    np.testing.assert_array_equal(np.isfinite(kept.sigma_m), np.isfinite(kept.range_change_m))
    assert kept.new_origin.tolist() == [True, False, False, False, False, True, False, False]  # 3's origin moves to 5
    for unchanged in (si_range_epochs(si, paths, "always"), si_range_epochs(si, None, "without-first-path")):
        assert unchanged is si
    with pytest.raises(ValueError, match="si range use"):
        si_range_epochs(si, paths, "never")
    with pytest.raises(ValueError, match="si_range"):
        FusionConfig(si_range="never")


def test_a_slowly_bent_si_range_is_left_out_where_the_first_path_is_tracked():
    """The SI range bent by 0.1 m/s from the first step on (a reflection's Doppler in the mix; too slow for the
    integrity monitor's 10 s window), the first path exact: taking the SI range too drags the filters."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=2, laps=2)
    ranges = exact_ranges(walk)
    bent = RangeSeries(ranges.t_s, ranges.range_change_m + 0.1 * np.clip(ranges.t_s - 10.0, 0.0, None),
                       ranges.snr_db, ranges.valid)
    pdr95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk.truth)).p95_m
    fused = {}
    for use in SI_RANGE_USES:
        result = fuse(walk.pdr, bent, (0.0, 0.0), (walk.geometry.tower_x_m, walk.geometry.tower_y_m), ("pf", "ukf"),
                      tower_height_m=walk.geometry.tower_height_m, paths=exact_paths(walk),
                      config=FusionConfig(n_particles=1000, si_range=use))
        fused[use] = {name: error_stats(position_errors_m(track, walk.truth)).p95_m
                      for name, track in result.tracks.items()}
    for name in ("pf", "ukf"):
        assert fused["without-first-path"][name] < 0.35 * pdr95, (name, fused, pdr95)
        assert fused["always"][name] > 1.5 * fused["without-first-path"][name], (name, fused)


def test_fuse_takes_the_towers_and_the_paths():
    walk = park_like_walk(gain=1.1, seed=5, other_towers=SECOND_TOWER)
    result = fuse(walk.pdr, exact_ranges(walk), (0.0, 0.0), (walk.geometry.tower_x_m, walk.geometry.tower_y_m),
                  ("pf", "rank-kf"), tower_height_m=walk.geometry.tower_height_m, other_towers=SECOND_TOWER,
                  paths=exact_paths(walk), config=FusionConfig(n_particles=500))
    assert result.epochs.first_path_range_m.shape == (len(walk.pdr), 2)
    assert result.epochs.range_difference_m.shape == (len(walk.pdr), 1)
    with pytest.raises(ValueError, match="clock_model"):
        FusionConfig(clock_model="rubidium")
    with pytest.raises(ValueError, match="Allan deviation"):
        ClockModel("free-running", allan_deviation=-1.0)


def test_default_epochs_have_no_path_columns():
    walk = park_like_walk()
    epochs = build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s), 0.0)
    assert epochs.first_path_range_m.shape == (len(walk.pdr), 0)
    copy = FilterEpochs(**epochs.columns())
    np.testing.assert_array_equal(copy.interval_s, epochs.interval_s)


# --- the receiver file's path columns -> PathRanges (dtmbnav.chain.inputs) ---------------------------

@pytest.mark.parametrize("name", ["pf", "ukf"])
def test_a_code_range_difference_takes_out_the_fix_error_along_the_hyperbola(name):
    """The GNSS fix is 2 m off the true start along the towers' hyperbola gradient (and 0.3 m across it): with
    the difference's code range (the transmit delays known) the filter starts on the right hyperbola; with its
    carrier alone it keeps the fix's error, which a range-difference change cannot see."""
    import dataclasses

    walk = park_like_walk(gain=1.05, seed=0, other_towers=SECOND_TOWER)
    g = walk.geometry
    towers = g.towers()
    unit = [-towers[k, :2] / np.hypot(*towers[k, :2]) for k in range(2)]      # d range / d position at the start
    gradient = (unit[1] - unit[0]) / np.hypot(*(unit[1] - unit[0]))
    across = np.array([-gradient[1], gradient[0]])
    fix = 2.0 * gradient + 0.3 * across
    at_fix = dataclasses.replace(g, start_x_m=float(fix[0]), start_y_m=float(fix[1]))
    config = FusionConfig(n_particles=2000, **FREE_TCXO)
    t = epoch_times(walk.pdr.t_s, 0.0, config.standstills)
    ranges = exact_ranges(walk)
    drifting = RangeSeries(ranges.t_s, ranges.range_change_m + clock_range_m(ranges.t_s, 1.6e-9, 100.0, seed=0),
                           ranges.snr_db, ranges.valid)
    paths = exact_paths(walk, first_path=False)
    difference = paths.differences[1]
    x, y = (np.interp(difference.t_s, walk.truth.t_s, v) for v in (walk.truth.x_m, walk.truth.y_m))
    rng = np.random.default_rng(5)
    code = g.range_m(x, y, 1) - g.range_m(x, y, 0) + 0.1 + 0.3 * rng.standard_normal(len(x))   # biased, noisy
    with_code = dataclasses.replace(paths, differences={1: dataclasses.replace(difference, code_range_m=code)})

    def along_error_m(path_ranges):
        # The towers' transmit delay offsets known exactly (both 0 here): the code is the range difference.
        tied, _ = tie_code_differences(aggregate_paths(path_ranges, t, g.n_towers), at_fix,
                                       TransmitDelays((0.0, 0.0), (0.0, 0.0), "exact"), float(walk.pdr.t_s[0]), 1.5)
        epochs = build_epochs(walk.pdr, aggregate_ranges(drifting, t), walk.initial_heading_rad, tied)
        track = FILTERS[name](epochs, at_fix, config)
        truth = (np.interp(track.t_s, walk.truth.t_s, walk.truth.x_m), np.interp(track.t_s, walk.truth.t_s,
                                                                                 walk.truth.y_m))
        return np.median((track.x_m - truth[0]) * gradient[0] + (track.y_m - truth[1]) * gradient[1])

    assert abs(along_error_m(with_code)) < 0.4
    assert along_error_m(paths) > 1.5


def test_receiver_towers_are_put_in_the_tower_tables_order_by_their_delays():
    """Three towers; the receiver found tower C (62 chips after A) before tower B (30 chips): matched back by delay,
    and a tower the receiver never saw keeps its number."""
    from receiver.observables import expected_tower_delays_s, receiver_tower_order

    towers = Geometry(1.0, -2.0, 2000.0, 2200.0, 148.5,
                      other_towers=((-1372.0, -3771.0, 118.5), (-3574.0, 3969.0, 98.5)))
    expected = expected_tower_delays_s(towers.start_ranges_m(), (0.0, 0.5e-6, 0.3e-6))
    chip_s = 1.0 / 7.56e6
    assert expected[1] / chip_s == pytest.approx(30.0, abs=0.5) and expected[2] / chip_s == pytest.approx(62.0, abs=0.5)
    rng = np.random.default_rng(0)
    delay_a = 5e-6 + 1e-8 * rng.standard_normal(100)
    delay_c, delay_b = delay_a + expected[2] + 3e-8, delay_a + expected[1] - 3e-8    # the fix off by metres
    delay_b[:50] = np.nan                                                            # found later
    np.testing.assert_array_equal(receiver_tower_order([delay_a, delay_c, delay_b], expected), [0, 2, 1])
    np.testing.assert_array_equal(receiver_tower_order([delay_a, delay_b, delay_c], expected), [0, 1, 2])
    unseen = np.full(100, np.nan)
    np.testing.assert_array_equal(receiver_tower_order([delay_a, unseen, delay_b], expected), [0, 2, 1])


def test_receiver_path_columns_become_path_ranges():
    """First path 7 then 9 (a new origin), a cycle slip on path 9, a difference that starts late."""
    from receiver.observables import paths_from_frames
    from dtmbnav_core.records import FrameFlag, PathFlag

    n = 10
    t = 0.1 * np.arange(n)
    ids = np.array([-1, 7, 7, 7, 9, 9, 9, 9, 9, 9])
    flags = np.zeros(n, np.uint8)
    flags[8] = FrameFlag.LOW_QUALITY
    diff = np.where(np.arange(n) >= 3, 0.01 * np.arange(n), np.nan)
    frames = {"t_s": t, "frame_index": np.arange(100, 100 + n), "flags": flags,
              "first_path_range_change_m": 0.05 * np.arange(n), "first_path_snr_db": np.full(n, 20.0, np.float32),
              "first_path_id": ids.astype(np.int32), "range_difference_change_1_m": diff,
              "range_difference_change_2_m": np.full(n, np.nan)}
    # /receiver/paths: tower 0's first paths as in the frames, tower 1's first path 4 from frame 3, slip at 6.
    frame_index, path_id, tower_id, row_flags = [], [], [], []
    for i in range(n):
        if ids[i] >= 0:
            frame_index.append(100 + i), path_id.append(ids[i]), tower_id.append(0)
            row_flags.append(PathFlag.FIRST_PATH | (PathFlag.CYCLE_SLIP if i == 6 else 0))
        if i >= 3:
            frame_index.append(100 + i), path_id.append(4), tower_id.append(1), row_flags.append(PathFlag.FIRST_PATH)
    rows = {"frame_index": np.array(frame_index), "path_id": np.array(path_id), "tower_id": np.array(tower_id),
            "flags": np.array(row_flags, np.uint8), "snr_db": np.where(np.array(tower_id) == 1, 12.0, 20.0)}
    paths = paths_from_frames(frames, rows, n_towers=2, time_offset_s=5.0)
    first = paths.first_path[0]
    np.testing.assert_allclose(first.t_s, t + 5.0)
    assert first.valid.tolist() == [False] + [True] * 7 + [False, True]          # no path, then a bad frame
    assert first.slip.tolist() == [False, True, False, False, True, False, True, False, False, False]
    np.testing.assert_allclose(first.path_age_s[1:4], [0.0, 0.1, 0.2])          # path 7
    np.testing.assert_allclose(first.path_age_s[4:], 0.1 * np.arange(6), atol=1e-12)  # path 9 from its first frame
    difference = paths.differences[1]
    assert difference.valid.tolist() == [False] * 3 + [True] * 5 + [False, True]
    assert difference.slip[3] and difference.slip[4] and difference.slip[6]      # start, first-path change, slip
    np.testing.assert_allclose(difference.snr_db[3:], 12.0)                      # the weaker path's
    assert list(paths.differences) == [1]                                        # no tower 2 in a 2-tower geometry
    assert np.isnan(difference.code_range_m).all()                              # rows without delays
    # The delays of the two first paths: c times their difference, the towers' transmit delay offsets still in
    # it (fusion.transmit_delays takes them out).
    frames["first_path_delay_s"] = np.full(n, 2.0e-6)
    rows["delay_s"] = np.where(np.array(tower_id) == 1, 9.5e-6, 2.0e-6)
    coded = paths_from_frames(frames, rows, n_towers=2).differences[1]
    np.testing.assert_allclose(coded.code_range_m[3:], 7.5e-6 * SPEED_OF_LIGHT_MPS)
    assert np.isnan(coded.code_range_m[:3]).all()                                # tower 1 not yet found
    frames.pop("first_path_range_change_m")
    assert paths_from_frames(frames, rows, n_towers=2) is None                    # tracker off: SI range only


def test_the_first_path_code_range_is_the_range_up_to_a_constant_on_a_drifting_clock():
    """A path 500 m + 1.2 m/s t away, a receiver clock 2.3 ppb fast (f_s = -1.5 Hz at 666 MHz), frame starts on the
    sample grid, and a frame counter that skips one frame in a gap: the code range is the range plus a constant."""
    from receiver.observables import first_path_code_range_m
    from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS as c
    from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode

    period_s, carrier_hz, eps = PnMode.PN420.value.frame_duration_s, 666e6, 2.3e-9
    k = np.arange(20000)
    range_m = 500.0 + 1.2 * k * period_s
    arrival_s = (k * period_s + range_m / c) * (1.0 + eps)       # on the receiver's clock
    t_s = np.floor(arrival_s * SYMBOL_RATE_HZ) / SYMBOL_RATE_HZ     # the frame start the tracker takes
    frames = {"t_s": t_s, "first_path_delay_s": arrival_s - t_s, "frame_index": k + (k >= 15000)}
    attrs = {"pn_mode": "PN420", "carrier_hz": carrier_hz, "first_path_clock_offset_hz": -eps * carrier_hz}
    code = first_path_code_range_m(frames, attrs)
    error = code - range_m
    assert np.ptp(error) < 0.01                              # a constant (without the f_s term: 0.7 m/s of drift)
    assert first_path_code_range_m(frames, {**attrs, "first_path_clock_offset_hz": np.nan}) is None
    assert first_path_code_range_m(frames, {"pn_mode": "none", "carrier_hz": carrier_hz,
                                            "first_path_clock_offset_hz": 1.0}) is None


def test_the_sensors_file_gives_every_towers_height_above_the_antenna(tmp_path):
    """``dtmbnav fuse`` reads an SFN's further towers like the first: height above the receiver's antenna."""
    from dtmbnav.chain.inputs import read_other_towers
    from dtmbnav_core.sensors import read_tower
    from dtmbnav.simulation.capture_set import simulate_capture_set
    from sim.scenario import load_scenario

    scn = load_scenario("sfn-park")
    truth = simulate_capture_set(scn, tmp_path, seconds=1.0, with_iq=False).truth_path
    antenna_m = scn.channel.antenna_height_m
    assert read_tower(truth)[2] == pytest.approx(scn.sites[0].height_m - antenna_m)
    (x, y, height), = read_other_towers(truth)
    assert (x, y, height) == pytest.approx((scn.sites[1].x_m, scn.sites[1].y_m, scn.sites[1].height_m - antenna_m))
