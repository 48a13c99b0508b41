"""The seeds' other filters (UKF, WT-UKF, quality-adaptive EKF, rank KF, ZUPT INS) against truth."""

import numpy as np
import pytest
from fusion_synth import exact_ranges, foot_imu_straight, park_like_walk, ranges_with_blockage
from scipy.stats import norm

from fusion import foot_ins, rank_kf
from fusion.adaptive_kf import GnssFixes, quality_grade_factors, run_adaptive_kf
from fusion.integrity import IntegrityConfig
from fusion.metrics import error_stats, place_pdr, position_errors_m
from fusion.model import (ClockModel, EpochObservation, Geometry, ModelNoise, StepControl, X, propagate,
                          transition_jacobian)
from fusion.observations import aggregate_ranges, build_epochs
from fusion.run import FILTERS, FusionConfig, fuse
from fusion.ukf import RangePdrUkf, run_ukf
from fusion.wt_ukf import WaveletUkf, run_wt_ukf, wavelet_noise_estimate


@pytest.fixture(scope="module")
def gain_walk():
    walk = park_like_walk(gain=1.15, seed=4)
    epochs = build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s), walk.initial_heading_rad)
    pdr95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk.truth)).p95_m
    return walk, epochs, pdr95


@pytest.mark.parametrize("clock_model", ["disciplined", "free-running"])
@pytest.mark.parametrize("make", [RangePdrUkf, rank_kf.RangePdrRankKf])
def test_a_re_anchored_range_says_nothing_of_where_the_walker_is(make, clock_model):
    """A range re-anchored on the state (a new origin; under a free-running clock, the first observation too) and
    then observed standing still measures no change: the position along the line of sight stays as uncertain as
    P0 made it (the origin is a clone of the state, not a number), and the covariance stays positive definite.
    An origin fixed to a number turned the second observation into an absolute range (docs/method.md §8)."""
    geometry = Geometry(0.0, 0.0, 2000.0, 0.0, 150.0)            # the tower due east: the line of sight is x
    f = make(geometry, ModelNoise(), 0.0, 1.3, clock=ClockModel(clock_model))
    start_var = f.P[X, X]
    for n in range(5):
        f.predict(StepControl(dt_s=0.0, interval_s=0.5))
        f.update(EpochObservation(n, 7.0, 0.1, np.nan, np.nan, range_new_origin=n == 0))
    assert f.P[X, X] > 0.9 * start_var, (f.P[X, X], start_var)
    assert abs(f.x[X]) < 0.01 and f.start_range_m != pytest.approx(np.hypot(2000.0, 150.0), abs=1.0)
    assert np.linalg.eigvalsh(f.P).min() > 0.0


@pytest.mark.parametrize("runner", [run_ukf, rank_kf.run_rank_kf])
def test_kalman_filters_let_the_origin_wander_over_a_long_gap(runner):
    """The range returns from a 20 s gap 8 m off: the origin state's random walk over the gap (its variance grown
    by ``range_offset_m**2`` an epoch) takes the jump, not the position. The integrity monitor is off, as it would
    catch the held jump too (and fall back on the PDR)."""
    walk = park_like_walk(gain=1.15, seed=4)
    shifted = ranges_with_blockage(walk, 40.0, 60.0, 8.0)
    epochs = build_epochs(walk.pdr, aggregate_ranges(shifted, walk.pdr.t_s), walk.initial_heading_rad)
    off = IntegrityConfig(enabled=False)
    anchored = error_stats(position_errors_m(runner(epochs, walk.geometry, ModelNoise(), integrity=off),
                                             walk.truth)).p95_m
    held = error_stats(position_errors_m(runner(epochs, walk.geometry, ModelNoise(range_offset_m=0.0), integrity=off),
                                         walk.truth)).p95_m
    assert anchored < 0.5 * held, (anchored, held)


@pytest.mark.parametrize("runner", [run_ukf, run_wt_ukf, run_adaptive_kf, rank_kf.run_rank_kf])
def test_each_filter_corrects_a_step_gain_error_with_the_range(gain_walk, runner):
    walk, epochs, pdr95 = gain_walk
    fused95 = error_stats(position_errors_m(runner(epochs, walk.geometry), walk.truth)).p95_m
    assert fused95 < 0.75 * pdr95


def test_fuse_runs_every_filter_on_the_same_epochs():
    walk = park_like_walk(gain=1.1, seed=5)
    result = fuse(walk.pdr, exact_ranges(walk), (0.0, 0.0), (walk.geometry.tower_x_m, walk.geometry.tower_y_m),
                  tower_height_m=walk.geometry.tower_height_m, config=FusionConfig(n_particles=500))
    assert set(result.tracks) == set(FILTERS)
    assert abs(result.heading.heading_rad - walk.initial_heading_rad) < np.deg2rad(2.0)
    for track in result.tracks.values():
        np.testing.assert_array_equal(track.t_s, walk.pdr.t_s)
    with pytest.raises(ValueError, match="unknown filter"):
        fuse(walk.pdr, exact_ranges(walk), (0.0, 0.0), (1.0, 1.0), ("kalman",))


def test_transition_jacobian_matches_finite_differences():
    x = np.array([3.0, -2.0, 0.01, 0.8, 1.3])
    control = StepControl(0.55, 0.1, 1.05)
    f = transition_jacobian(x, control)
    eps = 1e-6
    numeric = np.column_stack([(propagate(x + eps * e, control) - propagate(x - eps * e, control)) / (2 * eps)
                               for e in np.eye(5)])
    np.testing.assert_allclose(f, numeric, atol=1e-6)


# --- [CN0-KF] grading ------------------------------------------------------------------------

def test_quality_grades_follow_seed_003():
    snr = np.array([15.0, 15.0, 15.0, 15.0, 13.0, 15.0, 5.0, np.nan])
    factors = quality_grade_factors(snr)
    # Equal quality: good. 2 dB down: P = 1.58 P_good against a running mean ~1.12 P_good -> 1.41 C: medium.
    # 10 dB down: P = 10 P_good -> bad. No observation: neutral.
    assert factors.tolist() == [1.0, 1.0, 1.0, 1.0, 5.0, 1.0, 10.0, 1.0]


def test_adaptive_filter_uses_good_gnss_fixes():
    walk = park_like_walk(gain=1.15, seed=6)
    epochs = build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s), walk.initial_heading_rad)
    t = np.arange(10.0, walk.truth.t_s[-1], 1.0)
    rng = np.random.default_rng(0)
    fixes = GnssFixes(t, np.interp(t, walk.truth.t_s, walk.truth.x_m) + rng.normal(0, 1.0, len(t)),
                      np.interp(t, walk.truth.t_s, walk.truth.y_m) + rng.normal(0, 1.0, len(t)),
                      np.full(len(t), 44.0), sigma_m=1.0)
    without = error_stats(position_errors_m(run_adaptive_kf(epochs, walk.geometry), walk.truth)).p95_m
    with_gnss = error_stats(position_errors_m(run_adaptive_kf(epochs, walk.geometry, gnss=fixes), walk.truth)).p95_m
    assert with_gnss < 0.7 * without and with_gnss < 2.0


# --- [WT-UKF] wavelet noise estimation -------------------------------------------------------

def test_wavelet_noise_estimate_recovers_white_noise_on_a_smooth_signal():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 20.0, 256)
    signal = 2.0 * np.sin(0.3 * t) + 0.5 * t
    mean, sigma = wavelet_noise_estimate(signal + rng.normal(0.0, 0.4, t.size))
    assert sigma == pytest.approx(0.4, rel=0.15)
    assert abs(mean) < 0.1


@pytest.mark.parametrize("rows", [(0,), (0, 1, 2)])
def test_wt_ukf_re_estimates_only_the_chosen_channels(gain_walk, rows, monkeypatch):
    """By default only the range's R comes from the wavelet; the PDR pseudo-observations keep their nominal R."""
    walk, epochs, _ = gain_walk
    noise = ModelNoise()
    kf = WaveletUkf(walk.geometry, noise, epochs, window=32, wavelet_rows=rows,
                    integrity=IntegrityConfig(enabled=False))  # a filter still at P0 sees a far-off range here
    seen = {}
    monkeypatch.setattr(kf, "_update", lambda z, r, observation: seen.update(r=np.sqrt(np.diag(r))))
    n = int(np.nonzero(np.isfinite(epochs.range_change_m[40:]))[0][0]) + 40
    kf.update(epochs.observation(n))
    nominal = np.array([epochs.range_sigma_m[n], noise.pdr_heading_rad, noise.pdr_speed_mps])
    changed = ~np.isclose(seen["r"], nominal)
    assert changed[0]  # a smooth exact range: the wavelet sees far less than the nominal sigma
    assert list(changed[1:]) == [1 in rows, 2 in rows]


# --- [Rank-KF] rank sampling -------------------------------------------------------------------

def test_rank_quantiles_follow_seed_004():
    lambdas, omega = rank_kf.rank_quantiles(2)
    p = (np.array([1, 2, 4, 5]) - 0.3) / 5.4
    np.testing.assert_allclose(lambdas, norm.ppf(p))
    assert lambdas.sum() == pytest.approx(0.0, abs=1e-12)  # eq. 5 with r_j = 1
    assert omega == pytest.approx(3.0105, abs=1e-3)


def test_rank_kf_is_exact_for_a_linear_gaussian_model():
    """With linear f and h, rank sampling reproduces the Kalman filter's moments exactly."""
    rng = np.random.default_rng(1)
    n = 4
    a = rng.normal(size=(n, n))
    P = a @ a.T + np.eye(n)
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    Q = np.diag(rng.uniform(0.1, 0.5, n))
    H = rng.normal(size=(2, n))
    R = np.diag([0.3, 0.7])
    x = rng.normal(size=n)
    z = rng.normal(size=2)
    f = rank_kf.RankKalmanFilter(x, P, lambda pts: pts.mean(axis=0), np.subtract)
    f.predict(lambda pts: pts @ F.T, Q)
    x_pred, P_pred = F @ x, F @ P @ F.T + Q
    np.testing.assert_allclose(f.x, x_pred, atol=1e-12)
    np.testing.assert_allclose(f.P, P_pred, atol=1e-10)
    f.update(z, lambda pts: pts @ H.T, R, lambda zs: zs.mean(axis=0), np.subtract)
    s = H @ P_pred @ H.T + R
    k = P_pred @ H.T @ np.linalg.inv(s)
    np.testing.assert_allclose(f.x, x_pred + k @ (z - H @ x_pred), atol=1e-10)
    np.testing.assert_allclose(f.P, P_pred - k @ s @ k.T, atol=1e-10)


def test_strapdown_kernel_covariance_equals_rank_sampled_prediction():
    """The ZUPT INS propagates P in closed form; that is what rank sampling gives for its linear model."""
    rng = np.random.default_rng(2)
    a = rng.normal(size=(15, 15))
    P0 = a @ a.T * 1e-3 + np.eye(15) * 1e-4
    C = foot_ins.level_attitude(np.array([[0.3, -0.2, 9.8]]), 0.4)
    gyro, acc, dt = np.array([[0.1, -0.2, 0.3]]), np.array([[1.0, 0.5, 9.9]]), np.array([0.01])
    q = np.zeros(15)
    P = P0.copy()
    out = np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3, 3))
    foot_ins.strapdown_kernel(C.copy(), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), P, gyro, acc, dt, q, *out)
    C1 = out[2][0]
    F = np.eye(15)
    F[0:3, 3:6] = -C1 * dt[0]
    F[6:9, 9:12] = np.eye(3) * dt[0]
    f_n = C1 @ acc[0]
    skew = np.array([[0, -f_n[2], f_n[1]], [f_n[2], 0, -f_n[0]], [-f_n[1], f_n[0], 0]])
    F[9:12, 0:3] = -skew * dt[0]
    F[9:12, 12:15] = -C1 * dt[0]
    sampled = rank_kf.RankKalmanFilter(np.zeros(15), P0, lambda pts: pts.mean(axis=0), np.subtract)
    sampled.predict(lambda pts: pts @ F.T, np.zeros((15, 15)))
    np.testing.assert_allclose(P, sampled.P, rtol=1e-9, atol=1e-15)


def test_strapdown_kernel_matches_reference():
    rng = np.random.default_rng(4)
    n = 50
    gyro, acc = rng.normal(0, 0.5, (n, 3)), rng.normal(0, 2.0, (n, 3)) + [0.0, 0.0, 9.81]
    dt, q = np.full(n, 0.01), rng.uniform(0, 1e-4, 15)
    a = [foot_ins.level_attitude(acc[:5], 0.3), np.zeros(3), np.zeros(3), rng.normal(0, 1e-3, 3),
         rng.normal(0, 1e-2, 3), np.eye(15) * 1e-3]
    b = [x.copy() for x in a]
    out = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
    foot_ins.strapdown_kernel(*a, gyro, acc, dt, q, *out)
    ref = foot_ins.strapdown_reference(*b, gyro, acc, dt, q)
    for x, y in zip(a + list(out), b + list(ref)):
        np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-12)


def test_zupt_ins_bounds_the_drift_of_a_foot_imu():
    heading = np.deg2rad(30.0)
    t, acc, gyro, pos = foot_imu_straight(heading_rad=heading)
    stance = foot_ins.shoe_stance(acc, gyro)
    moving = np.r_[False, np.hypot(*np.diff(pos, axis=0).T) > 0]
    assert not np.any(stance & moving)                   # never a ZUPT while the foot moves
    track = foot_ins.ZuptInsRankKf().run(t, acc, gyro, (0.0, 0.0), heading)
    err = np.hypot(track.x_m - pos[:, 0], track.y_m - pos[:, 1])
    assert err.max() < 0.02 * 16.8                       # < 2 % of the distance walked
    free = foot_ins.ZuptInsRankKf(foot_ins.ZuptConfig(shoe_threshold=-1.0)).run(t, acc, gyro, (0.0, 0.0), heading)
    assert np.hypot(free.x_m - pos[:, 0], free.y_m - pos[:, 1]).max() > 10 * err.max()


def test_zupt_ins_rejects_mismatched_logs():
    with pytest.raises(ValueError, match="must agree"):
        foot_ins.ZuptInsRankKf().run(np.arange(5.0), np.zeros((5, 3)), np.zeros((4, 3)), (0.0, 0.0), 0.0)


def test_noise_model_defaults_used_by_all_filters_are_consistent():
    assert ModelNoise().pdr_heading_rad > ModelNoise().heading_rad
