"""Receiver range -> filter epochs (the aggregation rule), and the accuracy metrics."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core.records import PdrSteps, RangeSeries, Track
from fusion.metrics import (error_cdf, error_stats, heading_error_rad, interpolate_track, place_pdr, position_errors_m,
                            true_initial_heading_rad)
from fusion.observations import AggregationConfig, aggregate_ranges, build_epochs, rician_k_db, step_durations_s

FRAME_S = 1 / 1800.0


def ramp_series(duration_s=10.0, slope_mps=-1.2, snr_db=20.0):
    t = np.arange(0.0, duration_s, FRAME_S)
    return RangeSeries(t, slope_mps * t, np.full(len(t), snr_db), np.ones(len(t), bool))


@given(st.floats(0.5, 9.5), st.floats(-3.0, 3.0))
@settings(max_examples=40, deadline=None)
def test_window_mean_of_a_linear_range_is_its_value_at_the_epoch(t_epoch, slope):
    obs = aggregate_ranges(ramp_series(slope_mps=slope), np.array([t_epoch]))
    assert obs.range_change_m[0] == pytest.approx(slope * t_epoch, abs=abs(slope) * FRAME_S + 1e-9)
    assert obs.sigma_m[0] == pytest.approx(AggregationConfig().base_sigma_m)


def test_gap_drops_the_epoch_and_flagged_frames_are_left_out():
    rs = ramp_series()
    valid = rs.valid.copy()
    valid[(rs.t_s > 2.0) & (rs.t_s < 3.0)] = False             # a gap: nothing valid around t = 2.5
    valid[(rs.t_s > 5.0) & (rs.t_s < 5.04)] = False            # a few flagged frames near t = 5
    corrupt = rs.range_change_m.copy()
    corrupt[~valid] = 1e6                                      # flagged frames carry garbage
    obs = aggregate_ranges(RangeSeries(rs.t_s, corrupt, rs.snr_db, valid), np.array([2.5, 5.0, 7.0]),
                           AggregationConfig(settle_s=0.0))
    assert np.isnan(obs.range_change_m[0]) and np.isnan(obs.sigma_m[0])
    assert obs.range_change_m[1] == pytest.approx(-1.2 * 5.0, abs=0.05)
    assert obs.sigma_m[1] > obs.sigma_m[2]                      # fewer valid frames: less weight
    assert obs.range_change_m[2] == pytest.approx(-1.2 * 7.0, abs=0.01)


def test_low_snr_inflates_sigma_like_one_over_snr():
    cfg = AggregationConfig(good_snr_db=10.0, base_sigma_m=0.5)
    weak = aggregate_ranges(ramp_series(snr_db=0.0), np.array([5.0]), cfg)
    strong = aggregate_ranges(ramp_series(snr_db=15.0), np.array([5.0]), cfg)
    assert strong.sigma_m[0] == pytest.approx(0.5)
    assert weak.sigma_m[0] == pytest.approx(0.5 * np.sqrt(10.0), rel=1e-6)  # 10 dB below: variance x 10


def rician_snr_db(t_s, k_db, seed, cn_db=15.0, doppler_hz=5.0, sinusoids=64):
    """SNR of a Rician link: a steady path plus Clarke-model diffuse power 1/K (sum of sinusoids)."""
    rng = np.random.default_rng(seed)
    k = 10.0 ** (k_db / 10.0)
    freq = doppler_hz * np.cos(rng.uniform(0, 2 * np.pi, sinusoids))
    phase = rng.uniform(0, 2 * np.pi, sinusoids)
    diffuse = np.exp(1j * (2 * np.pi * freq[:, None] * t_s + phase[:, None])).sum(axis=0) / np.sqrt(sinusoids)
    h = (np.sqrt(k) + diffuse) / np.sqrt(k + 1.0)
    return cn_db + 10.0 * np.log10(np.abs(h) ** 2)


@pytest.mark.parametrize("k_db", [0.0, 6.0, 10.0])
def test_rician_k_estimate_recovers_the_k_factor_of_a_fading_link(k_db):
    t = np.arange(0.0, 60.0, 1 / 450.0)
    estimates = [rician_k_db(t, rician_snr_db(t, k_db, seed), np.ones(len(t), bool), np.array([30.0]), 60.0)[0]
                 for seed in range(8)]
    assert np.median(estimates) == pytest.approx(k_db, abs=1.5)


def test_two_paths_with_different_dopplers_fade_and_are_dropped():
    """Direct path blocked, a reflection (0 dB) and a second one at -3 dB with the opposite Doppler beating at 5 Hz."""
    rs = ramp_series()
    beat = np.abs(1.0 + 10 ** (-3 / 20) * np.exp(2j * np.pi * 5.0 * rs.t_s)) ** 2
    fading = RangeSeries(rs.t_s, rs.range_change_m, 15.0 + 10 * np.log10(beat), rs.valid)
    # Moments of a two-tone: gamma = 2 a^2 b^2 / (a^2 + b^2)^2.
    gamma = 2 * 10 ** (-3 / 10) / (1 + 10 ** (-3 / 10)) ** 2
    expected_k_db = 10 * np.log10(np.sqrt(1 - gamma) / (1 - np.sqrt(1 - gamma)))
    obs = aggregate_ranges(fading, np.array([5.0]))
    assert obs.rician_k_db[0] == pytest.approx(expected_k_db, abs=0.3)
    assert np.isnan(obs.range_change_m[0])
    steady = aggregate_ranges(rs, np.array([5.0]))
    assert np.isfinite(steady.range_change_m[0]) and steady.rician_k_db[0] > 30.0
    kept = aggregate_ranges(fading, np.array([5.0]), AggregationConfig(min_rician_k_db=None))
    assert kept.range_change_m[0] == pytest.approx(-6.0, abs=0.01)


def test_epochs_far_below_the_line_of_sight_snr_are_dropped():
    rs = ramp_series()
    snr = np.where(rs.t_s < 5.0, 15.0, 9.0)   # the direct path is blocked from t = 5 s: 6 dB down
    obs = aggregate_ranges(RangeSeries(rs.t_s, rs.range_change_m, snr, rs.valid), np.array([2.0, 3.0, 7.0, 8.0]))
    assert np.all(np.isfinite(obs.range_change_m[:2])) and np.all(np.isnan(obs.range_change_m[2:]))
    lenient = aggregate_ranges(RangeSeries(rs.t_s, rs.range_change_m, snr, rs.valid), np.array([2.0, 3.0, 7.0, 8.0]),
                               AggregationConfig(max_snr_deficit_db=8.0))
    assert np.all(np.isfinite(lenient.range_change_m))


def test_range_returns_only_after_the_link_has_settled():
    rs = ramp_series(20.0)
    valid = rs.valid & ~((rs.t_s > 4.0) & (rs.t_s < 6.0))       # the link drops out from 4 to 6 s
    epochs = np.arange(0.5, 20.0, 0.5)
    series = RangeSeries(rs.t_s, rs.range_change_m, rs.snr_db, valid)
    obs = aggregate_ranges(series, epochs, AggregationConfig(settle_s=3.0))
    unsettled = aggregate_ranges(series, epochs, AggregationConfig(settle_s=0.0))
    last_lost = epochs[~np.isfinite(unsettled.range_change_m)].max()
    back = epochs[np.isfinite(obs.range_change_m) & (epochs > 4.0)]
    assert back.min() == pytest.approx(last_lost + 3.0)
    assert np.all(np.isfinite(obs.range_change_m[epochs < 3.9]))   # the opening run needs no settling


def test_bad_ranges_raise():
    with pytest.raises(ValueError, match="increase"):
        aggregate_ranges(RangeSeries(np.array([0.0, 1.0, 0.5]), np.zeros(3), np.zeros(3), np.ones(3, bool)),
                         np.array([0.5]))


def pdr_steps(n=6):
    t = 10.0 + 0.5 * np.arange(1, n + 1)
    heading = np.deg2rad([0.0, 10.0, 350.0, 20.0, 20.0, 20.0][:n])
    return PdrSteps(t, np.zeros(n), np.arange(1, n + 1) * 0.7, heading, np.full(n, 1.4), np.full(n, 0.7))


def test_build_epochs_makes_heading_absolute_and_increments_wrapped():
    pdr = pdr_steps()
    epochs = build_epochs(pdr, aggregate_ranges(ramp_series(20.0), pdr.t_s), initial_heading_rad=1.0)
    np.testing.assert_allclose(epochs.pdr_heading_rad, pdr.heading_rad + 1.0)
    # 10 deg -> 350 deg is a 20 deg left turn, not 340 deg right.
    assert np.rad2deg(epochs.pdr_heading_increment_rad[2]) == pytest.approx(-20.0)
    np.testing.assert_allclose(epochs.dt_s, 0.5)
    assert epochs.control(3).speed_ratio == pytest.approx(1.0)


def test_step_duration_falls_back_on_the_time_gap():
    pdr = pdr_steps()
    pdr.speed_mps[2] = 0.0
    dt = step_durations_s(pdr)
    assert dt[2] == pytest.approx(0.5)


# --- metrics --------------------------------------------------------------------------------

def test_error_stats_percentiles_and_max():
    errors = np.arange(1.0, 101.0)
    stats = error_stats(errors)
    assert stats.p68_m == pytest.approx(np.percentile(errors, 68))
    assert stats.p95_m == pytest.approx(95.05)
    assert stats.max_m == 100.0 and stats.n == 100
    x, p = error_cdf(errors[::-1])
    assert x[0] == 1.0 and p[-1] == 1.0 and np.all(np.diff(p) > 0)


def test_interpolation_and_errors_against_truth():
    t = np.arange(0.0, 10.0, 0.01)
    truth = Track(t, 1.3 * t, np.zeros_like(t), np.full_like(t, np.deg2rad(359.5)), np.full_like(t, 1.3))
    truth.heading_rad[t > 5] = np.deg2rad(0.5)
    mid = interpolate_track(truth, np.array([5.005]))
    assert heading_error_rad(mid.heading_rad[0], 0.0) < np.deg2rad(0.6)  # interpolated across north, not via 180
    estimate = Track(np.array([2.0, 4.0]), np.array([2.6, 5.2]), np.array([3.0, 4.0]), np.zeros(2), np.zeros(2))
    np.testing.assert_allclose(position_errors_m(estimate, truth), [3.0, 4.0], atol=1e-9)
    with pytest.raises(ValueError, match="span"):
        interpolate_track(truth, np.array([11.0]))


def test_place_pdr_and_true_initial_heading():
    pdr = PdrSteps(np.array([1.0, 2.0]), np.array([0.0, 0.0]), np.array([1.0, 2.0]), np.zeros(2), np.ones(2),
                   np.ones(2))
    placed = place_pdr(pdr, 10.0, 20.0, np.pi / 2)  # PDR north becomes east
    np.testing.assert_allclose(placed.x_m, [11.0, 12.0])
    np.testing.assert_allclose(placed.y_m, [20.0, 20.0], atol=1e-12)
    t = np.arange(0.0, 20.0, 0.01)
    walking = np.clip(t - 10.0, 0, None) * 1.3
    truth = Track(t, walking * np.sin(0.7), walking * np.cos(0.7), np.full_like(t, 0.7), np.zeros_like(t))
    assert true_initial_heading_rad(truth, 10.0) == pytest.approx(0.7, abs=1e-9)
