"""The walker's step-length calibration walk (how a user obtains the Weinberg K).

A PDR user calibrates the Weinberg gain K once, on a straight walk of known
length with the same phone. The simulator reproduces that walk: the same
walker and device (the scenario's pace, seed and IMU preset) on a straight
line, with the scenario's deliberate PDR faults switched off (no step-gain
error, no late heading drift), so that a scenario's ``step_gain_error`` stays
an error of the calibrated PDR (``docs/scenarios.md``). Estimating K from the
walk is the PDR's job (``fusion.pdr.calibrate_weinberg_k_from_walk``), so the
simulator never hands the PDR the true K.
"""

from __future__ import annotations

from dtmbnav_core.records import ImuLog
from sim.imu import simulate_imu
from sim.scenario import Scenario
from sim.walk import simulate_walk

#: Length of the straight calibration walk, m.
CALIBRATION_WALK_M = 50.0


def simulate_calibration_walk(scenario: Scenario, distance_m: float = CALIBRATION_WALK_M) -> tuple[ImuLog, float]:
    """The IMU log of the walker of ``scenario`` on a straight walk of ``distance_m``.

    Returns
    -------
    imu : ImuLog
        The calibration walk's IMU log.
    distance_m : float
        The walked distance, m (what the user measured with a tape).
    """
    calibration = scenario.replace(
        walk={"waypoints_m": [[0.0, 0.0], [0.0, distance_m]], "closed": False, "pauses": [], "pace_changes": []},
        imu={"step_gain_error": 0.0, "heading_drift_start_s": None})
    walk = simulate_walk(calibration)
    return simulate_imu(calibration, walk), float(walk.distance_m[-1])
