"""What the Kalman-type fusion filters share: range channels, re-anchoring and integrity around their correction step.

The Kalman-type filters (UKF, WT-UKF, adaptive EKF, rank KF) have no
range-offset state (the particle filter has, :mod:`fusion.particle_filter`);
each range channel (:class:`fusion.model.ObservationLayout`) has a fixed
origin instead, its value at P0 to start with (under a free-running clock
a single-tower channel's first observation re-anchors it instead, as the
particle filter starts those channels at each particle's own range: its
first value holds the clock's drift since the capture start, which the
fix's range would read as position). Their stand-in for the
offset's random walk: when a channel comes back after ``k`` epochs without
it and the offset a random walk of ``noise.range_offset_m`` per epoch would
have gathered, ``range_offset_m * sqrt(k)``, exceeds three times the
returning observation's sigma, the filter re-anchors the channel: its origin
is moved so that this observation agrees with the predicted state, and the
channel says only how it changes from there. So does a channel whose data
restart from a new origin (:mod:`fusion.observations`) and one the integrity
monitor (:mod:`fusion.integrity`) takes back after dropping it (its epochs
without the channel count as a gap too); an observation used to re-anchor is
not weighed (it says nothing about the state). A tower difference that
carries its code range difference (docs/paths.md) re-anchors on the code
instead, its origin the code's value less the observation, and is then
weighed with the code's sigma added: it places the state on the towers'
hyperbola, which P0 knows only to the GNSS fix's error. Where the monitor drops a
channel, the filter takes the monitor's open-loop state instead of its own
(:meth:`RangeKalmanFilter.replace_state`). With a free-running clock
(:class:`fusion.model.ClockModel`) the state carries the clock's integrated
range and rate (:data:`fusion.model.CLOCK_STATE_SIZE` columns).
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod

import numpy as np

from fusion.integrity import IntegrityConfig, IntegrityMonitor
from fusion.model import (CODE_ANCHOR_GATE_SIGMAS, ClockModel, EpochObservation, Geometry, KalmanObservation,
                          ModelNoise, ObservationLayout, StepControl, observation_jacobian, observe)

#: Re-anchor when the offset gathered without range exceeds this many observation sigmas.
REANCHOR_SIGMAS = 3.0


class RangeKalmanFilter(ABC):
    """Base of the Kalman-type filters: ``update`` re-anchors and vets the ranges, then ``correct`` updates.

    Parameters
    ----------
    geometry : Geometry
        P0 and the towers.
    noise : ModelNoise
        Process and observation noise.
    clock : ClockModel
        The receiver clock (a free-running one adds the clock states).
    integrity : IntegrityConfig
        The range integrity monitor.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise, clock: ClockModel = ClockModel(),
                 integrity: IntegrityConfig = IntegrityConfig()) -> None:
        self.geometry = geometry
        self.noise = noise
        self.clock = clock
        self.layout = ObservationLayout(geometry.n_towers)
        #: Origin of each range channel (|P_0 - P_b| for the SI-carrier range), m; moved by re-anchoring.
        self.origins_m = self.layout.start_values_m(geometry)
        self.monitor = IntegrityMonitor(geometry, noise, clock, integrity)
        self._epochs_without = np.zeros(self.layout.n_channels, dtype=np.int64)
        #: Per channel, whether its current origin came from its code (:meth:`_code_anchors_pass`).
        self._origin_from_code = np.zeros(self.layout.n_channels, dtype=bool)
        #: Channels whose first observation re-anchors them: under a free-running clock the single-tower ones,
        #: whose first value holds the clock's drift since the capture start, not the fix's error.
        self._unanchored = clock.free_running & (self.layout.clock_coefficients() > 0)

    @property
    def start_range_m(self) -> float:
        """Origin of the SI-carrier range, m."""
        return float(self.origins_m[0])

    @property
    @abstractmethod
    def x(self) -> np.ndarray:
        """Current state estimate."""

    @property
    @abstractmethod
    def P(self) -> np.ndarray:
        """Current state covariance."""

    @abstractmethod
    def time_update(self, control: StepControl) -> None:
        """Propagate the state and its covariance one epoch."""

    @abstractmethod
    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """The filter's own measurement update with the epoch's present observations."""

    @abstractmethod
    def replace_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Take ``x``, ``P`` as the state (the integrity monitor's fallback)."""

    def predict(self, control: StepControl) -> None:
        """:meth:`time_update`, and the integrity monitor's open-loop predictions with it."""
        self.time_update(control)
        self.monitor.predict(control)

    def update(self, observation: EpochObservation) -> None:
        """Vet and re-anchor the range channels (module docstring), then :meth:`correct` with the rest."""
        z, sigma, new_origin = observation.range_channels(self.layout.n_towers)
        code_m = observation.code_channels(self.layout.n_towers)
        use, returning, fallback = self.monitor.assess(z, new_origin, code_m)
        if fallback is not None:
            self.replace_state(*fallback)
        gathered_m = self.noise.range_offset_m * np.sqrt(self._epochs_without)
        gap = gathered_m > REANCHOR_SIGMAS * np.where(use, sigma, np.inf)
        reanchor = use & (new_origin | returning | gap | self._unanchored)
        self._unanchored &= ~use
        predicted = observe(self.x, self.geometry, self.origins_m)[self.layout.rows()]
        # A channel takes its origin from the code where it has to re-anchor, and where it has one but its
        # origin has not come from the code yet (its first epochs, a code that failed the gate before).
        anchors = observation.anchor_channels(self.layout.n_towers)
        # (A difference has no clock term, so its geometric value is the prediction plus its origin.)
        on_code = (reanchor | (use & ~self._origin_from_code)) & self._code_anchors_pass(anchors,
                                                                                         predicted + self.origins_m)
        self.origins_m[reanchor] += predicted[reanchor] - z[reanchor]
        self.origins_m[on_code] = anchors[on_code] - z[on_code]
        self._origin_from_code = on_code | (self._origin_from_code & ~reanchor)
        self._epochs_without = np.where(use, 0, self._epochs_without + 1)
        if on_code.any():   # an origin from the code leaves the epoch's range an observation, less sure by its sigma
            differences = slice(self.layout.n_towers + 1, None)
            observation = dataclasses.replace(observation, range_difference_sigma_m=np.hypot(
                sigma[differences], np.where(on_code, self.noise.difference_code_sigma_m, 0.0)[differences]))
        kalman = observation.kalman(self.noise, self.layout.n_towers, use & (~reanchor | on_code))
        if len(kalman.rows):
            self.correct(kalman, observation.index)
        self.monitor.posterior(self.x, self.P)

    def _code_anchors_pass(self, anchors: np.ndarray, geometric: np.ndarray) -> np.ndarray:
        """Per range channel, whether its code value (:meth:`fusion.model.EpochObservation.anchor_channels`) can be
        its origin: present, a finite ``ModelNoise.difference_code_sigma_m``, and within
        :data:`fusion.model.CODE_ANCHOR_GATE_SIGMAS` of the state's value ``geometric`` (m; a late first path
        fails)."""
        code_sigma = self.noise.difference_code_sigma_m
        if not np.isfinite(code_sigma) or not np.isfinite(anchors).any():
            return np.zeros(len(anchors), dtype=bool)
        h = observation_jacobian(self.x, self.geometry)[self.layout.rows()]
        spread = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", h, self.P, h), 0.0))
        with np.errstate(invalid="ignore"):
            return np.abs(anchors - geometric) <= CODE_ANCHOR_GATE_SIGMAS * np.hypot(spread, code_sigma)

    def estimate(self) -> np.ndarray:
        """The state estimate (a copy)."""
        return np.array(self.x, dtype=np.float64)
