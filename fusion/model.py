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

Beyond eq. 18 an epoch may carry the receiver's path observations
(docs/paths.md): the first-path range change to each tower of the
:class:`Geometry` (``|P - P_k| - |P_0 - P_k|``), and the change of the
difference of the first-path ranges of tower k and tower 0,
``(|P - P_k| - |P - P_0b|) - D_k(P_0)``, whose start value ``D_k(P_0)`` is
known from the GNSS fix, so that the difference places the walker on a
hyperbola instead of only measuring motion. :class:`ObservationLayout`
orders these range channels.

Every single-tower carrier-phase range (the SI-carrier range and each
first-path range) also carries the receiver clock. With a free-running
oscillator (:class:`ClockModel`; for a disciplined one in holdover an
option) the filters add a clock state, the range the clock has integrated
since the f_s calibration (``c``, m) and its rate (``b``, m/s, the f_s
drift of eq. 9-10 times c / fc), a random-walk rate::

    c_{n+1} = c_n + b_n * dt_n        b_{n+1} = b_n + w_n,  Var(w_n) = q dt_n

and the range observations become ``... + c``. A tower difference cancels
the clock.

The module also holds the observation record every filter's ``update``
takes (:class:`EpochObservation`) and what the Kalman-type filters share: the
noise covariances, the Jacobians, and the observation vector of an epoch
with only the components it has (:class:`KalmanObservation`). The loop that
drives any filter over the epochs is :func:`fusion.driver.run_filter`.

Keeping the model here lets the particle filter, the UKF family and the rank
Kalman filter be compared on exactly the same equations.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from dtmbnav_core.constants import CLOCK_PRESETS, SPEED_OF_LIGHT_MPS
from fusion import CLOCK_MODELS

#: A tower difference's code value further than this many sigmas (the filter's own spread of the channel and
#: ``ModelNoise.difference_code_sigma_m`` together) from the filter's value is not taken as its origin.
CODE_ANCHOR_GATE_SIGMAS = 4.0

#: Column indices of the state vector.
X, Y, HEADING_RATE, HEADING, SPEED = range(5)
STATE_SIZE = 5
#: Columns of the clock states a Kalman-type filter appends with a free-running clock (module docstring).
CLOCK_BIAS, CLOCK_RATE = 5, 6
CLOCK_STATE_SIZE = 7
#: Component indices of the observation vector (eq. 18); the path observations follow (:class:`ObservationLayout`).
RANGE_ROW, HEADING_ROW, SPEED_ROW = range(3)


@dataclass(frozen=True)
class Geometry:
    """Where the walk starts and where the towers are.

    Attributes
    ----------
    start_x_m, start_y_m : float
        Start position P0 (the last GNSS fix), ENU m.
    tower_x_m, tower_y_m : float
        Position of tower 0, P_b, ENU m: the tower whose SI carriers give the
        range of eq. 18, and the reference of the tower differences.
    tower_height_m : float
        Tower 0's antenna height above the walker's plane, m.
    other_towers : tuple of (x_m, y_m, height_m)
        Towers 1, 2, ... of a single-frequency network, same units.
    """

    start_x_m: float
    start_y_m: float
    tower_x_m: float
    tower_y_m: float
    tower_height_m: float = 0.0
    other_towers: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        if any(len(t) != 3 for t in self.other_towers):
            raise ValueError(f"Geometry.other_towers: each tower is (x_m, y_m, height_m), got {self.other_towers}")

    @property
    def n_towers(self) -> int:
        """Number of towers (tower 0 and the others)."""
        return 1 + len(self.other_towers)

    def towers(self) -> np.ndarray:
        """Tower positions and heights, shape (n_towers, 3): x m, y m, height m (a copy)."""
        return self._towers.copy()

    @cached_property
    def _towers(self) -> np.ndarray:
        return np.array([(self.tower_x_m, self.tower_y_m, self.tower_height_m), *self.other_towers],
                        dtype=np.float64).reshape(self.n_towers, 3)

    def range_m(self, x_m: np.ndarray, y_m: np.ndarray, tower: int = 0) -> np.ndarray:
        """3-D distance from ground points to a tower's antenna, m."""
        tx, ty, th = self._towers[tower]
        return np.sqrt((x_m - tx) ** 2 + (y_m - ty) ** 2 + th**2)

    def start_range_m(self, tower: int = 0) -> float:
        """Range from P0 to a tower, m."""
        return float(self.range_m(np.float64(self.start_x_m), np.float64(self.start_y_m), tower))

    def start_ranges_m(self) -> np.ndarray:
        """Range from P0 to every tower, in the tower table's order, m."""
        return np.array([self.start_range_m(k) for k in range(self.n_towers)])


@dataclass(frozen=True)
class ObservationLayout:
    """The range channels of a geometry and where they sit in the observation vector.

    Range channel ``j`` (the order of :meth:`EpochObservation.range_channels`):
    0 the SI-carrier range to tower 0 (row :data:`RANGE_ROW`); ``1 .. T`` the
    first-path range to tower ``j - 1``; ``T + 1 .. 2T - 1`` the difference of
    tower ``j - T`` and tower 0. Rows of the observation vector: 0 the
    SI-carrier range, 1 the PDR heading, 2 the PDR speed, then range channels
    ``1 ..`` in order (row ``j + 2``).

    Attributes
    ----------
    n_towers : int
        T.
    """

    n_towers: int = 1

    @property
    def n_channels(self) -> int:
        """Number of range channels, 2T."""
        return 2 * self.n_towers

    @property
    def size(self) -> int:
        """Length of the observation vector."""
        return self.n_channels + 2

    def rows(self) -> np.ndarray:
        """Observation-vector row of each range channel."""
        return np.concatenate([[RANGE_ROW], np.arange(1, self.n_channels) + 2])

    def tower_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Per channel the tower whose range is added and the one subtracted (-1: none)."""
        t = self.n_towers
        added = np.concatenate([[0], np.arange(t), np.arange(1, t)]).astype(np.int64)
        subtracted = np.concatenate([np.full(t + 1, -1), np.zeros(t - 1)]).astype(np.int64)
        return added, subtracted

    def clock_coefficients(self) -> np.ndarray:
        """Per channel 1.0 where the receiver clock enters (single-tower carrier phases), 0.0 for differences."""
        return np.concatenate([np.ones(self.n_towers + 1), np.zeros(self.n_towers - 1)])

    def start_values_m(self, geometry: Geometry) -> np.ndarray:
        """Each channel's geometric value at P0 (its origin when the walk starts at the fix), m."""
        ranges = geometry.start_ranges_m()
        return np.concatenate([[ranges[0]], ranges, ranges[1:] - ranges[0]])

    def geometric_m(self, geometry: Geometry, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Each channel's geometric value (range or range difference) at points, shape (..., n_channels), m."""
        ranges = np.stack([geometry.range_m(x_m, y_m, k) for k in range(self.n_towers)], axis=-1)
        return np.concatenate([ranges[..., :1], ranges, ranges[..., 1:] - ranges[..., :1]], axis=-1)

    def gradients(self, geometry: Geometry, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """d (each channel's geometric value) / d (x, y) at points, shape (..., n_channels, 2) (unitless)."""
        ranges = np.stack([geometry.range_m(x_m, y_m, k) for k in range(self.n_towers)], axis=-1)
        xy = np.stack([np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)], axis=-1)
        unit = (xy[..., None, :] - geometry.towers()[:, :2]) / ranges[..., None]  # d range_k / d (x, y)
        added, subtracted = self.tower_pairs()
        return unit[..., added, :] - np.where(subtracted[:, None] >= 0, unit[..., subtracted, :], 0.0)


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
        ``sqrt(heading_rad * pdr_heading_rad)``, and the mean position of a
        cloud spread over an arc falls short of the distance walked. The
        range corrects a heading error mostly through the heading rate
        instead (docs/decisions.md, D19).
    speed_mps : float
        xi5: speed random walk per step, m/s.
    scale_per_step : float
        The marginalised particle filter's xi5 (:mod:`fusion.rb_particle_filter`): random walk per step
        of the step-length scale, the PDR's gain error (a fraction). An honest prior: a gait changes its
        step length slowly, so the scale a range has shown is kept across a stretch the range does not
        see. Far below ``speed_mps`` over the PDR speed (which samples a speed cloud wide enough for a
        particle filter's draws to find a gain error; docs/decisions.md, D59).
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
        integrated) in epochs without a range observation, m, for each range
        channel (:class:`ObservationLayout`): across a gap, a fade or a
        multipath stretch the integrated range may have jumped or drifted,
        and what it says afterwards is a range change from an unknown new
        origin. The Kalman-type filters add it, per epoch without the
        channel, to the variance of the channel's origin state
        (:mod:`fusion.kalman`).
    range_reanchor_m : float
        Every filter re-anchors a returning range channel (a new origin) once
        its offset's (the Kalman-type filters': its origin state's) standard
        deviation has grown past this, m. A long blocked stretch leaves an
        integrated range error that is a drift (a reflection's Doppler summed
        over minutes), not the random walk above: the first returning range
        is then tens of metres off every particle, the likelihood mixture
        keeps only the tail particles that happen to fit it, and the cloud
        jumps along the line of sight. Short fades keep their offset. 10 m
        by default, about 50 s without the channel at two epochs a second
        (chosen on the tuning walks against a tighter bound and none;
        docs/decisions.md, D17).
    difference_code_sigma_m : float
        Standard deviation of a tower difference's origin taken from its
        code range difference (:meth:`EpochObservation.anchor_channels`),
        m: where a filter re-anchors a difference that carries one (its
        first epoch, a new origin, a return), the origin comes from the
        code, known to this, instead of from the filter's own position,
        which would inherit the GNSS fix's error; the carrier then holds the
        walker on that hyperbola. 0.3 m by default: the per-frame scatter of
        the IQ receiver's code difference, which outweighs its bias over a
        walk (docs/paths.md; docs/decisions.md, D15). The uncertainty of the
        towers' transmit delay offsets taken out of the code is added per
        difference (:meth:`EpochObservation.anchor_sigmas`). ``inf``: the
        code is not used.
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
    scale_per_step: float = 0.0015
    pdr_heading_rad: float = np.deg2rad(40.0)
    pdr_speed_mps: float = 1.0
    range_outlier_probability: float = 0.01
    range_outlier_span_m: float = 100.0
    range_offset_m: float = 1.0
    range_reanchor_m: float = 10.0
    difference_code_sigma_m: float = 0.3
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


#: The oscillator preset (:data:`dtmbnav_core.constants.CLOCK_PRESETS`) each clock model stands for.
CLOCK_MODEL_PRESETS = {"disciplined": "gnss-disciplined", "free-running": "free-running"}
#: Standard deviation of the clock rate at the first epoch per clock model, m/s. A disciplined clock: what the
#: f_s calibration of the standstill leaves (0.02 Hz at 666 MHz is 0.009 m/s; docs/method.md §2). A free-running
#: one: its wander since the calibration as well.
CLOCK_INITIAL_RATE_MPS = {"disciplined": 0.01, "free-running": 0.5}


@dataclass(frozen=True)
class ClockModel:
    """The receiver clock as the filters model it (module docstring).

    ``disciplined``: a GNSS-disciplined oscillator, which once GNSS is lost
    runs on its own reference (holdover) with an Allan deviation about 1e-12
    (docs/paths.md): its rate's random walk integrates to sigma 1.6 m of
    range over 300 s, metres over a street walk; with ``state`` the filters
    carry its states (off by default: docs/method.md §8; docs/decisions.md, D23),
    without it there is no clock (the paper's model).
    ``free-running``: a TCXO whose frequency wanders by a random walk
    (random-walk FM); the filters always carry its states. Its Allan variance
    is ``q_y tau / 3`` (q_y per second, fractional), so a deviation
    ``sigma_y`` at ``tau`` gives ``q_y = 3 sigma_y^2 / tau``; in range units
    the rate's random walk has ``q = c^2 q_y`` (m^2/s^3; 1e-9 of fractional
    frequency is c * 1e-9 = 0.3 m/s of false radial velocity).

    Attributes
    ----------
    kind : {"disciplined", "free-running"}
    allan_deviation : float or None
        Allan deviation at ``allan_tau_s``; None takes the preset of the
        clock's kind (:data:`dtmbnav_core.constants.CLOCK_PRESETS`, the clocks
        the simulator draws).
    allan_tau_s : float
        Averaging time of ``allan_deviation``, s.
    initial_rate_mps : float or None
        Standard deviation of the clock rate at the first epoch, m/s; None:
        :data:`CLOCK_INITIAL_RATE_MPS` of the clock's kind.
    initial_bias_m : float
        Standard deviation of the range the clock integrated before the
        first epoch, m.
    state : bool
        Whether a disciplined clock has states (a free-running one always has).
    """

    kind: str = "disciplined"
    allan_deviation: float | None = None
    allan_tau_s: float = 1.0
    initial_rate_mps: float | None = None
    initial_bias_m: float = 0.1
    state: bool = False

    def __post_init__(self) -> None:
        if self.kind not in CLOCK_MODELS:
            raise ValueError(f"clock model {self.kind!r}: expected one of {', '.join(CLOCK_MODELS)}")
        if self.allan_deviation is not None and not self.allan_deviation > 0:
            raise ValueError(f"clock Allan deviation must be positive, got {self.allan_deviation}")
        if not self.allan_tau_s > 0:
            raise ValueError(f"clock Allan tau must be positive, got {self.allan_tau_s}")

    @property
    def free_running(self) -> bool:
        """Whether the clock runs free (the filters then also use the standstills and, in an SFN, solve eq. 15 on a
        tower difference: ``fusion.run``)."""
        return self.kind == "free-running"

    @property
    def has_state(self) -> bool:
        """Whether the filters carry the clock states."""
        return self.free_running or self.state

    def rate_psd_m2ps3(self) -> float:
        """q: spectral density of the clock rate's random walk in range units, m^2/s^3."""
        adev = self.allan_deviation
        if adev is None:
            adev = CLOCK_PRESETS[CLOCK_MODEL_PRESETS[self.kind]][1]
        return SPEED_OF_LIGHT_MPS**2 * 3.0 * adev**2 / self.allan_tau_s

    def process_covariance(self, elapsed_s: float) -> np.ndarray:
        """Covariance of the noise the clock states [c, b] pick up over ``elapsed_s`` (integrated random walk)."""
        q = self.rate_psd_m2ps3() if self.has_state else 0.0
        t = elapsed_s
        return q * np.array([[t**3 / 3.0, t**2 / 2.0], [t**2 / 2.0, t]])

    def initial_covariance(self) -> np.ndarray:
        """Covariance of [c, b] at the first epoch."""
        if not self.has_state:
            return np.zeros((2, 2))
        rate = CLOCK_INITIAL_RATE_MPS[self.kind] if self.initial_rate_mps is None else self.initial_rate_mps
        return np.diag([self.initial_bias_m**2, rate**2])


@dataclass(frozen=True)
class StepControl:
    """What the PDR says about one step, used as the process model's control input.

    An epoch without a step (a standstill, :mod:`fusion.observations`) has
    ``dt_s = 0``: nothing moves and no motion noise is added; only the clock
    runs on, over ``interval_s``.

    Attributes
    ----------
    dt_s : float
        Step duration, s (0 for an epoch without a step).
    heading_increment_rad : float
        PDR heading change since the previous step, rad.
    speed_ratio : float
        PDR speed of this step over that of the previous step.
    interval_s : float or None
        Time since the previous epoch, s (over which the clock runs); None
        takes ``dt_s``.
    """

    dt_s: float
    heading_increment_rad: float = 0.0
    speed_ratio: float = 1.0
    interval_s: float | None = None

    @property
    def elapsed_s(self) -> float:
        """Time since the previous epoch, s."""
        return self.dt_s if self.interval_s is None else self.interval_s

    @property
    def is_step(self) -> bool:
        """Whether the walker takes a step in this epoch."""
        return self.dt_s > 0.0


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

    Rows with the clock states (:data:`CLOCK_STATE_SIZE` columns) also
    integrate the clock rate over ``control.elapsed_s``.

    Parameters
    ----------
    states : ndarray, shape (..., 5) or (..., 7)
        States before the step.
    control : StepControl

    Returns
    -------
    ndarray
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
    if states.shape[-1] == CLOCK_STATE_SIZE:
        out[..., CLOCK_BIAS] += states[..., CLOCK_RATE] * control.elapsed_s
    return out


def observe(states: np.ndarray, geometry: Geometry, origins_m: np.ndarray | float) -> np.ndarray:
    """Noise-free observation model (eq. 18-19 and the path channels) of rows of ``states``.

    Parameters
    ----------
    states : ndarray, shape (..., 5) or (..., 7)
        With 7 columns the clock's integrated range enters every single-tower range.
    geometry : Geometry
    origins_m : float or ndarray
        Origin of each range channel (:class:`ObservationLayout`), m, shape
        (..., n_channels): for the SI-carrier range |P_0 - P_b| (a particle
        carries its own start); a scalar gives the SI-carrier range's and
        leaves the others at their values at P0.

    Returns
    -------
    ndarray, shape (..., ObservationLayout.size)
        [SI range change m, heading rad, speed m/s, path channels m].
    """
    layout = ObservationLayout(geometry.n_towers)
    origins = np.asarray(origins_m, dtype=np.float64)
    if origins.ndim == 0:
        origins = np.concatenate([[origins], layout.start_values_m(geometry)[1:]])
    channels = layout.geometric_m(geometry, states[..., X], states[..., Y]) - origins
    if states.shape[-1] == CLOCK_STATE_SIZE:
        channels = channels + layout.clock_coefficients() * states[..., CLOCK_BIAS, None]
    return np.concatenate([channels[..., :1], states[..., HEADING, None], states[..., SPEED, None], channels[..., 1:]],
                          axis=-1)


def initial_state(geometry: Geometry, heading_rad: float, speed_mps: float,
                  clock: ClockModel = ClockModel()) -> np.ndarray:
    """State at P0 walking at ``heading_rad`` and ``speed_mps`` with no turn rate (clock states 0 if any)."""
    motion = np.array([geometry.start_x_m, geometry.start_y_m, 0.0, heading_rad, speed_mps])
    return np.concatenate([motion, np.zeros(2)]) if clock.has_state else motion


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


def _with_clock(motion: np.ndarray, clock_block: np.ndarray, clock: ClockModel) -> np.ndarray:
    if not clock.has_state:
        return motion
    out = np.zeros((CLOCK_STATE_SIZE, CLOCK_STATE_SIZE))
    out[:STATE_SIZE, :STATE_SIZE] = motion
    out[STATE_SIZE:, STATE_SIZE:] = clock_block
    return out


def process_covariance(noise: ModelNoise, control: StepControl | None = None,
                       clock: ClockModel = ClockModel()) -> np.ndarray:
    """Q: diagonal covariance of xi1..xi5 per step (none in an epoch without a step), and the clock's over the epoch."""
    stepping = control is None or control.is_step
    motion = np.diag(noise.process_sigmas() ** 2) if stepping else np.zeros((STATE_SIZE, STATE_SIZE))
    return _with_clock(motion, clock.process_covariance(0.0 if control is None else control.elapsed_s), clock)


def walk_range_origins(cov: np.ndarray, columns: np.ndarray, observed: np.ndarray, noise: ModelNoise) -> np.ndarray:
    """One epoch of the range channels' origin random walk, in place; which origins are lost.

    Every filter keeps its range channels' origins (the particle filter's
    offsets, the Kalman-type filters' origin states) in a covariance ``cov``.
    Each channel not ``observed`` this epoch adds ``range_offset_m**2`` to its
    origin's variance (``ModelNoise``); a channel whose origin's standard
    deviation is then past ``range_reanchor_m`` is lost: it re-anchors when
    it is next used.

    Parameters
    ----------
    cov : ndarray, (n, n)
        Covariance holding the origins, m^2 on their diagonal (changed in place).
    columns : ndarray of int, (channels,)
        Row/column of each channel's origin in ``cov``.
    observed : ndarray of bool, (channels,)
        Whether each channel is used this epoch.
    noise : ModelNoise

    Returns
    -------
    ndarray of bool, (channels,)
        Lost origins.
    """
    unobserved = columns[~observed]
    cov[unobserved, unobserved] += noise.range_offset_m**2
    return cov[columns, columns] > noise.range_reanchor_m**2


def initial_covariance(noise: ModelNoise, clock: ClockModel = ClockModel()) -> np.ndarray:
    """P0: diagonal covariance of the initial state."""
    return _with_clock(np.diag(noise.initial_sigmas() ** 2), clock.initial_covariance(), clock)


def transition_jacobian(x: np.ndarray, control: StepControl) -> np.ndarray:
    """d propagate / d x at ``x`` (:func:`propagate`); ``x`` may hold rows of states, shape (..., n) -> (..., n, n)."""
    x = np.asarray(x, dtype=np.float64)
    dt = control.dt_s
    heading = x[..., HEADING] + control.heading_increment_rad + x[..., HEADING_RATE] * dt
    s, c = np.sin(heading), np.cos(heading)
    distance = x[..., SPEED] * control.speed_ratio * dt
    d_distance_d_speed = control.speed_ratio * dt
    n = x.shape[-1]
    f = np.broadcast_to(np.eye(n), x.shape[:-1] + (n, n)).copy()
    f[..., X, HEADING], f[..., X, HEADING_RATE], f[..., X, SPEED] = (distance * c, distance * c * dt,
                                                                     d_distance_d_speed * s)
    f[..., Y, HEADING], f[..., Y, HEADING_RATE], f[..., Y, SPEED] = (-distance * s, -distance * s * dt,
                                                                     d_distance_d_speed * c)
    f[..., HEADING, HEADING_RATE] = dt
    f[..., SPEED, SPEED] = control.speed_ratio
    if n == CLOCK_STATE_SIZE:
        f[..., CLOCK_BIAS, CLOCK_RATE] = control.elapsed_s
    return f


def observation_jacobian(x: np.ndarray, geometry: Geometry) -> np.ndarray:
    """d observe / d x at ``x``: one row per observation-vector component (:class:`ObservationLayout`)."""
    layout = ObservationLayout(geometry.n_towers)
    h = np.zeros((layout.size, len(x)))
    rows = layout.rows()
    h[rows[:, None], [X, Y]] = layout.gradients(geometry, x[X], x[Y])
    h[HEADING_ROW, HEADING] = 1.0
    h[SPEED_ROW, SPEED] = 1.0
    if len(x) == CLOCK_STATE_SIZE:
        h[rows, CLOCK_BIAS] = layout.clock_coefficients()
    return h


@dataclass(frozen=True)
class KalmanObservation:
    """An epoch's observations as a Kalman-type filter uses them: the present components.

    Attributes
    ----------
    z : ndarray
        Observed values, in the order of ``rows``.
    rows : ndarray of int
        Which components of the observation vector they are (:data:`RANGE_ROW`,
        :data:`HEADING_ROW`, :data:`SPEED_ROW`, then the path channels of
        :class:`ObservationLayout`); a range is left out where the epoch has
        none, the PDR's heading and speed in an epoch without a step.
    sigma : ndarray
        Their standard deviations.
    """

    z: np.ndarray
    rows: np.ndarray
    sigma: np.ndarray

    @property
    def heading_index(self) -> int | None:
        """Position of the heading in ``z`` (None without one)."""
        where = np.nonzero(self.rows == HEADING_ROW)[0]
        return int(where[0]) if where.size else None

    def residual(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``a - b`` for observation vectors, the heading wrapped."""
        d = np.asarray(a, dtype=np.float64) - b
        k = self.heading_index
        if k is not None:
            d[..., k] = wrap_angle(d[..., k])
        return d

    def mean(self, predicted: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Weighted mean of predicted observation rows, circular for the heading."""
        mean = weights @ predicted
        k = self.heading_index
        if k is not None:
            h = predicted[:, k]
            mean[k] = np.arctan2(weights @ np.sin(h), weights @ np.cos(h))
        return mean


def _empty() -> np.ndarray:
    return np.empty(0)


@dataclass(frozen=True)
class EpochObservation:
    """Everything one epoch observes (eq. 18 and the path channels); every filter's ``update`` takes this.

    Attributes
    ----------
    index : int
        Epoch number (filters that keep per-epoch side information look it up).
    range_change_m : float
        SI-carrier range change since P0, m; NaN when the epoch has no range.
    range_sigma_m : float
        Its standard deviation, m (NaN with the range).
    pdr_heading_rad : float
        PDR heading made absolute with the solved initial heading, rad; NaN
        in an epoch without a step.
    pdr_speed_mps : float
        PDR speed, m/s; NaN in an epoch without a step.
    first_path_range_m, first_path_sigma_m : ndarray
        First-path range change to tower k (index k) and its standard
        deviation, m; NaN where none; empty without path observations.
    first_path_new_origin : ndarray of bool
        Where a first-path range restarts from an unknown origin (a slip or a
        re-acquired path, :mod:`fusion.observations`).
    range_difference_m, range_difference_sigma_m, range_difference_new_origin : ndarray
        The same for the difference of tower k and tower 0 (index k - 1).
    first_path_code_m : ndarray
        Code range of tower k's first path (index k), m, up to a constant;
        NaN where none (:mod:`fusion.integrity` checks the first path against
        it; no filter weighs it).
    range_difference_code_m : ndarray
        Code range difference of tower k and tower 0 (index k - 1), m, with
        the towers' transmit delay offsets taken out as far as they are
        known; NaN where none (:meth:`anchor_channels`).
    range_difference_code_sigma_m : ndarray
        Standard deviation of the constant left in that code by the offsets'
        uncertainty (index k - 1), m (:mod:`fusion.transmit_delays`); ``inf``
        where the offsets are not known, so the code is not used.
    range_new_origin : bool
        Whether the SI-carrier range restarts from an unknown origin (a new
        lock segment, :mod:`fusion.observations`).
    """

    index: int
    range_change_m: float
    range_sigma_m: float
    pdr_heading_rad: float
    pdr_speed_mps: float
    first_path_range_m: np.ndarray = field(default_factory=_empty)
    first_path_sigma_m: np.ndarray = field(default_factory=_empty)
    first_path_new_origin: np.ndarray = field(default_factory=_empty)
    range_difference_m: np.ndarray = field(default_factory=_empty)
    range_difference_sigma_m: np.ndarray = field(default_factory=_empty)
    range_difference_new_origin: np.ndarray = field(default_factory=_empty)
    first_path_code_m: np.ndarray = field(default_factory=_empty)
    range_difference_code_m: np.ndarray = field(default_factory=_empty)
    range_difference_code_sigma_m: np.ndarray = field(default_factory=_empty)
    range_new_origin: bool = False

    @property
    def has_range(self) -> bool:
        """Whether the epoch has an SI-carrier range observation."""
        return not np.isnan(self.range_change_m)

    def range_channels(self, n_towers: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every range channel of :class:`ObservationLayout` (``n_towers``): values, sigmas (NaN: none), new origins.

        Raises
        ------
        ValueError
            If the epoch has path observations for more towers than ``n_towers``.
        """
        padded = self._padded
        z = np.concatenate([[self.range_change_m], padded(self.first_path_range_m, n_towers, np.nan),
                            padded(self.range_difference_m, n_towers - 1, np.nan)]).astype(np.float64)
        sigma = np.concatenate([[self.range_sigma_m], padded(self.first_path_sigma_m, n_towers, np.nan),
                                padded(self.range_difference_sigma_m, n_towers - 1, np.nan)]).astype(np.float64)
        new_origin = np.concatenate([[self.range_new_origin], padded(self.first_path_new_origin, n_towers, False),
                                     padded(self.range_difference_new_origin, n_towers - 1, False)]).astype(bool)
        present = np.isfinite(z) & np.isfinite(sigma)
        return np.where(present, z, np.nan), np.where(present, sigma, np.nan), new_origin & present

    def code_channels(self, n_towers: int = 1) -> np.ndarray:
        """Per range channel (as :meth:`range_channels`) the code range, m: the first paths' only, NaN elsewhere."""
        return np.concatenate([[np.nan], self._padded(self.first_path_code_m, n_towers, np.nan),
                               np.full(n_towers - 1, np.nan)]).astype(np.float64)

    def anchor_channels(self, n_towers: int = 1) -> np.ndarray:
        """Per range channel (as :meth:`range_channels`) its geometric value from the code, m: NaN but for the
        tower differences that carry their code range difference.

        A tower difference's carrier phase gives its change from an unknown
        origin; its code (the two first paths' delays, the towers' transmit
        delay offsets known) gives the difference itself, to decimetres, so
        a filter re-anchoring the channel can take the origin from the code
        instead of from its own position (``ModelNoise.difference_code_sigma_m``).
        """
        return np.concatenate([np.full(n_towers + 1, np.nan),
                               self._padded(self.range_difference_code_m, n_towers - 1, np.nan)]).astype(np.float64)

    def anchor_sigmas(self, scatter_sigma_m: float, n_towers: int = 1) -> np.ndarray:
        """Per range channel (as :meth:`anchor_channels`) the standard deviation of an origin taken from its code,
        m: the code's own scatter ``scatter_sigma_m`` (``ModelNoise.difference_code_sigma_m``) and the
        uncertainty of the transmit delay offsets taken out of it (``range_difference_code_sigma_m``) together;
        NaN for the channels without a code, ``inf`` where the offsets are unknown."""
        offsets = self._padded(self.range_difference_code_sigma_m, n_towers - 1, np.inf)
        return np.concatenate([np.full(n_towers + 1, np.nan),
                               np.hypot(scatter_sigma_m, offsets)]).astype(np.float64)

    def _padded(self, values: np.ndarray, n: int, fill: float | bool) -> np.ndarray:
        """Per-tower ``values`` padded with ``fill`` to ``n`` channels."""
        values = np.asarray(values)
        if len(values) > n:
            raise ValueError(f"epoch {self.index}: path observations for {len(values)} channels, "
                             f"the geometry has {n}")
        return np.concatenate([values, np.full(n - len(values), fill)])

    def kalman(self, noise: ModelNoise, n_towers: int = 1, use: np.ndarray | None = None) -> KalmanObservation:
        """The present components with their sigmas (the PDR's from ``noise``).

        ``use`` (bool per range channel) keeps only those range channels
        (default: every present one).
        """
        z, sigma, _ = self.range_channels(n_towers)
        keep = np.isfinite(z) if use is None else np.asarray(use, dtype=bool) & np.isfinite(z)
        layout = ObservationLayout(n_towers)
        rows = layout.rows()
        full_z = np.full(layout.size, np.nan)
        full_sigma = np.full(layout.size, np.nan)
        full_z[rows[keep]] = z[keep]
        full_sigma[rows[keep]] = sigma[keep]
        if not np.isnan(self.pdr_heading_rad):
            full_z[[HEADING_ROW, SPEED_ROW]] = self.pdr_heading_rad, self.pdr_speed_mps
            full_sigma[[HEADING_ROW, SPEED_ROW]] = noise.pdr_heading_rad, noise.pdr_speed_mps
        present = np.flatnonzero(np.isfinite(full_z))
        return KalmanObservation(z=full_z[present], rows=present, sigma=full_sigma[present])
