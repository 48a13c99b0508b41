"""Simulation as a user gets it: the capture set plus the walker's calibrated step gain.

The simulator walks the calibration line (:func:`sim.calibration.simulate_calibration_walk`);
the PDR estimates K from that IMU log and the known distance
(:func:`fusion.pdr.calibrate_weinberg_k_from_walk`). Wiring the two is the
application's job, so neither library imports the other.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fusion.model import CLOCK_MODEL_PRESETS
from fusion.pdr import calibrate_weinberg_k_from_walk
from sim.calibration import simulate_calibration_walk
from sim.scenario import Scenario
from sim.simulate import SimulationResult, simulate


def calibration_walk_k_m(scenario: Scenario) -> float:
    """Weinberg gain K (m) the walker of ``scenario`` gets from the straight calibration walk."""
    return calibrate_weinberg_k_from_walk(*simulate_calibration_walk(scenario))


def simulate_capture_set(scenario: Scenario, out_dir: str | Path, *, seed: int | None = None,
                         **options: Any) -> SimulationResult:
    """:func:`sim.simulate.simulate` with the walker's calibrated Weinberg gain stored for the PDR.

    ``seed`` replaces the scenario's seed before anything is drawn; ``options``
    are :func:`sim.simulate.simulate`'s keywords.
    """
    if seed is not None:
        scenario = scenario.replace(seed=int(seed))
    return simulate(scenario, out_dir, weinberg_k_m=calibration_walk_k_m(scenario), **options)


def receiver_clock_model(scenario: Scenario) -> str:
    """The fusion's clock model for the scenario's receiver: disciplined for a GNSS-disciplined oscillator,
    free-running for any other (a user knows which clock their SDR has, as ``dtmbnav fuse --clock-model``)."""
    return "disciplined" if scenario.receiver.clock.preset == CLOCK_MODEL_PRESETS["disciplined"] else "free-running"
