"""The marginalised particle filter (fusion/rb_particle_filter.py) against truth and against its linear part's
exact answer."""

import numpy as np
import pytest
from fusion_synth import exact_ranges, park_like_walk, polyline_truth, make_pdr, SyntheticWalk

from fusion.metrics import error_stats, place_pdr, position_errors_m
from fusion.model import EpochObservation, Geometry, ModelNoise, StepControl, X, Y
from fusion.observations import aggregate_ranges, build_epochs
from fusion.driver import drive_filter
from fusion.rb_particle_filter import LIN_SCALE, MarginalisedParticleFilter, start_marginalised_filter


def _errors(track, walk):
    return error_stats(position_errors_m(track, walk.truth)).p95_m


@pytest.fixture(scope="module")
def gain_run():
    walk = park_like_walk(gain=1.15, seed=4)
    epochs = build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s), walk.initial_heading_rad)
    rbpf = start_marginalised_filter(epochs, walk.geometry, n_particles=1000, seed=1)
    run = drive_filter(rbpf, epochs, smooth=True)
    pdr95 = _errors(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk)
    return walk, rbpf, run, pdr95


def test_the_range_corrects_a_step_length_gain_error(gain_run):
    """Steps 15 % long: the range brings the track well inside the PDR's error (the particle filter's own bar),
    and the particles' scale (the PDR's gain error, kept exactly) moves from its prior 1 to the truth's 1 / 1.15."""
    walk, rbpf, run, pdr95 = gain_run
    assert _errors(run.track, walk) < 0.6 * pdr95, (_errors(run.track, walk), pdr95)
    scale = float(rbpf.weights @ rbpf.mean[:, LIN_SCALE])
    assert scale == pytest.approx(1.0 / 1.15, abs=0.03)


def test_the_stated_error_holds_the_truth(gain_run):
    """Every row states a 2x2 covariance; the truth lies in its 95 % ellipse on most rows, filtered and smoothed."""
    walk, _, run, _ = gain_run
    for track in (run.track, run.smoothed):
        cov = track.position_covariance_m2()
        assert cov.shape == (len(track.t_s), 2, 2)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        x = np.interp(track.t_s, walk.truth.t_s, walk.truth.x_m)
        y = np.interp(track.t_s, walk.truth.t_s, walk.truth.y_m)
        d = np.stack([track.x_m - x, track.y_m - y], axis=1)
        nees = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov), d)
        assert np.mean(nees < 5.991) > 0.9, np.mean(nees < 5.991)


def test_a_re_anchored_range_says_nothing_of_where_the_walker_is():
    """A range re-anchored on the particles (a new origin) and then observed standing still measures no change:
    the position along the line of sight stays as uncertain as P0 made it, as in the Kalman-type filters."""
    geometry = Geometry(0.0, 0.0, 2000.0, 0.0, 150.0)
    rbpf = MarginalisedParticleFilter(geometry, ModelNoise(), n_particles=200, seed=0)
    rbpf.initialise(0.0, 1.3)
    start_var = rbpf.position_covariance_m2()[0, 0]
    for n in range(5):
        rbpf.predict(StepControl(dt_s=0.0, interval_s=0.5))
        rbpf.update(EpochObservation(n, 7.0, 0.1, np.nan, np.nan, range_new_origin=n == 0))
    assert rbpf.position_covariance_m2()[0, 0] > 0.9 * start_var
    assert abs(rbpf.estimate()[X]) < 0.05 and abs(rbpf.estimate()[Y]) < 0.05
    assert np.all(np.linalg.eigvalsh(rbpf.cov) > -1e-9)


def test_a_straight_walk_at_the_tower_is_the_kalman_filter_of_its_scale():
    """Walking straight at the tower with the heading known (no heading noise, one hypothesis), the model is
    linear but for the range's curvature: every particle is the same extended Kalman filter, whose scale after
    the walk is the range walked over the PDR's distance (to the range's own noise)."""
    truth = polyline_truth([[0.0, 0.0], [0.0, 80.0]])
    pdr, initial = make_pdr(truth, 10.0, gain=0.9, seed=0)
    walk = SyntheticWalk(truth, pdr, Geometry(0.0, 0.0, 0.0, 3000.0, 150.0), initial)
    epochs = build_epochs(pdr, aggregate_ranges(exact_ranges(walk), pdr.t_s), initial)
    noise = ModelNoise(heading_rad=0.0, heading_rate_radps=0.0, initial_heading_rad=0.0,
                       initial_heading_rate_radps=0.0, speed_mps=0.0)
    rbpf = start_marginalised_filter(epochs, walk.geometry, noise, n_particles=20, seed=0)
    drive_filter(rbpf, epochs)
    assert np.ptp(rbpf.mean[:, LIN_SCALE]) < 1e-9
    assert rbpf.mean[0, LIN_SCALE] == pytest.approx(1.0 / 0.9, abs=0.01)


def test_the_start_covariance_ties_every_single_tower_origin_to_the_position():
    """Two towers: the SI carriers' and both first paths' origins are the walker's own start ranges, moved by the
    fix's error together with the position (their covariance a rank-2 map of it), the difference's origin is the
    fix's value with its own variance; the whole stays positive semi-definite (a first version tied each origin to
    the position but not to the others, and its first range update went negative)."""
    geometry = Geometry(0.0, 0.0, 2000.0, 2200.0, 150.0, other_towers=((-1800.0, 1500.0, 100.0),))
    rbpf = MarginalisedParticleFilter(geometry, ModelNoise(), n_particles=10, seed=0)
    rbpf.initialise(0.3, 1.3)
    cov = rbpf.cov[0]
    assert np.linalg.eigvalsh(cov).min() > -1e-9
    offsets = rbpf._offsets
    # The SI range's origin and tower 0's first path's are the same range of the same start: fully correlated.
    si, first = offsets[0], offsets[1]
    assert cov[si, first] == pytest.approx(np.sqrt(cov[si, si] * cov[first, first]))
