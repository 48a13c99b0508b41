"""PDR accuracy against truth, as the paper reports it (docs/method.md §6, Tables 1-2 "PDR" rows).

The PDR's relative track is placed with the TRUE initial heading and the TRUE
start (:func:`fusion.metrics.place_pdr`); the position error is taken at the
step epochs and summarised as 68 % / 95 % / max. Also reported: detected vs
true step count, mean step length vs truth, and the heading drift (slope of a
straight-line fit of the heading error over the walk, deg/min).

``dtmbnav evaluate --pdr [SCENARIO ...]`` prints these for the reference
walks (:mod:`dtmbnav.evaluation.pdr_table`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.records import Track
from fusion.metrics import ErrorStats, error_stats, place_pdr, position_errors_m, true_initial_heading_rad
from fusion.pdr.pipeline import PdrResult


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
