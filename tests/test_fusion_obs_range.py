"""Observation-level range simulator: its errors against the true geometry, scene by scene."""

import numpy as np
import pytest
from fusion_synth import loop_truth, polyline_truth
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core.gb20600 import PnMode
from fusion.metrics import interpolate_track
from fusion.model import Geometry
from sim.channel import segment_crosses_polygon
from sim.obs_range import (EXACT_RANGE_SNR_DB, ObsRangeConfig, coarse_cfo_sigma_hz, exact_range, si_carrier_grid_hz,
                           si_frames_kernel, si_frames_reference, simulate_obs_range)
from sim.frames import FrameConfig
from sim.frontend import mean_signal_power
from sim.scenario import load_scenario


def true_range_change(scenario, truth, t_s):
    at = interpolate_track(truth, t_s)
    tower = scenario.tower
    g = Geometry(truth.x_m[0], truth.y_m[0], tower.x_m, tower.y_m, tower.height_m - scenario.channel.antenna_height_m)
    return g.range_m(at.x_m, at.y_m) - g.start_range_m()


@pytest.fixture(scope="module")
def park():
    scn = load_scenario("park-loop-cw")
    truth = loop_truth(scn)
    return scn, truth, simulate_obs_range(scn, truth)


def test_line_of_sight_range_follows_the_geometry(park):
    scn, truth, rs = park
    err = rs.range_change_m - true_range_change(scn, truth, rs.t_s)
    still = rs.t_s < scn.walk.start_still_s
    wavelength = 299792458.0 / scn.tower.carrier_hz
    # The diffuse component (K = 10 dB) ripples the composite phase by up to asin(10^(-K/20)) rad.
    ripple_m = np.arcsin(10.0 ** (-scn.channel.rician_k_db / 20.0)) * wavelength / (2.0 * np.pi)
    # Calibrated f_s: the error at the end of the calibration window is back at the start's, up to the ripple.
    cal_end = np.searchsorted(rs.t_s, scn.walk.start_still_s - ObsRangeConfig().calibration_guard_s)
    assert abs(err[cal_end] - err[0]) < 2.0 * ripple_m
    # In between, eq. 8's noise-times-noise term (which does not telescope) random-walks: about
    # 1 / (sqrt(72) snr) rad a frame, a bridge of ~2 cm (1 sigma) over the standstill, plus the ripple.
    assert np.abs(err[still]).max() < 0.1
    assert np.abs(err).max() < 0.5              # LOS: centimetre ripple + sub-metre clock wander
    assert rs.valid.mean() > 0.95
    assert np.median(rs.snr_db) == pytest.approx(scn.receiver.cn_db, abs=1.5)


def test_exact_range_is_the_geometry_on_the_observation_grid(park):
    scn, truth, rs = park
    exact = exact_range(scn, truth)
    np.testing.assert_array_equal(exact.t_s, rs.t_s)
    # The channel interpolates the track with a cubic spline: a millimetre from linear at the corners.
    np.testing.assert_allclose(exact.range_change_m, true_range_change(scn, truth, exact.t_s), atol=2e-3)
    assert exact.valid.all() and np.all(exact.snr_db == EXACT_RANGE_SNR_DB)
    # The observation level's errors are what it adds: not zero, as the exact range's are.
    assert np.abs(rs.range_change_m - exact.range_change_m).max() > 0.01


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


def test_si_frames_kernel_matches_reference():
    rng = np.random.default_rng(0)
    coef = rng.normal(size=(4, 300)) + 1j * rng.normal(size=(4, 300))
    delay = 1e-5 + rng.uniform(0, 2e-6, (4, 300))
    common = rng.uniform(-np.pi, np.pi, 300)
    noise = 0.3 * (rng.normal(size=(300, 36)) + 1j * rng.normal(size=(300, 36)))
    first = 0.2 * (rng.normal(size=36) + 1j * rng.normal(size=36))
    ref_kernel, ref_reference = first.copy(), first.copy()
    phase_kernel, phase_reference = np.array([0.3]), np.array([0.3])
    first_hz, spacing_hz, count = si_carrier_grid_hz()
    kernel = si_frames_kernel(coef, delay, common, first_hz, spacing_hz, count, noise, ref_kernel, phase_kernel)
    reference = si_frames_reference(coef, delay, common, first_hz, spacing_hz, count, noise, ref_reference,
                                    phase_reference)
    for a, b in zip(kernel, reference, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    # Both carry the reference and the last frame's phase on.
    np.testing.assert_allclose(ref_kernel, ref_reference, rtol=1e-9)
    np.testing.assert_allclose(phase_kernel, phase_reference, rtol=1e-9)


def test_si_carriers_are_36_consecutive_carriers():
    first_hz, spacing_hz, count = si_carrier_grid_hz()
    assert count == 36 and spacing_hz == pytest.approx(7.56e6 / 3780) and first_hz == pytest.approx(-18 * spacing_hz)


@settings(max_examples=5, deadline=None)
@given(st.integers(1, 3000))
def test_output_does_not_depend_on_the_block_length(block_frames):
    scn = load_scenario("street-out").replace(walk={"start_still_s": 1.5})
    truth = polyline_truth([[0.0, 0.0], [0.0, 2.0]], still_s=1.5)
    a = simulate_obs_range(scn, truth)
    b = simulate_obs_range(scn, truth, block_frames=block_frames)
    # The same draws frame by frame; numpy's vector and scalar paths may round the last bit differently.
    for name, column in a.columns().items():
        np.testing.assert_allclose(column, getattr(b, name), rtol=1e-12, atol=1e-12, err_msg=name)


def test_si_snr_carries_the_receivers_estimation_noise():
    """A steady channel: the per-frame SI SNR estimate spreads as 36 noisy carriers over a noisy noise estimate."""
    config = ObsRangeConfig(decimation=1)
    scn = load_scenario("park-loop-cw").replace(channel={"ground_reflection": False, "rician_k_db": None},
                                                walk={"start_still_s": 8.0})
    truth = polyline_truth([[0.0, 0.0], [0.0, 1.0]], still_s=8.0)
    rs = simulate_obs_range(scn, truth, config)
    # The C/N is of the whole signal, whose boosted headers raise its mean power above the body's.
    mean_power = mean_signal_power(FrameConfig(pn_mode=PnMode.PN420))
    assert mean_power == pytest.approx((420 * 2 + 3780) / 4200)
    snr = 10.0 ** ((scn.receiver.cn_db - config.implementation_loss_db) / 10.0) / mean_power
    dof = 2 * config.noise_bins
    # mean |Y|^2 / sigma^2 over 36 carriers: mean snr + 1, variance (2 snr + 1) / 36; sigma_hat^2 / sigma^2:
    # mean 1, variance 2 / dof (to first order in both).
    expected_std = np.sqrt((2.0 * snr + 1.0) / 36.0 + (snr + 1.0) ** 2 * 2.0 / dof)
    estimate = 10.0 ** (rs.snr_db / 10.0)
    assert np.mean(estimate) == pytest.approx(snr * (1.0 + 2.0 / dof), rel=0.02)
    assert np.std(estimate) == pytest.approx(expected_std, rel=0.1)
    assert np.median(rs.snr_db) < scn.receiver.cn_db  # the implementation loss


def test_coarse_cfo_spread_is_that_of_the_lag_p_product():
    """The angle of a sum of N products of two noisy copies of the same samples, simulated directly."""
    mode = PnMode.PN420
    rng = np.random.default_rng(1)
    n = mode.value.cyclic_length * 16
    for snr in (3.0, 30.0):
        s = np.exp(2j * np.pi * rng.uniform(size=(400, n)))
        noise = lambda: (rng.normal(size=s.shape) + 1j * rng.normal(size=s.shape)) / np.sqrt(2.0 * snr)  # noqa: E731
        angles = np.angle(np.sum(np.conj(s + noise()) * (s + noise()), axis=1))
        sigma_hz = np.std(angles) * 7.56e6 / (2.0 * np.pi * mode.value.period)
        assert coarse_cfo_sigma_hz(snr, mode, 16) == pytest.approx(sigma_hz, rel=0.1)
    with pytest.raises(ValueError, match="cyclic"):
        coarse_cfo_sigma_hz(10.0, PnMode.PN595, 16)


def test_noise_draws_share_the_walk_and_differ_in_noise(park):
    scn, truth, rs = park
    other = simulate_obs_range(scn, truth, ObsRangeConfig(noise_draw=1))
    assert not np.array_equal(rs.snr_db, other.snr_db) and not np.array_equal(rs.range_change_m, other.range_change_m)
    # The same channel: the SNR's fading is the same in both draws. Per frame an estimate carries about 10 %
    # of noise on this link (36 carriers, 191 noise bins), so the means of two draws over the 225 frames of a
    # second differ by about 1 % (0.04 dB, 1 sigma).
    second = np.floor(rs.t_s).astype(int)
    full = second < second[-1]
    means = [10.0 * np.log10(np.bincount(second[full], 10.0 ** (r.snr_db[full] / 10.0)) / np.bincount(second[full]))
             for r in (rs, other)]
    assert np.ptp(means[0]) > 1.0 and np.abs(means[0] - means[1]).max() < 0.2


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
