"""PDR accuracy against truth, as the paper reports it (method.md §6, Tables 1-2 "PDR" rows).

The PDR's relative track is placed with the TRUE initial heading and the TRUE
start (:func:`fusion.metrics.place_pdr`); the position error is taken at the
step epochs and summarised as 68 % / 95 % / max. Also reported: detected vs
true step count, mean step length vs truth, and the heading drift (slope of a
straight-line fit of the heading error over the walk, deg/min).

``python -m fusion.pdr.evaluate [SCENARIO ...]`` prints these for the
reference walks (all four by default). That entry point simulates the walks,
so it imports ``sim`` inside :func:`main` only: the functions above it stay
free of the simulator (package layering); the driver belongs in the CLI.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np

from fusion.metrics import ErrorStats, error_stats, place_pdr, position_errors_m, true_initial_heading_rad
from fusion.pdr.pipeline import PdrResult
from fusion.records import Track


@dataclass(frozen=True)
class PdrEvaluation:
    """PDR against truth.

    Attributes
    ----------
    steps_detected, steps_true : int
        Step counts.
    mean_step_length_m, true_mean_step_length_m : float
        Mean step length of the PDR and of the truth, m.
    heading_drift_dpm : float
        Slope of the heading error (PDR placed with the true initial heading,
        minus truth) over the walk, deg/min.
    position : ErrorStats
        Position error at the step epochs, m.
    initial_heading_rad : float
        The true initial heading used to place the PDR, rad.
    """

    steps_detected: int
    steps_true: int
    mean_step_length_m: float
    true_mean_step_length_m: float
    heading_drift_dpm: float
    position: ErrorStats
    initial_heading_rad: float

    @property
    def step_count_error(self) -> float:
        """(detected - true) / true."""
        return (self.steps_detected - self.steps_true) / self.steps_true

    @property
    def step_length_error(self) -> float:
        """Relative error of the mean step length."""
        return self.mean_step_length_m / self.true_mean_step_length_m - 1.0


def heading_error_rad(pdr_heading_rad: np.ndarray, t_s: np.ndarray, truth: Track,
                      initial_heading_rad: float) -> np.ndarray:
    """PDR heading (placed with ``initial_heading_rad``) minus the truth heading at ``t_s``, unwrapped, rad."""
    truth_heading = np.interp(t_s, truth.t_s, np.unwrap(truth.heading_rad))
    wrapped = np.angle(np.exp(1j * (pdr_heading_rad + initial_heading_rad - truth_heading)))
    return np.unwrap(wrapped)


def heading_drift_dpm(t_s: np.ndarray, heading_error: np.ndarray) -> float:
    """Least-squares slope of a heading error over time, deg/min."""
    if len(t_s) < 2:
        raise ValueError("heading_drift_dpm: need at least two epochs")
    slope_rad_per_s = np.polyfit(t_s, heading_error, 1)[0]
    return float(np.degrees(slope_rad_per_s) * 60.0)


def evaluate_pdr(result: PdrResult, truth: Track, step_t_s: np.ndarray, step_length_m: np.ndarray,
                 walk_start_t_s: float) -> PdrEvaluation:
    """Compare a PDR run with the truth of its walk.

    Parameters
    ----------
    result : PdrResult
        The PDR (relative frame).
    truth : Track
        Truth trajectory.
    step_t_s, step_length_m : ndarray
        Truth step events and lengths.
    walk_start_t_s : float
        When the walker sets off (the initial heading is measured from there), s.

    Raises
    ------
    ValueError
        If the PDR detected no step.
    """
    steps = result.steps
    if len(steps) == 0:
        raise ValueError("evaluate_pdr: the PDR detected no step")
    initial = true_initial_heading_rad(truth, walk_start_t_s)
    placed = place_pdr(steps, float(truth.x_m[0]), float(truth.y_m[0]), initial)
    errors = heading_error_rad(steps.heading_rad, steps.t_s, truth, initial)
    return PdrEvaluation(
        steps_detected=len(steps), steps_true=len(step_t_s),
        mean_step_length_m=float(np.mean(steps.step_length_m)),
        true_mean_step_length_m=float(np.mean(step_length_m)),
        heading_drift_dpm=heading_drift_dpm(steps.t_s, errors),
        position=error_stats(position_errors_m(placed, truth)), initial_heading_rad=initial)


def predicted_gyro_drift_dpm(t_s: np.ndarray, acc_mps2: np.ndarray, gyro_bias_radps: np.ndarray,
                             walk_start_t_s: float, walk_end_t_s: float) -> float:
    """Heading drift that the simulated gyro bias leaves after the standing-still bias removal, deg/min.

    The bias removed is the one during the standing period; what remains
    during the walk (wander and any late extra bias), projected on the
    vertical (the device's "up" from the mean accelerometer at rest), turns
    the heading at minus that rate (heading is clockwise, rates right-handed
    about up). Returned as a time average over the walk.
    """
    rest = t_s < walk_start_t_s - 0.5
    walking = (t_s >= walk_start_t_s) & (t_s <= walk_end_t_s)
    up = acc_mps2[rest].mean(axis=0)
    up /= np.linalg.norm(up)
    residual = gyro_bias_radps[walking] @ up - gyro_bias_radps[rest].mean(axis=0) @ up
    # The heading error grows as the integral of the residual; fit its slope like the measured drift.
    error = -np.cumsum(residual) * (t_s[1] - t_s[0])
    return heading_drift_dpm(t_s[walking], error)


#: The paper's PDR rows (68 % / 95 % / max, m): Table 1 (LOS loop), Table 2 (street).
PAPER_PDR_M = {"park-loop": (2.67, 9.19, 10.84), "street": (9.70, 13.27, 15.41)}
#: Length of the straight calibration walk whose distance the user knows, m.
CALIBRATION_DISTANCE_M = 60.0


def main(argv: list[str] | None = None) -> int:
    """Print the PDR figures of the reference walks (see the module docstring)."""
    # The simulator is needed only by this driver (the lead's CLI is its proper home).
    from sim.imu import simulate_imu_with_errors
    from sim.scenario import load_scenario, packaged_scenarios
    from sim.walk import simulate_walk

    from fusion.pdr.attitude import AttitudeConfig
    from fusion.pdr.pipeline import PdrConfig, calibrate_weinberg_k_from_walk, run_pdr

    parser = argparse.ArgumentParser(prog="python -m fusion.pdr.evaluate", description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", default=packaged_scenarios(), help="scenario names or .toml paths")
    args = parser.parse_args(argv)
    print("scenario        steps det/true  L err   K      drift deg/min (MARG | gyro-only | gyro predicted)"
          "   PDR 68/95/max m   paper")
    for name in args.scenarios:
        scenario = load_scenario(name)
        # K comes from a separate calibration walk of known length by the same walker and phone:
        # straight, no step-gain error, no late gyro drift, no buildings.
        calibration = scenario.replace(
            walk={"waypoints_m": [[0.0, 0.0], [0.0, CALIBRATION_DISTANCE_M]], "closed": False, "pauses": [],
                  "pace_changes": []},
            imu={"step_gain_error": 0.0, "heading_drift_start_s": None}, channel={"buildings": []})
        cal_imu, _ = simulate_imu_with_errors(calibration, simulate_walk(calibration))
        k_m = calibrate_weinberg_k_from_walk(cal_imu, CALIBRATION_DISTANCE_M)

        walk = simulate_walk(scenario)
        imu, errors = simulate_imu_with_errors(scenario, walk)
        config = PdrConfig(weinberg_k_m=k_m)
        result = evaluate_pdr(run_pdr(imu, config), walk.track, walk.step_t_s, walk.step_length_m,
                              walk.walk_start_t_s)
        gyro_only = evaluate_pdr(run_pdr(imu, PdrConfig(weinberg_k_m=k_m, attitude=AttitudeConfig(
            gain=config.attitude.gain, use_magnetometer=False))), walk.track, walk.step_t_s,
            walk.step_length_m, walk.walk_start_t_s)
        predicted = predicted_gyro_drift_dpm(imu.t_s, imu.acc_mps2, errors.gyro_bias_radps,
                                             walk.walk_start_t_s, walk.walk_end_t_s)
        paper = PAPER_PDR_M["park-loop" if "park" in scenario.name else "street"]
        p = result.position
        print(f"{scenario.name:15s} {result.steps_detected:4d}/{result.steps_true:<4d}     "
              f"{100 * result.step_length_error:+5.1f}%  {k_m:.3f}  "
              f"{result.heading_drift_dpm:+6.2f} | {gyro_only.heading_drift_dpm:+6.2f} | {predicted:+6.2f}"
              f"                 {p.p68_m:5.2f}/{p.p95_m:5.2f}/{p.max_m:5.2f}   "
              f"{paper[0]:.2f}/{paper[1]:.2f}/{paper[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
