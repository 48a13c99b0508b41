"""Marginalised (Rao-Blackwellised) particle filter: headings sampled, position and step-length scale exact.

The model is :mod:`fusion.model`'s, written so that everything but the
heading enters linearly. The walker's speed is the PDR's speed times a
step-length scale ``s`` (the PDR's gain error), and a step moves the
position by ``s * v_n * dt_n * (sin phi, cos phi)`` (eq. 17). Given the
headings, position and scale therefore follow a linear-Gaussian model::

    p_{n+1} = p_n + s_n d_n(phi) + w_p        s_{n+1} = s_n + w_s

(``d_n`` the PDR step under the particle's heading), and the range channels
add their offsets and the clock linearly (:mod:`fusion.particle_filter`). So
each particle samples only its heading and heading rate, and carries for the
rest a mean and a covariance of its own: the linear state::

    a = [x_m, y_m, scale, offset_0 .. offset_{C-1}, clock_m, clock_rate_mps]

A range observation ``g(p) + H a`` is nonlinear in ``p`` only through the
range to a tower kilometres away, so each particle takes it as an extended
Kalman step linearised at its own mean position; the particle's weight is
the innovation's density under its own variance ``h P h^T + sigma^2`` (with
the Gaussian/uniform outlier mixture of :class:`fusion.model.ModelNoise`,
the Kalman step scaled by the inlier probability, as in the particle filter).

Why: where the walk runs across the line of sight the range does not see the
along-street direction. A particle filter that samples the speed keeps a
cloud of speeds there that no observation weighs, and resampling on the
headings lets that cloud's mean wander (genetic drift); here that direction
is a Gaussian per particle, moved only by what the ranges say of it
(Schon, Gustafsson and Nordlund 2005, "Marginalized particle filters for
mixed linear/nonlinear state-space models"). It is not free of the heading:
a particle whose heading is off explains part of its cross-track miss by a
shorter step (its scale's Kalman step), so where the heading cloud is wide
the weighted scale leans short. And with only the heading sampled, far fewer
particles carry the posterior than the particle filter's.

The scale has an honest prior (``ModelNoise``): its initial spread is
``initial_speed_mps`` over the first PDR speed, its random walk per step
``scale_per_step`` (slow: a gait's step length changes slowly), and the PDR
speed observation (``pdr_speed_mps``) is the same linear observation of
``s v`` the other filters weigh.

The per-particle algebra is vectorised numpy over (Np, L, L) arrays, not numba
kernels: with only the heading sampled, Np is a tenth of the particle filter's
and the filter costs less than it.

Single-tower channels start from each particle's own start range: the
offset's covariance is tied to the start position's (the range constrains
the walked displacement). A re-anchored channel takes the particle's own
geometric value as its origin, with the same tie to the position. Stated
error: the weighted covariance of the particles' mean positions plus the
weighted mean of their own position covariances. Smoothing: the fixed-lag
ancestry smoother of :mod:`fusion.particle_filter` on each particle's mean and
own position covariance (the filtered ones: a later range does not revise a
particle's earlier linear state).
"""

from __future__ import annotations

import numpy as np

from fusion import DEFAULT_RB_PARTICLES, DEFAULT_SMOOTHING_LAG
from fusion.integrity import IntegrityConfig
from fusion.model import (HEADING, HEADING_RATE, SPEED, STATE_SIZE, ClockModel, EpochObservation, Geometry,
                          ModelNoise, StepControl, X, Y, state_mean, state_residual, wrap_angle)
from fusion.observations import FilterEpochs
from fusion.particle_filter import (AncestrySmoother, ParticleUpdate, normalise_kernel, systematic_resample_kernel,
                                    weighted_position_covariance)

#: Columns of the linear state (module docstring); the range offsets follow, then the clock.
LIN_X, LIN_Y, LIN_SCALE = 0, 1, 2
N_MOTION = 3


class MarginalisedParticleFilter(ParticleUpdate):
    """Particle filter over headings with an exact Gaussian position and step-length scale per particle.

    Parameters
    ----------
    geometry, noise, clock, integrity
        As :class:`fusion.particle_filter.ParticleFilter`.
    n_particles : int
        Np.
    seed : int
        Seeds the only random generator the filter uses.
    resample_ess_fraction : float
        Resample when ESS < this fraction of Np (eq. 23).
    smoothing_lag : int
        Lag of the fixed-lag ancestry smoother, epochs.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                 n_particles: int = DEFAULT_RB_PARTICLES, seed: int = 0, resample_ess_fraction: float = 0.5,
                 clock: ClockModel = ClockModel(), integrity: IntegrityConfig = IntegrityConfig(),
                 smoothing_lag: int = DEFAULT_SMOOTHING_LAG) -> None:
        self._set_up(geometry, noise, clock, integrity, n_particles, seed, resample_ess_fraction, smoothing_lag)
        n_channels = self.layout.n_channels
        self._offsets = N_MOTION + np.arange(n_channels)
        self._bias, self._rate = N_MOTION + n_channels, N_MOTION + n_channels + 1
        size = N_MOTION + n_channels + 2
        # Observation rows on the linear state but for the position: -1 on the channel's offset, the clock's range.
        self._h_linear = np.zeros((n_channels, size))
        self._h_linear[np.arange(n_channels), self._offsets] = -1.0
        self._h_linear[:, self._bias] = self.layout.clock_coefficients()
        #: Sampled part per particle: heading rate (rad/s) and heading (rad).
        self.heading_rate = np.zeros(n_particles)
        self.heading = np.zeros(n_particles)
        #: Linear part per particle: means (Np, size) and covariances (Np, size, size).
        self.mean = np.zeros((n_particles, size))
        self.cov = np.zeros((n_particles, size, size))
        #: The PDR's speed of the latest step, m/s: the scale multiplies it.
        self.pdr_speed_mps = 1.0

    # --- set-up and prediction ------------------------------------------------------------------

    def initialise(self, heading_rad: float, speed_mps: float) -> None:
        """Headings drawn around the solved heading; every particle's linear state at P0, scale 1."""
        n = self.n_particles
        self.pdr_speed_mps = float(speed_mps)
        self.heading = heading_rad + self.noise.initial_heading_rad * self.rng.standard_normal(n)
        self.heading_rate = self.noise.initial_heading_rate_radps * self.rng.standard_normal(n)
        start = np.array([self.geometry.start_x_m, self.geometry.start_y_m])
        size = self.mean.shape[1]
        mean = np.zeros(size)
        mean[[LIN_X, LIN_Y]] = start
        mean[LIN_SCALE] = 1.0
        mean[self._offsets] = self.layout.start_values_m(self.geometry)
        sigma_p2 = self.noise.initial_position_m**2
        gradient = self.layout.gradients(self.geometry, start[0], start[1])          # (channels, 2)
        difference = self._subtracted >= 0
        # The start position's error moves the position and every single-tower origin (the walker's own start
        # range) together: both are the linear map `tie` of it. A difference's origin is its value at the fix,
        # known to the fix's error but not tied to the position.
        tie = np.zeros((size, 2))
        tie[[LIN_X, LIN_Y], [0, 1]] = 1.0
        tie[self._offsets[~difference]] = gradient[~difference]
        cov = sigma_p2 * tie @ tie.T
        cov[self._offsets[difference], self._offsets[difference]] = sigma_p2 * np.sum(gradient[difference]**2, axis=1)
        cov[LIN_SCALE, LIN_SCALE] = (self.noise.initial_speed_mps / max(speed_mps, 1e-3)) ** 2
        cov[self._bias:, self._bias:] = self.clock.initial_covariance()
        self.mean[:] = mean
        self.cov[:] = cov
        self.log_w[:] = -np.log(n)
        self.weights[:] = 1.0 / n
        self.ess = float(n)

    def predict(self, control: StepControl) -> None:
        """Sample each particle's heading (eq. 17) and carry its linear state over the step exactly."""
        if control.is_step:
            n = self.n_particles
            self.heading_rate += self.noise.heading_rate_radps * self.rng.standard_normal(n)
            self.heading += control.heading_increment_rad + self.heading_rate * control.dt_s
            self.heading += self.noise.heading_rad * self.rng.standard_normal(n)
            self.pdr_speed_mps *= control.speed_ratio
            step = self.pdr_speed_mps * control.dt_s
            d = np.stack([step * np.sin(self.heading), step * np.cos(self.heading)], axis=1)   # (Np, 2)
            scale = self.mean[:, LIN_SCALE]
            self.mean[:, LIN_X] += d[:, 0] * scale
            self.mean[:, LIN_Y] += d[:, 1] * scale
            # P <- F P F^T with F = I + d e_scale^T on the position rows.
            self.cov[:, [LIN_X, LIN_Y], :] += d[:, :, None] * self.cov[:, None, LIN_SCALE, :]
            self.cov[:, :, [LIN_X, LIN_Y]] += self.cov[:, :, LIN_SCALE, None] * d[:, None, :]
            self.cov[:, LIN_X, LIN_X] += self.noise.position_m**2
            self.cov[:, LIN_Y, LIN_Y] += self.noise.position_m**2
            self.cov[:, LIN_SCALE, LIN_SCALE] += self.noise.scale_per_step**2
        self.monitor.predict(control)
        if self.clock.has_state:
            elapsed = control.elapsed_s
            self.mean[:, self._bias] += self.mean[:, self._rate] * elapsed
            self.cov[:, self._bias, :] += elapsed * self.cov[:, self._rate, :]
            self.cov[:, :, self._bias] += elapsed * self.cov[:, :, self._rate]
            self.cov[:, self._bias:, self._bias:] += self.clock.process_covariance(elapsed)

    # --- the update -----------------------------------------------------------------------------

    def update(self, observation: EpochObservation) -> None:
        """Weigh and correct with the epoch's range channels (:class:`fusion.particle_filter.ParticleUpdate`)
        and PDR; resample on low ESS (eq. 20-23)."""
        self._update_range_channels(observation)
        if not np.isnan(observation.pdr_heading_rad):
            dh = wrap_angle(self.heading - observation.pdr_heading_rad)
            self.log_w -= 0.5 * (dh / self.noise.pdr_heading_rad) ** 2
            self._weigh_speed(observation.pdr_speed_mps)
        self.ess = normalise_kernel(self.log_w, self.weights)
        self._resample_and_record(systematic_resample_kernel)

    def _take(self, index: np.ndarray) -> None:
        """Keep the particles of ``index`` (a resampling)."""
        self.heading, self.heading_rate = self.heading[index], self.heading_rate[index]
        self.mean, self.cov = self.mean[index], self.cov[index]

    def _smoother_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the smoother records of this epoch: the particles' states, weights and own position covariances."""
        return self._particle_states(), self.weights, self.cov[:, :2, :2]

    def _geometric_m(self, channel: int) -> np.ndarray:
        """Each particle's geometric value of ``channel`` (its range, or range difference) at its mean, m."""
        return self.layout.geometric_m(self.geometry, self.mean[:, LIN_X], self.mean[:, LIN_Y])[:, channel]

    def _channel_row(self, channel: int) -> tuple[np.ndarray, np.ndarray]:
        """Each particle's linearised observation row of ``channel`` and its predicted value at the means."""
        x, y = self.mean[:, LIN_X], self.mean[:, LIN_Y]
        h = np.broadcast_to(self._h_linear[channel], self.mean.shape).copy()
        h[:, [LIN_X, LIN_Y]] = self.layout.gradients(self.geometry, x, y)[:, channel]
        predicted = self._geometric_m(channel) + self.mean @ self._h_linear[channel]
        return h, predicted

    def _weigh_range(self, channel: int, z: float, sigma: float) -> None:
        """One range channel: every particle's likelihood and extended Kalman step (module docstring)."""
        h, predicted = self._channel_row(channel)
        ph = np.einsum("nij,nj->ni", self.cov, h)
        s = np.einsum("ni,ni->n", h, ph) + sigma**2
        innovation = z - predicted
        p = self.noise.range_outlier_probability
        gaussian = np.log1p(-p) - 0.5 * np.log(2.0 * np.pi * s) - 0.5 * innovation**2 / s
        mixture = np.logaddexp(gaussian, np.log(p / self.noise.range_outlier_span_m))
        inlier = np.exp(gaussian - mixture)
        self.log_w += mixture
        gain = ph / s[:, None]
        self.mean += (inlier * innovation)[:, None] * gain
        self.cov -= (inlier * s)[:, None, None] * gain[:, :, None] * gain[:, None, :]

    def _weigh_speed(self, pdr_speed_mps: float) -> None:
        """The PDR speed as a linear observation of ``scale * v`` (weights and Kalman step)."""
        v = self.pdr_speed_mps
        ph = v * self.cov[:, :, LIN_SCALE]
        s = v * ph[:, LIN_SCALE] + self.noise.pdr_speed_mps**2
        innovation = pdr_speed_mps - v * self.mean[:, LIN_SCALE]
        self.log_w -= 0.5 * innovation**2 / s + 0.5 * np.log(s)
        gain = ph / s[:, None]
        self.mean += innovation[:, None] * gain
        self.cov -= s[:, None, None] * gain[:, :, None] * gain[:, None, :]

    def _walk_origins(self, use: np.ndarray) -> np.ndarray:
        """The unused channels' origin random walk; which origins are lost (``fusion.model.walk_range_origins``)."""
        unused = self._offsets[~use]
        self.cov[:, unused, unused] += self.noise.range_offset_m**2
        variance = self.weights @ self.cov[:, self._offsets, self._offsets]
        return variance > self.noise.range_reanchor_m**2

    def _reanchor(self, channel: int, z: float, sigma: float) -> None:
        """Make ``z`` a new origin: each particle's offset so that it agrees, tied to its position as it is."""
        h, predicted = self._channel_row(channel)
        col = self._offsets[channel]
        # offset_new = g(p) + clock - z: the channel's own row without its old offset, applied to the state.
        t = h.copy()
        t[:, col] = 0.0
        row = np.einsum("ni,nij->nj", t, self.cov)
        self.mean[:, col] = predicted + self.mean[:, col] - z     # predicted holds -offset: remove it
        self.cov[:, col, :] = row
        self.cov[:, :, col] = row
        self.cov[:, col, col] = np.einsum("ni,ni->n", row, t) + sigma**2

    def _anchor_on_code(self, channel: int, z: float, code_m: float, code_sigma: float) -> bool:
        """A tower difference's origin from its code, one offset for every particle known to ``code_sigma``
        (``ParticleFilter._anchor_on_code``); False where the code does not agree with the cloud
        (:meth:`fusion.particle_filter.ParticleUpdate._code_agrees`)."""
        if not self._code_agrees(channel, code_m, code_sigma):
            return False
        col = self._offsets[channel]
        self.mean[:, col] = code_m - z
        self.cov[:, col, :] = 0.0
        self.cov[:, :, col] = 0.0
        self.cov[:, col, col] = code_sigma**2
        return True

    # --- what the filter states -----------------------------------------------------------------

    def _particle_states(self) -> np.ndarray:
        """Each particle's state in :mod:`fusion.model`'s columns (its means for the linear part)."""
        states = np.empty((self.n_particles, STATE_SIZE))
        states[:, X], states[:, Y] = self.mean[:, LIN_X], self.mean[:, LIN_Y]
        states[:, HEADING_RATE], states[:, HEADING] = self.heading_rate, self.heading
        states[:, SPEED] = self.mean[:, LIN_SCALE] * self.pdr_speed_mps
        return states

    def _to_state(self) -> np.ndarray:
        """Rows mapping the linear state to the summary's columns (state, then the clock's two)."""
        size = self.mean.shape[1]
        rows = STATE_SIZE + (2 if self.clock.has_state else 0)
        m = np.zeros((rows, size))
        m[X, LIN_X] = m[Y, LIN_Y] = 1.0
        m[SPEED, LIN_SCALE] = self.pdr_speed_mps
        if self.clock.has_state:
            m[STATE_SIZE, self._bias] = m[STATE_SIZE + 1, self._rate] = 1.0
        return m

    def summary(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean and covariance of the state (clock after it, if any): the particles' spread and
        their own covariances together."""
        w = self.weights
        states = self._particle_states()
        if self.clock.has_state:
            states = np.column_stack([states, self.mean[:, self._bias:]])
        mean = state_mean(states, w)
        d = state_residual(states, mean)
        m = self._to_state()
        own = np.einsum("n,nij->ij", w, self.cov)
        return mean, (d * w[:, None]).T @ d + m @ own @ m.T

    def fall_back(self, x: np.ndarray) -> None:
        """Move every particle so that the filter's mean is ``x`` (the integrity monitor's fallback)."""
        shift = state_residual(x, self.summary()[0])
        self.mean[:, LIN_X] += shift[X]
        self.mean[:, LIN_Y] += shift[Y]
        self.heading_rate += shift[HEADING_RATE]
        self.heading += shift[HEADING]
        self.mean[:, LIN_SCALE] += shift[SPEED] / max(self.pdr_speed_mps, 1e-3)
        if self.clock.has_state:
            self.mean[:, self._bias:] += shift[STATE_SIZE:]

    def estimate(self) -> np.ndarray:
        """Weighted mean state (eq. 22), circular mean for the heading, heading in [0, 2 pi)."""
        mean = self.weights @ self._particle_states()
        mean[HEADING] = np.arctan2(self.weights @ np.sin(self.heading),
                                   self.weights @ np.cos(self.heading)) % (2.0 * np.pi)
        return mean

    def position_covariance_m2(self) -> np.ndarray:
        """The particles' weighted east/north spread plus their own position covariances, m^2."""
        own = np.einsum("n,nij->ij", self.weights, self.cov[:, :2, :2])
        return weighted_position_covariance(self._particle_states(), self.weights) + own

    def record_history(self) -> None:
        """Smooth from now on (the fixed-lag ancestry smoother on the particles' means)."""
        self._smoother = AncestrySmoother(self.smoothing_lag, self.n_particles, own_covariance=True)

    def smoothed(self) -> tuple[np.ndarray, np.ndarray]:
        """Smoothed states and east/north covariances of the recorded epochs."""
        if self._smoother is None:
            raise ValueError("smoothed: no recorded epochs (call record_history before the run)")
        return self._smoother.smoothed(self.weights)


def start_marginalised_filter(epochs: FilterEpochs, geometry: Geometry, noise: ModelNoise = ModelNoise(),
                              n_particles: int = DEFAULT_RB_PARTICLES, seed: int = 0,
                              clock: ClockModel = ClockModel(), integrity: IntegrityConfig = IntegrityConfig(),
                              smoothing_lag: int = DEFAULT_SMOOTHING_LAG) -> MarginalisedParticleFilter:
    """A :class:`MarginalisedParticleFilter` started at P0 with the first step's heading and PDR speed."""
    rbpf = MarginalisedParticleFilter(geometry, noise, n_particles, seed, clock=clock, integrity=integrity,
                                      smoothing_lag=smoothing_lag)
    rbpf.initialise(*epochs.initial_heading_speed())
    return rbpf
