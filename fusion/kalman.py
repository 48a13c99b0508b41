"""What the Kalman-type fusion filters share: range channels with origin states, re-anchoring and integrity.

The Kalman-type filters (UKF, WT-UKF, adaptive EKF, rank KF) carry, after
the motion state (and the clock's, :class:`fusion.model.ClockModel`), one
**origin state** per range channel (:class:`fusion.model.ObservationLayout`):
the value the channel's integrated range counts from, so that channel ``j``
observes ``g_j(x, y) + clock - o_j``. These are the particle filter's range
offsets (:mod:`fusion.particle_filter`), with the same model, so that every
filter is compared on the same equations:

- At P0 a single-tower channel's origin is the walker's own start range:
  ``o_j = g_j(P0)``, carried with its covariance with the initial position
  (``J P0``; a clone of the start, as each particle starts at its own
  range), so that the range says how the walker moved and the fix's error is
  not read as a range error. A tower difference's origin is its value at
  the fix, known to its gradient times the fix's spread and independent of
  the position, so that it places the walker on a hyperbola.
- In epochs without a channel's observation its origin takes a random-walk
  step of ``ModelNoise.range_offset_m``; once its standard deviation has
  grown past ``ModelNoise.range_reanchor_m`` the returning channel is
  re-anchored.
- **Re-anchoring** (a new origin in the data, a channel the integrity
  monitor :mod:`fusion.integrity` takes back, a lost origin, and under a
  free-running clock a single-tower channel's first observation, whose value
  holds the clock's drift since the capture start): the origin becomes the
  state's value less the observation, ``o_j = g_j(x) + clock - z_j``, with
  its covariance with the state (``J P``, and ``J P J^T + sigma^2`` its
  variance): stochastic cloning. The observation is not weighed (it says
  nothing about the state), and later ones say how the state changed since.
  An origin set to a number, without that covariance, would make the next
  observations absolute ranges from the state of that epoch: the state's
  uncertainty along the line of sight would collapse to the observation's,
  around a position still the fix's (docs/method.md §8).
- A tower difference that carries its code range difference (docs/paths.md)
  re-anchors on the code instead: ``o_j = code - z_j``, of variance
  ``ModelNoise.difference_code_sigma_m^2`` plus that of the transmit delay offsets taken out of
  the code (:mod:`fusion.transmit_delays`), independent of the state, and
  the epoch's observation then weighs.

Where the monitor drops a channel, the filter takes the monitor's open-loop
motion (and clock) state instead of its own
(:meth:`RangeKalmanFilter.replace_state`); the origins keep their values.

Every epoch states its error: the east/north block of ``P``
(:meth:`RangeKalmanFilter.position_covariance_m2`). For a recorded walk
(:meth:`RangeKalmanFilter.record_history`) the filter keeps each epoch's
prior, posterior and ``Cov(x_{k-1}, x_k^-)``, carried through the
re-anchoring above, for the RTS smoother (:mod:`fusion.smoothing`).
The model functions of :mod:`fusion.model` work on the motion and clock
columns; :meth:`RangeKalmanFilter.model_propagate`,
:meth:`~RangeKalmanFilter.model_observe` and the Jacobians here extend them
to the origin columns.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from fusion.integrity import IntegrityConfig, IntegrityMonitor
from fusion.model import (CLOCK_STATE_SIZE, CODE_ANCHOR_GATE_SIGMAS, STATE_SIZE, ClockModel, EpochObservation,
                          Geometry, KalmanObservation, ModelNoise, ObservationLayout, StepControl, X, Y,
                          initial_covariance, initial_state, observation_jacobian, observe, process_covariance,
                          propagate, transition_jacobian, walk_range_origins)
from fusion.smoothing import KalmanHistory, rts_smooth

#: Independent standard deviation of a single-tower channel's origin at P0, m. A clone of the start is an exact
#: function of the state, which would leave P singular (and the sigma-point filters' Cholesky factor undefined);
#: 1 cm is far below any range's sigma.
ORIGIN_FLOOR_M = 0.01


class RangeKalmanFilter(ABC):
    """Base of the Kalman-type filters: ``update`` re-anchors and vets the ranges, then ``correct`` updates.

    The state is ``[motion (5), clock (2, if the clock has states), origins (n_channels)]``
    (module docstring). A filter builds its state with :meth:`initial_state_covariance`,
    and its process and observation models from :meth:`model_propagate`,
    :meth:`model_observe`, :meth:`model_process_covariance` and the Jacobians.

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
        #: Columns of the motion and clock states; the origin states follow.
        self.core_size = CLOCK_STATE_SIZE if clock.has_state else STATE_SIZE
        self._origins = slice(self.core_size, self.core_size + self.layout.n_channels)
        self._origin_columns = np.arange(self._origins.start, self._origins.stop)
        self.monitor = IntegrityMonitor(geometry, noise, clock, integrity)
        #: Per channel, whether its current origin came from its code (:meth:`_code_anchors_pass`).
        self._origin_from_code = np.zeros(self.layout.n_channels, dtype=bool)
        #: Channels whose first observation re-anchors them: under a free-running clock the single-tower ones,
        #: whose first value holds the clock's drift since the capture start, not the fix's error.
        self._unanchored = clock.free_running & (self.layout.clock_coefficients() > 0)
        #: ``Cov(x_{k-1}, x)``: the last filtered state with the current one (:meth:`time_update`, re-anchoring).
        self._cross: np.ndarray | None = None
        #: What the RTS smoother needs, when recording (:meth:`record_history`).
        self.history: KalmanHistory | None = None

    @property
    def origins_m(self) -> np.ndarray:
        """Each range channel's origin (the state's origin columns, a copy), m."""
        return np.array(self.x[self._origins])

    @property
    def start_range_m(self) -> float:
        """Origin of the SI-carrier range, m."""
        return float(self.x[self.core_size])

    @property
    @abstractmethod
    def x(self) -> np.ndarray:
        """Current state estimate."""

    @property
    @abstractmethod
    def P(self) -> np.ndarray:
        """Current state covariance."""

    @abstractmethod
    def time_update(self, control: StepControl) -> np.ndarray:
        """Propagate the state and its covariance one epoch; return ``Cov(x_before, x_after)``
        (the filter's own cross-covariance of its state before and after, for the smoother)."""

    @abstractmethod
    def correct(self, observation: KalmanObservation, epoch: int) -> None:
        """The filter's own measurement update with the epoch's present observations."""

    @abstractmethod
    def replace_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Take ``x``, ``P`` as the state (re-anchoring, the integrity monitor's fallback)."""

    def initial_state_covariance(self, heading_rad: float, speed_mps: float) -> tuple[np.ndarray, np.ndarray]:
        """The state at P0 and its covariance, origins included (module docstring)."""
        core = initial_state(self.geometry, heading_rad, speed_mps, self.clock)
        core_cov = initial_covariance(self.noise, self.clock)
        jacobian = observation_jacobian(core, self.geometry)[self.layout.rows()]
        difference = self.layout.clock_coefficients() == 0.0
        h = np.where(difference[:, None], 0.0, jacobian)   # a difference's origin is independent of the start
        n = self.core_size + self.layout.n_channels
        x = np.concatenate([core, self.layout.start_values_m(self.geometry)])
        P = np.zeros((n, n))
        P[:self.core_size, :self.core_size] = core_cov
        P[self._origins, :self.core_size] = h @ core_cov
        P[:self.core_size, self._origins] = P[self._origins, :self.core_size].T
        P[self._origins, self._origins] = h @ core_cov @ h.T
        gradient = np.hypot(jacobian[:, X], jacobian[:, Y])
        P[self._origin_columns, self._origin_columns] += np.where(
            difference, (gradient * self.noise.initial_position_m) ** 2, ORIGIN_FLOOR_M**2)
        return x, P

    def model_propagate(self, states: np.ndarray, control: StepControl) -> np.ndarray:
        """:func:`fusion.model.propagate` of rows of states; the origins stay."""
        out = np.array(states, dtype=np.float64, copy=True)
        out[..., :self.core_size] = propagate(states[..., :self.core_size], control)
        return out

    def model_observe(self, states: np.ndarray) -> np.ndarray:
        """:func:`fusion.model.observe` of rows of states, each with its own origins."""
        return observe(states[..., :self.core_size], self.geometry, states[..., self._origins])

    def model_transition_jacobian(self, x: np.ndarray, control: StepControl) -> np.ndarray:
        """d :meth:`model_propagate` / d x at ``x``."""
        f = np.eye(len(x))
        f[:self.core_size, :self.core_size] = transition_jacobian(x[:self.core_size], control)
        return f

    def model_observation_jacobian(self, x: np.ndarray) -> np.ndarray:
        """d :meth:`model_observe` / d x at ``x``: each range channel -1 on its origin."""
        h = np.zeros((self.layout.size, len(x)))
        h[:, :self.core_size] = observation_jacobian(x[:self.core_size], self.geometry)
        h[self.layout.rows(), self._origin_columns] = -1.0
        return h

    def model_process_covariance(self, control: StepControl) -> np.ndarray:
        """:func:`fusion.model.process_covariance`; the origins' random walk is added by :meth:`update`."""
        q = np.zeros((len(self.x), len(self.x)))
        q[:self.core_size, :self.core_size] = process_covariance(self.noise, control, self.clock)
        return q

    def predict(self, control: StepControl) -> None:
        """:meth:`time_update`, and the integrity monitor's open-loop predictions with it."""
        self._cross = self.time_update(control)
        self.monitor.predict(control)

    def record_history(self) -> None:
        """Keep every epoch's prior, posterior and cross-covariance from now on (:meth:`smoothed`)."""
        self.history = KalmanHistory()

    def position_covariance_m2(self) -> np.ndarray:
        """The stated error of the current position: the east/north block of ``P``, m^2."""
        return np.array(self.P[np.ix_([X, Y], [X, Y])])

    def smoothed(self) -> tuple[np.ndarray, np.ndarray]:
        """The RTS-smoothed states (N, n) and their east/north covariances (N, 2, 2) of the recorded epochs.

        Raises
        ------
        ValueError
            If nothing was recorded (:meth:`record_history` not called before the run).
        """
        if self.history is None or not self.history.post_x:
            raise ValueError("smoothed: no recorded epochs (call record_history before the run)")
        states, covariances = rts_smooth(self.history)
        return states, covariances[:, [X, Y]][:, :, [X, Y]]

    def update(self, observation: EpochObservation) -> None:
        """Vet and re-anchor the range channels (module docstring), then :meth:`correct` with the rest."""
        z, sigma, new_origin = observation.range_channels(self.layout.n_towers)
        code_m = observation.code_channels(self.layout.n_towers)
        use, returning, fallback = self.monitor.assess(z, new_origin, code_m)
        x, P = np.array(self.x), np.array(self.P)
        core = slice(0, self.core_size)
        if fallback is not None:   # the monitor's motion and clock, without their covariance with the origins
            x[core], P[core, core] = fallback
            P[core, self._origins] = P[self._origins, core] = 0.0
            self._reset_cross(core)
        origins = self._origin_columns
        lost = walk_range_origins(P, origins, use, self.noise)
        reanchor = use & (new_origin | returning | lost | self._unanchored)
        self._unanchored &= ~use
        predicted = self.model_observe(x)[self.layout.rows()]
        # A channel takes its origin from the code where it has to re-anchor, and where it has one but its
        # origin has not come from the code yet (its first epochs, a code that failed the gate before).
        anchors = observation.anchor_channels(self.layout.n_towers)
        anchor_sigmas = observation.anchor_sigmas(self.noise.difference_code_sigma_m, self.layout.n_towers)
        on_code = (reanchor | (use & ~self._origin_from_code)) & self._code_anchors_pass(
            anchors, anchor_sigmas, predicted + x[self._origins], x, P)   # (a difference has no clock term)
        for j in np.flatnonzero(reanchor & ~on_code):
            self._clone_origin(x, P, j, predicted[j] + x[origins[j]] - z[j], sigma[j])
        for j in np.flatnonzero(on_code):
            o = origins[j]
            x[o] = anchors[j] - z[j]
            P[o, :] = P[:, o] = 0.0
            P[o, o] = anchor_sigmas[j]**2
            self._reset_cross(o)
        self._origin_from_code = on_code | (self._origin_from_code & ~reanchor)
        self.replace_state(x, P)
        if self.history is not None:
            self.history.record_prior(self.x, self.P, self._cross)
        kalman = observation.kalman(self.noise, self.layout.n_towers, use & (~reanchor | on_code))
        if len(kalman.rows):
            self.correct(kalman, observation.index)
        if self.history is not None:
            self.history.record_posterior(self.x, self.P)
        self.monitor.posterior(self.x[core], self.P[core, core])

    def _reset_cross(self, columns: slice | int) -> None:
        """State columns set anew, independent of the last filtered state: their cross-covariance is 0."""
        if self._cross is not None:
            self._cross[:, columns] = 0.0

    def _clone_origin(self, x: np.ndarray, P: np.ndarray, channel: int, origin_m: float, sigma_m: float) -> None:
        """Set ``channel``'s origin in ``x``, ``P`` (in place) to ``origin_m``, the state's value less the
        observation, with its covariance with the state (module docstring): stochastic cloning."""
        o = self._origins.start + channel
        h = self.model_observation_jacobian(x)[self.layout.rows()[channel]]
        h[o] = 0.0                         # the state's value of the channel, without its old origin
        row = h @ P
        P[o, :] = P[:, o] = row
        P[o, o] = row @ h + sigma_m**2
        x[o] = origin_m
        if self._cross is not None:          # the clone is h x: its covariance with the last filtered state is C h
            self._cross[:, o] = self._cross @ h

    def _code_anchors_pass(self, anchors: np.ndarray, anchor_sigmas: np.ndarray, geometric: np.ndarray,
                           x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Per range channel, whether its code value (:meth:`fusion.model.EpochObservation.anchor_channels`) can be
        its origin: present, a finite ``anchor_sigmas`` (m; :meth:`fusion.model.EpochObservation.anchor_sigmas`),
        and within :data:`fusion.model.CODE_ANCHOR_GATE_SIGMAS` of the state's value ``geometric`` (m; a late
        first path fails)."""
        usable = np.isfinite(anchors) & np.isfinite(anchor_sigmas)
        if not usable.any():
            return np.zeros(len(anchors), dtype=bool)
        h = observation_jacobian(x[:self.core_size], self.geometry)[self.layout.rows()]
        core = P[:self.core_size, :self.core_size]
        spread = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", h, core, h), 0.0))
        with np.errstate(invalid="ignore"):
            return usable & (np.abs(anchors - geometric) <= CODE_ANCHOR_GATE_SIGMAS * np.hypot(spread, anchor_sigmas))

    def estimate(self) -> np.ndarray:
        """The state estimate (a copy)."""
        return np.array(self.x, dtype=np.float64)
