"""The simulator's phone carriages (sim/carriage.py) against their physics and their truth.

Short walks, each checked for what its model claims: a swinging arm's rate is its
pendulum's, a thigh in a pocket flexes faster than it extends, a bag rings at its own
frequency after the walker stops, a phone at rest feels gravity only, and handling
the phone into another carriage takes the time it is given and ends in that carriage.
"""

from __future__ import annotations

import tomllib
from itertools import pairwise

import numpy as np
import pytest

from dtmbnav_core.constants import GRAVITY_MPS2
from sim.carriage import CARRIAGES, attitude_ypr
from sim.imu import simulate_imu
from sim.scenario import Scenario, scenario_from_dict, scenario_to_toml
from sim.walk import simulate_walk

NEW_CARRIAGES = ("pocket-gait", "swinging-wide", "ear", "bag")
#: Walker's stride frequency in these walks: half the step frequency, Hz.
STEP_HZ = 1.8


def _walked(carriage: str, length_m: float = 25.0, start_still_s: float = 3.0, end_still_s: float = 1.0,
            seed: int = 5, **imu):
    walk = {"waypoints_m": [[0.0, 0.0], [0.0, length_m]], "start_still_s": start_still_s,
            "end_still_s": end_still_s, "step_frequency_hz": STEP_HZ}
    scenario = Scenario(seed=seed).replace(walk=walk, imu={"carriage": carriage, **imu})
    walk = simulate_walk(scenario)
    return walk, simulate_imu(scenario, walk)


def _steady(imu, walk, margin_s: float = 3.0) -> np.ndarray:
    """Samples of steady walking (away from setting off and stopping)."""
    return (imu.t_s > walk.walk_start_t_s + margin_s) & (imu.t_s < walk.walk_end_t_s - margin_s)


def _principal_rate(gyro: np.ndarray) -> np.ndarray:
    """The angular rate about the axis the sensor turns about most, rad/s (sign: the axis's)."""
    centred = gyro - gyro.mean(axis=0)
    return centred @ np.linalg.svd(centred, full_matrices=False)[2][0]


def _amplitude_at(x: np.ndarray, freq_hz: float, rate_hz: float = 100.0) -> float:
    """Amplitude of ``x``'s Fourier component nearest ``freq_hz`` (largest of the bins around it)."""
    spectrum = np.abs(np.fft.rfft(x - x.mean())) * 2.0 / len(x)
    i = int(np.argmin(np.abs(np.fft.rfftfreq(len(x), 1.0 / rate_hz) - freq_hz)))
    return float(spectrum[i - 2:i + 3].max())


@pytest.mark.parametrize(("carriage", "imu"), [("swinging-wide", {}), ("swinging", {"swing_deg": 30.0})])
def test_swinging_arm_turns_at_its_pendulums_rate(carriage, imu):
    walk, log = _walked(carriage, **imu)
    amplitude_rad = np.radians(imu.get("swing_deg", np.degrees(CARRIAGES[carriage].swing_rad)))
    stride_hz = 0.5 / np.median(np.diff(walk.step_t_s))
    steady = _steady(log, walk)
    rate = _principal_rate(log.gyro_radps[steady])
    # theta = A cos(2 pi f t): the rate's amplitude is 2 pi f A; half its range over each stride.
    strides = np.searchsorted(log.t_s[steady], walk.step_t_s[::2])
    halves = [0.5 * np.ptp(rate[a:b]) for a, b in pairwise(strides) if 0 < a < b < len(rate)]
    assert np.median(halves) == pytest.approx(2.0 * np.pi * stride_hz * amplitude_rad, rel=0.06)


def test_wide_swing_puts_stride_and_centripetal_terms_into_the_norm():
    """Centripetal L theta'^2 beats at twice the stride frequency; the forward-centred swing adds the stride's."""
    norms = {}
    for carriage in ("swinging", "swinging-wide"):
        walk, log = _walked(carriage)
        norms[carriage] = np.linalg.norm(log.acc_mps2[_steady(log, walk)], axis=1)
    stride_hz = STEP_HZ / 2.0
    wide, narrow = norms["swinging-wide"], norms["swinging"]
    assert _amplitude_at(wide, stride_hz) > 1.0 > 3.0 * _amplitude_at(narrow, stride_hz)
    limb_m, swing_rad = CARRIAGES["swinging-wide"].limb_m, CARRIAGES["swinging-wide"].swing_rad
    centripetal_peak = limb_m * (2.0 * np.pi * stride_hz * swing_rad) ** 2
    assert centripetal_peak > 10.0 and np.ptp(wide) > centripetal_peak


def test_thigh_in_a_pocket_flexes_faster_than_it_extends_and_one_strike_dominates():
    walk, log = _walked("pocket-gait", length_m=30.0)
    steady = _steady(log, walk)
    rate = _principal_rate(log.gyro_radps[steady])
    fast, slow = sorted([np.percentile(rate, 99), -np.percentile(rate, 1)], reverse=True)
    assert fast > 1.25 * slow  # ~40 deg flexion in a third of the stride, the extension in a half
    symmetric = _principal_rate(_walked("pocket", length_m=30.0)[1].gyro_radps[steady])
    assert np.percentile(symmetric, 99) == pytest.approx(-np.percentile(symmetric, 1), rel=0.1)
    # Double-peaked strides: the pocket leg's strikes (the ends of odd steps) peak above the other leg's.
    norm = np.linalg.norm(log.acc_mps2, axis=1)
    strikes = walk.step_t_s[(walk.step_t_s > walk.walk_start_t_s + 3.0) & (walk.step_t_s < walk.walk_end_t_s - 3.0)]
    index = np.searchsorted(walk.step_t_s, strikes)
    peaks = np.array([norm[np.abs(log.t_s - t) < 0.05].max() for t in strikes])
    assert np.mean(peaks[index % 2 == 1]) > 1.3 * np.mean(peaks[index % 2 == 0])


def test_bag_rings_at_its_own_frequency_after_the_walker_stops():
    walk, log = _walked("bag", end_still_s=5.0)
    after = (log.t_s > walk.walk_end_t_s + 0.3) & (log.t_s < walk.walk_end_t_s + 4.0)
    rate = _principal_rate(log.gyro_radps[after])
    rising = np.flatnonzero((rate[:-1] < 0.0) & (rate[1:] >= 0.0))
    period_s = np.median(np.diff(log.t_s[after][rising]))
    bag = CARRIAGES["bag"]
    natural_hz = np.sqrt(GRAVITY_MPS2 / bag.limb_m) / (2.0 * np.pi) * np.sqrt(1.0 - bag.sway_damping**2)
    assert 1.0 / period_s == pytest.approx(natural_hz, rel=0.08)
    assert abs(1.0 / period_s - STEP_HZ / 2.0) > 0.03  # its own, not the stride's
    # Damped: the sway dies down over the standstill.
    assert np.abs(rate[-50:]).max() < 0.3 * np.abs(rate[:100]).max()


@pytest.mark.parametrize("carriage", sorted(CARRIAGES))
def test_a_phone_at_rest_feels_gravity_alone(carriage):
    walk, log = _walked(carriage, length_m=5.0)
    still = log.t_s < walk.walk_start_t_s - 0.2
    # Noise, bias (0.03 m/s^2 per axis) and scale errors (0.5 %) only.
    assert np.linalg.norm(log.acc_mps2[still], axis=1).mean() == pytest.approx(GRAVITY_MPS2, abs=0.12)
    if CARRIAGES[carriage].head_turn_rad == 0.0:  # the head at the ear may turn while standing
        assert np.abs(log.gyro_radps[still]).max() < 0.05


def test_handling_takes_its_time_and_moves_the_phone():
    """Standing still, the phone is taken out of the pocket into the hand over [2, 3.5] s."""
    walk, log = _walked("pocket", length_m=5.0, start_still_s=6.0,
                        carriage_changes=[{"t_s": 2.0, "carriage": "hand", "duration_s": 1.5}])
    still = log.t_s < walk.walk_start_t_s
    turning = still & (np.linalg.norm(log.gyro_radps, axis=1) > 0.05)
    assert log.t_s[turning].min() >= 2.0 and log.t_s[turning].max() <= 3.5
    assert np.ptp(log.t_s[turning]) > 1.0
    pulled = still & (np.abs(np.linalg.norm(log.acc_mps2, axis=1) - GRAVITY_MPS2) > 0.3)
    assert pulled.any() and log.t_s[pulled].min() >= 2.0 and log.t_s[pulled].max() <= 3.5
    # After it, the phone is held at the hand's pitch: gravity along y and z as 20 deg nose up says.
    held = still & (log.t_s > 4.0)
    expected = attitude_ypr(np.zeros(1), np.array([CARRIAGES["hand"].pitch_rad]), np.zeros(1)).inv().apply(
        [0.0, 0.0, GRAVITY_MPS2])[0]
    assert log.acc_mps2[held].mean(axis=0) == pytest.approx(expected, abs=0.15)


def test_carriage_changes_at_its_time_mid_walk():
    walk, log = _walked("hand", length_m=30.0, carriage_changes=[{"t_s": 12.0, "carriage": "ear"}])
    gravity = {}
    for name, (start, end) in {"hand": (7.0, 11.9), "ear": (13.6, walk.walk_end_t_s - 1.0)}.items():
        window = (log.t_s >= start) & (log.t_s < end)
        gravity[name] = log.acc_mps2[window].mean(axis=0)  # the gait's acceleration averages out
        carriage = CARRIAGES[name]
        expected = attitude_ypr(np.zeros(1), np.array([carriage.pitch_rad]), np.array([carriage.roll_rad])).inv()
        assert gravity[name] == pytest.approx(expected.apply([0.0, 0.0, GRAVITY_MPS2])[0], abs=0.4)
    assert walk.walk_start_t_s < 7.0 and walk.walk_end_t_s > 16.0


def test_carriage_changes_are_checked_and_written_back():
    scenario = Scenario().replace(imu={"carriage": "pocket", "swing_deg": 30.0, "carriage_changes": [
        {"t_s": 2.0, "carriage": "swinging"}, {"t_s": 9.0, "carriage": "bag", "duration_s": 2.0}]})
    assert scenario_from_dict(tomllib.loads(scenario_to_toml(scenario))) == scenario
    walk = simulate_walk(Scenario().replace(walk={"waypoints_m": [[0.0, 0.0], [0.0, 5.0]]}))
    bad = {"unknown carriage 'purse'": {"carriage_changes": [{"t_s": 1.0, "carriage": "purse"}]},
           "previous change's end": {"carriage_changes": [{"t_s": 1.0, "carriage": "ear"},
                                                           {"t_s": 2.0, "carriage": "hand"}]},
           "swings an arm": {"swing_deg": 30.0, "carriage": "pocket"}}
    for message, imu in bad.items():
        with pytest.raises(ValueError, match=message):
            simulate_imu(Scenario().replace(imu=imu), walk)
