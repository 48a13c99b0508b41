"""The PDR integrates the walking direction, not the phone's yaw (fusion/pdr/walking_direction.py).

Simulated L-shaped walks (north 35 m, then east) with the phone in a trouser
pocket or a hand swinging at the side: the heading follows the truth on the
straight legs and after the turn; a phone held in front keeps the phone's
heading; a change of carriage mid-walk (two simulated logs of one walk
spliced between two steps) is found and makes no turn. The principal-axis
estimator is checked on synthetic accelerations of known direction.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core.records import ImuLog
from fusion.pdr import PdrConfig, run_pdr
from fusion.pdr.walking_direction import principal_axis, stride_windows
from sim.imu import simulate_imu
from sim.scenario import Scenario
from sim.walk import Walk, simulate_walk

L_WALK = {"waypoints_m": [[0.0, 0.0], [0.0, 35.0], [35.0, 35.0]], "start_still_s": 6.0, "end_still_s": 2.0}
TOLERANCE_DEG = 5.0


def _walk(seed: int = 7) -> tuple[Scenario, Walk]:
    scenario = Scenario(seed=seed).replace(walk=L_WALK)
    return scenario, simulate_walk(scenario)


def _carried(scenario: Scenario, walk: Walk, carriage: str) -> ImuLog:
    return simulate_imu(scenario.replace(imu={"carriage": carriage}), walk)


def _error_deg(walk: Walk, t_s: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
    truth = np.interp(t_s, walk.track.t_s, np.unwrap(walk.track.heading_rad))
    return np.degrees(np.angle(np.exp(1j * (heading_rad - truth))))


def _on_straights(walk: Walk, t_s: np.ndarray) -> np.ndarray:
    """Steps at a walking pace along a leg (the truth heading due north or east), clear of the turn.

    The stride a step's heading is taken over reaches back about 1.2 s, so the
    truth must be straight from 1.5 s before the step to 0.5 s after it.
    """
    heading_deg = np.degrees(np.unwrap(walk.track.heading_rad))
    straight = np.ones(len(t_s), dtype=bool)
    for shift_s in np.arange(-1.5, 0.51, 0.1):
        truth_deg = np.interp(t_s + shift_s, walk.track.t_s, heading_deg)
        straight &= np.minimum(np.abs(truth_deg), np.abs(truth_deg - 90.0)) < 0.5
    return straight & (np.interp(t_s, walk.track.t_s, walk.track.speed_mps) > 0.5)


@pytest.mark.parametrize("carriage", ["pocket", "swinging", "pocket-gait", "swinging-wide"])
def test_the_heading_follows_the_walk_not_the_swinging_phone(carriage):
    scenario, walk = _walk()
    imu = _carried(scenario, walk, carriage)
    pdr = run_pdr(imu, PdrConfig(step_model="frequency"))
    assert pdr.walking_used and not pdr.walking.carriage_change.any()
    error = _error_deg(walk, pdr.steps.t_s, pdr.steps.heading_rad)
    straight = _on_straights(walk, pdr.steps.t_s)
    assert straight.sum() > 50
    assert np.abs(error[straight]).max() < TOLERANCE_DEG
    after_turn = straight & (pdr.steps.t_s > pdr.steps.t_s[-1] - 10.0)
    assert after_turn.sum() >= 10 and np.abs(error[after_turn]).max() < TOLERANCE_DEG
    # The offset is the phone's, constant along the walk.
    assert np.ptp(np.degrees(pdr.walking.offset_rad[straight])) < TOLERANCE_DEG


def test_a_phone_held_in_front_keeps_the_phones_heading():
    scenario, walk = _walk()
    imu = _carried(scenario, walk, "hand")
    phone = run_pdr(imu, PdrConfig(step_model="frequency", heading_source="phone"))
    auto = run_pdr(imu, PdrConfig(step_model="frequency"))
    assert not auto.walking_used
    assert np.array_equal(auto.steps.heading_rad, phone.steps.heading_rad)
    walking = run_pdr(imu, PdrConfig(step_model="frequency", heading_source="walking"))
    assert walking.walking_used
    change = np.degrees(np.angle(np.exp(1j * (walking.steps.heading_rad - phone.steps.heading_rad))))
    assert np.abs(change).max() < 1.0


@pytest.mark.parametrize("before, after", [("hand", "pocket"), ("pocket", "swinging")])
def test_a_change_of_carriage_is_no_turn(before, after):
    scenario, walk = _walk(seed=3)
    logs = [_carried(scenario, walk, carriage) for carriage in (before, after)]
    # Abrupt, between two steps on the first leg: the second log takes over with its own attitude.
    k = len(walk.step_t_s) // 4
    change_t_s = 0.5 * (walk.step_t_s[k] + walk.step_t_s[k + 1])
    first = (logs[0].t_s < change_t_s)[:, None]
    imu = ImuLog(t_s=logs[0].t_s, **{name: np.where(first, getattr(logs[0], name), getattr(logs[1], name))
                                     for name in ("acc_mps2", "gyro_radps", "mag_ut")})
    pdr = run_pdr(imu, PdrConfig(step_model="frequency"))
    assert pdr.walking_used
    found = pdr.steps.t_s[pdr.walking.carriage_change]
    assert len(found) == 1 and abs(found[0] - change_t_s) < 1.5
    assert sum("changed carriage" in note for note in pdr.notes) == 1
    straight = _on_straights(walk, pdr.steps.t_s)
    error = _error_deg(walk, pdr.steps.t_s, pdr.steps.heading_rad)
    assert np.abs(error[straight]).max() < TOLERANCE_DEG
    # The phone's own heading takes the change for a turn.
    phone = run_pdr(imu, PdrConfig(step_model="frequency", heading_source="phone"))
    assert np.abs(_error_deg(walk, phone.steps.t_s, phone.steps.heading_rad)[straight]).max() > 30.0


@settings(max_examples=60, deadline=None)
@given(direction_deg=st.floats(0.0, 179.9), amplitude=st.floats(0.5, 8.0), sway=st.floats(0.0, 0.6),
       noise=st.floats(0.0, 0.1), seed=st.integers(0, 2**31 - 1))
def test_the_principal_axis_is_the_direction_of_the_acceleration(direction_deg, amplitude, sway, noise, seed):
    """Forward surge along a known direction, a sideways sway at half its frequency, white noise.

    ``sway`` and ``noise`` are relative to the surge's amplitude (m/s^2).
    """
    rng = np.random.default_rng(seed)
    t_s = np.arange(120) / 100.0  # a stride of two 0.6 s steps at 100 Hz
    along = amplitude * np.sin(2.0 * np.pi * t_s / 0.6)
    across = sway * amplitude * np.sin(np.pi * t_s / 0.6)
    angle = np.radians(direction_deg)
    forward, right = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
    horizontal = along[:, None] * forward + across[:, None] * right + rng.normal(0.0, noise * amplitude, (len(t_s), 2))
    axis_rad, linearity = principal_axis(horizontal)
    assert 0.0 <= axis_rad < np.pi
    off_deg = np.degrees(np.angle(np.exp(2j * (axis_rad - angle)))) / 2.0  # modulo 180 deg
    assert abs(off_deg) < 4.0
    assert linearity > 1.5


def test_stride_windows_pair_each_step_with_a_neighbour():
    # Two steps from a standstill, a stop, then three steps.
    t_s = np.array([1.5, 2.0, 5.5, 6.0, 6.5])
    start = np.array([1.0, 1.5, 5.0, 5.5, 6.0])
    stride_start, stride_end = stride_windows(t_s, start)
    assert list(stride_start) == [1.0, 1.0, 5.0, 5.0, 5.5]
    assert list(stride_end) == [2.0, 2.0, 6.0, 6.0, 6.5]


def test_an_unknown_heading_source_is_refused():
    imu = ImuLog(t_s=np.arange(300) / 100.0, acc_mps2=np.tile([0.0, 0.0, 9.8], (300, 1)),
                 gyro_radps=np.zeros((300, 3)), mag_ut=np.zeros((300, 3)))
    with pytest.raises(ValueError, match="heading_source"):
        run_pdr(imu, PdrConfig(step_model="frequency", heading_source="compass"))
