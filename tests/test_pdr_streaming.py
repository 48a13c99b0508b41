"""The streaming PDR against the batch one (fusion/pdr/streaming.py): same steps, bounded memory.

Simulated walks (a hand-held phone, a trouser pocket) and a committed real trace
(Oxford step counter data set, accelerometer only) are fed in chunks; the steps
given out must be the batch ``run_pdr``'s within a sample in time, 1 % in length,
1 deg in heading and 1 % of the distance in position.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from dtmbnav.evaluation.step_count import data_set_walks
from dtmbnav_core.records import ImuLog
from dtmbnav_core.resampling import interpolate, uniform_grid
from fusion.pdr import PdrConfig, run_pdr
from fusion.pdr.streaming import StreamingPdr
from sim.imu import simulate_imu
from sim.scenario import Scenario
from sim.walk import simulate_walk

CONFIG = PdrConfig(step_model="frequency")
WALK = {"waypoints_m": [[0.0, 0.0], [0.0, 25.0], [20.0, 25.0]], "start_still_s": 5.0, "end_still_s": 2.0}
OXFORD = Path(__file__).parent / "data" / "oxford_steps"


@cache
def _imu(carriage: str, seed: int = 104) -> ImuLog:
    scenario = Scenario(seed=seed).replace(walk=WALK)
    return simulate_imu(scenario.replace(imu={"carriage": carriage}), simulate_walk(scenario))


def _stream(imu: ImuLog, bounds: list[int], stream: StreamingPdr | None = None) -> dict[str, np.ndarray]:
    """The steps given out for ``imu`` cut at the sample indices ``bounds``, then finished."""
    stream = stream or StreamingPdr(CONFIG)
    edges = [0, *bounds, len(imu.t_s)]
    parts = [stream.add(imu.select(slice(a, b))) for a, b in zip(edges[:-1], edges[1:])] + [stream.finish()]
    return {name: np.concatenate([getattr(p, name) for p in parts]) for name in parts[0].columns()}


def _every(imu: ImuLog, chunk_s: float) -> list[int]:
    return list(range(round(chunk_s * 100), len(imu.t_s), round(chunk_s * 100)))


def _assert_as_batch(streamed: dict[str, np.ndarray], imu: ImuLog) -> None:
    batch = run_pdr(imu, CONFIG).steps
    assert len(batch) > 20 and len(streamed["t_s"]) == len(batch)
    interval = np.mean(np.diff(imu.t_s))
    assert np.abs(streamed["t_s"] - batch.t_s).max() <= 1.01 * interval
    assert np.abs(streamed["step_length_m"] / batch.step_length_m - 1.0).max() <= 0.01
    turn = np.angle(np.exp(1j * (streamed["heading_rad"] - batch.heading_rad)))
    assert np.degrees(np.abs(turn)).max() <= 1.0
    moved = np.hypot(streamed["x_m"] - batch.x_m, streamed["y_m"] - batch.y_m)
    assert moved.max() <= 0.01 * batch.step_length_m.sum()


@pytest.mark.parametrize("carriage", ["hand", "pocket"])
def test_streamed_steps_are_the_batch_steps(carriage):
    imu = _imu(carriage)
    stream = StreamingPdr(CONFIG)
    _assert_as_batch(_stream(imu, _every(imu, 0.5), stream), imu)
    assert stream.walking_used == run_pdr(imu, CONFIG).walking_used == (carriage == "pocket")
    assert stream.carriage == ("swinging" if carriage == "pocket" else "steady")


@settings(max_examples=2, deadline=None, phases=[Phase.generate])
@given(st.lists(st.integers(20, 200), min_size=40, max_size=40))
def test_any_chunking_gives_the_batch_steps(sizes):
    """Chunks of 0.2-2 s cut anywhere: the reruns fall elsewhere, the steps stay the batch's."""
    imu = _imu("hand")
    _assert_as_batch(_stream(imu, [b for b in np.cumsum(np.array(sizes) * 5) if b < len(imu.t_s)]), imu)


def test_a_real_trace_gives_the_batch_steps():
    """Accelerometer only (no gyro, no magnetometer): the count and the step times."""
    folder = data_set_walks(OXFORD, "optimisation")[0]
    rows = np.loadtxt(folder / "accelerometer.csv", delimiter=",", usecols=(0, 2, 3, 4))  # time (ns), x, y, z
    t_s = (rows[:, 0] - rows[0, 0]) * 1e-9
    grid = uniform_grid(t_s[0], min(t_s[-1], 90.0), 100.0)
    zeros = np.zeros((len(grid), 3))
    imu = ImuLog(t_s=grid, acc_mps2=interpolate(t_s, rows[:, 1:], grid), gyro_radps=zeros, mag_ut=zeros)
    _assert_as_batch(_stream(imu, _every(imu, 0.7)), imu)


def test_memory_stays_within_the_trailing_window():
    """A walk four times the window: the samples held never exceed it (plus a rerun's worth)."""
    scenario = Scenario(seed=105).replace(walk={"waypoints_m": [[0.0, 0.0], [0.0, 150.0]], "start_still_s": 3.0})
    imu = simulate_imu(scenario, simulate_walk(scenario))
    stream = StreamingPdr(CONFIG, trailing_s=20.0)
    held = []
    for a in range(0, len(imu.t_s), 50):
        stream.add(imu.select(slice(a, a + 50)))
        held.append(stream.buffered_samples)
    assert imu.t_s[-1] > 4 * stream.trailing_s
    limit = (stream.trailing_s + stream.update_s + 0.5) * 100
    assert max(held[len(held) // 3:]) <= limit
    assert stream._quat.shape[0] == stream.buffered_samples  # the attitude is trimmed with the samples


def test_standing_still_gives_no_steps():
    imu = _imu("hand")
    still = imu.select(imu.t_s < 4.5)
    stream = StreamingPdr(CONFIG)
    assert len(_stream(still, _every(still, 0.5), stream)["t_s"]) == 0
    assert stream.carriage == "unknown" and not stream.walking_used


def test_a_stream_off_its_grid_is_refused():
    imu = _imu("hand")
    stream = StreamingPdr(CONFIG)
    stream.add(imu.select(slice(0, 100)))
    with pytest.raises(ValueError, match="uniform grid"):
        stream.add(imu.select(slice(150, 200)))
