"""GNSS simulator: the start fix P0 and a per-epoch fix log whose quality follows the sky view.

Sky view: from each epoch's true position, ``SKY_AZIMUTHS`` horizontal rays of
``SKY_BLOCK_RANGE_M`` are tested against the building footprints; the blocked
fraction ``b`` lowers the mean C/N0 by ``blocked_cn0_drop_db * min(1, 2 b)``
(a wall along one side of a street hides the low satellites of half the sky,
which is already the full drop). C/N0 also carries a slow random wander.

Position error per axis is a first-order Gauss-Markov process with the
correlation time :data:`dtmbnav_core.start_fix.FIX_ERROR_TAU_S` (multipath and
atmosphere errors are correlated over tens of seconds) whose standard deviation
scales with the signal amplitude lost: ``start_fix_sigma_m * 10^((open - cn0)/20)``.
That standard deviation is each fix's stated one (a phone log states it as its
accuracy, ``sim/phone_log_writer.py``).

The start fix P0 (:func:`simulate_start_fix`) is made of the log's own fixes by
the importer's rule (:func:`dtmbnav_core.start_fix.standstill_start_fix`): every
fix of the standstill before the walk, weighted by its stated sigma, with the
sigma their correlation leaves. It is a :class:`dtmbnav_core.records.StartFix`.

Random stream: the log uses ``[seed, GNSS_STREAM]``, so it does not shift the walk.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from dtmbnav_core.records import GnssLog, StartFix
from dtmbnav_core.start_fix import FIX_ERROR_TAU_S, standstill_start_fix
from sim.scenario import Building, GnssConfig, Scenario
from sim.walk import Walk

GNSS_STREAM = 3
#: Number of horizontal directions in which the sky view is tested.
SKY_AZIMUTHS = 16
#: A building further away than this hides no useful satellite, m.
SKY_BLOCK_RANGE_M = 40.0
#: Standard deviation and correlation time of the C/N0 wander, dB and s.
CN0_WANDER_DB = 1.0
CN0_WANDER_TAU_S = 10.0


def _segments_cross(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether segments p-q (rays, shape R x 2) cross segment a-b (2,) (proper crossings)."""
    def side(o: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0])

    d1, d2 = side(a, b, p), side(a, b, q)
    d3, d4 = side(p, q, a), side(p, q, b)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def blocked_sky_fraction(xy: np.ndarray, buildings: list[Building]) -> np.ndarray:
    """Fraction of the horizontal directions blocked by a building within SKY_BLOCK_RANGE_M, per point."""
    if not buildings:
        return np.zeros(len(xy))
    az = np.arange(SKY_AZIMUTHS) * 2.0 * np.pi / SKY_AZIMUTHS
    reach = SKY_BLOCK_RANGE_M * np.column_stack([np.sin(az), np.cos(az)])
    blocked = np.zeros((len(xy), SKY_AZIMUTHS), dtype=bool)
    for building in buildings:
        poly = np.asarray(building.polygon_m, dtype=np.float64)
        for a, b in zip(poly, np.roll(poly, -1, axis=0)):
            ends = xy[:, None, :] + reach[None, :, :]
            blocked |= _segments_cross(xy[:, None, :], ends, a, b)
    return blocked.mean(axis=1)


def _gauss_markov(rng: np.random.Generator, n: int, shape_tail: tuple[int, ...], dt_s: float,
                  tau_s: float) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov sequence along axis 0, stationary from the start."""
    phi = np.exp(-dt_s / tau_s)
    drive = rng.standard_normal((n, *shape_tail)) * np.sqrt(1.0 - phi**2)
    drive[0] = rng.standard_normal(shape_tail)
    # y[k] = phi y[k-1] + drive[k] with y[0] = drive[0] (a stationary draw).
    return lfilter([1.0], [1.0, -phi], drive, axis=0)


def fix_sigma_m(cfg: GnssConfig, cn0_dbhz: np.ndarray) -> np.ndarray:
    """Standard deviation of a fix's error per axis at C/N0 ``cn0_dbhz`` (dB-Hz), m (module docstring)."""
    return cfg.start_fix_sigma_m * 10.0 ** ((cfg.open_sky_cn0_dbhz - np.asarray(cn0_dbhz, dtype=np.float64)) / 20.0)


def simulate_gnss(scenario: Scenario, walk: Walk) -> GnssLog:
    """Per-epoch GNSS fixes over the whole walk.

    Parameters
    ----------
    scenario : Scenario
        Uses ``scenario.gnss``, ``scenario.channel.buildings`` and the seed.
    walk : Walk
        The walker.

    Raises
    ------
    ValueError
        Non-positive rate or sigma.
    """
    cfg = scenario.gnss
    if cfg.rate_hz <= 0 or cfg.start_fix_sigma_m <= 0:
        raise ValueError(f"gnss.rate_hz and gnss.start_fix_sigma_m must be > 0, got {cfg.rate_hz}, "
                         f"{cfg.start_fix_sigma_m}")
    rng = np.random.default_rng([scenario.seed, GNSS_STREAM])
    dt = 1.0 / cfg.rate_hz
    t_s = np.arange(int(np.floor(walk.track.t_s[-1] * cfg.rate_hz)) + 1) * dt
    tr = walk.track
    xy = np.column_stack([np.interp(t_s, tr.t_s, tr.x_m), np.interp(t_s, tr.t_s, tr.y_m)])
    drop = cfg.blocked_cn0_drop_db * np.minimum(1.0, 2.0 * blocked_sky_fraction(xy, scenario.channel.buildings))
    cn0 = (cfg.open_sky_cn0_dbhz - drop
           + CN0_WANDER_DB * _gauss_markov(rng, len(t_s), (), dt, CN0_WANDER_TAU_S))
    sigma = fix_sigma_m(cfg, cn0)
    error = sigma[:, None] * _gauss_markov(rng, len(t_s), (2,), dt, FIX_ERROR_TAU_S)
    return GnssLog(t_s=t_s, x_m=xy[:, 0] + error[:, 0], y_m=xy[:, 1] + error[:, 1], cn0_dbhz=cn0)


def simulate_start_fix(scenario: Scenario, walk: Walk, gnss: GnssLog) -> StartFix:
    """The start fix P0 from the walk's own fixes over the standstill before it sets off (module docstring).

    Parameters
    ----------
    scenario : Scenario
        Gives each fix's stated sigma (:func:`fix_sigma_m`).
    walk : Walk
        When the walker sets off.
    gnss : GnssLog
        The walk's fixes, :func:`simulate_gnss` of the same scenario and walk. The walker stands still from
        t_s = 0, where the log's first fix is, so the standstill always holds one.
    """
    combined = standstill_start_fix(gnss.t_s, gnss.x_m, gnss.y_m, fix_sigma_m(scenario.gnss, gnss.cn0_dbhz),
                                    0.0, walk.walk_start_t_s)
    if combined is None:
        raise ValueError(f"no GNSS fix at or before the walk's start ({walk.walk_start_t_s} s)")
    return combined.fix
