"""Particle-filter fusion of DTMB range and PDR (docs/method.md §5, eq. 16-23, Algorithm 1).

State and observations are those of :mod:`fusion.model`. Each particle also
carries a range offset: its own start range |P_0 - P_b| (eq. 19 uses the
state at n = 0), so the range observation constrains the walked displacement
and an error in the GNSS start fix is not mistaken for a range error. In
epochs without a range observation (gap, fade, multipath:
:mod:`fusion.observations`) the offset takes a random-walk step of
``ModelNoise.range_offset_m``: the range error integrated across such a
stretch becomes a new, uncertain origin instead of a position error.

The offset enters the range observation linearly, so it is not sampled but
marginalised (a Rao-Blackwellised particle filter): each particle holds the
mean of its offset, and one variance ``P`` serves all of them, because every
particle sees the same sequence of gaps and observation sigmas. A range
observation weighs a particle by its innovation over ``S = sigma_r^2 + P`` and
moves its offset by the Kalman gain ``P / S``; ``P`` then shrinks to
``P sigma_r^2 / S``. Sampling the offset instead (a random-walk draw per
particle) fails where it matters: after a blocked stretch the offsets are
spread over tens of metres, the first returning range keeps only the few
particles whose draw happens to match it, and the cloud collapses onto
positions picked by the offset noise, and each such collapse kicks the track
along the line of sight (a test measures the effective sample size both ways).
With the outlier mixture below, the Kalman step of each particle is scaled by
its probability that the observation is an inlier, and ``P`` shrinks by the
mean of that probability.

Algorithm 1 per epoch: propagate with the transition prior (eq. 17) ->
weight by the likelihood in the log domain and normalise (eq. 20-21) ->
systematic resampling when the effective sample size ``1 / sum w^2`` falls
below ``resample_ess_fraction * Np`` (eq. 23) -> weighted-mean estimate with a
circular mean for the heading (eq. 22).

Robustness choices:
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

from dtmbnav.core.records import Track
from fusion import DEFAULT_PARTICLES
from fusion.driver import run_filter
from fusion.model import (HEADING, HEADING_RATE, HEADING_ROW, RANGE_ROW, SPEED, SPEED_ROW, STATE_SIZE,
                          EpochObservation, Geometry, ModelNoise, StepControl, X, Y, propagate)
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
def log_likelihood_kernel(particles: np.ndarray, range_offset_m: np.ndarray, tower: np.ndarray,
                          observation: np.ndarray, sigma: np.ndarray, outlier: np.ndarray, offset_gain: float,
                          log_w: np.ndarray) -> float:
    """Eq. 20 in the log domain, and the Kalman step of each particle's range offset.

    Adds each particle's log-likelihood to ``log_w``. ``tower`` is
    [x, y, height]; ``observation`` is [range change, heading, speed] and
    ``sigma`` their standard deviations, the range one being the innovation's
    ``sqrt(sigma_r^2 + P)`` with ``P`` the offset variance (module docstring);
    a NaN range observation is skipped. The range term is the
    Gaussian/uniform mixture of :class:`ModelNoise`: ``outlier`` is
    [log(1 - p) - log(sigma sqrt(2 pi)), log(p / span)].

    Each particle's offset then moves by ``-offset_gain * innovation``
    (``offset_gain = P / S``), scaled by the particle's posterior probability
    that the observation is not an outlier.

    Returns
    -------
    float
        Mean of that probability over the particles (1.0 without a range).
    """
    use_range = not np.isnan(observation[RANGE_ROW])
    inlier_sum = 0.0
    for i in range(particles.shape[0]):
        ll = 0.0
        if use_range:
            dx = particles[i, X] - tower[0]
            dy = particles[i, Y] - tower[1]
            r = np.sqrt(dx * dx + dy * dy + tower[2] * tower[2])
            innovation = observation[RANGE_ROW] - (r - range_offset_m[i])
            d = innovation / sigma[RANGE_ROW]
            gaussian = outlier[0] - 0.5 * d * d
            ll = np.logaddexp(gaussian, outlier[1])
            inlier = np.exp(gaussian - ll)
            range_offset_m[i] -= inlier * offset_gain * innovation
            inlier_sum += inlier
        dh = ((particles[i, HEADING] - observation[HEADING_ROW] + np.pi) % (2.0 * np.pi) - np.pi) / sigma[HEADING_ROW]
        ds = (particles[i, SPEED] - observation[SPEED_ROW]) / sigma[SPEED_ROW]
        log_w[i] += ll - 0.5 * (dh * dh + ds * ds)
    if not use_range:
        return 1.0
    return inlier_sum / particles.shape[0]


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


def log_likelihood_reference(particles: np.ndarray, range_offset_m: np.ndarray, tower: np.ndarray,
                             observation: np.ndarray, sigma: np.ndarray, outlier: np.ndarray, offset_gain: float,
                             log_w: np.ndarray) -> float:
    """Numpy twin of :func:`log_likelihood_kernel`."""
    ll = -0.5 * (((particles[:, HEADING] - observation[HEADING_ROW] + np.pi) % (2.0 * np.pi) - np.pi) / sigma[HEADING_ROW]) ** 2
    ll -= 0.5 * ((particles[:, SPEED] - observation[SPEED_ROW]) / sigma[SPEED_ROW]) ** 2
    inlier_mean = 1.0
    if not np.isnan(observation[RANGE_ROW]):
        r = np.sqrt((particles[:, X] - tower[0]) ** 2 + (particles[:, Y] - tower[1]) ** 2 + tower[2] ** 2)
        innovation = observation[RANGE_ROW] - (r - range_offset_m)
        gaussian = outlier[0] - 0.5 * (innovation / sigma[RANGE_ROW]) ** 2
        mixture = np.logaddexp(gaussian, outlier[1])
        inlier = np.exp(gaussian - mixture)
        range_offset_m -= inlier * offset_gain * innovation
        inlier_mean = float(np.mean(inlier))
        ll += mixture
    log_w += ll
    return inlier_mean


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
    """One implementation of the four filter kernels."""

    propagate: Callable[..., None]
    log_likelihood: Callable[..., None]
    normalise: Callable[..., float]
    resample: Callable[..., np.ndarray]


BACKENDS = {
    "numba": Kernels(propagate_kernel, log_likelihood_kernel, normalise_kernel, systematic_resample_kernel),
    "numpy": Kernels(propagate_reference, log_likelihood_reference, normalise_reference,
                     systematic_resample_reference),
}


class ParticleFilter:
    """Bootstrap particle filter of Algorithm 1, driven like a filterpy filter.

    Parameters
    ----------
    geometry : Geometry
        P0 and the tower.
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
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise = ModelNoise(), n_particles: int = DEFAULT_PARTICLES,
                 seed: int = 0, resample_ess_fraction: float = 0.5, backend: str = "numba") -> None:
        if n_particles < 2:
            raise ValueError(f"n_particles must be >= 2, got {n_particles}")
        if not 0.0 < resample_ess_fraction <= 1.0:
            raise ValueError(f"resample_ess_fraction must be in (0, 1], got {resample_ess_fraction}")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {sorted(BACKENDS)}, got {backend!r}")
        self.geometry = geometry
        self.noise = noise
        self.n_particles = n_particles
        self.resample_ess_fraction = resample_ess_fraction
        self.kernels = BACKENDS[backend]
        self.rng = np.random.default_rng(seed)
        self._tower = np.array([geometry.tower_x_m, geometry.tower_y_m, geometry.tower_height_m])
        self._process_sigmas = noise.process_sigmas()
        self.particles = np.zeros((n_particles, STATE_SIZE))
        self.range_offset_m = np.zeros(n_particles)
        self.range_offset_var_m2 = 0.0
        self.log_w = np.full(n_particles, -np.log(n_particles))
        self.weights = np.full(n_particles, 1.0 / n_particles)
        self.ess = float(n_particles)
        self.resample_count = 0

    def initialise(self, heading_rad: float, speed_mps: float) -> None:
        """Draw the particles around P0, the initial heading and speed (Algorithm 1, step 1)."""
        centre = np.array([self.geometry.start_x_m, self.geometry.start_y_m, 0.0, heading_rad, speed_mps])
        spread = self.noise.initial_sigmas()
        self.particles = centre + spread * self.rng.standard_normal((self.n_particles, STATE_SIZE))
        self.range_offset_m = self.geometry.range_m(self.particles[:, X], self.particles[:, Y])
        self.range_offset_var_m2 = 0.0
        self.log_w[:] = -np.log(self.n_particles)
        self.weights[:] = 1.0 / self.n_particles
        self.ess = float(self.n_particles)

    def predict(self, control: StepControl) -> None:
        """Propagate every particle one step (eq. 17, :func:`fusion.model.propagate`)."""
        noise = self.rng.standard_normal((self.n_particles, STATE_SIZE)) * self._process_sigmas
        self.kernels.propagate(self.particles, control.dt_s, control.heading_increment_rad, control.speed_ratio,
                               noise)

    def update(self, observation: EpochObservation) -> None:
        """Weight by the observation (eq. 20-21) and resample on low ESS (eq. 23).

        The observation may lack the range (NaN): only the PDR heading and
        speed then weigh, and the range offsets' variance grows by one
        random-walk step (module docstring).
        """
        offset_gain = 0.0
        innovation_sigma_m = observation.range_sigma_m
        if not observation.has_range:
            self.range_offset_var_m2 += self.noise.range_offset_m**2
        else:
            innovation_var_m2 = observation.range_sigma_m**2 + self.range_offset_var_m2
            innovation_sigma_m = np.sqrt(innovation_var_m2)
            offset_gain = self.range_offset_var_m2 / innovation_var_m2
        z = np.array([observation.range_change_m, observation.pdr_heading_rad, observation.pdr_speed_mps],
                     dtype=np.float64)
        sigma = np.array([innovation_sigma_m, self.noise.pdr_heading_rad, self.noise.pdr_speed_mps])
        p = self.noise.range_outlier_probability
        outlier = np.array([np.log1p(-p) - np.log(innovation_sigma_m * np.sqrt(2.0 * np.pi)),
                            np.log(p / self.noise.range_outlier_span_m)])
        inlier = self.kernels.log_likelihood(self.particles, self.range_offset_m, self._tower, z, sigma,
                                             outlier, offset_gain, self.log_w)
        self.range_offset_var_m2 *= 1.0 - inlier * offset_gain
        self.ess = self.kernels.normalise(self.log_w, self.weights)
        if self.ess < self.resample_ess_fraction * self.n_particles:
            index = self.kernels.resample(self.weights, self.rng.random())
            self.particles = self.particles[index]
            self.range_offset_m = self.range_offset_m[index]
            self.log_w[:] = -np.log(self.n_particles)
            self.weights[:] = 1.0 / self.n_particles
            self.resample_count += 1

    def estimate(self) -> np.ndarray:
        """Weighted mean state (eq. 22), circular mean for the heading, heading in [0, 2 pi)."""
        w = self.weights
        mean = w @ self.particles
        heading = self.particles[:, HEADING]
        mean[HEADING] = np.arctan2(w @ np.sin(heading), w @ np.cos(heading)) % (2.0 * np.pi)
        return mean


def run_particle_filter(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                        n_particles: int = DEFAULT_PARTICLES, seed: int = 0, backend: str = "numba",
                        resample_ess_fraction: float = 0.5) -> Track:
    """Run Algorithm 1 over all epochs and return the estimated track.

    The initial heading and speed are the first epoch's PDR heading (already
    absolute: relative heading + solved initial heading) and PDR speed.

    Returns
    -------
    Track
        One row per epoch, at the epoch times.
    """
    pf = ParticleFilter(geometry, noise, n_particles, seed, resample_ess_fraction, backend)
    pf.initialise(float(epochs.pdr_heading_rad[0]), float(epochs.pdr_speed_mps[0]))
    return run_filter(pf, epochs)


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

