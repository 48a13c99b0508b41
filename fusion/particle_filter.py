"""Particle-filter fusion of DTMB range and PDR (docs/method.md §5, eq. 16-23, Algorithm 1).

State and observations are those of :mod:`fusion.model`. Each particle also
carries a range offset per range channel (:class:`fusion.model.ObservationLayout`):
for the SI-carrier range and the first-path ranges its own start range
|P_0 - P_k| (eq. 19 uses the state at n = 0), so these ranges constrain the
walked displacement and an error in the GNSS start fix is not mistaken for a
range error; for a tower difference the difference's value at the GNSS fix,
with the fix's uncertainty (its gradient times ``initial_position_m``), so
that the difference constrains the position itself (a hyperbola). In epochs
without a channel's observation (gap, fade, multipath, slip:
:mod:`fusion.observations`; or dropped by :mod:`fusion.integrity`) its offset
takes a random-walk step of ``ModelNoise.range_offset_m``: the range error
integrated across such a stretch becomes a new, uncertain origin instead of
a position error. With a free-running clock (:class:`fusion.model.ClockModel`)
the particle also carries the clock's integrated range and rate, which enter
every single-tower range.

Offsets and clock enter the range observations linearly, so they are not
sampled but marginalised (a Rao-Blackwellised particle filter): each particle
holds the mean of this linear state, and one covariance ``P`` serves all of
them, because every particle sees the same sequence of gaps, observation
sigmas and epoch intervals. A range observation ``z = g(x, y) + H a`` (``g``
the range or range difference, ``a`` the linear state, ``H`` -1 on the
channel's offset and 1 on the clock's range for a single-tower range) weighs
a particle by its innovation over ``S = sigma^2 + H P H^T`` and moves its
linear state by the Kalman gain ``K = P H^T / S``; ``P`` then shrinks to
``P - K S K^T``; several channels are taken one after the other. Sampling
the offset instead (a random-walk draw per particle) fails where it
matters: after a blocked stretch the offsets are spread over tens of metres,
the first returning range keeps only the few particles whose draw happens
to match it, and the cloud collapses onto positions picked by the offset
noise, and each such collapse kicks the track along the line of sight (a
test measures the effective sample size both ways). With the outlier
mixture below, the Kalman step of each particle is scaled by its probability
that the observation is an inlier, and ``P`` shrinks by the mean of that
probability. A channel that restarts from a new origin (the data say so, or
it returns after the integrity monitor dropped it) is re-anchored: each
particle's offset is set so that the observation agrees with the particle,
and the observation weighs nothing. A tower difference that carries its code
range difference (docs/paths.md) takes its origin from the code instead, one
offset for every particle, known to the code's scatter and the uncertainty
of the towers' transmit delay offsets taken out of it
(:mod:`fusion.transmit_delays`), and its observation then weighs the
particles: with the offsets known, the difference places the cloud on the
towers' hyperbola, which the GNSS fix P0 knows only to its own error.

Algorithm 1 per epoch: propagate with the transition prior (eq. 17) ->
weight by the likelihood in the log domain and normalise (eq. 20-21) ->
systematic resampling when the effective sample size ``1 / sum w^2`` falls
below ``resample_ess_fraction * Np`` (eq. 23) -> weighted-mean estimate with a
circular mean for the heading (eq. 22).

Robustness choices:
- The integrity monitor (:mod:`fusion.integrity`) drops a channel whose
  innovations stop being consistent (a steady multipath or clock bend the
  mixture cannot see) and takes it back as a new origin.
- Log-weights, normalised by subtracting their maximum, so a likelihood that
  underflows for every particle (an outlier observation) still leaves a valid
  weight vector; if every log-weight is -inf or NaN the weights are reset to
  uniform rather than divided by zero.
- The range likelihood is a Gaussian/uniform mixture (:class:`ModelNoise`),
  so a single wild range cannot collapse the cloud onto one particle.
- The systematic resampler places its pointers on the actual total of the
  weights (not on 1), so weights summing slightly below 1 neither run off the
  end of the cumulative sum nor bias the last particle (the failure of
  filterpy's ``monte_carlo`` resamplers).
- All randomness comes from one ``numpy.random.Generator`` seeded by the
  caller and is handed to the kernels as arrays, so a seed fixes the result and
  the numba kernels and their plain-numpy references are exactly comparable.

Stated error: each epoch's east/north covariance is the weighted covariance
of the particles' positions. The marginalised linear state (offsets, clock)
holds no position, so it adds nothing to it.

Smoothing a recorded walk (:meth:`ParticleFilter.record_history`): a
fixed-lag smoother on the particles' ancestry [Kitagawa 1996]. Each
particle carries its ancestors' states of the last ``lag`` epochs, resampled
with it, so that epoch ``k``'s smoothed state is the weighted cloud of epoch
``k + lag - 1``'s particles' ancestors at ``k`` (the last epochs: the final
cloud's). Memory is bounded by ``Np x lag`` states (float32).
Forward-filtering backward-simulation was not taken: its backward weights
need every stored particle's transition density to every later one, and the
process noise per step (centimetres) is far narrower than the cloud (metres),
so on a bounded subsample of stored particles the backward draw degenerates
to the nearest neighbour (docs/decisions.md).

The hot kernels are numba ``@njit`` functions; each has a ``*_reference``
twin in vectorised numpy that the tests compare against and the benchmark
times.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

from dtmbnav_core.records import FusedTrack
from fusion import DEFAULT_PARTICLES, DEFAULT_SMOOTHING_LAG
from fusion.driver import run_filter
from fusion.integrity import IntegrityConfig, IntegrityMonitor
from fusion.model import (CODE_ANCHOR_GATE_SIGMAS, HEADING, HEADING_RATE, SPEED, STATE_SIZE, ClockModel,
                          EpochObservation, Geometry, ModelNoise, ObservationLayout, StepControl, X, Y, initial_state,
                          observation_jacobian, propagate, state_mean, state_residual, walk_range_origins)
from fusion.observations import FilterEpochs

# --- numba kernels -------------------------------------------------------------------------

@njit(cache=True)
def propagate_kernel(particles: np.ndarray, dt_s: float, heading_increment_rad: float, speed_ratio: float,
                     noise: np.ndarray) -> None:
    """Eq. 17 as :func:`fusion.model.propagate` in place, plus the drawn noise."""
    for i in range(particles.shape[0]):
        heading = particles[i, HEADING] + heading_increment_rad + particles[i, HEADING_RATE] * dt_s
        speed = particles[i, SPEED] * speed_ratio
        particles[i, X] += speed * dt_s * np.sin(heading) + noise[i, X]
        particles[i, Y] += speed * dt_s * np.cos(heading) + noise[i, Y]
        particles[i, HEADING_RATE] += noise[i, HEADING_RATE]
        particles[i, HEADING] = heading + noise[i, HEADING]
        particles[i, SPEED] = speed + noise[i, SPEED]


@njit(cache=True)
def range_likelihood_kernel(particles: np.ndarray, linear: np.ndarray, towers: np.ndarray, added: int,
                            subtracted: int, h_linear: np.ndarray, gain: np.ndarray, observation: float,
                            sigma: float, outlier: np.ndarray, log_w: np.ndarray) -> float:
    """Eq. 20 in the log domain for one range channel, and the Kalman step of each particle's linear state.

    The predicted observation of particle ``i`` is the range to tower
    ``added`` (rows of ``towers``: x, y, height) minus the range to tower
    ``subtracted`` (-1: none) plus ``h_linear . linear[i]``; its log-likelihood
    is added to ``log_w``. ``sigma`` is the innovation's ``sqrt(sigma_r^2 + H P H^T)``
    (module docstring). The term is the Gaussian/uniform mixture of
    :class:`ModelNoise`: ``outlier`` is [log(1 - p) - log(sigma sqrt(2 pi)),
    log(p / span)]. Each particle's linear state then moves by ``gain *
    innovation``, scaled by the particle's posterior probability that the
    observation is not an outlier.

    Returns
    -------
    float
        Mean of that probability over the particles.
    """
    inlier_sum = 0.0
    for i in range(particles.shape[0]):
        dx = particles[i, X] - towers[added, 0]
        dy = particles[i, Y] - towers[added, 1]
        predicted = np.sqrt(dx * dx + dy * dy + towers[added, 2] * towers[added, 2])
        if subtracted >= 0:
            dx = particles[i, X] - towers[subtracted, 0]
            dy = particles[i, Y] - towers[subtracted, 1]
            predicted -= np.sqrt(dx * dx + dy * dy + towers[subtracted, 2] * towers[subtracted, 2])
        for k in range(linear.shape[1]):
            predicted += h_linear[k] * linear[i, k]
        innovation = observation - predicted
        d = innovation / sigma
        gaussian = outlier[0] - 0.5 * d * d
        ll = np.logaddexp(gaussian, outlier[1])
        inlier = np.exp(gaussian - ll)
        for k in range(linear.shape[1]):
            linear[i, k] += inlier * gain[k] * innovation
        inlier_sum += inlier
        log_w[i] += ll
    return inlier_sum / particles.shape[0]


@njit(cache=True)
def pdr_likelihood_kernel(particles: np.ndarray, heading_rad: float, speed_mps: float, heading_sigma_rad: float,
                          speed_sigma_mps: float, log_w: np.ndarray) -> None:
    """Eq. 20 in the log domain for the PDR heading (wrapped) and speed observations, added to ``log_w``."""
    for i in range(particles.shape[0]):
        dh = ((particles[i, HEADING] - heading_rad + np.pi) % (2.0 * np.pi) - np.pi) / heading_sigma_rad
        ds = (particles[i, SPEED] - speed_mps) / speed_sigma_mps
        log_w[i] -= 0.5 * (dh * dh + ds * ds)


@njit(cache=True)
def normalise_kernel(log_w: np.ndarray, weights: np.ndarray) -> float:
    """Eq. 21: normalise log-weights in place, fill ``weights``; return the ESS (eq. 23)."""
    n = log_w.shape[0]
    peak = -np.inf
    for i in range(n):
        if log_w[i] > peak:
            peak = log_w[i]
    if not np.isfinite(peak):
        for i in range(n):
            log_w[i] = -np.log(n)
            weights[i] = 1.0 / n
        return float(n)
    total = 0.0
    for i in range(n):
        weights[i] = np.exp(log_w[i] - peak) if log_w[i] == log_w[i] else 0.0
        total += weights[i]
    log_total = np.log(total) + peak
    sum_sq = 0.0
    for i in range(n):
        weights[i] /= total
        log_w[i] -= log_total
        sum_sq += weights[i] * weights[i]
    return 1.0 / sum_sq


@njit(cache=True)
def systematic_resample_kernel(weights: np.ndarray, u: float) -> np.ndarray:
    """Systematic resampling: indices of the particles drawn with one uniform ``u`` in [0, 1).

    Pointer ``i`` sits at ``(u + i) * total / n`` on the running sum of the
    weights and selects the first particle whose cumulative weight reaches it.
    """
    n = weights.shape[0]
    total = 0.0
    for i in range(n):
        total += weights[i]
    step = total / n
    out = np.empty(n, dtype=np.int64)
    j = 0
    cumulative = weights[0]
    for i in range(n):
        pointer = (u + i) * step
        while cumulative < pointer and j < n - 1:
            j += 1
            cumulative += weights[j]
        out[i] = j
    return out


# --- plain-numpy references of the same kernels ---------------------------------------------

def propagate_reference(particles: np.ndarray, dt_s: float, heading_increment_rad: float, speed_ratio: float,
                        noise: np.ndarray) -> None:
    """Numpy twin of :func:`propagate_kernel`."""
    particles[:] = propagate(particles, StepControl(dt_s, heading_increment_rad, speed_ratio)) + noise


def tower_distance_m(particles: np.ndarray, towers: np.ndarray, tower: int) -> np.ndarray:
    """3-D distance of each particle to a tower (rows of ``towers``: x, y, height), m."""
    return np.sqrt((particles[:, X] - towers[tower, 0]) ** 2 + (particles[:, Y] - towers[tower, 1]) ** 2
                   + towers[tower, 2] ** 2)


def range_likelihood_reference(particles: np.ndarray, linear: np.ndarray, towers: np.ndarray, added: int,
                               subtracted: int, h_linear: np.ndarray, gain: np.ndarray, observation: float,
                               sigma: float, outlier: np.ndarray, log_w: np.ndarray) -> float:
    """Numpy twin of :func:`range_likelihood_kernel`."""
    predicted = tower_distance_m(particles, towers, added) + linear @ h_linear
    if subtracted >= 0:
        predicted -= tower_distance_m(particles, towers, subtracted)
    innovation = observation - predicted
    gaussian = outlier[0] - 0.5 * (innovation / sigma) ** 2
    mixture = np.logaddexp(gaussian, outlier[1])
    inlier = np.exp(gaussian - mixture)
    linear += (inlier * innovation)[:, None] * gain
    log_w += mixture
    return float(np.mean(inlier))


def pdr_likelihood_reference(particles: np.ndarray, heading_rad: float, speed_mps: float, heading_sigma_rad: float,
                             speed_sigma_mps: float, log_w: np.ndarray) -> None:
    """Numpy twin of :func:`pdr_likelihood_kernel`."""
    dh = ((particles[:, HEADING] - heading_rad + np.pi) % (2.0 * np.pi) - np.pi) / heading_sigma_rad
    log_w -= 0.5 * (dh**2 + ((particles[:, SPEED] - speed_mps) / speed_sigma_mps) ** 2)


def normalise_reference(log_w: np.ndarray, weights: np.ndarray) -> float:
    """Numpy twin of :func:`normalise_kernel`."""
    n = len(log_w)
    peak = np.nanmax(log_w) if not np.all(np.isnan(log_w)) else -np.inf
    if not np.isfinite(peak):
        log_w[:] = -np.log(n)
        weights[:] = 1.0 / n
        return float(n)
    weights[:] = np.nan_to_num(np.exp(log_w - peak), nan=0.0)
    total = weights.sum()
    weights /= total
    log_w -= np.log(total) + peak
    return float(1.0 / np.sum(weights**2))


def systematic_resample_reference(weights: np.ndarray, u: float) -> np.ndarray:
    """Numpy twin of :func:`systematic_resample_kernel`."""
    cumulative = np.cumsum(weights)
    n = len(weights)
    pointers = (u + np.arange(n)) * (cumulative[-1] / n)
    return np.minimum(np.searchsorted(cumulative, pointers, side="left"), n - 1).astype(np.int64)


@dataclass(frozen=True)
class Kernels:
    """One implementation of the filter kernels."""

    propagate: Callable[..., None]
    range_likelihood: Callable[..., float]
    pdr_likelihood: Callable[..., None]
    normalise: Callable[..., float]
    resample: Callable[..., np.ndarray]


BACKENDS = {
    "numba": Kernels(propagate_kernel, range_likelihood_kernel, pdr_likelihood_kernel, normalise_kernel,
                     systematic_resample_kernel),
    "numpy": Kernels(propagate_reference, range_likelihood_reference, pdr_likelihood_reference, normalise_reference,
                     systematic_resample_reference),
}


class ParticleUpdate:
    """The parts of a particle filter's update that both particle filters share.

    The range channels (:meth:`_update_range_channels`): the integrity monitor decides which
    channels the epoch uses (and may send the cloud back to its open-loop state); unused
    channels' origins take a random-walk step; a channel restarting from a new origin is
    re-anchored (a tower difference on its code where it carries one, and then it weighs too);
    the others weigh the particles one after the other. After the weights
    (:meth:`_resample_and_record`): systematic resampling on a low ESS (eq. 23), the monitor's
    posterior, the smoother's record. The filter provides ``monitor``, ``layout``, ``noise``,
    ``rng``, ``weights``, ``log_w``, ``ess``, ``n_particles``, ``resample_ess_fraction``,
    ``resample_count``, ``_origin_from_code``, ``_smoother`` (all set by :meth:`_set_up`) and the
    methods ``fall_back``, ``summary``, ``_walk_origins``, ``_anchor_on_code``, ``_reanchor``,
    ``_weigh_range``, ``_geometric_m`` (a channel's value at each particle's position), ``_take``
    (keep the particles of an index) and ``_smoother_rows``.
    """

    def _set_up(self, geometry: Geometry, noise: ModelNoise, clock: ClockModel, integrity: IntegrityConfig,
                n_particles: int, seed: int, resample_ess_fraction: float, smoothing_lag: int) -> None:
        """Check the arguments both filters take and set what this class reads (uniform weights).

        Raises
        ------
        ValueError
            For fewer than 2 particles, an ESS fraction outside (0, 1], a smoothing lag below 1.
        """
        if n_particles < 2:
            raise ValueError(f"n_particles must be >= 2, got {n_particles}")
        if not 0.0 < resample_ess_fraction <= 1.0:
            raise ValueError(f"resample_ess_fraction must be in (0, 1], got {resample_ess_fraction}")
        if smoothing_lag < 1:
            raise ValueError(f"smoothing_lag must be >= 1, got {smoothing_lag}")
        self.smoothing_lag = smoothing_lag
        self.geometry = geometry
        self.noise = noise
        self.clock = clock
        self.n_particles = n_particles
        self.resample_ess_fraction = resample_ess_fraction
        self.rng = np.random.default_rng(seed)
        self.layout = ObservationLayout(geometry.n_towers)
        self.monitor = IntegrityMonitor(geometry, noise, clock, integrity)
        self._towers = geometry.towers()
        self._added, self._subtracted = self.layout.tower_pairs()
        #: Per channel, whether its current origin came from its code (:meth:`_code_agrees`).
        self._origin_from_code = np.zeros(self.layout.n_channels, dtype=bool)
        self.log_w = np.full(n_particles, -np.log(n_particles))
        self.weights = np.full(n_particles, 1.0 / n_particles)
        self.ess = float(n_particles)
        self.resample_count = 0
        self._smoother: AncestrySmoother | None = None

    def _code_agrees(self, channel: int, code_m: float, code_sigma: float) -> bool:
        """Whether ``channel`` may take its origin from its code value ``code_m`` (a tower difference's,
        :meth:`fusion.model.EpochObservation.anchor_channels`), known to ``code_sigma`` (m;
        :meth:`fusion.model.EpochObservation.anchor_sigmas`).

        Not (False) without a code value, with an infinite sigma (the transmit delay offsets unknown), or
        where the code lies outside :data:`fusion.model.CODE_ANCHOR_GATE_SIGMAS` of the cloud's own value (a
        first path taken from a reflection arrives late): the channel re-anchors on the particles instead.
        """
        if not (np.isfinite(code_m) and np.isfinite(code_sigma)):
            return False
        geometric = self._geometric_m(channel)
        mean = float(self.weights @ geometric)
        spread = float(np.sqrt(max(self.weights @ (geometric - mean) ** 2, 0.0)))
        return not abs(code_m - mean) > CODE_ANCHOR_GATE_SIGMAS * np.hypot(spread, code_sigma)

    def _update_range_channels(self, observation: EpochObservation) -> None:
        z, sigma, new_origin = observation.range_channels(self.layout.n_towers)
        code_m = observation.code_channels(self.layout.n_towers)
        use, returning, fallback = self.monitor.assess(z, new_origin, code_m)
        if fallback is not None:
            self.fall_back(fallback[0])
        lost = self._walk_origins(use)
        reanchor = use & (new_origin | returning | lost)
        # A channel takes its origin from the code where it has to re-anchor, and where it has one but its
        # origin has not come from the code yet (its first epochs, a code that failed the gate before).
        anchors = observation.anchor_channels(self.layout.n_towers)
        anchor_sigmas = observation.anchor_sigmas(self.noise.difference_code_sigma_m, self.layout.n_towers)
        on_code = np.zeros(self.layout.n_channels, dtype=bool)   # anchored on its code now: its range still weighs
        for j in np.flatnonzero(reanchor | (use & ~self._origin_from_code & np.isfinite(anchors))):
            on_code[j] = self._anchor_on_code(j, z[j], anchors[j], anchor_sigmas[j])
            if reanchor[j] and not on_code[j]:
                self._reanchor(j, z[j], sigma[j])
            self._origin_from_code[j] = on_code[j] or (self._origin_from_code[j] and not reanchor[j])
        for j in np.flatnonzero(use & (~reanchor | on_code)):
            self._weigh_range(j, z[j], sigma[j])

    def _resample_and_record(self, resample: Callable[[np.ndarray, float], np.ndarray]) -> None:
        """Resample with ``resample(weights, u)`` where the ESS is below the threshold; then the monitor's
        posterior and the smoother's record."""
        if self.ess < self.resample_ess_fraction * self.n_particles:
            index = resample(self.weights, self.rng.random())
            self._take(index)
            if self._smoother is not None:
                self._smoother.resample(index)
            self.log_w[:] = -np.log(self.n_particles)
            self.weights[:] = 1.0 / self.n_particles
            self.resample_count += 1
        if self.monitor.config.enabled:
            self.monitor.posterior(*self.summary())
        if self._smoother is not None:
            self._smoother.record(*self._smoother_rows())


class ParticleFilter(ParticleUpdate):
    """Bootstrap particle filter of Algorithm 1, driven like a filterpy filter.

    Parameters
    ----------
    geometry : Geometry
        P0 and the towers.
    noise : ModelNoise
        Process and observation noise.
    n_particles : int
        Np.
    seed : int
        Seeds the only random generator the filter uses.
    resample_ess_fraction : float
        Resample when ESS < this fraction of Np (eq. 23).
    backend : {"numba", "numpy"}
        Kernel implementation; both give the same numbers for the same seed.
    clock : ClockModel
        The receiver clock; a free-running one adds the clock to the linear state.
    integrity : IntegrityConfig
        The range integrity monitor (:mod:`fusion.integrity`).
    smoothing_lag : int
        Lag of the fixed-lag smoother, epochs (:meth:`record_history`).

    Attributes
    ----------
    linear : ndarray, shape (Np, n_channels + 2)
        Each particle's mean of the marginalised linear state: the offset of
        every range channel, then the clock's integrated range (m) and rate (m/s).
    linear_cov : ndarray
        Their covariance, one for all particles.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise = ModelNoise(), n_particles: int = DEFAULT_PARTICLES,
                 seed: int = 0, resample_ess_fraction: float = 0.5, backend: str = "numba",
                 clock: ClockModel = ClockModel(), integrity: IntegrityConfig = IntegrityConfig(),
                 smoothing_lag: int = DEFAULT_SMOOTHING_LAG) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {sorted(BACKENDS)}, got {backend!r}")
        self._set_up(geometry, noise, clock, integrity, n_particles, seed, resample_ess_fraction, smoothing_lag)
        self.kernels = BACKENDS[backend]
        n_channels = self.layout.n_channels
        self._bias, self._rate = n_channels, n_channels + 1
        # Observation rows of the linear state: -1 on the channel's offset, the clock's range where it enters.
        self._h_linear = np.zeros((n_channels, n_channels + 2))
        self._h_linear[np.arange(n_channels), np.arange(n_channels)] = -1.0
        self._h_linear[:, self._bias] = self.layout.clock_coefficients()
        self._process_sigmas = noise.process_sigmas()
        self.particles = np.zeros((n_particles, STATE_SIZE))
        self.linear = np.zeros((n_particles, n_channels + 2))
        self.linear_cov = np.zeros((n_channels + 2, n_channels + 2))

    @property
    def range_offset_m(self) -> np.ndarray:
        """Each particle's offset of the SI-carrier range (a view), m."""
        return self.linear[:, 0]

    @property
    def range_offset_var_m2(self) -> float:
        """Variance of the SI-carrier range offset, m^2."""
        return float(self.linear_cov[0, 0])

    @property
    def clock_rate_mps(self) -> float:
        """Weighted mean of the clock rate, m/s (0 with a disciplined clock)."""
        return float(self.weights @ self.linear[:, self._rate])

    def initialise(self, heading_rad: float, speed_mps: float) -> None:
        """Draw the particles around P0, the initial heading and speed (Algorithm 1, step 1)."""
        centre = np.array([self.geometry.start_x_m, self.geometry.start_y_m, 0.0, heading_rad, speed_mps])
        spread = self.noise.initial_sigmas()
        self.particles = centre + spread * self.rng.standard_normal((self.n_particles, STATE_SIZE))
        # Single-tower channels start at each particle's own range; differences at the fix's (module docstring).
        own = self.layout.geometric_m(self.geometry, self.particles[:, X], self.particles[:, Y])
        at_fix = self.layout.start_values_m(self.geometry)
        difference = self._subtracted >= 0
        self.linear[:] = 0.0
        self.linear[:, :self.layout.n_channels] = np.where(difference, at_fix, own)
        start = initial_state(self.geometry, heading_rad, speed_mps)
        gradient = np.hypot(*observation_jacobian(start, self.geometry)[self.layout.rows()][:, [X, Y]].T)
        self.linear_cov[:] = 0.0
        self.linear_cov[np.arange(self.layout.n_channels), np.arange(self.layout.n_channels)] = np.where(
            difference, (gradient * self.noise.initial_position_m) ** 2, 0.0)
        self.linear_cov[self._bias:, self._bias:] = self.clock.initial_covariance()
        self.log_w[:] = -np.log(self.n_particles)
        self.weights[:] = 1.0 / self.n_particles
        self.ess = float(self.n_particles)

    def predict(self, control: StepControl) -> None:
        """Propagate every particle one step (eq. 17, :func:`fusion.model.propagate`) and the linear state.

        An epoch without a step moves nothing and adds no motion noise; the
        clock runs on over the epoch's interval.
        """
        if control.is_step:
            noise = self.rng.standard_normal((self.n_particles, STATE_SIZE)) * self._process_sigmas
            self.kernels.propagate(self.particles, control.dt_s, control.heading_increment_rad, control.speed_ratio,
                                   noise)
        self.monitor.predict(control)
        if self.clock.has_state:
            elapsed = control.elapsed_s
            self.linear[:, self._bias] += self.linear[:, self._rate] * elapsed
            f = np.eye(len(self.linear_cov))
            f[self._bias, self._rate] = elapsed
            self.linear_cov = f @ self.linear_cov @ f.T
            self.linear_cov[self._bias:, self._bias:] += self.clock.process_covariance(elapsed)

    def summary(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean and covariance of the state (with the clock's range and rate after it, if any).

        What the integrity monitor carries forward (:mod:`fusion.integrity`);
        the clock's part adds the shared covariance of the marginalised state.
        """
        w = self.weights
        states = self.particles
        if self.clock.has_state:
            states = np.column_stack([states, self.linear[:, self._bias:]])
        mean = state_mean(states, w)
        d = state_residual(states, mean)
        cov = (d * w[:, None]).T @ d
        if self.clock.has_state:
            cov[STATE_SIZE:, STATE_SIZE:] += self.linear_cov[self._bias:, self._bias:]
        return mean, cov

    def fall_back(self, x: np.ndarray) -> None:
        """Move the cloud (and the clock means) so that its mean is ``x`` (the integrity monitor's fallback)."""
        shift = state_residual(x, self.summary()[0])
        self.particles += shift[:STATE_SIZE]
        if self.clock.has_state:
            self.linear[:, self._bias:] += shift[STATE_SIZE:]

    def update(self, observation: EpochObservation) -> None:
        """Weight by the observation (eq. 20-21) and resample on low ESS (eq. 23).

        Each range channel the epoch lacks (NaN), or the integrity monitor
        drops, lets its offset's variance grow by one random-walk step
        (module docstring); a channel restarting from a new origin is
        re-anchored (a tower difference on its code where it carries one,
        and then it weighs too); the others weigh the particles one after
        the other. The
        PDR heading and speed weigh in epochs with a step. Where the monitor
        drops a channel the cloud first moves to the monitor's open-loop
        state (:meth:`fall_back`).
        """
        self._update_range_channels(observation)
        if not np.isnan(observation.pdr_heading_rad):
            self.kernels.pdr_likelihood(self.particles, observation.pdr_heading_rad, observation.pdr_speed_mps,
                                        self.noise.pdr_heading_rad, self.noise.pdr_speed_mps, self.log_w)
        self.ess = self.kernels.normalise(self.log_w, self.weights)
        self._resample_and_record(self.kernels.resample)

    def _take(self, index: np.ndarray) -> None:
        """Keep the particles of ``index`` (a resampling)."""
        self.particles = self.particles[index]
        self.linear = self.linear[index]

    def _smoother_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """What the smoother records of this epoch: the particles' states and their weights."""
        return self.particles, self.weights

    def record_history(self) -> None:
        """Smooth from now on with a fixed lag of ``smoothing_lag`` epochs (module docstring; :meth:`smoothed`)."""
        self._smoother = AncestrySmoother(self.smoothing_lag, self.n_particles)

    def smoothed(self) -> tuple[np.ndarray, np.ndarray]:
        """The fixed-lag smoothed states (N, STATE_SIZE) and east/north covariances (N, 2, 2) of the recorded
        epochs (module docstring); the last ``lag - 1`` from the final cloud's ancestry.

        Raises
        ------
        ValueError
            If nothing was recorded (:meth:`record_history` not called before the run).
        """
        if self._smoother is None:
            raise ValueError("smoothed: no recorded epochs (call record_history before the run)")
        return self._smoother.smoothed(self.weights)

    def position_covariance_m2(self) -> np.ndarray:
        """The stated error of the current position: the particles' weighted east/north covariance, m^2."""
        return weighted_position_covariance(self.particles, self.weights)

    def _walk_origins(self, use: np.ndarray) -> np.ndarray:
        """The unused channels' origin random walk; which origins are lost (:func:`fusion.model.walk_range_origins`)."""
        return walk_range_origins(self.linear_cov, np.arange(self.layout.n_channels), use, self.noise)

    def _weigh_range(self, channel: int, z: float, sigma: float) -> None:
        """One range channel's likelihood and Kalman step of the linear state (module docstring)."""
        h = self._h_linear[channel]
        ph = self.linear_cov @ h
        innovation_var = sigma**2 + h @ ph
        gain = ph / innovation_var
        innovation_sigma = np.sqrt(innovation_var)
        p = self.noise.range_outlier_probability
        outlier = np.array([np.log1p(-p) - np.log(innovation_sigma * np.sqrt(2.0 * np.pi)),
                            np.log(p / self.noise.range_outlier_span_m)])
        inlier = self.kernels.range_likelihood(self.particles, self.linear, self._towers,
                                               int(self._added[channel]), int(self._subtracted[channel]), h, gain,
                                               z, innovation_sigma, outlier, self.log_w)
        self.linear_cov -= inlier * innovation_var * np.outer(gain, gain)

    def _reanchor(self, channel: int, z: float, sigma: float) -> None:
        """Make ``z`` a new origin of ``channel``: each particle's offset so that it agrees, known to ``sigma``."""
        geometric = self._geometric_m(channel)
        clock = self._h_linear[channel, self._bias] * self.linear[:, self._bias]
        self.linear[:, channel] = geometric + clock - z
        self.linear_cov[channel, :] = 0.0
        self.linear_cov[:, channel] = 0.0
        self.linear_cov[channel, channel] = sigma**2

    def _geometric_m(self, channel: int) -> np.ndarray:
        """Each particle's geometric value of ``channel`` (its range, or range difference), m."""
        geometric = tower_distance_m(self.particles, self._towers, int(self._added[channel]))
        if self._subtracted[channel] >= 0:
            geometric -= tower_distance_m(self.particles, self._towers, int(self._subtracted[channel]))
        return geometric

    def _anchor_on_code(self, channel: int, z: float, code_m: float, code_sigma: float) -> bool:
        """Make ``z`` a new origin of ``channel`` taken from its code value ``code_m`` (a tower difference's,
        :meth:`fusion.model.EpochObservation.anchor_channels`): one offset for every particle, known to
        ``code_sigma`` (m; :meth:`fusion.model.EpochObservation.anchor_sigmas`), so that the epoch's range then
        weighs the particles. Not done (False) where the code does not agree with the cloud
        (:meth:`ParticleUpdate._code_agrees`).
        """
        if not self._code_agrees(channel, code_m, code_sigma):
            return False
        self.linear[:, channel] = code_m - z
        self.linear_cov[channel, :] = 0.0
        self.linear_cov[:, channel] = 0.0
        self.linear_cov[channel, channel] = code_sigma**2
        return True

    def estimate(self) -> np.ndarray:
        """Weighted mean state (eq. 22), circular mean for the heading, heading in [0, 2 pi)."""
        w = self.weights
        mean = w @ self.particles
        heading = self.particles[:, HEADING]
        mean[HEADING] = np.arctan2(w @ np.sin(heading), w @ np.cos(heading)) % (2.0 * np.pi)
        return mean


def weighted_position_covariance(states: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted east/north covariance of state rows (weights summing to 1), m^2."""
    d = states[:, [X, Y]] - weights @ states[:, [X, Y]]
    return (d * weights[:, None]).T @ d


class AncestrySmoother:
    """The fixed-lag smoother on a particle cloud's ancestry [Kitagawa 1996] (module docstring).

    Each particle carries its ancestors' states of the last ``lag`` epochs,
    resampled with it; once an epoch is ``lag - 1`` epochs old its smoothed
    state is the weighted cloud of its descendants' ancestors. A particle
    that holds a covariance of its own position (a marginalised filter's)
    hands it in too, and it adds to the cloud's spread.

    Parameters
    ----------
    lag : int
        Epochs each particle remembers.
    n_particles : int
        Np.
    own_covariance : bool
        Whether each particle's east/north covariance is recorded with its state.
    """

    def __init__(self, lag: int, n_particles: int, own_covariance: bool = False) -> None:
        #: Each particle's ancestors' states, (lag, Np, STATE_SIZE), a ring over axis 0 (float32: memory).
        self._ancestry = np.empty((lag, n_particles, STATE_SIZE), dtype=np.float32)
        #: Their own east/north covariances (lag, Np, 2, 2), if recorded.
        self._own = np.empty((lag, n_particles, 2, 2), dtype=np.float32) if own_covariance else None
        self._epoch = 0
        self._final: list[tuple[np.ndarray, np.ndarray]] = []

    def resample(self, index: np.ndarray) -> None:
        """The particles were resampled by ``index``: their ancestries go with them."""
        self._ancestry = self._ancestry[:, index]
        if self._own is not None:
            self._own = self._own[:, index]

    def record(self, states: np.ndarray, weights: np.ndarray, own_covariance_m2: np.ndarray | None = None) -> None:
        """Store this epoch's particle states (Np, STATE_SIZE) and, if recorded, their own east/north
        covariances (Np, 2, 2), m^2; the epoch ``lag - 1`` back is then final."""
        lag = len(self._ancestry)
        self._ancestry[self._epoch % lag] = states
        if self._own is not None:
            self._own[self._epoch % lag] = own_covariance_m2
        self._epoch += 1
        if self._epoch >= lag:
            self._final.append(self._summary((self._epoch - lag) % lag, weights))

    def _summary(self, slot: int, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean state and east/north covariance of the current particles' ancestors in ``slot``."""
        states = self._ancestry[slot].astype(np.float64)
        cov = weighted_position_covariance(states, weights)
        if self._own is not None:
            cov += np.einsum("n,nij->ij", weights, self._own[slot].astype(np.float64))
        return state_mean(states, weights), cov

    def smoothed(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smoothed states (N, STATE_SIZE) and east/north covariances (N, 2, 2) of every recorded epoch, the
        last ``lag - 1`` from the cloud of ``weights``.

        Raises
        ------
        ValueError
            If no epoch was recorded.
        """
        if self._epoch == 0:
            raise ValueError("smoothed: no recorded epochs (call record_history before the run)")
        lag = len(self._ancestry)
        final = [self._summary(k % lag, weights) for k in range(max(self._epoch - lag + 1, 0), self._epoch)]
        rows = self._final + final
        return np.array([state for state, _ in rows]), np.array([cov for _, cov in rows])


def start_particle_filter(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                          n_particles: int = DEFAULT_PARTICLES, seed: int = 0, backend: str = "numba",
                          resample_ess_fraction: float = 0.5, clock: ClockModel = ClockModel(),
                          integrity: IntegrityConfig = IntegrityConfig(),
                          smoothing_lag: int = DEFAULT_SMOOTHING_LAG) -> ParticleFilter:
    """A :class:`ParticleFilter` drawn at P0 (Algorithm 1, step 1) for ``epochs``.

    The initial heading and speed are the first step's PDR heading (already
    absolute: relative heading + solved initial heading) and PDR speed.
    """
    pf = ParticleFilter(geometry, noise, n_particles, seed, resample_ess_fraction, backend, clock, integrity,
                        smoothing_lag)
    pf.initialise(*epochs.initial_heading_speed())
    return pf


def run_particle_filter(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                        n_particles: int = DEFAULT_PARTICLES, seed: int = 0, backend: str = "numba",
                        resample_ess_fraction: float = 0.5, clock: ClockModel = ClockModel(),
                        integrity: IntegrityConfig = IntegrityConfig()) -> FusedTrack:
    """Run Algorithm 1 over all epochs and return the estimated track with its stated error.

    Returns
    -------
    FusedTrack
        One row per step epoch, at the epoch times.
    """
    return run_filter(start_particle_filter(epochs, geometry, noise, n_particles, seed, backend,
                                            resample_ess_fraction, clock, integrity), epochs)


def particle_updates_per_second(n_particles: int, backend: str, n_epochs: int = 50, seed: int = 0) -> float:
    """Benchmark: particle-updates per second (one update = predict + weight + resample check).

    Runs ``n_epochs`` epochs of a straight synthetic walk (after a warm-up
    epoch that triggers numba compilation) with resampling every epoch (the
    worst case: ESS threshold 1.0).
    """
    geometry = Geometry(0.0, 0.0, 2000.0, 2200.0, 150.0)
    pf = ParticleFilter(geometry, ModelNoise(), n_particles, seed, resample_ess_fraction=1.0, backend=backend)
    pf.initialise(np.deg2rad(40.0), 1.3)
    heading = np.deg2rad(40.0)
    direction = np.array([np.sin(heading), np.cos(heading)])
    tower_dir = np.array([geometry.tower_x_m, geometry.tower_y_m]) / np.hypot(geometry.tower_x_m, geometry.tower_y_m)

    def epoch(n: int) -> None:
        pf.predict(StepControl(0.54))
        pf.update(EpochObservation(n, -0.7 * n * float(direction @ tower_dir), 1.0, heading, 1.3))
        pf.estimate()

    epoch(1)
    start = time.perf_counter()
    for n in range(2, n_epochs + 2):
        epoch(n)
    return n_particles * n_epochs / (time.perf_counter() - start)

