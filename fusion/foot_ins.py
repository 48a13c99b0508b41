"""Foot-mounted strapdown INS with rank-KF zero-velocity updates [Rank-KF].

:class:`ZuptInsRankKf` is the rank-KF paper's pedestrian navigator: a
strapdown INS on a foot-mounted IMU with a 15-state error model (attitude,
gyro bias, position, velocity, accelerometer bias) and zero-velocity pseudo
measurements during stance (detected with the SHOE statistic), the
measurement noise a two-component Gaussian mixture entered through its mean
and covariance. The error model is linear, so the rank sampling's covariance
prediction equals ``F P F^T``; the per-sample prediction uses that closed form
in a numba kernel (a test checks the equality), and the ZUPT updates use rank
sampling (:mod:`fusion.rank_kf`). Citation: ``docs/method.md``, references.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from dtmbnav_core.constants import GRAVITY_MPS2
from dtmbnav_core.records import Track
from fusion.rank_kf import RankKalmanFilter, rank_quantiles

#: Error-state layout (docs/method.md §7 order).
ATT, BG, POS, VEL, BA = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15))
ERROR_SIZE = 15


@dataclass(frozen=True)
class ZuptConfig:
    """Foot-mounted INS / ZUPT parameters.

    Attributes
    ----------
    gyro_noise_radps : float
        Gyro white noise density, rad/s/sqrt(Hz).
    accel_noise_mps2 : float
        Accelerometer white noise density, m/s^2/sqrt(Hz).
    gyro_bias_walk : float
        Gyro bias random walk, rad/s^2/sqrt(Hz).
    accel_bias_walk : float
        Accelerometer bias random walk, m/s^3/sqrt(Hz).
    shoe_window : int
        SHOE detector window, samples.
    shoe_threshold : float
        SHOE detection threshold (statistic below it = stance).
    shoe_accel_sigma_mps2, shoe_gyro_sigma_radps : float
        Noise levels normalising the SHOE statistic.
    zupt_mixture_weights, zupt_mixture_sigmas_mps : tuple of float
        Zero-velocity pseudo-measurement noise: a zero-mean Gaussian mixture
        (stance proper, and stance with foot roll / micro-slip).
    initial_attitude_rad, initial_bias_radps : float
        Initial attitude and gyro bias standard deviations.
    initial_accel_bias_mps2 : float
        Initial accelerometer bias standard deviation.
    """

    gyro_noise_radps: float = np.deg2rad(0.05)
    accel_noise_mps2: float = 0.02
    gyro_bias_walk: float = 1e-5
    accel_bias_walk: float = 1e-4
    shoe_window: int = 5
    shoe_threshold: float = 3e4
    shoe_accel_sigma_mps2: float = 0.01
    shoe_gyro_sigma_radps: float = np.deg2rad(0.1)
    zupt_mixture_weights: tuple[float, float] = (0.9, 0.1)
    zupt_mixture_sigmas_mps: tuple[float, float] = (0.01, 0.05)
    initial_attitude_rad: float = np.deg2rad(1.0)
    initial_bias_radps: float = np.deg2rad(0.2)
    initial_accel_bias_mps2: float = 0.05


def shoe_stance(acc_mps2: np.ndarray, gyro_radps: np.ndarray, config: ZuptConfig = ZuptConfig()) -> np.ndarray:
    """Stance (zero-velocity) samples by the SHOE statistic (Skog et al.), bool per sample.

    ``T = mean over a window of |f - g u|^2 / sigma_a^2 + |w|^2 / sigma_w^2``
    with ``u`` the window's mean specific-force direction; stance where
    ``T < threshold``.
    """
    n = len(acc_mps2)
    w = config.shoe_window
    kernel = np.ones(w) / w
    mean_f = np.stack([np.convolve(acc_mps2[:, i], kernel, mode="same") for i in range(3)], axis=1)
    u = mean_f / np.linalg.norm(mean_f, axis=1, keepdims=True)
    specific = np.sum((acc_mps2 - GRAVITY_MPS2 * u) ** 2, axis=1) / config.shoe_accel_sigma_mps2**2
    rotation = np.sum(gyro_radps**2, axis=1) / config.shoe_gyro_sigma_radps**2
    statistic = np.convolve(specific + rotation, kernel, mode="same")
    return statistic[:n] < config.shoe_threshold


@njit(cache=True)
def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@njit(cache=True)
def _rotation(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``phi`` (Rodrigues)."""
    angle = np.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    k = _skew(phi)
    if angle < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(angle) / angle * k + (1.0 - np.cos(angle)) / angle**2 * (k @ k)


@njit(cache=True)
def strapdown_kernel(C: np.ndarray, v: np.ndarray, p: np.ndarray, bg: np.ndarray, ba: np.ndarray, P: np.ndarray,
                     gyro: np.ndarray, acc: np.ndarray, dt: np.ndarray, q_diag: np.ndarray,
                     out_p: np.ndarray, out_v: np.ndarray, out_C: np.ndarray) -> None:
    """Mechanise a run of IMU samples and propagate the 15-state error covariance in place.

    Nominal: ``C <- C R(w dt)``, ``v <- v + (C f + g) dt``, ``p <- p + v dt``
    (ENU, g = (0, 0, -GRAVITY_MPS2)). Error (truth minus estimate, ``C = (I + [phi x]) C_hat``):
    ``phi' = -C dbg``, ``dp' = dv``, ``dv' = -[f_n x] phi - C dba``; biases
    random walks. ``P <- F P F^T + Q dt`` with ``F = I + A dt``.
    """
    g = np.array([0.0, 0.0, -GRAVITY_MPS2])
    for k in range(gyro.shape[0]):
        h = dt[k]
        w = gyro[k] - bg
        f_b = acc[k] - ba
        C[:, :] = C @ _rotation(w * h)
        f_n = C @ f_b
        v += (f_n + g) * h
        p += v * h
        F = np.eye(15)
        F[0:3, 3:6] = -C * h
        F[6:9, 9:12] = np.eye(3) * h
        F[9:12, 0:3] = -_skew(f_n) * h
        F[9:12, 12:15] = -C * h
        P[:, :] = F @ P @ F.T
        for i in range(15):
            P[i, i] += q_diag[i] * h
        out_p[k] = p
        out_v[k] = v
        out_C[k] = C


def strapdown_reference(C: np.ndarray, v: np.ndarray, p: np.ndarray, bg: np.ndarray, ba: np.ndarray,
                        P: np.ndarray, gyro: np.ndarray, acc: np.ndarray, dt: np.ndarray, q_diag: np.ndarray,
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plain-numpy twin of :func:`strapdown_kernel` (updates C, v, p, P in place; returns the histories)."""
    g = np.array([0.0, 0.0, -GRAVITY_MPS2])
    out_p, out_v, out_C = np.zeros((len(dt), 3)), np.zeros((len(dt), 3)), np.zeros((len(dt), 3, 3))
    for k, h in enumerate(dt):
        phi = (gyro[k] - bg) * h
        angle = np.linalg.norm(phi)
        skew_phi = np.cross(np.eye(3), phi)  # [phi x]
        rotation = np.eye(3) + skew_phi if angle < 1e-12 else (
            np.eye(3) + np.sin(angle) / angle * skew_phi + (1 - np.cos(angle)) / angle**2 * skew_phi @ skew_phi)
        C[:] = C @ rotation
        f_n = C @ (acc[k] - ba)
        v += (f_n + g) * h
        p += v * h
        F = np.eye(15)
        F[ATT, BG] = -C * h
        F[POS, VEL] = np.eye(3) * h
        F[VEL, ATT] = np.cross(f_n, np.eye(3)) * h  # -[f_n x]
        F[VEL, BA] = -C * h
        P[:] = F @ P @ F.T + np.diag(q_diag * h)
        out_p[k], out_v[k], out_C[k] = p, v, C
    return out_p, out_v, out_C


def level_attitude(acc_mps2: np.ndarray, heading_rad: float) -> np.ndarray:
    """Body-to-ENU rotation from a still accelerometer mean and the heading of the body y axis.

    The foot-mounted unit's frame (:class:`dtmbnav_core.records.ImuLog`) is x right,
    y forward along the foot, z up; roll and pitch level the mean specific
    force, and the yaw turns body y to ``heading_rad`` (clockwise from north).
    """
    f = acc_mps2.mean(axis=0)
    roll = np.arctan2(f[1], f[2])
    pitch = np.arctan2(-f[0], np.hypot(f[1], f[2]))
    yaw = -heading_rad  # counter-clockwise about up; body y starts pointing north
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


class ZuptInsRankKf:
    """Foot-mounted strapdown INS corrected by rank-KF zero-velocity updates ([Rank-KF]).

    Parameters
    ----------
    config : ZuptConfig
    """

    def __init__(self, config: ZuptConfig = ZuptConfig()) -> None:
        self.config = config
        self.lambdas, self.omega = rank_quantiles(2)
        weights = np.asarray(config.zupt_mixture_weights)
        sigmas = np.asarray(config.zupt_mixture_sigmas_mps)
        self.zupt_variance = float(weights @ sigmas**2)  # zero-mean mixture: its variance
        c = config
        self.q_diag = np.concatenate([np.full(3, c.gyro_noise_radps**2), np.full(3, c.gyro_bias_walk**2),
                                      np.zeros(3), np.full(3, c.accel_noise_mps2**2),
                                      np.full(3, c.accel_bias_walk**2)])

    def zupt_update(self, P: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rank-sampled ZUPT on the error state (mean zero): returns the error estimate and new P."""
        h = np.zeros((3, ERROR_SIZE))
        h[:, VEL] = np.eye(3)
        rkf = RankKalmanFilter(np.zeros(ERROR_SIZE), P, lambda pts: pts.mean(axis=0), np.subtract)
        # Observation: the true velocity is zero, so the error dv = 0 - v_hat is observed.
        rkf.update(-v, lambda pts: pts @ h.T, np.eye(3) * self.zupt_variance,
                   lambda zs: zs.mean(axis=0), np.subtract)
        return rkf.x, rkf.P

    def run(self, t_s: np.ndarray, acc_mps2: np.ndarray, gyro_radps: np.ndarray, start_xy_m: tuple[float, float],
            initial_heading_rad: float) -> Track:
        """Navigate a foot IMU log; returns the track at every IMU sample.

        The walker must stand still for the first ``shoe_window`` samples at
        least (levelling). Heading in the track is the body y (forward) axis's,
        clockwise from north; speed is the horizontal speed.
        """
        if acc_mps2.shape != gyro_radps.shape or acc_mps2.shape[1:] != (3,) or len(t_s) != len(acc_mps2):
            raise ValueError("ZuptInsRankKf.run: t_s (N), acc_mps2 (N x 3) and gyro_radps (N x 3) must agree")
        stance = shoe_stance(acc_mps2, gyro_radps, self.config)
        c = self.config
        C = level_attitude(acc_mps2[: max(c.shoe_window, 10)], initial_heading_rad)
        v = np.zeros(3)
        p = np.array([start_xy_m[0], start_xy_m[1], 0.0])
        bg, ba = np.zeros(3), np.zeros(3)
        P = np.diag(np.concatenate([np.full(3, c.initial_attitude_rad**2), np.full(3, c.initial_bias_radps**2),
                                    np.zeros(3) + 1e-6, np.zeros(3) + 1e-6, np.full(3, c.initial_accel_bias_mps2**2)]))
        n = len(t_s)
        dt = np.diff(t_s, prepend=t_s[0] - np.median(np.diff(t_s)))
        out_p, out_v, out_C = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
        # Mechanise up to and including each stance sample in one kernel call, then correct.
        boundaries = np.concatenate([np.nonzero(stance)[0] + 1, [n]])
        start = 0
        for stop in boundaries:
            if stop <= start:
                continue
            strapdown_kernel(C, v, p, bg, ba, P, gyro_radps[start:stop], acc_mps2[start:stop], dt[start:stop],
                             self.q_diag, out_p[start:stop], out_v[start:stop], out_C[start:stop])
            if stance[stop - 1]:
                dx, P = self.zupt_update(P, v)
                C = _rotation(dx[ATT]) @ C
                bg += dx[BG]
                p += dx[POS]
                v += dx[VEL]
                ba += dx[BA]
                out_p[stop - 1], out_v[stop - 1], out_C[stop - 1] = p, v, C
            start = stop
        heading = np.arctan2(out_C[:, 0, 1], out_C[:, 1, 1]) % (2.0 * np.pi)
        return Track(t_s=np.asarray(t_s, dtype=np.float64), x_m=out_p[:, 0], y_m=out_p[:, 1], heading_rad=heading,
                     speed_mps=np.hypot(out_v[:, 0], out_v[:, 1]))
