"""Rank Kalman filter [Rank-KF], and the rank KF on the range/PDR fusion model.

Rank sampling ([Rank-KF] eq. 4-5, 19; ``docs/method.md`` §7): with ``q`` layers, the
layer probabilities are ``p_j = (j - 0.3) / (2q + 1.4)`` for
``j = 1..2q+1, j != q+1``; ``lambda_j`` is the standard normal quantile at
``p_j`` and the correction factors are ``r_j = 1`` (the quantiles are
symmetric, so ``sum r_j lambda_j = 0``, eq. 5). The ``2qn`` points are
``x + r_j lambda_j S_l`` for every column ``S_l`` of a square root of P; the
mean is their plain average (eq. 6) and covariances are
``(1/omega) sum (.)(.)^T`` with ``omega = sum r_j^2 lambda_j^2`` (eq. 9, 17-19).
For a linear map these covariances are exact (``sum_j lambda_j^2 = omega``).

:class:`RangePdrRankKf` runs it on the shared range/PDR model
(:mod:`fusion.model`), for the same comparison as the other filters; the
foot-mounted INS with ZUPT of the same paper is :mod:`fusion.foot_ins`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.stats import norm

from dtmbnav_core.records import FusedTrack
from fusion.driver import run_filter
from fusion.integrity import IntegrityConfig
from fusion.kalman import RangeKalmanFilter
from fusion.model import ClockModel, Geometry, KalmanObservation, ModelNoise, StepControl, state_mean, state_residual
from fusion.observations import FilterEpochs


def rank_quantiles(layers: int = 2) -> tuple[np.ndarray, float]:
    """Layer quantiles ``r_j lambda_j`` (r_j = 1) and the covariance weight omega (eq. 19)."""
    j = np.array([k for k in range(1, 2 * layers + 2) if k != layers + 1], dtype=np.float64)
    lambdas = norm.ppf((j - 0.3) / (2 * layers + 1.4))
    return lambdas, float(np.sum(lambdas**2))


def rank_points(x: np.ndarray, P: np.ndarray, lambdas: np.ndarray) -> np.ndarray:
    """The ``2qn`` rank-sampling points around ``x`` (eq. 4/10), shape (2qn, n)."""
    root = np.linalg.cholesky(P)
    offsets = lambdas[:, None, None] * root.T[None, :, :]  # (layers, n columns, n)
    return x + offsets.reshape(-1, len(x))


class RankKalmanFilter:
    """Generic rank Kalman filter.

    Parameters
    ----------
    x, P : ndarray
        Initial state and covariance.
    mean_fn : callable(points) -> ndarray
        Average of state points (a plain mean, or circular for angles).
    residual_fn : callable(a, b) -> ndarray
        State difference (angles wrapped).
    layers : int
        q, the number of sampling layers on each side.
    """

    def __init__(self, x: np.ndarray, P: np.ndarray, mean_fn: Callable[[np.ndarray], np.ndarray],
                 residual_fn: Callable[[np.ndarray, np.ndarray], np.ndarray], layers: int = 2) -> None:
        self.x = np.asarray(x, dtype=np.float64)
        self.P = np.asarray(P, dtype=np.float64)
        self.mean_fn = mean_fn
        self.residual_fn = residual_fn
        self.lambdas, self.omega = rank_quantiles(layers)

    def predict(self, fx: Callable[[np.ndarray], np.ndarray], Q: np.ndarray) -> np.ndarray:
        """Eq. 6-9: propagate the rank points through ``fx`` (rows -> rows).

        Returns
        -------
        ndarray
            The cross-covariance of the state before and after, ``(1/omega) sum (.)(.)^T`` of the points'
            residuals before and after (as eq. 17 forms ``P_xz``), for a smoother.
        """
        before_x = self.x
        points = rank_points(self.x, self.P, self.lambdas)
        propagated = fx(points)
        self.x = self.mean_fn(propagated)
        d = self.residual_fn(propagated, self.x)
        self.P = d.T @ d / self.omega + Q
        return self.residual_fn(points, before_x).T @ d / self.omega

    def update(self, z: np.ndarray, hx: Callable[[np.ndarray], np.ndarray], R: np.ndarray,
               z_mean_fn: Callable[[np.ndarray], np.ndarray],
               z_residual_fn: Callable[[np.ndarray, np.ndarray], np.ndarray], noise_mean: np.ndarray | float = 0.0,
               ) -> None:
        """Eq. 10-18: re-sample, predict the observation, correct."""
        points = rank_points(self.x, self.P, self.lambdas)
        predicted = hx(points) + noise_mean
        z_hat = z_mean_fn(predicted)
        dz = z_residual_fn(predicted, z_hat)
        dx = self.residual_fn(points, self.x)
        p_zz = dz.T @ dz / self.omega + R
        p_xz = dx.T @ dz / self.omega
        gain = np.linalg.solve(p_zz, p_xz.T).T
        self.x = self.x + gain @ z_residual_fn(z, z_hat)
        self.P = self.P - gain @ p_zz @ gain.T
        self.P = 0.5 * (self.P + self.P.T)


class RangePdrRankKf(RangeKalmanFilter):
    """Rank KF on the shared range/PDR model (:class:`fusion.kalman.RangeKalmanFilter`)."""

    def __init__(self, geometry: Geometry, noise: ModelNoise, initial_heading_rad: float,
                 initial_speed_mps: float, layers: int = 2, clock: ClockModel = ClockModel(),
                 integrity: IntegrityConfig = IntegrityConfig()) -> None:
        super().__init__(geometry, noise, clock, integrity)
        self.rkf = RankKalmanFilter(*self.initial_state_covariance(initial_heading_rad, initial_speed_mps),
                                    self._mean, state_residual, layers)

    @staticmethod
    def _mean(points: np.ndarray) -> np.ndarray:
        return state_mean(points, np.full(len(points), 1.0 / len(points)))

    @property
    def x(self) -> np.ndarray:
        """Current state estimate."""
        return self.rkf.x

    @property
    def P(self) -> np.ndarray:
        """Current state covariance."""
        return self.rkf.P

    def time_update(self, control: StepControl) -> np.ndarray:
        """Rank-sampled prediction through :meth:`model_propagate`; returns the cross-covariance of the state
        before and after."""
        return self.rkf.predict(lambda pts: self.model_propagate(pts, control),
                                self.model_process_covariance(control))

    def replace_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Take ``x``, ``P`` as the state."""
        self.rkf.x, self.rkf.P = x, P

    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """Rank-sampled update with the epoch's observations (``epoch`` unused)."""
        self.rkf.update(
            observation.z,
            lambda pts: self.model_observe(pts)[:, observation.rows],
            np.diag(observation.sigma**2),
            lambda zs: observation.mean(zs, np.full(len(zs), 1.0 / len(zs))),
            observation.residual)


def run_rank_kf(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                clock: ClockModel = ClockModel(), integrity: IntegrityConfig = IntegrityConfig()) -> FusedTrack:
    """Run the rank KF over all epochs."""
    kf = RangePdrRankKf(geometry, noise, *epochs.initial_heading_speed(), clock=clock, integrity=integrity)
    return run_filter(kf, epochs)
