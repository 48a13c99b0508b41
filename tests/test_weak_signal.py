"""Weak signals (dtmbnav.evaluation.weak_signal): the table's rows and format, and the tiny walk received above and below
the C/N at which the receiver can lock. ``python -m dtmbnav.evaluation.weak_signal`` prints the full table."""

from pathlib import Path

import numpy as np
import pytest
from fusion_synth import exact_paths, exact_ranges, park_like_walk

from dtmbnav.evaluation.weak_signal import (MAX_PF_OVER_FIX, WeakSignalWalk, per_walk_table, run_case, summarise,
                                 weak_signal_table)
from dtmbnav_core.records import RangeSeries, Track
from fusion import DEFAULT_SI_RANGE_USE
from fusion.metrics import error_stats, place_pdr, position_errors_m
from fusion.run import FusionConfig, fuse
from sim.scenario import load_scenario

TINY = Path(__file__).parent / "data" / "tiny-walk.toml"


def _walk(cn_db: float, k: int, pf: float | None, usable: int = 900, at_fix: float = 4.0) -> WeakSignalWalk:
    """A walk of 1000 frames sent; ``pf`` None: no lock."""
    if pf is None:
        return WeakSignalWalk("park", cn_db, k, k, 1000, 0, 0, np.nan, np.nan, np.nan, None)
    return WeakSignalWalk("park", cn_db, k, k, 1000, 950, usable, 0.5, 0.02, 0.8,
                          {"pdr": 6.0, "pdr@fix": at_fix, "pf": pf})


def test_rows_average_the_walks_and_flag_a_walk_made_worse():
    walks = [_walk(10.0, 0, 2.0), _walk(10.0, 1, 3.0, usable=700, at_fix=2.0),
             _walk(-5.0, 0, None), _walk(-5.0, 1, None)]
    ten, minus_five = summarise(walks)
    assert (ten.walks, ten.locked) == (2, 2)
    assert ten.lock_rate == pytest.approx(0.8) and ten.received_share == pytest.approx(0.95)
    assert ten.pf_p95_m == pytest.approx(2.5) and ten.pdr_at_fix_p95_m == pytest.approx(3.0)
    assert ten.reduction == pytest.approx(1 - 2.5 / 6.0) and ten.reduction_at_fix == pytest.approx(1 - 2.5 / 3.0)
    # Walk 1's PF is 1.5 times its PDR@fix: the row fails although the mean PF is below the mean PDR@fix.
    assert ten.worst_at_fix == pytest.approx(0.5) and ten.walks_worse == 1
    assert (minus_five.locked, minus_five.lock_rate, minus_five.walks_worse) == (0, 0.0, 0)
    assert np.isnan(minus_five.pf_p95_m) and np.isnan(minus_five.si_range_p95_m)
    table, failed = weak_signal_table([ten, minus_five])
    assert failed == 1
    lines = table.splitlines()
    assert len(lines) == 4 and all(line.count("|") == lines[0].count("|") for line in lines)
    assert "| park | 10 dB | 2 of 2 | 80.0 % (95.0 %) |" in lines[2] and "2.50 m (58.3 % / 16.7 %)" in lines[2]
    assert "| park | -5 dB | 0 of 2 | no lock |" in lines[3] and "nothing fused" in lines[3]
    assert "no lock" in per_walk_table(walks).splitlines()[-1]
    # One walk just inside the bound does not fail the row.
    assert weak_signal_table(summarise([_walk(10.0, 0, MAX_PF_OVER_FIX * 3.99, at_fix=4.0)]))[1] == 0


@pytest.fixture(scope="module")
def tiny():
    return load_scenario(TINY)


@pytest.mark.slow
def test_the_tiny_walk_at_15_db_locks_ranges_and_fuses(tiny):
    walk = run_case(tiny, 15.0, 0, first_seed=100)
    # 1800 frames a second over the whole capture, nearly all usable.
    assert walk.frames_sent == pytest.approx(1800 * 13.86, abs=2) and walk.lock_rate > 0.98
    assert walk.si_range_p95_m < 0.1 and walk.first_path_range_p95_m < 0.05 and walk.first_path_share > 0.9
    assert set(walk.p95_m) == {"pdr", "pdr@fix", "pf"} and walk.pf_over_fix < MAX_PF_OVER_FIX


@pytest.mark.slow
def test_far_below_its_lock_threshold_the_receiver_reports_no_lock(tiny):
    """At C/N -15 dB the receiver finds no signal: the walk says so, with no frame, range or fused track."""
    walk = run_case(tiny, -15.0, 0, first_seed=100)
    assert not walk.locked and walk.frames_received == walk.frames_usable == 0 and walk.lock_rate == 0.0
    assert walk.frames_sent > 20_000 and walk.p95_m is None and np.isnan(walk.si_range_p95_m)
    table, failed = weak_signal_table(summarise([walk]))
    assert "no lock" in table.splitlines()[2] and failed == 0


# --- a weak SI carrier cannot outvote a clean first path ------------------------------------------

#: SI-carrier SNR the receiver measures at C/N -5 dB (the SI carriers' slice of the band sits a dB or two below
#: the C/N).
WEAK_SI_SNR_DB = -6.0


def test_a_weak_si_range_cannot_outvote_a_clean_first_path():
    """A weak SI carrier's range wanders (a random walk of its phase, 0.5 m per root second) next to an exact
    first path. The filters take the SI range only where no first path is observed, so the PF's track is the one
    it makes of the first path alone, as good as without the SI carriers at all; weighed at every epoch
    (``si_range="always"``) the same range drags the PF off it."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=2, laps=2)
    exact = exact_ranges(walk)
    dt = np.diff(exact.t_s, prepend=exact.t_s[0])
    wander = np.cumsum(0.5 * np.sqrt(dt) * np.random.default_rng(0).standard_normal(len(dt)))
    pdr = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad), walk.truth)).p95_m

    def pf_track(valid: bool, use: str = DEFAULT_SI_RANGE_USE) -> Track:
        si = RangeSeries(exact.t_s, exact.range_change_m + wander, np.full(len(exact), WEAK_SI_SNR_DB),
                         np.full(len(exact), valid))
        return fuse(walk.pdr, si, (0.0, 0.0), (walk.geometry.tower_x_m, walk.geometry.tower_y_m), ("pf",),
                    tower_height_m=walk.geometry.tower_height_m, paths=exact_paths(walk),
                    config=FusionConfig(n_particles=1000, si_range=use)).tracks["pf"]

    alone, weak_si = pf_track(valid=False), pf_track(valid=True)
    np.testing.assert_array_equal(weak_si.x_m, alone.x_m)
    np.testing.assert_array_equal(weak_si.y_m, alone.y_m)
    first_path = error_stats(position_errors_m(alone, walk.truth)).p95_m
    assert first_path < 0.35 * pdr, (first_path, pdr)
    always = error_stats(position_errors_m(pf_track(valid=True, use="always"), walk.truth)).p95_m
    assert always > 1.5 * first_path, (always, first_path)
