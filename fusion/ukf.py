"""Unscented Kalman filter on the fusion model (filterpy), the baseline of [WT-UKF].

Same state, process and observations as the particle filter
(:mod:`fusion.model`), so the two are compared on identical equations; the
UKF's Gaussian assumption and single linearisation-free mean are what differ.
Headings are averaged on the circle and their residuals wrapped.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from dtmbnav_core.records import FusedTrack
from fusion.driver import run_filter
from fusion.integrity import IntegrityConfig
from fusion.kalman import RangeKalmanFilter
from fusion.model import ClockModel, Geometry, KalmanObservation, ModelNoise, StepControl, state_mean, state_residual
from fusion.observations import FilterEpochs


class RangePdrUkf(RangeKalmanFilter):
    """filterpy's UKF on the shared model (:class:`fusion.kalman.RangeKalmanFilter`).

    Parameters
    ----------
    geometry : Geometry
    noise : ModelNoise
    initial_heading_rad, initial_speed_mps : float
        Initial state at P0.
    clock : ClockModel
    integrity : IntegrityConfig
    alpha, beta, kappa : float
        Van der Merwe's scaled sigma-point parameters. ``alpha`` is kept
        moderate (0.3) so the sigma points span the heading uncertainty
        without the large negative centre weight a tiny alpha gives.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise, initial_heading_rad: float, initial_speed_mps: float,
                 clock: ClockModel = ClockModel(), integrity: IntegrityConfig = IntegrityConfig(),
                 alpha: float = 0.3, beta: float = 2.0, kappa: float = 0.0) -> None:
        super().__init__(geometry, noise, clock, integrity)
        x0, P0 = self.initial_state_covariance(initial_heading_rad, initial_speed_mps)
        points = MerweScaledSigmaPoints(len(x0), alpha=alpha, beta=beta, kappa=kappa, subtract=state_residual)
        self.ukf = UnscentedKalmanFilter(
            dim_x=len(x0), dim_z=self.layout.size, dt=1.0, hx=self._hx, fx=self._fx, points=points,
            x_mean_fn=state_mean, residual_x=state_residual)
        self.ukf.x = x0
        self.ukf.P = P0

    def _fx(self, x: np.ndarray, dt: float, control: StepControl) -> np.ndarray:
        return self.model_propagate(x, control)

    def _hx(self, x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return self.model_observe(x)[rows]

    @property
    def x(self) -> np.ndarray:
        """Current state estimate."""
        return self.ukf.x

    @property
    def P(self) -> np.ndarray:
        """Current state covariance."""
        return self.ukf.P

    def time_update(self, control: StepControl) -> np.ndarray:
        """Unscented prediction through :meth:`model_propagate`; returns the sigma points' cross-covariance of
        the state before and after (what filterpy's ``rts_smoother`` forms from them)."""
        before_x = np.array(self.ukf.x)
        before = self.ukf.points_fn.sigma_points(before_x, self.ukf.P)   # the points filterpy's predict draws
        self.ukf.Q = self.model_process_covariance(control)
        self.ukf.predict(dt=control.dt_s, control=control)
        # filterpy replaces its propagated points by fresh ones around the prior: propagate them again here.
        d_before = state_residual(before, before_x)
        d_after = state_residual(self.model_propagate(before, control), self.ukf.x)
        return (d_before * self.ukf.Wc[:, None]).T @ d_after

    def replace_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Take ``x``, ``P`` as the prior (and its sigma points, which the update propagates)."""
        self.ukf.x, self.ukf.P = x, P
        self.ukf.sigmas_f = self.ukf.points_fn.sigma_points(x, P)

    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """Unscented update with the epoch's observations (``epoch`` is unused here)."""
        self._update(observation.z, np.diag(observation.sigma**2), observation)

    def _update(self, z: np.ndarray, R: np.ndarray, observation: KalmanObservation) -> None:
        # The observation vector's length and heading position change when the range is
        # missing, so the circular mean and wrapped residual are set per update.
        self.ukf.z_mean = observation.mean
        self.ukf.residual_z = observation.residual
        self.ukf.update(z, R=R, rows=observation.rows)


def run_ukf(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
            clock: ClockModel = ClockModel(), integrity: IntegrityConfig = IntegrityConfig()) -> FusedTrack:
    """Run the UKF over all epochs; initial heading and speed from the first step's PDR."""
    return run_filter(RangePdrUkf(geometry, noise, *epochs.initial_heading_speed(), clock, integrity), epochs)
