"""Particle filter (eq. 16-23): kernels against their numpy twins, the resampler's bias, robustness, physics."""

import numpy as np
import pytest
from fusion_synth import exact_ranges, park_like_walk, ranges_with_blockage
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion import particle_filter as pf
from fusion.metrics import error_stats, place_pdr, position_errors_m
from fusion.model import EpochObservation, Geometry, ModelNoise
from fusion.observations import FilterEpochs, aggregate_ranges, build_epochs


def epochs_for(walk, ranges):
    return build_epochs(walk.pdr, aggregate_ranges(ranges, walk.pdr.t_s), walk.initial_heading_rad)


# --- kernels == numpy references ------------------------------------------------------------

def random_particles(n, seed):
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.normal(0, 5, n), rng.normal(0, 5, n), rng.normal(0, 0.01, n),
                         rng.uniform(-4, 4, n), rng.normal(1.3, 0.2, n)])
    return p, rng


def test_propagate_kernel_matches_reference():
    a, rng = random_particles(500, 1)
    b = a.copy()
    noise = rng.standard_normal(a.shape) * 0.1
    pf.propagate_kernel(a, 0.55, 0.3, 1.1, noise)
    pf.propagate_reference(b, 0.55, 0.3, 1.1, noise)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


@pytest.mark.parametrize("subtracted", [-1, 1])
def test_range_likelihood_kernel_matches_reference(subtracted):
    """A single-tower range (with the clock's range in the linear state) and a tower difference."""
    p, rng = random_particles(500, 2)
    linear = np.column_stack([2900.0 + rng.normal(0, 1, 500), rng.normal(0, 0.3, 500), rng.normal(0, 0.1, 500)])
    towers = np.array([[2000.0, 2200.0, 150.0], [-1500.0, 900.0, 80.0]])
    h = np.array([-1.0, 1.0, 0.0])
    gain = np.array([0.4, -0.1, 0.02])
    outlier = np.array([np.log(0.99 / np.sqrt(2 * np.pi)), np.log(0.01 / 100.0)])
    a, b = np.zeros(500), np.zeros(500)
    linear_b = linear.copy()
    inlier_a = pf.range_likelihood_kernel(p, linear, towers, 0, subtracted, h, gain, 3.2, 1.0, outlier, a)
    inlier_b = pf.range_likelihood_reference(p, linear_b, towers, 0, subtracted, h, gain, 3.2, 1.0, outlier, b)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(linear, linear_b, rtol=0, atol=1e-9)
    assert inlier_a == pytest.approx(inlier_b, abs=1e-12)


def test_pdr_likelihood_kernel_matches_reference():
    p, _ = random_particles(500, 3)
    a, b = np.zeros(500), np.zeros(500)
    pf.pdr_likelihood_kernel(p, 3.1, 1.2, 0.3, 0.2, a)  # heading near +pi exercises the wrap
    pf.pdr_likelihood_reference(p, 3.1, 1.2, 0.3, 0.2, b)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)


@given(st.lists(st.floats(-1e6, 10.0), min_size=2, max_size=60))
@settings(max_examples=60, deadline=None)
def test_normalise_kernel_matches_reference(log_w):
    a = np.array(log_w)
    b = a.copy()
    wa, wb = np.empty_like(a), np.empty_like(b)
    ess_a = pf.normalise_kernel(a, wa)
    ess_b = pf.normalise_reference(b, wb)
    np.testing.assert_allclose(wa, wb, rtol=1e-12, atol=1e-300)
    assert ess_a == pytest.approx(ess_b, rel=1e-12)
    assert wa.sum() == pytest.approx(1.0, abs=1e-12)
    assert 1.0 <= ess_a <= len(a) + 1e-9


@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=80), st.floats(0.0, 0.999999))
@settings(max_examples=100, deadline=None)
def test_resample_kernel_matches_reference(weights, u):
    w = np.array(weights) + 1e-12
    assert np.array_equal(pf.systematic_resample_kernel(w, u), pf.systematic_resample_reference(w, u))


# --- resampler bias -------------------------------------------------------------------------

def test_systematic_resampler_is_unbiased_and_stratified():
    """E[count_i] = N w_i, and every draw gives floor or ceil of N w_i (systematic sampling)."""
    rng = np.random.default_rng(7)
    n = 50
    w = rng.gamma(0.5, size=n)
    w /= w.sum()
    draws = 20000
    counts = np.zeros(n)
    for u in rng.random(draws):
        c = np.bincount(pf.systematic_resample_kernel(w, u), minlength=n)
        assert np.all((c >= np.floor(n * w) - 1e-9) & (c <= np.ceil(n * w) + 1e-9))
        counts += c
    mean = counts / draws
    # A count is floor or ceil of N w, so its std is <= 0.5; 6 sigma of the mean of 20000 draws.
    np.testing.assert_allclose(mean, n * w, atol=6 * 0.5 / np.sqrt(draws))


def test_resampler_survives_weights_summing_below_one():
    """filterpy's resamplers assume sum(w) == 1; ours places pointers on the actual total."""
    n = 10
    w = np.full(n, 0.5 / (n - 1))
    w[-1] = 0.5
    w *= 1 - 1e-9  # sums slightly below 1: filterpy's last pointer (u + 9) / 10 would pass the cumsum's end
    for u in np.linspace(0.0, 0.999999999, 101):
        idx = pf.systematic_resample_kernel(w, u)
        assert idx.min() >= 0 and idx.max() <= n - 1
    # The heavy last particle is drawn N w = 5 times whatever u is, not one fewer.
    assert [np.sum(pf.systematic_resample_kernel(w, u) == n - 1) for u in (0.25, 0.5, 0.75, 0.999999999)] == [5] * 4


# --- robustness -----------------------------------------------------------------------------

def test_normalise_survives_total_underflow():
    log_w = np.full(100, -1e6)
    log_w[3] = -1e6 + 1.0
    w = np.empty(100)
    ess = pf.normalise_kernel(log_w, w)
    assert np.isfinite(w).all() and w.sum() == pytest.approx(1.0)
    assert w.argmax() == 3 and 1.0 < ess < 100.0
    all_impossible = np.full(100, -np.inf)
    assert pf.normalise_kernel(all_impossible, w) == 100.0
    np.testing.assert_allclose(w, 0.01)


def test_filter_survives_an_outlier_range():
    walk = park_like_walk(gain=1.0, seed=3)
    ranges = exact_ranges(walk)
    epochs = epochs_for(walk, ranges)
    epochs.range_change_m[60] += 1e5  # every particle's likelihood underflows
    track = pf.run_particle_filter(epochs, walk.geometry, n_particles=500, seed=1)
    assert np.isfinite(track.x_m).all() and np.isfinite(track.y_m).all()
    errors = position_errors_m(track, walk.truth)
    assert errors[70:].max() < 3.0  # the filter recovers after the outlier


def test_circular_mean_heading_across_north():
    geometry = Geometry(0.0, 0.0, 2000.0, 2200.0)
    f = pf.ParticleFilter(geometry, n_particles=1000, seed=0)
    f.initialise(0.0, 1.3)
    f.particles[:, 3] = np.where(np.arange(1000) % 2 == 0, np.deg2rad(359.0), np.deg2rad(1.0))
    heading = f.estimate()[3]
    assert min(heading, 2 * np.pi - heading) < np.deg2rad(0.01)


# --- determinism and backends ---------------------------------------------------------------

def test_numba_and_numpy_filters_agree_and_seed_fixes_the_result():
    walk = park_like_walk(gain=1.15, seed=2)
    epochs = epochs_for(walk, exact_ranges(walk))
    a = pf.run_particle_filter(epochs, walk.geometry, n_particles=400, seed=5, backend="numba")
    b = pf.run_particle_filter(epochs, walk.geometry, n_particles=400, seed=5, backend="numpy")
    c = pf.run_particle_filter(epochs, walk.geometry, n_particles=400, seed=5, backend="numba")
    d = pf.run_particle_filter(epochs, walk.geometry, n_particles=400, seed=6, backend="numba")
    np.testing.assert_allclose(a.x_m, b.x_m, atol=1e-8)
    np.testing.assert_allclose(a.heading_rad, b.heading_rad, atol=1e-10)
    assert np.array_equal(a.x_m, c.x_m)
    assert not np.array_equal(a.x_m, d.x_m)


def test_bad_arguments_raise():
    g = Geometry(0.0, 0.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="backend"):
        pf.ParticleFilter(g, backend="cuda")
    with pytest.raises(ValueError, match="n_particles"):
        pf.ParticleFilter(g, n_particles=1)


# --- physics: the range corrects the PDR ----------------------------------------------------

def test_range_corrects_a_step_length_gain_error():
    """PDR 15 % too long: with the range the 95 % error drops well below the PDR's; without it, not."""
    walk = park_like_walk(gain=1.15, seed=4)
    epochs = epochs_for(walk, exact_ranges(walk))
    pdr95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk.truth)).p95_m
    fused95 = error_stats(position_errors_m(pf.run_particle_filter(epochs, walk.geometry, seed=1), walk.truth)).p95_m
    no_range = FilterEpochs(**{**epochs.columns(), "range_change_m": np.full(len(epochs), np.nan),
                               "range_sigma_m": np.full(len(epochs), np.nan)})
    blind95 = error_stats(position_errors_m(pf.run_particle_filter(no_range, walk.geometry, seed=1),
                                            walk.truth)).p95_m
    assert fused95 < 0.6 * pdr95
    assert blind95 > 0.8 * pdr95


def test_range_offset_absorbs_an_error_picked_up_in_a_gap():
    """The range returns from a 20 s gap 8 m off (a blocked stretch): the offset walk takes it, not the position."""
    walk = park_like_walk(gain=1.15, seed=4)
    epochs = epochs_for(walk, ranges_with_blockage(walk, 40.0, 60.0, 8.0))
    assert np.isnan(epochs.range_change_m[(epochs.t_s > 41.0) & (epochs.t_s < 59.0)]).all()
    errors = {}
    for offset_m in (ModelNoise().range_offset_m, 0.0):
        track = pf.run_particle_filter(epochs, walk.geometry, ModelNoise(range_offset_m=offset_m), seed=1)
        errors[offset_m] = error_stats(position_errors_m(track, walk.truth)).p95_m
    pdr95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk.truth)).p95_m
    assert errors[ModelNoise().range_offset_m] < 0.7 * pdr95
    assert errors[0.0] > 2.0 * errors[ModelNoise().range_offset_m], errors


def test_range_offset_kalman_step_matches_the_closed_form():
    """One returning range after a gap: each offset moves by the gain P / S times its innovation, P -> P sigma^2 / S."""
    geometry = Geometry(0.0, 0.0, 2000.0, 2200.0, 150.0)
    f = pf.ParticleFilter(geometry, ModelNoise(range_outlier_probability=1e-12), n_particles=300, seed=3)
    f.initialise(0.7, 1.3)
    for _ in range(25):  # 25 epochs without a range: P = 25 range_offset_m^2
        f.update(EpochObservation(0, np.nan, np.nan, 0.7, 1.3))
    p_m2 = 25 * ModelNoise().range_offset_m ** 2
    assert f.range_offset_var_m2 == pytest.approx(p_m2)
    before = f.range_offset_m.copy()
    predicted = geometry.range_m(f.particles[:, 0], f.particles[:, 1]) - before
    f.update(EpochObservation(25, 4.0, 0.5, 0.7, 1.3))
    s_m2 = p_m2 + 0.25
    np.testing.assert_allclose(f.range_offset_m, before - p_m2 / s_m2 * (4.0 - predicted), atol=1e-9)
    assert f.range_offset_var_m2 == pytest.approx(p_m2 * 0.25 / s_m2, rel=1e-6)


def test_range_returning_far_off_after_a_long_gap_keeps_the_cloud():
    """After 60 s blocked the range returns 8 m off: the offsets take it and the cloud does not collapse.

    A sampled offset (one random-walk draw per particle, spread about 7 m after
    the gap) leaves the few particles whose draw matches the returning range
    (ESS about 0.05 Np); the marginalised one weighs every particle by its
    innovation over the offset's whole variance.
    """
    walk = park_like_walk(gain=1.0, seed=5)
    epochs = epochs_for(walk, ranges_with_blockage(walk, 30.0, 90.0, 8.0))
    back = int(np.argmax(np.isfinite(epochs.range_change_m) & (epochs.t_s > 90.0)))
    f = pf.ParticleFilter(walk.geometry, n_particles=2000, seed=2)
    f.initialise(float(epochs.pdr_heading_rad[0]), float(epochs.pdr_speed_mps[0]))
    for n in range(back + 1):
        f.predict(epochs.control(n))
        f.update(epochs.observation(n))
    after = f.estimate()
    true_x = np.interp(epochs.t_s[back], walk.truth.t_s, walk.truth.x_m)
    true_y = np.interp(epochs.t_s[back], walk.truth.t_s, walk.truth.y_m)
    assert f.ess > 0.5 * f.n_particles
    assert np.hypot(after[0] - true_x, after[1] - true_y) < 1.5


def test_range_returning_from_minutes_blocked_is_a_new_origin():
    """After 150 s blocked the range returns 60 m off (a reflection's Doppler integrated for minutes): the filter
    re-anchors the channel instead of keeping the particles that happen to fit it, and the cloud stays put.

    With the offset kept however long the gap (``range_reanchor_m`` infinite)
    the returning range is far outside every particle's offset sigma (about
    17 m), only the mixture's tail particles fit it, and the estimate jumps
    along the line of sight.
    """
    walk = park_like_walk(gain=1.0, seed=5, laps=3)
    epochs = epochs_for(walk, ranges_with_blockage(walk, 20.0, 170.0, 60.0))
    back = int(np.argmax(np.isfinite(epochs.range_change_m) & (epochs.t_s > 170.0)))
    jumps = {}
    for reanchor_m in (ModelNoise().range_reanchor_m, np.inf):
        f = pf.ParticleFilter(walk.geometry, ModelNoise(range_reanchor_m=reanchor_m), n_particles=2000, seed=2)
        f.initialise(float(epochs.pdr_heading_rad[0]), float(epochs.pdr_speed_mps[0]))
        errors = []
        for n in range(back + 6):
            f.predict(epochs.control(n))
            f.update(epochs.observation(n))
            if n >= back - 1:
                true_xy = [np.interp(epochs.t_s[n], walk.truth.t_s, c) for c in (walk.truth.x_m, walk.truth.y_m)]
                errors.append(float(np.hypot(*(f.estimate()[:2] - true_xy))))
        # How much the returning ranges added to the position error the blocked stretch left.
        jumps[reanchor_m] = max(errors) - errors[0]
    assert jumps[ModelNoise().range_reanchor_m] < 1.0, jumps
    assert jumps[np.inf] > 5.0, jumps


def test_benchmark_reports_a_rate():
    assert pf.particle_updates_per_second(1000, "numba", n_epochs=3) > 1e4
    assert pf.particle_updates_per_second(1000, "numpy", n_epochs=3) > 1e3


def test_model_noise_defaults_are_positive():
    assert np.all(ModelNoise().process_sigmas() > 0) and np.all(ModelNoise().initial_sigmas() > 0)
