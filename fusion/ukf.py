"""Unscented Kalman filter on the fusion model (filterpy), the baseline of [WT-UKF].

Same state, process and observations as the particle filter
(:mod:`fusion.model`), so the two are compared on identical equations; the
UKF's Gaussian assumption and single linearisation-free mean are what differ.
Headings are averaged on the circle and their residuals wrapped.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from dtmbnav.core.records import Track
from fusion.driver import run_filter
from fusion.kalman import RangeKalmanFilter
from fusion.model import (STATE_SIZE, Geometry, KalmanObservation, ModelNoise, StepControl, initial_covariance,
                          initial_state, observe, process_covariance, propagate, state_mean, state_residual)
from fusion.observations import FilterEpochs


class RangePdrUkf(RangeKalmanFilter):
    """filterpy's UKF on the shared model (:class:`fusion.kalman.RangeKalmanFilter`).

    Parameters
    ----------
    geometry : Geometry
    noise : ModelNoise
    initial_heading_rad, initial_speed_mps : float
        Initial state at P0.
    alpha, beta, kappa : float
        Van der Merwe's scaled sigma-point parameters. ``alpha`` is kept
        moderate (0.3) so the sigma points span the heading uncertainty
        without the large negative centre weight a tiny alpha gives.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise, initial_heading_rad: float, initial_speed_mps: float,
                 alpha: float = 0.3, beta: float = 2.0, kappa: float = 0.0) -> None:
        super().__init__(geometry, noise)
        points = MerweScaledSigmaPoints(STATE_SIZE, alpha=alpha, beta=beta, kappa=kappa, subtract=state_residual)
        self.ukf = UnscentedKalmanFilter(
            dim_x=STATE_SIZE, dim_z=3, dt=1.0, hx=self._hx, fx=self._fx, points=points,
            x_mean_fn=state_mean, residual_x=state_residual)
        self.ukf.x = initial_state(geometry, initial_heading_rad, initial_speed_mps)
        self.ukf.P = initial_covariance(noise)
        self.ukf.Q = process_covariance(noise)

    @staticmethod
    def _fx(x: np.ndarray, dt: float, control: StepControl) -> np.ndarray:
        return propagate(x, control)

    def _hx(self, x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return observe(x, self.geometry, self.start_range_m)[rows]

    @property
    def x(self) -> np.ndarray:
        """Current state estimate."""
        return self.ukf.x

    @property
    def P(self) -> np.ndarray:
        """Current state covariance."""
        return self.ukf.P

    def predict(self, control: StepControl) -> None:
        """Unscented prediction through :func:`fusion.model.propagate`."""
        self.ukf.predict(dt=control.dt_s, control=control)

    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """Unscented update with the epoch's observations (``epoch`` is unused here)."""
        self._update(observation.z, np.diag(observation.sigma**2), observation)

    def _update(self, z: np.ndarray, R: np.ndarray, observation: KalmanObservation) -> None:
        # The observation vector's length and heading position change when the range is
        # missing, so the circular mean and wrapped residual are set per update.
        self.ukf.z_mean = observation.mean
        self.ukf.residual_z = observation.residual
        self.ukf.update(z, R=R, rows=observation.rows)


def run_ukf(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise()) -> Track:
    """Run the UKF over all epochs; initial heading and speed from the first epoch's PDR."""
    kf = RangePdrUkf(geometry, noise, float(epochs.pdr_heading_rad[0]), float(epochs.pdr_speed_mps[0]))
    return run_filter(kf, epochs)
