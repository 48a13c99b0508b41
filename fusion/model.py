"""The state-space model every fusion filter shares (docs/method.md §5, eq. 16-19).

State, one row per hypothesis (particle or sigma point), project convention
(heading clockwise from north, a step moves ``(s t sin(phi), s t cos(phi))``)::

    X = [x_m, y_m, heading_rate_radps, heading_rad, speed_mps]

Observations per filter epoch (one PDR step)::

    Z = [range_change_m, pdr_heading_rad, pdr_speed_mps]

with ``range_change = |P - P_b| - |P_0 - P_b|`` (eq. 18, 3-D distance to the
tower antenna, which stands ``tower_height_m`` above the walker's plane).
The process model also takes the PDR's step-to-step heading change and speed
ratio as a control input (:class:`StepControl`, :func:`propagate` says why),
which makes the heading-rate state the drift of the PDR heading.

The module also holds the observation record every filter's ``update``
takes (:class:`EpochObservation`) and what the Kalman-type filters share: the
noise covariances and the observation vector of an epoch without the range
where the epoch has none (:class:`KalmanObservation`). The loop that drives
any filter over the epochs is :func:`fusion.driver.run_filter`.

Keeping the model here lets the particle filter, the UKF family and the rank
Kalman filter be compared on exactly the same equations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Column indices of the state vector.
X, Y, HEADING_RATE, HEADING, SPEED = range(5)
STATE_SIZE = 5
#: Component indices of the observation vector (eq. 18).
RANGE_ROW, HEADING_ROW, SPEED_ROW = range(3)


@dataclass(frozen=True)
class Geometry:
    """Where the walk starts and where the tower is.

    Attributes
    ----------
    start_x_m, start_y_m : float
        Start position P0 (the last GNSS fix), ENU m.
    tower_x_m, tower_y_m : float
        Tower position P_b, ENU m.
    tower_height_m : float
        Tower antenna height above the walker's plane, m.
    """

    start_x_m: float
    start_y_m: float
    tower_x_m: float
    tower_y_m: float
    tower_height_m: float = 0.0

    def range_m(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """3-D distance from ground points to the tower antenna, m."""
        return np.sqrt((x_m - self.tower_x_m) ** 2 + (y_m - self.tower_y_m) ** 2 + self.tower_height_m**2)

    def start_range_m(self) -> float:
        """Range from P0 to the tower, m."""
        return float(self.range_m(np.float64(self.start_x_m), np.float64(self.start_y_m)))


@dataclass(frozen=True)
class ModelNoise:
    """Standard deviations of the process noise (xi) and observation noise (chi).

    Process noise is per filter epoch (one step); the range observation noise
    is given per epoch by :mod:`fusion.observations`, so only its floor lives
    here.

    Attributes
    ----------
    position_m : float
        xi1, xi2: position noise per step, m (step-to-step wobble the constant
        speed/heading model does not describe).
    heading_rate_radps : float
        xi3: random walk per step of the heading-rate error (gyro drift), rad/s.
        Small: the AHRS's magnetometer and accelerometer already hold most
        of the gyro bias, and the state is unobserved wherever the range is
        missing; a loose random walk there lets the heading wander off the
        PDR's (0.04 deg/s per step follows a 0.3 deg/s drift that sets in
        within a minute).
    heading_rad : float
        xi4: heading noise per step, rad. Small too: the PDR's heading
        increments over a step are good to far better than a degree, and
        where the range is missing only the wide PDR-heading observation
        holds this random walk, so the cloud widens to about
        ``sqrt(heading_rad * pdr_heading_rad)``; the mean position of a
        cloud that is 10-15 deg wide falls short of the distance walked.
        The range corrects a heading error mostly through the heading rate
        instead.
    speed_mps : float
        xi5: speed random walk per step, m/s.
    pdr_heading_rad : float
        chi2: PDR heading observation noise, rad. Wide, so that the range
        can pull the heading away from a drifting gyro (the PDR's turns
        enter through the control input, :class:`StepControl`).
    pdr_speed_mps : float
        chi3: PDR speed observation noise, m/s. Wide, so that the range can
        correct a step-length gain error of 10-20 % (the PDR's pace changes
        enter through the control input).
    range_outlier_probability, range_outlier_span_m : float
        The particle filter's range likelihood is a mixture of the Gaussian
        and a uniform density over this span (m) with this weight, so one
        wild range (a cycle slip, a reflection) cannot collapse every
        particle onto the one that happens to be nearest it. The Kalman-type
        filters are Gaussian and ignore these.
    range_offset_m : float
        Random walk per epoch of the particle filter's range offset (the
        particle's start range plus the range error the receiver has
        integrated) in epochs without a range observation, m: across a gap,
        a fade or a multipath stretch the integrated range may have jumped
        or drifted, and what it says afterwards is a range change from an
        unknown new origin. The Kalman-type filters have no offset state and
        ignore this.
    initial_position_m : float
        Spread of the initial position around P0 (GNSS fix error), m.
    initial_heading_rad : float
        Spread of the initial heading around the solved value, rad.
    initial_heading_rate_radps : float
        Spread of the initial heading rate, rad/s (the AHRS's residual gyro
        bias).
    initial_speed_mps : float
        Spread of the initial speed around the first PDR speed, m/s.
    """

    position_m: float = 0.05
    heading_rate_radps: float = np.deg2rad(0.04)
    heading_rad: float = np.deg2rad(0.5)
    speed_mps: float = 0.02
    pdr_heading_rad: float = np.deg2rad(40.0)
    pdr_speed_mps: float = 1.0
    range_outlier_probability: float = 0.01
    range_outlier_span_m: float = 100.0
    range_offset_m: float = 1.0
    initial_position_m: float = 1.5
    initial_heading_rad: float = np.deg2rad(5.0)
    initial_heading_rate_radps: float = np.deg2rad(0.1)
    initial_speed_mps: float = 0.1

    def process_sigmas(self) -> np.ndarray:
        """xi1..xi5 as a state-ordered vector."""
        return np.array([self.position_m, self.position_m, self.heading_rate_radps, self.heading_rad, self.speed_mps])

    def initial_sigmas(self) -> np.ndarray:
        """Initial spread as a state-ordered vector."""
        return np.array([self.initial_position_m, self.initial_position_m, self.initial_heading_rate_radps,
                         self.initial_heading_rad, self.initial_speed_mps])


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class StepControl:
    """What the PDR says about one step, used as the process model's control input.

    Attributes
    ----------
    dt_s : float
        Step duration, s.
    heading_increment_rad : float
        PDR heading change since the previous step, rad.
    speed_ratio : float
        PDR speed of this step over that of the previous step.
    """

    dt_s: float
    heading_increment_rad: float = 0.0
    speed_ratio: float = 1.0


def propagate(states: np.ndarray, control: StepControl) -> np.ndarray:
    """Noise-free process model (eq. 16-17) applied to rows of ``states``.

    Departures from eq. 17, so that the filter follows the walker through
    turns and pace changes instead of lagging a step behind, and so that the
    PDR's two systematic errors (docs/scenarios.md) become states the range can
    correct:

    - the PDR's heading increment over the step (the gyro's turn, accurate
      over one step even when its absolute heading has drifted) drives the
      heading, and the state's heading rate is the rate of the error of that
      increment (the gyro's drift), not the walker's turn rate;
    - the PDR's speed ratio to the previous step drives the speed, so the
      speed state keeps the PDR's pace changes while its ratio to the PDR
      speed (a step-length gain error) persists until the range corrects it;
    - the heading is advanced first and the step taken along the new heading
      (eq. 17 moves along the previous one, which at 90 deg corners puts the
      step on the wrong leg).

    Parameters
    ----------
    states : ndarray, shape (..., 5)
        States before the step.
    control : StepControl

    Returns
    -------
    ndarray, shape (..., 5)
        States after the step (a new array).
    """
    out = np.array(states, dtype=np.float64, copy=True)
    dt = control.dt_s
    heading = states[..., HEADING] + control.heading_increment_rad + states[..., HEADING_RATE] * dt
    speed = states[..., SPEED] * control.speed_ratio
    out[..., X] += speed * dt * np.sin(heading)
    out[..., Y] += speed * dt * np.cos(heading)
    out[..., HEADING] = heading
    out[..., SPEED] = speed
    return out


def observe(states: np.ndarray, geometry: Geometry, start_range_m: np.ndarray | float) -> np.ndarray:
    """Noise-free observation model (eq. 18-19) of rows of ``states``.

    Parameters
    ----------
    states : ndarray, shape (..., 5)
    geometry : Geometry
    start_range_m : float or ndarray
        |P_0 - P_b| for each row (a particle carries its own start), m.

    Returns
    -------
    ndarray, shape (..., 3)
        [range change m, heading rad, speed m/s].
    """
    rng = geometry.range_m(states[..., X], states[..., Y]) - start_range_m
    return np.stack([rng, states[..., HEADING], states[..., SPEED]], axis=-1)


def initial_state(geometry: Geometry, heading_rad: float, speed_mps: float) -> np.ndarray:
    """State at P0 walking at ``heading_rad`` and ``speed_mps`` with no turn rate."""
    return np.array([geometry.start_x_m, geometry.start_y_m, 0.0, heading_rad, speed_mps])


def state_mean(states: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of state rows, circular for the heading (eq. 22)."""
    mean = weights @ states
    heading = states[:, HEADING]
    mean[HEADING] = np.arctan2(weights @ np.sin(heading), weights @ np.cos(heading))
    return mean


def state_residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b`` with the heading difference wrapped to [-pi, pi)."""
    d = np.asarray(a, dtype=np.float64) - b
    d[..., HEADING] = wrap_angle(d[..., HEADING])
    return d


def process_covariance(noise: ModelNoise) -> np.ndarray:
    """Q: diagonal covariance of xi1..xi5 per step."""
    return np.diag(noise.process_sigmas() ** 2)


def initial_covariance(noise: ModelNoise) -> np.ndarray:
    """P0: diagonal covariance of the initial state."""
    return np.diag(noise.initial_sigmas() ** 2)


@dataclass(frozen=True)
class KalmanObservation:
    """An epoch's observations as a Kalman-type filter uses them: the present components of eq. 18.

    Attributes
    ----------
    z : ndarray
        Observed values, in the order of ``rows``.
    rows : ndarray of int
        Which components of eq. 18 they are (:data:`RANGE_ROW`, :data:`HEADING_ROW`,
        :data:`SPEED_ROW`); the range is left out where the epoch has none.
    sigma : ndarray
        Their standard deviations.
    """

    z: np.ndarray
    rows: np.ndarray
    sigma: np.ndarray

    @property
    def heading_index(self) -> int:
        """Position of the heading in ``z``."""
        return int(np.nonzero(self.rows == HEADING_ROW)[0][0])

    def residual(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``a - b`` for observation vectors, the heading wrapped."""
        d = np.asarray(a, dtype=np.float64) - b
        d[..., self.heading_index] = wrap_angle(d[..., self.heading_index])
        return d

    def mean(self, predicted: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Weighted mean of predicted observation rows, circular for the heading."""
        mean = weights @ predicted
        h = predicted[:, self.heading_index]
        mean[self.heading_index] = np.arctan2(weights @ np.sin(h), weights @ np.cos(h))
        return mean


@dataclass(frozen=True)
class EpochObservation:
    """Everything one epoch observes (eq. 18); every filter's ``update`` takes this.

    Attributes
    ----------
    index : int
        Epoch number (filters that keep per-epoch side information look it up).
    range_change_m : float
        Range change since P0, m; NaN when the epoch has no range.
    range_sigma_m : float
        Its standard deviation, m (NaN with the range).
    pdr_heading_rad : float
        PDR heading made absolute with the solved initial heading, rad.
    pdr_speed_mps : float
        PDR speed, m/s.
    """

    index: int
    range_change_m: float
    range_sigma_m: float
    pdr_heading_rad: float
    pdr_speed_mps: float

    @property
    def has_range(self) -> bool:
        """Whether the epoch has a range observation."""
        return not np.isnan(self.range_change_m)

    def kalman(self, noise: ModelNoise) -> KalmanObservation:
        """The present components with their sigmas (the PDR's from ``noise``)."""
        z = np.array([self.range_change_m, self.pdr_heading_rad, self.pdr_speed_mps])
        sigma = np.array([self.range_sigma_m, noise.pdr_heading_rad, noise.pdr_speed_mps])
        rows = np.array([RANGE_ROW, HEADING_ROW, SPEED_ROW]) if self.has_range else np.array([HEADING_ROW, SPEED_ROW])
        return KalmanObservation(z=z[rows], rows=rows, sigma=sigma[rows])
