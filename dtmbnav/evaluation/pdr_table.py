"""The PDR figures of the reference walks (``dtmbnav evaluate --pdr``, the results' ``pdr`` section).

For each walk: detected vs true steps, mean step-length error after the K
calibration walk, heading drift (with the magnetometer, gyro only, and what
the simulated gyro bias predicts), and the PDR's 68 % / 95 % / max position
error placed as the paper reports it, next to the paper's PDR row. Each walk
is its scenario file's own (its seed), so its figures depend on the code alone.
"""

from __future__ import annotations

from dataclasses import dataclass

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


@dataclass(frozen=True)
class PdrFigures:
    """The PDR's figures on one reference walk.

    Attributes
    ----------
    scenario : str
        The walk's scenario name.
    steps_detected, steps_true : int
        Steps the detector found, and the walk's.
    step_length_error : float
        Mean step-length error after the K calibration walk, a fraction of the true length.
    k_m : float
        Weinberg gain of the calibration walk, m.
    drift_dpm, gyro_only_drift_dpm, predicted_drift_dpm : float
        Heading drift with the magnetometer, with the gyro alone, and as the simulated gyro bias predicts it,
        deg/min.
    p68_m, p95_m, max_m : float
        The PDR's 68 %, 95 % and largest position error, m.
    paper_m : tuple of float or None
        The paper's PDR 68 / 95 / max for the walk's kind, m; None where it reports none.
    """

    scenario: str
    steps_detected: int
    steps_true: int
    step_length_error: float
    k_m: float
    drift_dpm: float
    gyro_only_drift_dpm: float
    predicted_drift_dpm: float
    p68_m: float
    p95_m: float
    max_m: float
    paper_m: tuple[float, float, float] | None


def pdr_figures(name: str) -> PdrFigures:
    """The figures of scenario ``name``'s own walk."""
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
    p = result.position
    return PdrFigures(scenario.name, result.steps_detected, result.steps_true, result.step_length_error, k_m,
                      result.heading_drift_dpm, gyro_only.heading_drift_dpm, predicted, p.p68_m, p.p95_m, p.max_m,
                      tuple(paper.pdr) if paper else None)


def pdr_row(figures: PdrFigures) -> str:
    """One line of the text table (:data:`HEADER`)."""
    f = figures
    paper_text = "/".join(f"{v:.2f}" for v in f.paper_m) if f.paper_m else "-"
    return (f"{f.scenario:15s} {f.steps_detected:4d}/{f.steps_true:<4d}     "
            f"{100 * f.step_length_error:+5.1f}%  {f.k_m:.3f}  "
            f"{f.drift_dpm:+6.2f} | {f.gyro_only_drift_dpm:+6.2f} | {f.predicted_drift_dpm:+6.2f}"
            f"                 {f.p68_m:5.2f}/{f.p95_m:5.2f}/{f.max_m:5.2f}   {paper_text}")


def pdr_table(names: list[str]) -> str:
    """The whole text table for the scenarios ``names``."""
    return "\n".join([HEADER, *(pdr_row(pdr_figures(n)) for n in names)])
