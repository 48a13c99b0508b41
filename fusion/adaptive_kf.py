"""Quality-adaptive Kalman filter ([CN0-KF]): inflate R where the link is graded poor.

[CN0-KF] grades the GNSS environment each epoch from the mean satellite C/N0:
``P = 10^((40 - C/N0) / 10)`` is compared with the running mean ``C`` of P;
the epoch is good if ``P <= 1.2 C``, medium if ``P <= 1.6 C`` and bad
otherwise, and the measurement noise is multiplied by 1, 5 or 10. Here the
same grading is applied to the DTMB link's SNR for the range observation
(the reference level 40 cancels in ``P / C``, so it is kept only for
fidelity), and to the C/N0 of GNSS fixes where the caller has any; a fix
without C/N0 is weighted by its stated accuracy instead, where it states one.

The filter is an extended Kalman filter on the shared model
(:mod:`fusion.model`) with its analytic Jacobians. The range's R is the
aggregation's sigma squared (:mod:`fusion.observations`, already inflated on
a weak link) times the grade factor: the grading is a second, relative
adaptation on top of the absolute one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS
from dtmbnav_core.records import FusedTrack
from fusion.driver import run_filter
from fusion.integrity import IntegrityConfig
from fusion.kalman import RangeKalmanFilter
from fusion.model import (HEADING, RANGE_ROW, ClockModel, Geometry, KalmanObservation, ModelNoise, StepControl, X, Y,
                          wrap_angle)
from fusion.observations import FilterEpochs

#: [CN0-KF]'s grade thresholds on P / C and the R multipliers of the grades.
GRADE_THRESHOLDS = (1.2, 1.6)
GRADE_FACTORS = (1.0, 5.0, 10.0)


def quality_grade_factors(quality_db: np.ndarray, reference_db: float = 40.0) -> np.ndarray:
    """R multipliers (1, 5, 10) per epoch from a quality series (C/N0 or SNR, dB).

    ``P_n = 10^((reference - q_n)/10)`` is graded against the causal running
    mean of P over the epochs up to and including n (NaN epochs are skipped
    and get factor 1).
    """
    quality_db = np.asarray(quality_db, dtype=np.float64)
    finite = np.isfinite(quality_db)
    p = np.where(finite, 10.0 ** ((reference_db - np.where(finite, quality_db, 0.0)) / 10.0), 0.0)
    running_mean = np.cumsum(p) / np.maximum(np.cumsum(finite), 1)
    factors = np.full(len(quality_db), GRADE_FACTORS[2])
    factors[p <= GRADE_THRESHOLDS[1] * running_mean] = GRADE_FACTORS[1]
    factors[p <= GRADE_THRESHOLDS[0] * running_mean] = GRADE_FACTORS[0]
    factors[~finite] = 1.0
    return factors


@dataclass(frozen=True)
class GnssFixes:
    """GNSS position fixes the adaptive filter may use during the walk.

    Attributes
    ----------
    t_s, x_m, y_m, cn0_dbhz : ndarray
        Fix time (s), position (m) and mean C/N0 (dB-Hz; NaN where the log gives none).
    sigma_m : float
        Per-axis standard deviation of a good-grade fix, m.
    accuracy_m : ndarray or None
        Each fix's stated horizontal accuracy, m (the radius of 68 % confidence, :mod:`dtmbnav_core.phone`;
        NaN where none is stated); None: not known.
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    cn0_dbhz: np.ndarray
    sigma_m: float = 3.0
    accuracy_m: np.ndarray | None = None

    def variances_m2(self) -> np.ndarray:
        """Each fix's per-axis variance, m^2: ``sigma_m`` squared times its C/N0 grade factor.

        A fix without C/N0 has no grade; where it states its accuracy, its variance is that accuracy's,
        ``(accuracy / 1.51)^2`` (:data:`~dtmbnav_core.phone.ACCURACY_RADIUS_SIGMAS`): the phone's own error
        estimate is a better guess than taking it for a good-grade fix. One that states neither keeps
        ``sigma_m`` squared."""
        variances = self.sigma_m**2 * quality_grade_factors(self.cn0_dbhz)
        if self.accuracy_m is None:
            return variances
        accuracy = np.asarray(self.accuracy_m, dtype=np.float64)
        stated = ~np.isfinite(self.cn0_dbhz) & np.isfinite(accuracy) & (accuracy > 0)
        variances[stated] = (accuracy[stated] / ACCURACY_RADIUS_SIGMAS) ** 2
        return variances


class AdaptiveEkf(RangeKalmanFilter):
    """EKF on the shared model with [CN0-KF]'s graded R.

    Parameters
    ----------
    geometry : Geometry
    noise : ModelNoise
    epochs : FilterEpochs
        Their SNR is graded up front (the grading is causal).
    gnss : GnssFixes or None
        Fixes within ``gnss_max_age_s`` of an epoch are used as position
        observations with their own C/N0 grade, or their stated accuracy
        where they have no C/N0 (:meth:`GnssFixes.variances_m2`).
    gnss_max_age_s : float
        How close a fix must be to an epoch, s.
    clock : ClockModel
    integrity : IntegrityConfig
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise, epochs: FilterEpochs,
                 gnss: GnssFixes | None = None, gnss_max_age_s: float = 0.5, clock: ClockModel = ClockModel(),
                 integrity: IntegrityConfig = IntegrityConfig()) -> None:
        super().__init__(geometry, noise, clock, integrity)
        self._x, self._P = self.initial_state_covariance(*epochs.initial_heading_speed())
        self.range_factors = quality_grade_factors(epochs.snr_db)
        self.gnss_index = np.full(len(epochs), -1)
        if gnss is not None and len(gnss.t_s) > 0:
            nearest = np.clip(np.searchsorted(gnss.t_s, epochs.t_s), 0, len(gnss.t_s) - 1)
            close = np.abs(gnss.t_s[nearest] - epochs.t_s) <= gnss_max_age_s
            self.gnss_index = np.where(close, nearest, -1)
            self.gnss_variances_m2 = gnss.variances_m2()
        self.gnss = gnss

    def time_update(self, control: StepControl) -> np.ndarray:
        """EKF prediction through :meth:`model_propagate`; returns ``P F^T``, the cross-covariance of the
        state before and after."""
        f = self.model_transition_jacobian(self.x, control)
        cross = self.P @ f.T
        self._x = self.model_propagate(self.x, control)
        self._P = f @ cross + self.model_process_covariance(control)
        return cross

    def replace_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Take ``x``, ``P`` as the state."""
        self._x, self._P = x, P

    @property
    def x(self) -> np.ndarray:
        """Current state estimate."""
        return self._x

    @property
    def P(self) -> np.ndarray:
        """Current state covariance."""
        return self._P

    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """EKF update with the graded range R (and a graded GNSS fix if one is near)."""
        variance = observation.sigma**2
        if observation.rows[0] == RANGE_ROW:
            variance[0] *= self.range_factors[epoch]
        predicted = self.model_observe(self.x)[observation.rows]
        residual = observation.residual(observation.z, predicted)
        h = self.model_observation_jacobian(self.x)[observation.rows]
        self._correct(residual, h, np.diag(variance))
        k = self.gnss_index[epoch]
        if k >= 0:
            fix = np.array([self.gnss.x_m[k], self.gnss.y_m[k]])
            h = np.zeros((2, len(self.x)))
            h[0, X] = h[1, Y] = 1.0
            r = np.eye(2) * self.gnss_variances_m2[k]
            self._correct(fix - self.x[[X, Y]], h, r)

    def _correct(self, residual: np.ndarray, h: np.ndarray, r: np.ndarray) -> None:
        s = h @ self.P @ h.T + r
        gain = np.linalg.solve(s, h @ self.P).T
        self._x = self.x + gain @ residual
        self._x[HEADING] = wrap_angle(self.x[HEADING])
        # Joseph form keeps P symmetric positive definite.
        i_kh = np.eye(len(self.x)) - gain @ h
        self._P = i_kh @ self.P @ i_kh.T + gain @ r @ gain.T


def run_adaptive_kf(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                    gnss: GnssFixes | None = None, clock: ClockModel = ClockModel(),
                    integrity: IntegrityConfig = IntegrityConfig()) -> FusedTrack:
    """Run the quality-adaptive EKF over all epochs."""
    return run_filter(AdaptiveEkf(geometry, noise, epochs, gnss, clock=clock, integrity=integrity), epochs)
