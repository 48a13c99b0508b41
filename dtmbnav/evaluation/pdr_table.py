"""The PDR figures of the reference walks (``dtmbnav evaluate --pdr``).

For each walk: detected vs true steps, mean step-length error after the K
calibration walk, heading drift (with the magnetometer, gyro only, and what
the simulated gyro bias predicts), and the PDR's 68 % / 95 % / max position
error placed as the paper reports it, next to the paper's PDR row.
"""

from __future__ import annotations

from dtmbnav.chain.paper import paper_figures
from dtmbnav.simulation.capture_set import calibration_walk_k_m
from fusion.pdr.attitude import AttitudeConfig
from fusion.pdr.evaluate import evaluate_pdr, predicted_gyro_drift_dpm
from fusion.pdr.pipeline import PdrConfig, run_pdr
from sim.imu import simulate_imu_with_errors
from sim.scenario import load_scenario
from sim.walk import simulate_walk

HEADER = ("scenario        steps det/true  L err   K      drift deg/min (MARG | gyro-only | gyro predicted)"
          "   PDR 68/95/max m   paper")


def pdr_row(name: str) -> str:
    """One line of the table for scenario ``name``."""
    scenario = load_scenario(name)
    k_m = calibration_walk_k_m(scenario)
    walk = simulate_walk(scenario)
    imu, errors = simulate_imu_with_errors(scenario, walk)
    config = PdrConfig(weinberg_k_m=k_m)
    result = evaluate_pdr(run_pdr(imu, config), walk.track, walk.step_t_s, walk.step_length_m, walk.walk_start_t_s)
    gyro_only = evaluate_pdr(
        run_pdr(imu, PdrConfig(weinberg_k_m=k_m, attitude=AttitudeConfig(gain=config.attitude.gain,
                                                                           use_magnetometer=False))),
        walk.track, walk.step_t_s, walk.step_length_m, walk.walk_start_t_s)
    predicted = predicted_gyro_drift_dpm(imu.t_s, imu.acc_mps2, errors.gyro_bias_radps,
                                         walk.walk_start_t_s, walk.walk_end_t_s)
    paper = paper_figures(scenario.name)
    paper_text = "/".join(f"{v:.2f}" for v in paper.pdr) if paper else "-"
    p = result.position
    return (f"{scenario.name:15s} {result.steps_detected:4d}/{result.steps_true:<4d}     "
            f"{100 * result.step_length_error:+5.1f}%  {k_m:.3f}  "
            f"{result.heading_drift_dpm:+6.2f} | {gyro_only.heading_drift_dpm:+6.2f} | {predicted:+6.2f}"
            f"                 {p.p68_m:5.2f}/{p.p95_m:5.2f}/{p.max_m:5.2f}   {paper_text}")


def pdr_table(names: list[str]) -> str:
    """The whole table for the scenarios ``names``."""
    return "\n".join([HEADER, *(pdr_row(n) for n in names)])
