"""Per-path truth of a capture: every tower's every path, at a fixed rate (``/truth/paths``).

The receiver's path tracker (``docs/paths.md``) measures each path's delay,
Doppler and range change; this is what it should find. One row per truth
epoch and channel path (:class:`sim.channel.Channel`: tower by tower, direct,
ground, scatterers, walls, diffuse taps). Epochs are ``1 / rate_hz`` apart on
the capture's clock (receiver time since the capture's first sample, as
``/truth/frames/t_s``); the geometry is evaluated at the matching true times.

- ``delay_s``: the path's delay, its length over c plus its tower's transmit
  delay, s;
- ``range_m``: the path's length (tower -> reflector -> receiver), m;
- ``doppler_hz``: ``-fc d(delay)/dt`` (true time), Hz, positive when the
  path shortens;
- ``power_db``: path power relative to the first tower's unobstructed direct
  path, dB (-inf while a wall's specular point is off the wall).

Paths change smoothly, so the rows interpolate to any frame time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import ColumnRecord
from sim.channel import PATH_KINDS
from sim.rf import CaptureGenerator

#: Truth epochs per second of capture.
PATH_TRUTH_RATE_HZ = 100.0
#: Half the time step of the central difference that gives each path's Doppler, s.
DOPPLER_HALF_STEP_S = 5e-4


@dataclass
class PathTruth(ColumnRecord):
    """True paths of a capture, one row per epoch and path (module docstring).

    Attributes
    ----------
    t_s : ndarray
        Epoch, receiver-clock seconds since the capture's first sample.
    tower_id : ndarray of int16
        Tower of the path (0 = the first tower of the scenario).
    path_index : ndarray of int16
        The path's place in the channel's list of paths.
    kind : ndarray of int8
        ``PATH_KINDS[kind]``: direct, ground, scatterer, wall or diffuse.
    delay_s : ndarray
        Length over c plus the tower's transmit delay, s.
    range_m : ndarray
        Path length, m.
    doppler_hz : ndarray
        ``-fc d(delay)/dt``, Hz.
    power_db : ndarray of float32
        Power relative to the first tower's unobstructed direct path, dB.
    """

    t_s: np.ndarray
    tower_id: np.ndarray
    path_index: np.ndarray
    kind: np.ndarray
    delay_s: np.ndarray
    range_m: np.ndarray
    doppler_hz: np.ndarray
    power_db: np.ndarray


def path_truth(generator: CaptureGenerator, rate_hz: float = PATH_TRUTH_RATE_HZ) -> PathTruth:
    """Every path of ``generator``'s channel at ``rate_hz`` epochs over its capture."""
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
    capture_start = generator.first_sample / generator.sample_rate_hz
    epochs = np.arange(0.0, generator.num_samples / generator.sample_rate_hz, 1.0 / rate_hz)
    true_t = generator.oscillator.true_time(capture_start + epochs)
    channel = generator.channel
    state = channel.state(true_t)
    ahead = channel.state(true_t + DOPPLER_HALF_STEP_S).delay_s
    behind = channel.state(true_t - DOPPLER_HALF_STEP_S).delay_s
    doppler = -generator.carrier_hz * (ahead - behind) / (2.0 * DOPPLER_HALF_STEP_S)
    transmit_delay = generator.scenario.transmit_delays_s()[channel.path_tower]
    n_paths, n_epochs = state.delay_s.shape
    with np.errstate(divide="ignore"):
        power = 20.0 * np.log10(np.abs(state.coef))
    return PathTruth(
        t_s=np.tile(epochs, n_paths).reshape(n_paths, n_epochs).T.ravel(),
        tower_id=np.tile(channel.path_tower.astype(np.int16), n_epochs),
        path_index=np.tile(np.arange(n_paths, dtype=np.int16), n_epochs),
        kind=np.tile(channel.path_kind.astype(np.int8), n_epochs),
        delay_s=state.delay_s.T.ravel(),
        range_m=((state.delay_s - transmit_delay[:, None]) * SPEED_OF_LIGHT_MPS).T.ravel(),
        doppler_hz=doppler.T.ravel(), power_db=power.T.ravel().astype(np.float32))


def path_truth_attributes(generator: CaptureGenerator, rate_hz: float = PATH_TRUTH_RATE_HZ) -> dict:
    """Attributes of ``/truth/paths``: the rate, the kind names and every tower's site (its true transmit delay
    offset on this walk, and the plan's)."""
    sites = generator.scenario.sites
    return {"rate_hz": rate_hz, "kinds": ",".join(PATH_KINDS), "carrier_hz": generator.carrier_hz,
            "towers_x_m": np.array([s.x_m for s in sites]), "towers_y_m": np.array([s.y_m for s in sites]),
            "towers_height_m": np.array([s.height_m for s in sites]),
            "towers_power_db": np.array([s.power_db for s in sites]),
            "towers_transmit_delay_s": generator.scenario.transmit_delays_s(),
            "towers_planned_transmit_delay_s": np.array([s.transmit_delay_s for s in sites])}
