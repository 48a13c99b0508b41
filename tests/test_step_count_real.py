"""Step counts on real phones' traces (Oxford step counter data set, tests/data/oxford_steps/README.md).

Two real walks counted against their foot switches, the data set's readers and the
foot-switch truth's bounce rule, and the results section's table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dtmbnav.evaluation.results_data import Table
from dtmbnav.evaluation.step_count import (
    SHORT_WALK_STEPS,
    SWITCH_BOUNCE_S,
    CountedWalk,
    data_set_walks,
    short_walk_summary,
    start_and_stop,
    step_count_table,
    switch_steps,
    tuning_walk,
    validation_walk,
)
from sim.imu import simulate_imu
from sim.scenario import Scenario
from sim.walk import simulate_walk

DATA = Path(__file__).parent / "data" / "oxford_steps"


@pytest.mark.parametrize("walk", data_set_walks(DATA, "optimisation"), ids=lambda p: p.name)
def test_real_walks_counted_within_3_percent(walk):
    counted = tuning_walk(walk)
    assert counted.true_steps > 250
    assert abs(counted.ours - counted.true_steps) <= 0.03 * counted.true_steps


@pytest.mark.parametrize("walk", data_set_walks(DATA, "optimisation"), ids=lambda p: p.name)
def test_a_real_start_and_stop_are_counted_within_2_steps(walk):
    """25 steps from the phone being put away to walking, and from walking to taking it out again."""
    for part in start_and_stop(walk):
        assert part.true_steps == SHORT_WALK_STEPS
        assert abs(part.ours - part.true_steps) <= 2, part


@given(st.lists(st.floats(0.05, 2.0), min_size=1, max_size=40))
def test_a_switch_closing_within_the_bounce_time_is_the_same_step(intervals_s):
    """Closings at the given spacing: each one kept exactly when it is a bounce time after the last kept one."""
    closings_ns = np.cumsum(np.array(intervals_s) * 1e9) + 1e9
    t_ns = np.sort(np.concatenate([closings_ns - 1e6, closings_ns]))
    closed = np.tile([0, 1], len(closings_ns))  # opens 1 ms before each closing
    steps = switch_steps(t_ns, closed)
    expected, last = [], -np.inf
    for t in closings_ns:
        if t - last >= SWITCH_BOUNCE_S * 1e9:
            expected.append(t)
            last = t
    assert np.array_equal(steps, expected)


def test_a_validation_trace_gives_each_counters_increase(tmp_path):
    """The validation format: time (ns), x, y, z, then three running counts; each count is its increase."""
    scenario = Scenario(seed=5).replace(walk={"waypoints_m": [[0.0, 0.0], [0.0, 30.0]], "start_still_s": 3.0})
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    n = len(imu.t_s)
    truth = np.searchsorted(walk.step_t_s, imu.t_s) + 100
    rows = np.column_stack([imu.t_s * 1e9 + 5e12, imu.acc_mps2, truth + 3, truth, np.full(n, 7.0)])
    path = tmp_path / "user9_hand_1.csv"
    np.savetxt(path, rows, delimiter=",", fmt="%.9g", header="time,x,y,z,algo,truth,hw", comments="")
    counted = validation_walk(path)
    assert counted.true_steps == truth[-1] - truth[0] == len(walk.step_t_s)
    assert counted.app == counted.true_steps and counted.hardware is None  # a count that never moved
    assert abs(counted.ours - counted.true_steps) <= 1


def test_readers_refuse_what_is_not_the_data_set(tmp_path):
    with pytest.raises(FileNotFoundError, match="no validation walks .*git clone https://github.com/Oxford"):
        data_set_walks(tmp_path, "validation")
    bad = tmp_path / "short.csv"
    bad.write_text("1,2,3\n4,5,6\n")
    with pytest.raises(ValueError, match="expected 7 columns"):
        validation_walk(bad)


def test_the_table_gives_each_counters_error_and_their_summary():
    walks = [CountedWalk("a", 200, 204, 190, 201), CountedWalk("b", 100, 99, 130, 100)]
    text = step_count_table(walks)
    assert Table.parse(text).markdown() == text  # the results file keeps it as data
    lines = text.splitlines()
    assert lines[2] == "| a | 200 | 204 | +2.0 % | -5.0 % | +0.5 % |"
    assert lines[3] == "| b | 100 | 99 | -1.0 % | +30.0 % | +0.0 % |"
    assert lines[4] == "| **median abs error** | - | - | 1.5 % (2) | 17.5 % (2) | 0.2 % (2) |"
    assert lines[5] == "| **largest abs error** | - | - | 2.0 % (2) | 30.0 % (2) | 0.5 % (2) |"
    lines = step_count_table([CountedWalk("c", 100, 101), CountedWalk("d", 100, 97, hardware=104)]).splitlines()
    assert lines[2] == "| c | 100 | 101 | +1.0 % | — | — |"
    assert lines[-1] == "| **largest abs error** | - | - | 3.0 % (2) | — | 4.0 % (1) |"


def test_the_short_walks_summary_counts_those_within_2_steps():
    walks = [CountedWalk(str(k), 25, 25 + error) for k, error in enumerate([0, 1, -2, 3, 2, -5])]
    text = short_walk_summary(walks)
    assert Table.parse(text).markdown() == text
    assert text.splitlines()[2].startswith("| 6 | 25 | 4 | ") and text.endswith("| -5 |")
