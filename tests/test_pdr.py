"""Pedestrian dead reckoning (fusion/pdr): each stage against the simulated walk's truth."""

from __future__ import annotations

import numpy as np
import pytest

from dtmbnav_core.records import ImuLog
from fusion.pdr import PdrConfig, calibrate_weinberg_k_from_walk, run_pdr
from fusion.pdr.attitude import AttitudeConfig
from fusion.pdr.dead_reckoning import dead_reckon, resample_steps
from fusion.pdr.evaluate import evaluate_pdr, predicted_gyro_drift_dpm
from fusion.pdr.pipeline import PdrResult
from fusion.pdr.step_length import calibrate_weinberg_k, frequency_length, weinberg_length
from sim.imu import simulate_imu_with_errors
from sim.scenario import Scenario
from sim.walk import simulate_walk

CALIBRATION_M = 40.0


def _scenario(seed: int = 21, imu: dict | None = None, **walk) -> Scenario:
    base = {"waypoints_m": [[0.0, 0.0], [0.0, 30.0], [30.0, 30.0], [30.0, 0.0], [12.0, 0.0]],
            "corner_radius_m": 2.0, "start_still_s": 8.0, "end_still_s": 3.0,
            "pauses": [{"at_waypoint": 2, "duration_s": 5.0}],
            "pace_changes": [{"after_m": 65.0, "speed_mps": 0.95, "step_frequency_hz": 1.55}]}
    return Scenario(seed=seed).replace(walk={**base, **walk}, imu=imu or {})


def _calibrated_k(scenario: Scenario) -> float:
    """K from a straight walk of known length by the same walker and phone (no truth K involved)."""
    calibration = scenario.replace(walk={"waypoints_m": [[0.0, 0.0], [0.0, CALIBRATION_M]], "pauses": [],
                                         "pace_changes": []},
                                   imu={"step_gain_error": 0.0, "heading_drift_start_s": None})
    imu, _ = simulate_imu_with_errors(calibration, simulate_walk(calibration))
    return calibrate_weinberg_k_from_walk(imu, CALIBRATION_M)


@pytest.fixture(scope="module")
def walked():
    scenario = _scenario()
    walk = simulate_walk(scenario)
    imu, errors = simulate_imu_with_errors(scenario, walk)
    k_m = _calibrated_k(scenario)
    return scenario, walk, imu, errors, k_m, run_pdr(imu, PdrConfig(weinberg_k_m=k_m))


def test_steps_match_truth_and_no_phantom_steps(walked):
    _, walk, _, _, _, pdr = walked
    detected = pdr.steps.t_s
    assert abs(len(detected) - len(walk.step_t_s)) <= 0.02 * len(walk.step_t_s)
    # Every detected step is a true heel strike (the acceleration peak follows it within 0.1 s).
    nearest = np.abs(detected[:, None] - walk.step_t_s[None, :]).min(axis=1)
    assert nearest.max() < 0.1
    # Standing still (start, the pause, the end): no step at all.
    tr = walk.track
    still = tr.t_s[tr.speed_mps == 0.0]
    pause = still[(still > walk.walk_start_t_s) & (still < walk.walk_end_t_s)]
    assert pause.size > 4.5 * walk.rate_hz
    for lo, hi in ((0.0, walk.walk_start_t_s), (pause[0] + 0.1, pause[-1]), (walk.walk_end_t_s + 0.1, tr.t_s[-1])):
        assert not np.any((detected > lo) & (detected < hi)), f"phantom step while standing in {lo:.1f}-{hi:.1f} s"


def test_change_of_pace_is_seen_in_cadence_and_step_length(walked):
    _, walk, _, _, _, pdr = walked
    s_at = np.interp(pdr.steps.t_s, walk.track.t_s, walk.distance_m)
    dt = np.diff(pdr.steps.t_s, prepend=np.nan)
    brisk = (s_at > 5.0) & (s_at < 25.0)
    slow = (s_at > 70.0) & (s_at < 95.0)
    assert 1.0 / np.median(dt[brisk]) == pytest.approx(1.85, rel=0.05)
    assert 1.0 / np.median(dt[slow]) == pytest.approx(1.55, rel=0.05)
    true_slow = 0.95 / 1.55
    assert np.median(pdr.steps.step_length_m[slow]) == pytest.approx(true_slow, rel=0.08)
    assert np.median(pdr.steps.speed_mps[slow]) == pytest.approx(0.95, rel=0.1)


def test_mean_step_length_within_5_percent_after_calibration(walked):
    _, walk, _, _, _, pdr = walked
    assert pdr.steps.step_length_m.mean() == pytest.approx(walk.step_length_m.mean(), rel=0.05)
    assert pdr.steps.step_length_m.sum() == pytest.approx(walk.path.total_m, rel=0.05)


def test_step_gain_error_makes_steps_long():
    scenario = _scenario(imu={"step_gain_error": 0.15})
    walk = simulate_walk(scenario)
    imu, _ = simulate_imu_with_errors(scenario, walk)
    pdr = run_pdr(imu, PdrConfig(weinberg_k_m=_calibrated_k(scenario)))
    ratio = pdr.steps.step_length_m.sum() / walk.path.total_m
    assert ratio == pytest.approx(1.15, abs=0.05)


def test_relative_heading_follows_the_turns(walked):
    _, walk, _, _, _, pdr = walked
    evaluation = evaluate_pdr(pdr, walk.track, walk.step_t_s, walk.step_length_m, walk.walk_start_t_s)
    assert evaluation.initial_heading_rad == pytest.approx(0.0, abs=0.01)  # the walk starts north
    truth = np.interp(pdr.steps.t_s, walk.track.t_s, np.unwrap(walk.track.heading_rad))
    error = np.degrees(np.angle(np.exp(1j * (pdr.steps.heading_rad - truth))))
    on_straights = np.interp(pdr.steps.t_s, walk.track.t_s, walk.track.speed_mps) > 0.5
    assert np.median(np.abs(error[on_straights])) < 3.0
    # After the three right turns the heading is 270 deg relative to the start.
    assert np.degrees(np.mod(pdr.steps.heading_rad[-3:], 2 * np.pi)) == pytest.approx([270.0] * 3, abs=5.0)
    assert evaluation.position.p95_m < 1.5


def test_gyro_only_heading_drift_matches_the_simulated_bias():
    """With the magnetometer off, the heading drifts as the late extra gyro bias predicts."""
    scenario = _scenario(imu={"heading_drift_start_s": 20.0, "heading_drift_dps": 0.5}, pauses=[])
    walk = simulate_walk(scenario)
    imu, errors = simulate_imu_with_errors(scenario, walk)
    config = PdrConfig(weinberg_k_m=0.48, attitude=AttitudeConfig(use_magnetometer=False))
    evaluation = evaluate_pdr(run_pdr(imu, config), walk.track, walk.step_t_s, walk.step_length_m,
                              walk.walk_start_t_s)
    predicted = predicted_gyro_drift_dpm(imu.t_s, imu.acc_mps2, errors.gyro_bias_radps, walk.walk_start_t_s,
                                         walk.walk_end_t_s)
    assert predicted < -15.0  # about -0.5 deg/s * cos(20 deg hold pitch) acting for most of the walk
    assert evaluation.heading_drift_dpm == pytest.approx(predicted, rel=0.15)


def test_dead_reckoning_convention():
    # Heading clockwise from north: 0 moves north, pi/2 moves east.
    steps = dead_reckon(t_s=np.array([1.0, 1.5, 2.0]), start_t_s=np.array([0.5, 1.0, 1.5]),
                        step_length_m=np.array([0.7, 0.7, 0.8]), heading_rad=np.array([0.0, np.pi / 2, np.pi / 2]))
    assert steps.x_m == pytest.approx([0.0, 0.7, 1.5])
    assert steps.y_m == pytest.approx([0.7, 0.7, 0.7])
    assert steps.speed_mps == pytest.approx([1.4, 1.4, 1.6])
    track = resample_steps(steps, np.array([0.5, 1.0, 1.5]), np.array([0.0, 0.75, 1.0, 2.0, 3.0]))
    assert track.x_m == pytest.approx([0.0, 0.0, 0.0, 1.5, 1.5])
    assert track.y_m == pytest.approx([0.0, 0.35, 0.7, 0.7, 0.7])
    assert track.speed_mps == pytest.approx([0.0, 1.4, 1.4, 1.6, 0.0])  # standing before and after
    assert track.heading_rad == pytest.approx([0.0, 0.0, 0.0, np.pi / 2, np.pi / 2])


def test_step_length_models():
    assert frequency_length(np.array([1.85, 0.4, 3.5])) == pytest.approx([0.73, 0.7, 0.7])
    acc_max = np.array([3.0, 2.0, 2.5])
    acc_min = np.array([-1.0, -0.5, -1.0])
    k = calibrate_weinberg_k(acc_max, acc_min, distance_m=2.0)
    assert weinberg_length(acc_max, acc_min, k).sum() == pytest.approx(2.0)
    assert weinberg_length(np.array([16.0]), np.array([0.0]), 0.5) == pytest.approx([1.0])
    with pytest.raises(ValueError, match="no steps"):
        calibrate_weinberg_k(np.zeros(0), np.zeros(0), 10.0)


def test_frequency_model_pipeline_needs_no_k(walked):
    _, walk, imu, _, _, _ = walked
    pdr = run_pdr(imu, PdrConfig(step_model="frequency"))
    cadence = 1.0 / (pdr.steps.t_s[1:] - pdr.steps.t_s[:-1])
    brisk = np.interp(pdr.steps.t_s[1:], walk.track.t_s, walk.distance_m) < 25.0
    assert np.median(pdr.steps.step_length_m[1:][brisk]) == pytest.approx(0.4 * np.median(cadence[brisk]) - 0.01,
                                                                          rel=0.02)


def test_resampled_track_matches_steps(walked):
    _, walk, imu, _, _, pdr = walked
    track = pdr.track
    assert np.diff(track.t_s) == pytest.approx(0.1)
    assert track.t_s[0] == imu.t_s[0] and track.t_s[-1] <= imu.t_s[-1]
    at_steps = np.searchsorted(track.t_s, pdr.steps.t_s)
    exact = np.isclose(track.t_s[np.minimum(at_steps, len(track) - 1)], pdr.steps.t_s)
    assert track.x_m[at_steps[exact]] == pytest.approx(pdr.steps.x_m[exact])
    assert np.all(track.speed_mps[track.t_s < walk.walk_start_t_s] == 0.0)


def test_evaluation_of_a_perfect_pdr_is_zero(walked):
    _, walk, _, _, _, _ = walked
    # A PDR built from the truth steps, in its relative frame (the walk starts north, at the origin).
    start = np.concatenate([[walk.walk_start_t_s], walk.step_t_s[:-1]])
    x = np.interp(walk.step_t_s, walk.track.t_s, walk.track.x_m)
    y = np.interp(walk.step_t_s, walk.track.t_s, walk.track.y_m)
    heading = np.interp(walk.step_t_s, walk.track.t_s, np.unwrap(walk.track.heading_rad))
    steps = dead_reckon(walk.step_t_s, start, walk.step_length_m, heading)
    steps.x_m[:], steps.y_m[:] = x, y
    perfect = PdrResult(steps=steps, track=resample_steps(steps, start, walk.track.t_s))
    evaluation = evaluate_pdr(perfect, walk.track, walk.step_t_s, walk.step_length_m, walk.walk_start_t_s)
    assert evaluation.position.max_m < 1e-6
    assert abs(evaluation.heading_drift_dpm) < 0.01
    assert evaluation.step_count_error == 0.0 and evaluation.step_length_error == pytest.approx(0.0)


def test_bad_input_raises(walked):
    _, _, imu, _, _, _ = walked
    with pytest.raises(ValueError, match="weinberg_k_m"):
        run_pdr(imu, PdrConfig())
    with pytest.raises(ValueError, match="step_model"):
        run_pdr(imu, PdrConfig(step_model="magic"))
    bad = ImuLog(t_s=imu.t_s, acc_mps2=imu.acc_mps2.copy(), gyro_radps=imu.gyro_radps, mag_ut=imu.mag_ut)
    bad.acc_mps2[100, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        run_pdr(bad, PdrConfig(weinberg_k_m=0.5))
    flat = ImuLog(t_s=imu.t_s, acc_mps2=imu.acc_mps2[:, 0], gyro_radps=imu.gyro_radps, mag_ut=imu.mag_ut)
    with pytest.raises(ValueError, match="N x 3"):
        run_pdr(flat, PdrConfig(weinberg_k_m=0.5))
