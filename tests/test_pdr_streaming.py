"""The streaming PDR against the batch one (fusion/pdr/streaming.py): same steps, bounded memory.

Simulated walks (a hand-held phone, a trouser pocket) and a committed real trace
(Oxford step counter data set, accelerometer only) are fed in chunks; the steps
given out must be the batch ``run_pdr``'s within a sample in time, 1 % in length,
1 deg in heading and 1 % of the distance in position. The provisional steps shown
between two settled batches must continue the settled track, keep close to the
newest sample, and be, for the most part, the steps that settle later.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from dtmbnav.evaluation.step_count import data_set_walks
from dtmbnav_core.records import ImuLog, PdrSteps
from dtmbnav_core.resampling import interpolate, uniform_grid
from fusion.pdr import PdrConfig, PdrResult, run_pdr
from fusion.pdr.streaming import StreamingPdr
from sim.imu import simulate_imu
from sim.scenario import Scenario
from sim.walk import simulate_walk

CONFIG = PdrConfig(step_model="frequency")
#: About 43 s: 5 s of rest, 35 m with a right turn made standing still for 6 s, 2 s of rest.
WALK = {"waypoints_m": [[0.0, 0.0], [0.0, 20.0], [15.0, 20.0]], "start_still_s": 5.0, "end_still_s": 2.0,
        "pauses": [{"at_waypoint": 1, "duration_s": 6.0}]}
OXFORD = Path(__file__).parent / "data" / "oxford_steps"
RATE_HZ = 100.0
#: The walks stream on a short trailing window (the least allowed, rounded up) that they outlast; the
#: chunking test streams on the default one.
TRAILING_S = 20.0


@cache
def _imu(carriage: str, seed: int = 104) -> ImuLog:
    scenario = Scenario(seed=seed).replace(walk=WALK)
    return simulate_imu(scenario.replace(imu={"carriage": carriage}), simulate_walk(scenario))


_BATCH: dict[int, PdrResult] = {}


def _batch(imu: ImuLog) -> PdrResult:
    """The batch run, once per log (the logs are cached)."""
    if id(imu) not in _BATCH:
        _BATCH[id(imu)] = run_pdr(imu, CONFIG)
    return _BATCH[id(imu)]


@cache
def _first_part() -> ImuLog:
    """The hand walk's first 25 s: the rest, the first leg, and an end while walking."""
    imu = _imu("hand")
    return imu.select(imu.t_s < 25.0)


def _columns(parts: list[PdrSteps]) -> dict[str, np.ndarray]:
    return {name: np.concatenate([getattr(p, name) for p in parts]) for name in parts[0].columns()}


def _stream(imu: ImuLog, bounds: list[int], stream: StreamingPdr | None = None) -> dict[str, np.ndarray]:
    """The steps given out for ``imu`` cut at the sample indices ``bounds``, then finished."""
    stream = stream or StreamingPdr(CONFIG)
    edges = [0, *bounds, len(imu.t_s)]
    return _columns([stream.add(imu.select(slice(a, b))) for a, b in pairwise(edges)] + [stream.finish()])


def _every(imu: ImuLog, chunk_s: float) -> list[int]:
    return list(range(round(chunk_s * RATE_HZ), len(imu.t_s), round(chunk_s * RATE_HZ)))


def _assert_as_batch(streamed: dict[str, np.ndarray], imu: ImuLog) -> None:
    batch = _batch(imu).steps
    assert len(batch) > 20 and len(streamed["t_s"]) == len(batch)
    interval = np.mean(np.diff(imu.t_s))
    assert np.abs(streamed["t_s"] - batch.t_s).max() <= 1.01 * interval
    assert np.abs(streamed["step_length_m"] / batch.step_length_m - 1.0).max() <= 0.01
    turn = np.angle(np.exp(1j * (streamed["heading_rad"] - batch.heading_rad)))
    assert np.degrees(np.abs(turn)).max() <= 1.0
    moved = np.hypot(streamed["x_m"] - batch.x_m, streamed["y_m"] - batch.y_m)
    assert moved.max() <= 0.01 * batch.step_length_m.sum()


@dataclass
class Run:
    """One simulated walk streamed in 0.5 s chunks, with what the stream showed after each chunk."""

    carriage: str
    imu: ImuLog
    stream: StreamingPdr
    settled: dict[str, np.ndarray]  # every settled step, finish() included
    newest_t_s: list[float]  # newest sample after each add
    settled_t_s: list[float]  # peak of the last settled step after each add (-inf: none yet)
    provisional: list[PdrSteps]  # provisional() after each add
    held: list[int]  # buffered_samples after each add


@pytest.fixture(scope="module", params=["hand", "pocket"])
def run(request) -> Run:
    imu = _imu(request.param)
    stream = StreamingPdr(CONFIG, trailing_s=TRAILING_S)
    parts, newest, last, provisional, held = [], [], [], [], []
    for a, b in pairwise([0, *_every(imu, 0.5), len(imu.t_s)]):
        parts.append(stream.add(imu.select(slice(a, b))))
        newest.append(float(imu.t_s[b - 1]))
        settled_t = np.concatenate([p.t_s for p in parts])
        last.append(float(settled_t[-1]) if settled_t.size else -np.inf)
        provisional.append(stream.provisional())
        held.append(stream.buffered_samples)
    parts.append(stream.finish())
    assert len(stream.provisional()) == 0  # nothing is provisional once the stream has ended
    return Run(request.param, imu, stream, _columns(parts), newest, last, provisional, held)


def test_streamed_steps_are_the_batch_steps(run):
    _assert_as_batch(run.settled, run.imu)
    assert run.stream.walking_used == _batch(run.imu).walking_used == (run.carriage == "pocket")
    assert run.stream.carriage == ("swinging" if run.carriage == "pocket" else "steady")


def test_provisional_steps_lead_the_settled_ones_to_the_newest_sample(run):
    """After every chunk: after the last settled step, continuing its track, within 1.5 s of the newest sample
    while walking (setting off from the pause too), and for the most part as they settle later."""
    settled = run.settled
    half_sample = 0.5 / RATE_HZ
    batch_t = _batch(run.imu).steps.t_s
    set_off = batch_t[np.flatnonzero(np.diff(batch_t) > CONFIG.steps.max_step_s) + 1]
    shown = matched = 0
    lags, moved, turned = [], [], []
    for newest, last, steps in zip(run.newest_t_s, run.settled_t_s, run.provisional):
        if not np.isfinite(last):
            assert len(steps) == 0  # no attitude, no heading reference yet
            continue
        if np.count_nonzero((batch_t > newest - 1.5) & (batch_t <= newest)) >= 2:  # walking
            lags.append(newest - steps.t_s[-1] if len(steps) else np.inf)
        if len(steps) == 0:
            continue
        assert steps.t_s[0] > last + half_sample
        # The first provisional step leaves from the last settled step's position.
        before = np.searchsorted(settled["t_s"], last + half_sample) - 1
        hop = np.hypot(steps.x_m[0] - settled["x_m"][before], steps.y_m[0] - settled["y_m"][before])
        assert hop == pytest.approx(steps.step_length_m[0], rel=1e-9)
        # Those that settle later, as they settle.
        nearest = np.clip(np.searchsorted(settled["t_s"], steps.t_s), 1, len(settled["t_s"]) - 1)
        nearest -= np.abs(settled["t_s"][nearest - 1] - steps.t_s) < np.abs(settled["t_s"][nearest] - steps.t_s)
        same = np.abs(settled["t_s"][nearest] - steps.t_s) <= 1.01 / RATE_HZ
        shown += len(steps)
        matched += np.count_nonzero(same)
        moved.extend(np.hypot(settled["x_m"][nearest] - steps.x_m, settled["y_m"][nearest] - steps.y_m)[same])
        turned.extend(np.angle(np.exp(1j * (settled["heading_rad"][nearest] - steps.heading_rad)))[same])
    assert len(set_off) == 1 and len(lags) > 25 and max(lags) <= 1.5
    assert matched >= 0.95 * shown
    assert np.degrees(np.abs(turned)).max() <= 2.0
    assert np.percentile(moved, 90) <= 0.05


def test_memory_stays_within_the_trailing_window(run):
    """A walk past the window: the samples held never exceed it (plus a rerun's worth), the attitude's neither."""
    stream = run.stream
    assert run.imu.t_s[-1] > stream.trailing_s + 10.0
    past = np.asarray(run.newest_t_s) > stream.trailing_s + 10.0  # the walk started after 5 s of rest
    assert max(np.asarray(run.held)[past]) <= (stream.trailing_s + stream.update_s + 0.5) * RATE_HZ
    assert stream._quat.shape[0] == stream.buffered_samples


@settings(max_examples=2, deadline=None, phases=[Phase.generate])
@given(st.lists(st.integers(20, 200), min_size=40, max_size=40))
def test_any_chunking_gives_the_batch_steps(sizes):
    """Chunks of 0.2-2 s cut anywhere: the reruns fall elsewhere, the steps stay the batch's (first 25 s)."""
    imu = _first_part()
    _assert_as_batch(_stream(imu, [b for b in np.cumsum(np.array(sizes) * 5) if b < len(imu.t_s)]), imu)


def test_a_change_of_carriage_turns_the_stream_to_the_walking_direction():
    """A hand-held phone pocketed while walking: the walking direction (held across the handling) from the start.

    The run sees the change a few steps after the steps given before it; those steps take the walking
    direction too, as the batch's do (it decides from the whole walk).
    """
    walk = {"waypoints_m": [[0.0, 0.0], [0.0, 12.0], [10.0, 12.0]], "start_still_s": 4.0, "end_still_s": 1.0}
    scenario = Scenario(seed=104).replace(walk=walk)
    pocketed = {"carriage": "hand", "carriage_changes": [{"t_s": 9.0, "carriage": "pocket"}]}
    imu = simulate_imu(scenario.replace(imu=pocketed), simulate_walk(scenario))
    stream = StreamingPdr(CONFIG)
    streamed = _stream(imu, _every(imu, 1.0), stream)
    batch = _batch(imu)
    assert batch.carriage_changes == 1 and batch.walking_used and stream.walking_used
    assert len(streamed["t_s"]) == len(batch.steps) > 20
    turn = np.angle(np.exp(1j * (streamed["heading_rad"] - batch.steps.heading_rad)))
    assert np.degrees(np.abs(turn)).max() <= 2.0


def test_a_real_trace_gives_the_batch_steps():
    """Accelerometer only (no gyro, no magnetometer): the count and the step times."""
    folder = data_set_walks(OXFORD, "optimisation")[0]
    rows = np.loadtxt(folder / "accelerometer.csv", delimiter=",", usecols=(0, 2, 3, 4))  # time (ns), x, y, z
    t_s = (rows[:, 0] - rows[0, 0]) * 1e-9
    grid = uniform_grid(t_s[0], min(t_s[-1], 40.0), RATE_HZ)
    zeros = np.zeros((len(grid), 3))
    imu = ImuLog(t_s=grid, acc_mps2=interpolate(t_s, rows[:, 1:], grid), gyro_radps=zeros, mag_ut=zeros)
    _assert_as_batch(_stream(imu, _every(imu, 0.7)), imu)


def test_standing_still_gives_no_steps():
    imu = _imu("hand")
    still = imu.select(imu.t_s < 4.5)
    stream = StreamingPdr(CONFIG)
    assert len(_stream(still, _every(still, 0.5), stream)["t_s"]) == 0
    assert stream.carriage == "unknown" and not stream.walking_used and len(stream.provisional()) == 0


def test_a_stream_off_its_grid_is_refused():
    imu = _imu("hand")
    stream = StreamingPdr(CONFIG)
    stream.add(imu.select(slice(0, 100)))
    with pytest.raises(ValueError, match="uniform grid"):
        stream.add(imu.select(slice(150, 200)))
