"""The receiver's reference oscillator: one clock for the LO and the ADC.

The oscillator's fractional frequency error is ``y(t) = y0 + w(t)``: a constant
offset ``y0`` plus a random-walk wander ``w`` (random-walk FM, whose Allan
variance is ``q tau / 3``, so ``adev(1 s) = sqrt(q / 3)``). ``w`` is drawn from
the seed on a coarse grid (``step_s``, default 10 ms) from t = 0 and is
piecewise linear in between; the time error is its exact integral
``x(t) = integral_0^t y dt'`` (piecewise quadratic). Times ``t`` are true
(scenario) times, seconds since the start of the scenario.

How it enters the capture (sim.rf):

- ADC clock: the receiver's clock reads ``t + x(t)`` at true time ``t``; sample
  ``k`` is taken when it reads ``k / fs``, i.e. at true time
  ``t_k = k / fs - x(t_k)`` (:meth:`Oscillator.true_time`).
- LO: downconversion by ``exp(-j 2 pi fc (t + x(t)))`` leaves the carrier phase
  ``-2 pi fc x(t)`` on the baseband.

Sign convention: ``clock_offset_hz = -fc * y(t)`` is the apparent CFO the clock
adds at RF (positive = received carrier appears above nominal, docs/conventions.md),
so a measured CFO is ``doppler_hz + clock_offset_hz`` (+ the tuner's constant
``bulk_cfo_hz``). A fast clock (y > 0) lowers the apparent carrier and takes
samples early.

Presets (:data:`dtmbnav_core.constants.CLOCK_PRESETS`; the fractional offset is drawn uniformly
within +-offset unless the scenario gives it): ``gnss-disciplined`` +-30 ppb
with adev 1e-12 at 1 s, the wander that keeps the integrated range error a
fraction of a wavelength over a minute (docs/scenarios.md); ``free-running`` TCXO
+-500 ppb with adev 1e-9. The IQ simulation (sim.rf) and the
observation-level one (sim.obs_range) draw the same clock from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.constants import CLOCK_PRESETS
from sim.scenario import Scenario


def clock_parameters(scenario: Scenario, rng: np.random.Generator) -> tuple[float, float]:
    """Fractional frequency offset and Allan deviation at 1 s of the receiver clock.

    Raises
    ------
    ValueError
        For an unknown preset, or ``custom`` without both values given.
    """
    clock = scenario.receiver.clock
    if clock.preset in CLOCK_PRESETS:
        max_ppb, adev = CLOCK_PRESETS[clock.preset]
    elif clock.preset == "custom":
        if clock.offset_ppb is None or clock.drift_adev is None:
            raise ValueError("scenario receiver.clock: preset 'custom' needs offset_ppb and drift_adev")
        max_ppb, adev = 0.0, clock.drift_adev
    else:
        raise ValueError(f"scenario receiver.clock.preset {clock.preset!r}: expected one of "
                         f"{sorted(CLOCK_PRESETS)} or 'custom'")
    offset_ppb = clock.offset_ppb if clock.offset_ppb is not None else rng.uniform(-max_ppb, max_ppb)
    adev = clock.drift_adev if clock.drift_adev is not None else adev
    return offset_ppb * 1e-9, adev



@dataclass(frozen=True)
class Oscillator:
    """A drawn oscillator trajectory (see the module docstring).

    Attributes
    ----------
    step_s : float
        Grid step of the wander, s.
    offset : float
        Constant fractional frequency offset y0.
    adev_1s : float
        Allan deviation of the wander at 1 s.
    y_grid : ndarray
        Fractional frequency error at ``t = i * step_s``.
    x_grid_s : ndarray
        Time error ``x`` at the grid points, s (``x_grid_s[0] = 0``).
    """

    step_s: float
    offset: float
    adev_1s: float
    y_grid: np.ndarray
    x_grid_s: np.ndarray

    @classmethod
    def draw(cls, offset: float, adev_1s: float, duration_s: float, rng: np.random.Generator,
             step_s: float = 0.01) -> "Oscillator":
        """Draw a wander covering ``[0, duration_s]`` (plus one grid step)."""
        if duration_s <= 0 or step_s <= 0:
            raise ValueError(f"oscillator needs a positive duration and step, got {duration_s}, {step_s}")
        n = int(np.ceil(duration_s / step_s)) + 2
        increments = rng.standard_normal(n - 1) * np.sqrt(3.0 * adev_1s**2 * step_s)
        y = offset + np.concatenate([[0.0], np.cumsum(increments)])
        x = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * step_s)])
        return cls(step_s, offset, adev_1s, y, x)

    def _cell(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_s = np.asarray(t_s, dtype=np.float64)
        i = np.floor(t_s / self.step_s).astype(np.int64)
        if i.size and (i.min() < 0 or i.max() >= len(self.y_grid) - 1):
            raise ValueError(f"oscillator: time outside [0, {(len(self.y_grid) - 1) * self.step_s:g}] s")
        return i, t_s - i * self.step_s

    def fractional_frequency(self, t_s: np.ndarray) -> np.ndarray:
        """``y(t)``: fractional frequency error at true times ``t_s``."""
        i, dt = self._cell(t_s)
        slope = (self.y_grid[i + 1] - self.y_grid[i]) / self.step_s
        return self.y_grid[i] + slope * dt

    def time_error_s(self, t_s: np.ndarray) -> np.ndarray:
        """``x(t)``: how far the receiver clock reads ahead of true time, s."""
        i, dt = self._cell(t_s)
        slope = (self.y_grid[i + 1] - self.y_grid[i]) / self.step_s
        return self.x_grid_s[i] + self.y_grid[i] * dt + 0.5 * slope * dt**2

    def true_time(self, receiver_time_s: np.ndarray) -> np.ndarray:
        """True time at which the receiver clock reads ``receiver_time_s``.

        Solves ``t + x(t) = tau`` by fixed-point iteration; |dx/dt| < 1e-5, so
        three iterations reach float64 precision.
        """
        tau = np.asarray(receiver_time_s, dtype=np.float64)
        t = tau.copy()
        for _ in range(3):
            t = tau - self.time_error_s(np.clip(t, 0.0, None))
        return t

    def clock_offset_hz(self, t_s: np.ndarray, carrier_hz: float) -> np.ndarray:
        """Apparent CFO the clock adds at RF, ``-fc * y(t)``, Hz."""
        return -carrier_hz * self.fractional_frequency(t_s)


def scenario_oscillator(scenario: Scenario, duration_s: float, seed: int, stream_id: int) -> Oscillator:
    """The oscillator of a scenario's receiver clock, drawn from ``seed``.

    Parameters
    ----------
    scenario : Scenario
        ``receiver.clock`` gives the preset, offset and Allan deviation.
    duration_s : float
        True time the trajectory must cover, s.
    seed, stream_id : int
        The draw uses ``default_rng([seed, stream_id, 0, 1])``.
    """
    rng = np.random.default_rng([seed, stream_id, 0, 1])
    offset, adev = clock_parameters(scenario, rng)
    return Oscillator.draw(offset, adev, duration_s, rng)
