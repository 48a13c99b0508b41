"""The PDR on what phones give: carriages, slow gentle gaits, uneven sample times, no magnetometer.

Simulated walks (sim/imu.py's carriages) with the phone held in front, held to text on a
slow gentle walk, in a trouser pocket and in a hand swinging at the side, each also with
1 % time-stamp jitter and no magnetometer: the adaptive step detector
(fusion/pdr/steps.py) must count their steps within 3 %, the first step after a
standstill must have a walker's speed, and a phone lying still must give no step.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from dtmbnav_core import schema
from dtmbnav_core.constants import GRAVITY_MPS2
from dtmbnav_core.records import ImuLog
from dtmbnav_core.resampling import GAP_INTERVALS, sample_timing
from dtmbnav_core.sensors import read_has_magnetometer, read_imu
from fusion.pdr import PdrConfig, calibrate_weinberg_k_from_walk, run_pdr
from fusion.pdr.steps import StepDetectorConfig, detect_steps
from sim.gnss import simulate_gnss
from sim.imu import simulate_imu, simulate_imu_with_errors
from sim.scenario import Scenario
from sim.walk import simulate_walk
from sim.walk_io import write_walk_groups

CARRIAGES = ("hand", "texting", "pocket", "swinging")
#: Texting walkers walk slower and with a lower cadence.
TEXTING_GAIT = {"speed_mps": 0.7, "step_frequency_hz": 1.1}
PHONE_AS_PHONES_ARE = {"time_jitter": 0.01, "magnetometer": False}


def _scenario(carriage: str, seed: int = 7, **imu) -> Scenario:
    walk = {"waypoints_m": [[0.0, 0.0], [0.0, 35.0], [15.0, 35.0]], "start_still_s": 6.0, "end_still_s": 2.0,
            **(TEXTING_GAIT if carriage == "texting" else {})}
    return Scenario(seed=seed).replace(walk=walk, imu={"carriage": carriage, **imu})


@pytest.fixture(scope="module", params=[(c, v) for c in CARRIAGES for v in ("clean", "phone-like")],
                ids=lambda p: f"{p[0]}-{p[1]}")
def walked(request):
    carriage, variant = request.param
    scenario = _scenario(carriage, **(PHONE_AS_PHONES_ARE if variant == "phone-like" else {}))
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    return scenario, walk, imu, run_pdr(imu, PdrConfig(step_model="frequency"))


def test_steps_counted_within_3_percent(walked):
    scenario, walk, _, pdr = walked
    assert len(walk.step_t_s) > 65
    assert abs(len(pdr.steps) - len(walk.step_t_s)) <= 0.03 * len(walk.step_t_s)
    if scenario.imu.carriage == "texting":
        assert 1.0 / np.median(np.diff(pdr.steps.t_s)) == pytest.approx(1.1, rel=0.05)


def test_steps_have_a_walkers_speed_from_the_first_one_on(walked):
    _, _, _, pdr = walked
    steps = pdr.steps
    first_duration = steps.step_length_m[0] / steps.speed_mps[0]
    config = StepDetectorConfig()
    assert config.min_step_s <= first_duration <= config.max_step_s
    # The first step from the standstill lasts as long as the next one.
    assert first_duration == pytest.approx(steps.t_s[1] - steps.t_s[0], abs=0.011)
    assert steps.speed_mps[0] < 3.0
    assert steps.speed_mps.max() < 3.5
    assert 0.3 < np.median(steps.speed_mps) < 2.0  # the uncalibrated frequency model: a walker's, not the truth


def test_the_carriage_is_told_from_the_phones_swing(walked):
    scenario, _, _, pdr = walked
    expected = "swinging" if scenario.imu.carriage in ("pocket", "swinging") else "steady"
    assert (pdr.carriage, pdr.walking_used, pdr.carriage_changes) == (expected, expected == "swinging", 0)


def test_uneven_times_are_resampled_and_a_missing_magnetometer_is_said(walked):
    scenario, _, imu, pdr = walked
    if scenario.imu.time_jitter == 0.0:
        assert pdr.timing.jitter < 1e-9 and pdr.notes == ()
        return
    assert np.ptp(np.diff(imu.t_s)) > 0.01 / scenario.imu.rate_hz  # the log really is uneven
    assert pdr.timing.jitter == pytest.approx(0.01, rel=0.15)
    assert pdr.timing.rate_hz == pytest.approx(scenario.imu.rate_hz, rel=1e-3)
    assert np.diff(pdr.track.t_s) == pytest.approx(0.1)
    assert any("resampled" in note for note in pdr.notes)
    assert any("no magnetometer" in note for note in pdr.notes)


def test_heading_without_magnetometer_follows_the_turn():
    """Gyro-and-accelerometer attitude, chosen by itself: the walk turns right by 90 deg."""
    scenario = _scenario("hand", **PHONE_AS_PHONES_ARE)
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    assert not np.any(imu.mag_ut)
    pdr = run_pdr(imu, PdrConfig(step_model="frequency"))
    def off_deg(heading_rad: np.ndarray, expected_deg: float) -> np.ndarray:
        return np.abs(np.degrees(np.angle(np.exp(1j * (heading_rad - np.radians(expected_deg))))))

    assert np.all(off_deg(pdr.steps.heading_rad[:5], 0.0) < 5.0)
    assert np.all(off_deg(pdr.steps.heading_rad[-5:], 90.0) < 5.0)


def test_a_phone_lying_still_gives_no_step():
    rng = np.random.default_rng(3)
    t_s = np.arange(6000) / 100.0
    # Sensor noise and a hand's tremor (a few hundredths of m/s^2 at 8-12 Hz) on gravity.
    acc = rng.normal(0.0, 0.02, (len(t_s), 3)) + [0.0, 3.0, np.sqrt(GRAVITY_MPS2**2 - 9.0)]
    acc += 0.05 * np.sin(2.0 * np.pi * 9.0 * t_s)[:, None] * [0.0, 0.6, 0.8]
    assert len(detect_steps(t_s, acc, StepDetectorConfig()).t_s) == 0
    imu = ImuLog(t_s=t_s, acc_mps2=acc, gyro_radps=rng.normal(0.0, 1e-3, (len(t_s), 3)),
                 mag_ut=np.tile([0.0, 20.0, -40.0], (len(t_s), 1)))
    pdr = run_pdr(imu, PdrConfig(step_model="frequency"))
    assert len(pdr.steps) == 0 and np.all(pdr.track.speed_mps == 0.0)


def test_gaps_are_found_and_reported():
    scenario = _scenario("hand", gaps_per_minute=4.0, gap_s=0.3)
    walk = simulate_walk(scenario)
    imu, errors = simulate_imu_with_errors(scenario, walk)
    assert len(errors.gyro_bias_radps) == len(imu.t_s)
    interval = np.diff(imu.t_s)
    dropped = interval > GAP_INTERVALS * np.median(interval)
    assert dropped.any()
    pdr = run_pdr(imu, PdrConfig(step_model="frequency"))
    assert len(pdr.timing.gaps_s) == np.count_nonzero(dropped)
    assert all(end - start >= 0.3 for start, end in pdr.timing.gaps_s)
    assert sum("bridged" in note for note in pdr.notes) == len(pdr.timing.gaps_s)
    assert pdr.timing.rate_hz == pytest.approx(100.0, rel=1e-6)  # the gaps leave the rate as it is
    assert abs(len(pdr.steps) - len(walk.step_t_s)) <= 0.05 * len(walk.step_t_s)


def test_repeated_or_decreasing_times_are_refused():
    t_s = np.arange(500) / 100.0
    acc = np.tile([0.0, 0.0, GRAVITY_MPS2], (len(t_s), 1))
    for bad_index, value in ((200, 1.99), (200, 2.5)):  # repeats sample 199's time, goes back
        bad = t_s.copy()
        bad[bad_index] = value
        imu = ImuLog(t_s=bad, acc_mps2=acc, gyro_radps=np.zeros_like(acc), mag_ut=np.ones_like(acc))
        with pytest.raises(ValueError, match=r"strictly increase \(every interval > 0 s\).*sample 20[01]"):
            run_pdr(imu, PdrConfig(step_model="frequency"))
    with pytest.raises(ValueError, match="uniform rate .* at most 0.001"):
        detect_steps(t_s + np.random.default_rng(1).normal(0.0, 1e-4, len(t_s)), acc, StepDetectorConfig())


def test_simulated_carriages_and_timing():
    """The carriages' magnitudes, the jitter's size, and the default sample grid untouched."""
    rates, bounce = {}, {}
    for carriage in CARRIAGES:
        scenario = _scenario(carriage)
        walk = simulate_walk(scenario)
        imu = simulate_imu(scenario, walk)
        walking = (imu.t_s > walk.walk_start_t_s + 2.0) & (imu.t_s < walk.walk_end_t_s - 2.0)
        rates[carriage] = np.degrees(np.percentile(np.linalg.norm(imu.gyro_radps[walking], axis=1), 99))
        bounce[carriage] = np.ptp(np.linalg.norm(imu.acc_mps2[walking], axis=1))
        assert np.array_equal(imu.t_s, np.arange(len(imu.t_s)) * (1.0 / 100.0))
    assert rates["pocket"] > 90.0 and rates["swinging"] > 90.0 and rates["hand"] < 60.0
    assert bounce["texting"] < 0.5 * bounce["hand"] < bounce["pocket"]
    jittered = _scenario("pocket", time_jitter=0.01)
    timing = sample_timing(simulate_imu(jittered, simulate_walk(jittered)).t_s)
    assert timing.jitter == pytest.approx(0.01, rel=0.1) and timing.gaps_s == ()


def test_no_magnetometer_is_written_as_an_imported_log_says_it(tmp_path):
    scenario = _scenario("hand", magnetometer=False)
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    with h5py.File(tmp_path / "walk.h5", "w") as h5:
        write_walk_groups(h5, scenario, walk, imu, simulate_gnss(scenario, walk))
    assert not read_has_magnetometer(tmp_path / "walk.h5")
    assert not np.any(read_imu(tmp_path / "walk.h5").mag_ut)
    with h5py.File(tmp_path / "walk.h5", "r") as h5:
        assert h5[schema.IMU].attrs[schema.HAS_MAGNETOMETER_ATTR] == np.False_


#: The carriages of issue 59 (sim/carriage.py), and a walk that handles the phone: out of the pocket
#: into the hand before the first step, to the ear mid-walk (where real logs overcount).
NEW_GAITS = {
    "pocket-gait": {"carriage": "pocket-gait"},
    "swinging-wide": {"carriage": "swinging-wide"},
    "ear": {"carriage": "ear"},
    "bag": {"carriage": "bag"},
    "handled": {"carriage": "pocket", "carriage_changes": [{"t_s": 3.0, "carriage": "hand"},
                                                           {"t_s": 20.0, "carriage": "ear"}]},
}


@pytest.mark.parametrize("gait", NEW_GAITS)
def test_steps_counted_within_3_percent_new_gaits(gait):
    imu_config = dict(NEW_GAITS[gait])
    scenario = _scenario(imu_config.pop("carriage"), **imu_config, **PHONE_AS_PHONES_ARE)
    walk = simulate_walk(scenario)
    pdr = run_pdr(simulate_imu(scenario, walk), PdrConfig(step_model="frequency"))
    assert abs(len(pdr.steps) - len(walk.step_t_s)) <= 0.03 * len(walk.step_t_s)
    if gait == "handled":
        # To the ear mid-walk; out of the pocket at 3 s is before the first step, not between two.
        assert pdr.carriage_changes == 1
    # Handling the phone before the first step (out of the pocket at 3 s) is no step.
    assert pdr.steps.t_s[0] > walk.step_t_s[0] - 0.5 * np.median(np.diff(walk.step_t_s))


@pytest.mark.parametrize("carriage", CARRIAGES + tuple(NEW_GAITS)[:-1])
def test_distance_within_5_percent_after_calibrating_in_the_carriage(carriage):
    """A walker calibrated once in a carriage (another walk, another seed) walks the distance in it.

    A swinging arm adds its own accelerations to what Weinberg's relation reads, so the gain is
    the carriage's (``pdr --calibrate`` keeps one per carriage class), not the walker's alone.
    """
    def walked(seed: int) -> tuple:
        scenario = _scenario(carriage, seed=seed, **PHONE_AS_PHONES_ARE)
        walk = simulate_walk(scenario)
        return walk, simulate_imu(scenario, walk)

    calibration_walk, calibration_imu = walked(1)
    k_m = calibrate_weinberg_k_from_walk(calibration_imu, float(calibration_walk.step_length_m.sum()))
    walk, imu = walked(7)
    pdr = run_pdr(imu, PdrConfig(weinberg_k_m=k_m))
    assert pdr.steps.step_length_m.sum() == pytest.approx(walk.step_length_m.sum(), rel=0.05)
