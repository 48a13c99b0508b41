"""The walker's step-length calibration walk (how a user obtains the Weinberg K).

A PDR user calibrates the Weinberg gain K once, on a straight walk of known
length with the same phone. The simulator reproduces that: the same walker and
device (the scenario's pace, seed and IMU preset) on a straight line, with the
scenario's deliberate PDR faults switched off (no step-gain error, no late
heading drift), so that a scenario's ``step_gain_error`` stays an error of the
calibrated PDR, as ``scenarios.md`` intends, and the PDR never sees the true K.
"""

from __future__ import annotations

from fusion.pdr import calibrate_weinberg_k_from_walk
from sim.imu import simulate_imu
from sim.scenario import Scenario
from sim.walk import simulate_walk

#: Length of the straight calibration walk, m.
CALIBRATION_WALK_M = 50.0


def calibration_walk_k_m(scenario: Scenario, distance_m: float = CALIBRATION_WALK_M) -> float:
    """Weinberg gain K (m) the walker of ``scenario`` gets from a calibration walk of ``distance_m``."""
    calibration = scenario.replace(
        walk={"waypoints_m": [[0.0, 0.0], [0.0, distance_m]], "closed": False, "pauses": [], "pace_changes": []},
        imu={"step_gain_error": 0.0, "heading_drift_start_s": None})
    walk = simulate_walk(calibration)
    return calibrate_weinberg_k_from_walk(simulate_imu(calibration, walk), float(walk.distance_m[-1]))
