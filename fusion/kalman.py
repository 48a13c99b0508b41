"""What the Kalman-type fusion filters share: range re-anchoring around their correction step.

The Kalman-type filters (UKF, WT-UKF, adaptive EKF, rank KF) have no
range-offset state (the particle filter has, :mod:`fusion.particle_filter`).
Their stand-in: when the range comes back after ``k`` epochs without it and
the offset a random walk of ``noise.range_offset_m`` per epoch would have
gathered, ``range_offset_m * sqrt(k)``, exceeds three times the returning
observation's sigma, the filter re-anchors: its range origin is moved so that
this observation agrees with the predicted position, and the range says only
how the range changes from there.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from fusion.model import EpochObservation, Geometry, KalmanObservation, ModelNoise, StepControl, X, Y

#: Re-anchor when the offset gathered without range exceeds this many observation sigmas.
REANCHOR_SIGMAS = 3.0


class RangeKalmanFilter(ABC):
    """Base of the Kalman-type filters: ``update`` re-anchors the range, then ``correct`` updates.

    Parameters
    ----------
    geometry : Geometry
        P0 and the tower.
    noise : ModelNoise
        Process and observation noise.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise) -> None:
        self.geometry = geometry
        self.noise = noise
        #: |P_0 - P_b| as the range observation's origin, m (moved by re-anchoring).
        self.start_range_m = geometry.start_range_m()
        self._epochs_without_range = 0

    @property
    @abstractmethod
    def x(self) -> np.ndarray:
        """Current state estimate."""

    @abstractmethod
    def predict(self, control: StepControl) -> None:
        """Propagate the state and its covariance one step."""

    @abstractmethod
    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """The filter's own measurement update with the epoch's present observations."""

    def update(self, observation: EpochObservation) -> None:
        """Re-anchor the range origin after a long gap (module docstring), then :meth:`correct`."""
        if not observation.has_range:
            self._epochs_without_range += 1
        else:
            gathered_m = self.noise.range_offset_m * np.sqrt(self._epochs_without_range)
            if gathered_m > REANCHOR_SIGMAS * observation.range_sigma_m:
                self.start_range_m = float(self.geometry.range_m(self.x[X], self.x[Y])) - observation.range_change_m
            self._epochs_without_range = 0
        self.correct(observation.kalman(self.noise), observation.index)

    def estimate(self) -> np.ndarray:
        """The state estimate (a copy)."""
        return np.array(self.x, dtype=np.float64)
