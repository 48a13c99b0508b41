"""Smoothers for recorded walks (fusion/smoothing.py, the particle filter's fixed-lag smoother)."""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

from fusion.model import EpochObservation, Geometry, ModelNoise, StepControl
from fusion.particle_filter import ParticleFilter, weighted_position_covariance
from fusion.smoothing import KalmanHistory, rts_smooth


def linear_problem(seed: int = 0, n: int = 12):
    """A 1-D constant-velocity walk observed in position: F, Q, H, R, x0, P0 and the observations."""
    rng = np.random.default_rng(seed)
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = np.diag([0.02, 0.05])
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.5]])
    x0, P0 = np.array([0.0, 1.0]), np.diag([1.0, 0.5])
    x = rng.multivariate_normal(x0, P0)
    zs = []
    for _ in range(n):
        x = F @ x + rng.multivariate_normal(np.zeros(2), Q)
        zs.append(H @ x + rng.normal(0.0, np.sqrt(R[0, 0]), 1))
    return F, Q, H, R, x0, P0, np.array(zs)


def kalman_history(F, Q, H, R, x0, P0, zs) -> KalmanHistory:
    """A linear Kalman filter's run recorded as the range filters record theirs (cross = P F^T)."""
    history = KalmanHistory()
    x, P = x0, P0
    for z in zs:
        cross = P @ F.T
        x, P = F @ x, F @ P @ F.T + Q
        history.record_prior(x, P, cross)
        gain = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        x, P = x + gain @ (z - H @ x), (np.eye(2) - gain @ H) @ P
        history.record_posterior(x, P)
    return history


def batch_least_squares(F, Q, H, R, x0, P0, zs):
    """The smoothed states as one weighted least-squares problem over x_1..x_n: its solution and covariance."""
    n = len(zs)
    rows, rhs, weights = [], [], []

    def add(block_row, value, cov):
        rows.append(block_row)
        rhs.append(value)
        weights.append(np.linalg.inv(cov))

    # x_1 = F x_0 + w with x_0 ~ N(x0, P0): prior of x_1 is N(F x0, F P0 F^T + Q).
    first = np.zeros((2, 2 * n))
    first[:, :2] = np.eye(2)
    add(first, F @ x0, F @ P0 @ F.T + Q)
    for k in range(1, n):
        dyn = np.zeros((2, 2 * n))
        dyn[:, 2 * k:2 * k + 2] = np.eye(2)
        dyn[:, 2 * k - 2:2 * k] = -F
        add(dyn, np.zeros(2), Q)
    for k, z in enumerate(zs):
        obs = np.zeros((1, 2 * n))
        obs[:, 2 * k:2 * k + 2] = H
        add(obs, z, R)
    A = np.vstack(rows)
    b = np.concatenate(rhs)
    W = np.zeros((len(b), len(b)))
    i = 0
    for w in weights:
        W[i:i + len(w), i:i + len(w)] = w
        i += len(w)
    information = A.T @ W @ A
    cov = np.linalg.inv(information)
    return (cov @ A.T @ W @ b).reshape(n, 2), cov


def test_rts_smoother_is_the_batch_least_squares_solution():
    """On a linear-Gaussian problem the smoother's means and covariances are the batch solution's, and
    filterpy's rts_smoother's."""
    problem = linear_problem()
    xs, Ps = rts_smooth(kalman_history(*problem), heading=None)
    batch_x, batch_cov = batch_least_squares(*problem)
    np.testing.assert_allclose(xs, batch_x, atol=1e-9)
    for k in range(len(xs)):
        np.testing.assert_allclose(Ps[k], batch_cov[2 * k:2 * k + 2, 2 * k:2 * k + 2], atol=1e-9)
    F, Q, H, R, x0, P0, zs = problem
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = x0, P0, F, Q, H, R
    means, covariances, _, _ = kf.batch_filter(zs)
    filterpy_x, filterpy_P, _, _ = kf.rts_smoother(means, covariances)
    np.testing.assert_allclose(xs, filterpy_x, atol=1e-9)
    np.testing.assert_allclose(Ps, filterpy_P, atol=1e-9)


def test_rts_smoother_differences_the_heading_on_the_circle():
    """A heading that crosses north: the smoothed heading stays by the filtered ones, not half a turn off."""
    history = KalmanHistory()
    for heading in (6.2, 0.05, 0.1):
        x = np.array([0.0, 0.0, 0.0, heading, 1.0])
        history.record_prior(x, np.eye(5), np.eye(5) * 0.5)
        history.record_posterior(x, np.eye(5))
    xs, _ = rts_smooth(history)
    assert np.all(np.abs((xs[:, 3] - np.array([6.2, 0.05, 0.1]) + np.pi) % (2 * np.pi) - np.pi) < 0.2)


def run_small_pf(lag: int, n_epochs: int = 12, seed: int = 3) -> tuple[ParticleFilter, list[np.ndarray]]:
    """A 400-particle filter on a straight walk seen by its range; each epoch's filtered state."""
    geometry = Geometry(0.0, 0.0, 300.0, 400.0, 50.0)
    pf = ParticleFilter(geometry, ModelNoise(), 400, seed, backend="numpy", smoothing_lag=lag)
    heading = np.deg2rad(30.0)
    pf.initialise(heading, 1.3)
    pf.record_history()
    filtered = []
    tower = np.array([300.0, 400.0]) / 500.0
    for n in range(n_epochs):
        pf.predict(StepControl(0.5))
        along = 0.65 * (n + 1) * float(np.array([np.sin(heading), np.cos(heading)]) @ tower)
        pf.update(EpochObservation(n, -along, 0.5, heading, 1.3))
        filtered.append(pf.estimate())
    return pf, filtered


def test_particle_covariance_is_the_weighted_spread_of_the_particles():
    pf, _ = run_small_pf(lag=3, n_epochs=4)
    pf.weights[:] = np.random.default_rng(0).random(pf.n_particles)
    pf.weights /= pf.weights.sum()
    expected = np.cov(pf.particles[:, :2].T, aweights=pf.weights, bias=True)
    np.testing.assert_allclose(pf.position_covariance_m2(), expected, rtol=1e-10)
    np.testing.assert_allclose(weighted_position_covariance(pf.particles, pf.weights), expected, rtol=1e-10)


def test_fixed_lag_smoother_rows_and_its_last_row_is_the_filter():
    """One smoothed row per epoch; the last epoch has no future, so it is the filtered estimate and spread."""
    pf, filtered = run_small_pf(lag=4)
    states, covariances = pf.smoothed()
    assert states.shape == (12, 5) and covariances.shape == (12, 2, 2)
    np.testing.assert_allclose(states[-1, :2], filtered[-1][:2], atol=1e-4)     # the ancestry is float32
    np.testing.assert_allclose(covariances[-1], pf.position_covariance_m2(), rtol=1e-4)
    assert not np.allclose(states[0, :2], filtered[0][:2], atol=1e-3)          # later ranges moved epoch 0


def test_fixed_lag_smoother_follows_the_ancestry_through_resampling():
    """Epoch 0's smoothed state is the weighted mean of the current particles' ancestors at epoch 0 (lag long
    enough): a resampling that picks one particle leaves only its ancestor."""
    pf, _ = run_small_pf(lag=12, n_epochs=3)
    keep = 7
    ancestor = pf._smoother._ancestry[0, keep].astype(np.float64)
    pf.weights[:] = 0.0
    pf.weights[keep] = 1.0
    states, covariances = pf.smoothed()
    np.testing.assert_allclose(states[0, :2], ancestor[:2], atol=1e-9)
    np.testing.assert_allclose(covariances[0], 0.0, atol=1e-12)
