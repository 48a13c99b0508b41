"""The IMU simulator (sim/imu.py): sensor readings against the walk's kinematics and the drawn errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dtmbnav_core.constants import GRAVITY_MPS2
from sim.imu import EARTH_FIELD_UT, PRESETS, simulate_imu, simulate_imu_with_errors
from sim.scenario import Scenario, load_scenario
from sim.walk import simulate_walk


def _scenario(preset: str = "phone", seed: int = 11, **imu) -> Scenario:
    return Scenario(seed=seed).replace(
        walk={"waypoints_m": [[0.0, 0.0], [0.0, 25.0], [20.0, 25.0]], "corner_radius_m": 2.0,
              "start_still_s": 6.0, "end_still_s": 2.0},
        imu={"preset": preset, **imu})


@pytest.fixture(scope="module", params=["phone", "foot-mems"])
def simulated(request):
    scenario = _scenario(request.param)
    walk = simulate_walk(scenario)
    imu, errors = simulate_imu_with_errors(scenario, walk)
    return scenario, walk, imu, errors


def test_at_rest_reads_gravity_bias_and_earth_field(simulated):
    scenario, walk, imu, errors = simulated
    rest = imu.t_s < walk.walk_start_t_s - 0.5
    acc = imu.acc_mps2[rest].mean(axis=0)
    assert np.linalg.norm(acc) == pytest.approx(GRAVITY_MPS2, rel=0.01)
    assert imu.gyro_radps[rest].mean(axis=0) == pytest.approx(errors.gyro_bias_radps[rest].mean(axis=0), abs=2e-4)
    lo, hi = PRESETS[scenario.imu.preset].gyro_bias_range_dps
    initial_bias_dps = np.abs(np.degrees(errors.gyro_bias_radps[0]))
    assert np.all((initial_bias_dps >= lo) & (initial_bias_dps <= hi))
    mag = imu.mag_ut[rest].mean(axis=0)
    assert np.linalg.norm(mag) == pytest.approx(np.linalg.norm(EARTH_FIELD_UT), abs=2.5)
    # Inclination: the field points about 45 deg below the horizontal, i.e. 135 deg from "up".
    angle = np.degrees(np.arccos(mag @ acc / np.linalg.norm(mag) / np.linalg.norm(acc)))
    assert angle == pytest.approx(135.0, abs=3.0)


def test_gyro_integrates_to_the_walked_heading(simulated):
    """Strapdown attitude from the gyro (true bias removed) turns the sensor's forward axis with the walk."""
    scenario, walk, imu, errors = simulated
    dt = imu.t_s[1] - imu.t_s[0]
    rates = imu.gyro_radps - errors.gyro_bias_radps
    increments = Rotation.from_rotvec(0.5 * (rates[1:] + rates[:-1]) * dt)
    attitude = Rotation.identity()  # an arbitrary start: only the change of heading is compared
    up_start = imu.acc_mps2[imu.t_s < walk.walk_start_t_s - 0.5].mean(axis=0)
    for step in increments:
        attitude = attitude * step
    up_end = imu.acc_mps2[imu.t_s > walk.walk_end_t_s + 0.5].mean(axis=0)
    # Forward axis at the start and at the end, expressed in the start's sensor frame.
    forward_end = attitude.apply([0.0, 1.0, 0.0])
    up = up_start / np.linalg.norm(up_start)
    assert attitude.apply(up_end / np.linalg.norm(up_end)) == pytest.approx(up, abs=0.02)  # still upright

    def horizontal(v: np.ndarray) -> np.ndarray:
        return v - (v @ up) * up

    a, b = horizontal(np.array([0.0, 1.0, 0.0])), horizontal(forward_end)
    # Clockwise turn seen from above (right-handed about up is counter-clockwise).
    turned = -np.degrees(np.arctan2(np.cross(a, b) @ up, a @ b))
    assert turned == pytest.approx(90.0, abs=2.0)  # the walk turns right from north to east


def test_phone_bounce_follows_weinberg_with_the_gain_error():
    """Vertical peak-to-peak acceleration per step is ((1 + g) L / K)^4 (module docstring)."""
    amplitude = {}
    for gain_error in (0.0, 0.15):
        scenario = _scenario("phone", step_gain_error=gain_error)
        walk = simulate_walk(scenario)
        imu, errors = simulate_imu_with_errors(scenario, walk)
        norm = np.linalg.norm(imu.acc_mps2, axis=1)
        step, _ = walk.step_phase(imu.t_s)
        inner = np.flatnonzero(~walk.first_of_leg)[2:-2]
        p2p = np.array([np.ptp(norm[step == i]) for i in inner])
        expected = ((1 + gain_error) * walk.step_length_m[inner] / errors.weinberg_k_m) ** 4
        assert np.median(p2p / expected) == pytest.approx(1.0, abs=0.1)
        amplitude[gain_error] = np.median(p2p)
    assert amplitude[0.15] / amplitude[0.0] == pytest.approx(1.15**4, rel=0.1)


def test_late_heading_drift_and_fixed_bias():
    scenario = _scenario("phone", gyro_bias_dps=0.3, heading_drift_start_s=20.0, heading_drift_dps=0.6)
    walk = simulate_walk(scenario)
    _, errors = simulate_imu_with_errors(scenario, walk)
    t = np.arange(len(errors.gyro_bias_radps)) / scenario.imu.rate_hz
    bias_z = np.degrees(errors.gyro_bias_radps[:, 2])
    assert bias_z[0] == pytest.approx(0.3, abs=0.01)
    jump = bias_z[np.searchsorted(t, 20.0)] - bias_z[np.searchsorted(t, 20.0) - 1]
    assert jump == pytest.approx(0.6, abs=0.01)


def test_magnetic_disturbance_near_buildings():
    building = {"polygon_m": [[2.0, 5.0], [12.0, 5.0], [12.0, 15.0], [2.0, 15.0]], "attenuation_db": 20.0}
    clean = _scenario("phone")
    disturbed = clean.replace(channel={"buildings": [building]}, imu={"mag_disturbance_ut": 15.0})
    walk = simulate_walk(clean)
    a = simulate_imu(clean, walk)
    b = simulate_imu(disturbed, walk)
    diff = np.linalg.norm(b.mag_ut - a.mag_ut, axis=1)
    x = np.interp(a.t_s, walk.track.t_s, walk.track.x_m)
    y = np.interp(a.t_s, walk.track.t_s, walk.track.y_m)
    # Distance to the footprint (x 2..12 m, y 5..15 m) for points outside it.
    dx = np.maximum(np.maximum(2.0 - x, x - 12.0), 0.0)
    dy = np.maximum(np.maximum(5.0 - y, y - 15.0), 0.0)
    expected = 15.0 * np.exp(-np.hypot(dx, dy) / 6.0)
    assert diff == pytest.approx(expected, rel=1e-6)  # nothing else changed: the scene has its own stream
    assert expected.max() == pytest.approx(15.0 * np.exp(-2.0 / 6.0))


def test_foot_stance_is_still_and_a_stride_integrates_to_its_length():
    """Foot unit: zero velocity in stance; strapdown over one swing moves the foot by one stride."""
    scenario = _scenario("foot-mems")
    walk = simulate_walk(scenario)
    imu, errors = simulate_imu_with_errors(scenario, walk)
    dt = imu.t_s[1] - imu.t_s[0]
    gyro = imu.gyro_radps - errors.gyro_bias_radps
    acc = (imu.acc_mps2 - errors.accel_bias_mps2) / (1.0 + errors.accel_scale)
    moving = np.linalg.norm(gyro, axis=1) > 0.2
    walking = (imu.t_s > walk.walk_start_t_s + 2.0) & (imu.t_s < walk.walk_end_t_s - 2.0)
    # Stance takes most of a stride: the foot is still more than half the time while walking.
    assert 0.4 < np.mean(~moving[walking]) < 0.8
    # Integrate one swing in the middle of the first straight.
    swings = np.flatnonzero(np.diff(moving.astype(int)) == 1)
    start = swings[np.searchsorted(imu.t_s[swings], walk.walk_start_t_s + 5.0)] - 5
    stop = start + int(0.6 / dt)
    up = acc[start - 10:start].mean(axis=0)
    # Initial attitude: tilt from the still accelerometer, yaw from the walking direction (north).
    tilt = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up / np.linalg.norm(up)])[0]
    forward = tilt.apply([0.0, 1.0, 0.0])
    attitude = Rotation.from_rotvec([0.0, 0.0, np.arctan2(forward[0], forward[1])]) * tilt
    velocity = np.zeros(3)
    position = np.zeros(3)
    for k in range(start, stop):
        attitude = attitude * Rotation.from_rotvec(0.5 * (gyro[k] + gyro[k + 1]) * dt)
        a_enu = attitude.apply(acc[k + 1]) - [0.0, 0.0, GRAVITY_MPS2]
        velocity_new = velocity + a_enu * dt
        position += 0.5 * (velocity + velocity_new) * dt
        velocity = velocity_new
    stride = 2.0 * np.median(walk.step_length_m)
    assert np.linalg.norm(velocity) < 0.1  # back at rest at the end of the swing
    assert np.hypot(position[0], position[1]) == pytest.approx(stride, rel=0.1)
    assert position[1] > 0.9 * stride  # forward = north on the first street
    assert abs(position[2]) < 0.05  # back on the ground


def test_deterministic_and_seed_dependent():
    scenario = _scenario("phone")
    walk = simulate_walk(scenario)
    a, b = simulate_imu(scenario, walk), simulate_imu(scenario, walk)
    c = simulate_imu(scenario.replace(seed=12), walk)
    assert np.array_equal(a.acc_mps2, b.acc_mps2) and np.array_equal(a.mag_ut, b.mag_ut)
    assert not np.array_equal(a.gyro_radps, c.gyro_radps)


def test_reference_scenario_phone_noise_levels():
    scenario = load_scenario("park-loop-ccw")
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    rest = imu.t_s < walk.walk_start_t_s - 0.5
    assert imu.acc_mps2[rest].std(axis=0) == pytest.approx([0.02] * 3, rel=0.15)
    gyro_sigma = np.radians(0.01) * np.sqrt(scenario.imu.rate_hz)
    assert imu.gyro_radps[rest].std(axis=0) == pytest.approx([gyro_sigma] * 3, rel=0.15)


def test_unknown_preset_raises():
    scenario = _scenario("wristwatch")
    with pytest.raises(ValueError, match="imu.preset"):
        simulate_imu(scenario, simulate_walk(scenario))
