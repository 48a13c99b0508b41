"""The range integrity monitor: a bent range is dropped and the filters fall back on the PDR, a good one is kept."""

import dataclasses

import numpy as np
import pytest
from fusion_synth import exact_ranges, park_like_walk, path_series, ranges_with_blockage, true_ranges

from dtmbnav_core.records import RangeSeries
from fusion import particle_filter as pf
from fusion.integrity import IntegrityConfig, IntegrityMonitor
from fusion.metrics import error_stats, place_pdr, position_errors_m
from fusion.model import Geometry, ModelNoise, StepControl, propagate
from fusion.observations import aggregate_paths, aggregate_ranges, build_epochs
from dtmbnav_core.records import PathRanges
from fusion.run import FILTERS, FusionConfig
from fusion.ukf import RangePdrUkf

BEND_START_S, BEND_S = 60.0, 60.0


def bent_walk(rate_mps):
    """Two laps with a drifting PDR; from 60 s on, for 60 s, the range bends at ``rate_mps`` (a reflection's Doppler)
    and keeps what it gathered afterwards."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=0, laps=2)
    ranges = exact_ranges(walk)
    bend = rate_mps * np.clip(ranges.t_s - BEND_START_S, 0.0, BEND_S)
    epochs = build_epochs(walk.pdr, aggregate_ranges(RangeSeries(ranges.t_s, ranges.range_change_m + bend,
                                                                 ranges.snr_db, ranges.valid), walk.pdr.t_s),
                          walk.initial_heading_rad)
    pdr_at_fix95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad),
                                                 walk.truth)).p95_m
    return walk, epochs, pdr_at_fix95


@pytest.fixture(scope="module", params=[0.5, 1.0])
def bent(request):
    return bent_walk(request.param)


@pytest.mark.parametrize("name", list(FILTERS))
def test_no_filter_is_dragged_beyond_the_pdr_by_a_bent_range(bent, name):
    """The start fix is the true start here, so the PDR at the fix is the PDR placed at the truth."""
    walk, epochs, pdr_at_fix95 = bent
    fused95 = error_stats(position_errors_m(FILTERS[name](epochs, walk.geometry, FusionConfig(n_particles=1000)),
                                            walk.truth)).p95_m
    assert fused95 <= 1.05 * pdr_at_fix95, (fused95, pdr_at_fix95)


@pytest.mark.parametrize("name", ["pf", "ukf"])
def test_without_the_monitor_the_bent_range_drags_the_track(name):
    walk, epochs, pdr_at_fix95 = bent_walk(0.5)
    config = FusionConfig(n_particles=1000, integrity=IntegrityConfig(enabled=False))
    fused95 = error_stats(position_errors_m(FILTERS[name](epochs, walk.geometry, config), walk.truth)).p95_m
    assert fused95 > 1.5 * pdr_at_fix95, (fused95, pdr_at_fix95)


def run_epochs(f, epochs, start_s, end_s):
    """Predict and update over the epochs with start_s <= t < end_s."""
    for n in range(*np.searchsorted(epochs.t_s, [start_s, end_s])):
        f.predict(epochs.control(n))
        f.update(epochs.observation(n))


def test_the_bend_is_dropped_within_seconds_and_the_range_returns_as_a_new_origin():
    walk, epochs, _ = bent_walk(1.0)
    f = RangePdrUkf(walk.geometry, ModelNoise(), *epochs.initial_heading_speed())
    run_epochs(f, epochs, 0.0, BEND_START_S)
    assert f.monitor.dropped_epochs[0] == 0 and f.monitor.fallbacks == 0
    run_epochs(f, epochs, BEND_START_S, BEND_START_S + 5.0)
    assert f.monitor.fallbacks == 1 and f.monitor.dropped_epochs[0] > 0
    origin = f.start_range_m
    run_epochs(f, epochs, BEND_START_S + 5.0, np.inf)
    assert f.monitor._in_use[0]                               # back after the bend ended
    assert abs(f.start_range_m - origin) > 20.0               # re-anchored: the bend left 60 m in the range


@pytest.mark.parametrize("name", ["pf", "ukf"])
def test_the_fallback_undoes_a_bend_from_before_a_new_origin(name):
    """A path tracker slides onto a reflection (the range bends 1 m/s from 60 s), then re-acquires it (a new origin
    at 63 s, before the bend is caught). The new origin restarts the channel's test, but the track was dragged
    before it: the fallback must go back past the new origin (street-out: the track was 10 m off when the
    re-acquired range failed its test)."""
    walk, epochs, pdr_at_fix95 = bent_walk(1.0)
    reacquired = epochs.range_new_origin.copy()
    reacquired[np.searchsorted(epochs.t_s, BEND_START_S + 3.0)] = True
    epochs = dataclasses.replace(epochs, range_new_origin=reacquired)
    fused95 = error_stats(position_errors_m(FILTERS[name](epochs, walk.geometry, FusionConfig(n_particles=1000)),
                                            walk.truth)).p95_m
    assert fused95 <= 1.05 * pdr_at_fix95, (fused95, pdr_at_fix95)


@pytest.mark.parametrize("runner", [lambda e, g: pf.run_particle_filter(e, g, n_particles=500, seed=1),
                                    lambda e, g: FILTERS["rank-kf"](e, g, FusionConfig())])
def test_a_good_range_is_never_dropped_and_a_gap_may_end_off(runner, monkeypatch):
    """Exact ranges, and a 20 s gap the range comes back from 8 m off (the filters allow a jump across a gap)."""
    dropped = []
    original = pf.IntegrityMonitor.assess

    def spy(self, z, new_origin, code_m=None):
        use, reanchor, fallback = original(self, z, new_origin, code_m)
        dropped.append(bool(np.any(np.isfinite(z) & ~use)) or fallback is not None)
        return use, reanchor, fallback

    monkeypatch.setattr(pf.IntegrityMonitor, "assess", spy)
    for seed, ranges in ((4, None), (4, (40.0, 60.0, 8.0))):
        walk = park_like_walk(gain=1.15, seed=seed)
        series = exact_ranges(walk) if ranges is None else ranges_with_blockage(walk, *ranges)
        runner(build_epochs(walk.pdr, aggregate_ranges(series, walk.pdr.t_s), walk.initial_heading_rad),
               walk.geometry)
    assert dropped and not any(dropped)


@pytest.mark.parametrize("make", [lambda g, e: RangePdrUkf(g, ModelNoise(), *e.initial_heading_speed()),
                                  lambda g, e: pf.ParticleFilter(g, n_particles=1000)])
def test_a_slow_bend_of_a_weak_range_is_dropped_though_its_sigma_is_large(make):
    """A street's direct path, 20 dB down, has a 1.5 m sigma for the filters to weigh it by; most of that error is
    an offset that a change cancels, so the test of the change must not hide a 0.4 m/s bend behind it (dropped here
    after 10.5 s, 4 m; with the sigma counted in the test it never was)."""
    walk, epochs, _ = bent_walk(0.4)
    weak = dataclasses.replace(epochs, range_sigma_m=np.where(np.isfinite(epochs.range_sigma_m), 1.5, np.nan))
    f = make(walk.geometry, weak)
    if isinstance(f, pf.ParticleFilter):
        f.initialise(*weak.initial_heading_speed())
    run_epochs(f, weak, 0.0, BEND_START_S)
    assert f.monitor.fallbacks == 0
    run_epochs(f, weak, BEND_START_S, BEND_START_S + 15.0)
    assert f.monitor.fallbacks == 1 and f.monitor.dropped_epochs[0] > 0


def coded_first_path_epochs(walk, code_excess_m, carrier_bend_m=np.zeros_like):
    """Epochs with a first path to the tower: its carrier range errs by ``carrier_bend_m(t)``, its code range is the
    range plus 1000 m plus ``code_excess_m(t)``."""
    t, r = true_ranges(walk, 50.0)
    series = dataclasses.replace(path_series(t, r + carrier_bend_m(t)), code_range_m=1000.0 + r + code_excess_m(t))
    paths = aggregate_paths(PathRanges(first_path={0: series}), walk.pdr.t_s, 1)
    return build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s), walk.initial_heading_rad,
                        paths)


@pytest.mark.parametrize("make", [lambda g, e, c: RangePdrUkf(g, ModelNoise(), *e.initial_heading_speed(), integrity=c),
                                  lambda g, e, c: pf.ParticleFilter(g, n_particles=1000, integrity=c)])
@pytest.mark.parametrize("gate", [True, False])
def test_a_first_path_whose_code_arrives_late_is_kept_from_the_filter(make, gate):
    """A reflection taken for the first path from 60 to 90 s: its carrier range is right here, but its code range
    arrives 8 m late; the monitor keeps exactly those epochs' first path from the filter (when the gate is on)."""
    walk = park_like_walk(gain=1.05, seed=2)
    epochs = coded_first_path_epochs(walk, lambda t: np.where((t >= 60.0) & (t < 90.0), 8.0, 0.0))
    f = make(walk.geometry, epochs, IntegrityConfig(code_gate=gate))
    if isinstance(f, pf.ParticleFilter):
        f.initialise(*epochs.initial_heading_speed())
    monitor = f.monitor  # the first path is range channel 1
    run_epochs(f, epochs, 0.0, 59.8)
    assert monitor.late_epochs[1] == 0
    run_epochs(f, epochs, 59.8, 90.2)
    inside = np.count_nonzero((epochs.t_s > 60.2) & (epochs.t_s < 89.8))
    if gate:
        assert inside <= monitor.late_epochs[1] <= inside + 2
    else:
        assert monitor.late_epochs[1] == 0
    late = monitor.late_epochs[1]
    run_epochs(f, epochs, 90.2, np.inf)
    assert monitor.late_epochs[1] == late
    assert monitor.dropped_epochs[1] == 0 and monitor.fallbacks == 0   # the carrier itself never was inconsistent


def test_with_code_change_m_a_late_path_is_kept_until_its_excess_changes():
    """8 m late from 60 to 120 s; its excess grows by 0.5 m/s from 90 s (a corner): kept to about 96 s, then dropped
    to the end of the stretch."""
    walk = park_like_walk(gain=1.05, seed=2)

    def excess(t):
        return np.where((t >= 60.0) & (t < 120.0), 8.0 + 0.5 * np.clip(t - 90.0, 0.0, None), 0.0)

    epochs = coded_first_path_epochs(walk, excess)
    f = RangePdrUkf(walk.geometry, ModelNoise(), *epochs.initial_heading_speed(),
                    integrity=IntegrityConfig(code_change_m=3.0))
    run_epochs(f, epochs, 0.0, 95.0)
    assert f.monitor.late_epochs[1] == 0
    run_epochs(f, epochs, 95.0, 120.2)
    dropped = np.count_nonzero((epochs.t_s > 97.0) & (epochs.t_s < 119.8))
    assert dropped <= f.monitor.late_epochs[1] <= dropped + 4
    late = f.monitor.late_epochs[1]
    run_epochs(f, epochs, 120.2, np.inf)
    assert f.monitor.late_epochs[1] == late


@pytest.mark.parametrize("name", ["pf", "ukf"])
def test_a_reflection_that_bends_round_a_corner_does_not_drag_the_track(name):
    """The street's case: from 40 s the tracker follows a wall reflection 6 m late, whose carrier follows the range
    for 20 s and then bends away at 0.15 m/s for 80 s (slowly enough for the carrier's own test to let it through).
    With the code gate the track stays better than the PDR; without it, it is dragged (to 15 m here for the PF)."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=0, laps=2)

    def bend(t):
        return -0.15 * np.clip(t - 60.0, 0.0, 80.0)

    epochs = coded_first_path_epochs(walk, lambda t: np.where(t >= 40.0, 6.0 - bend(t), 0.0), bend)
    pdr_at_fix95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad),
                                                 walk.truth)).p95_m
    errors = {gate: error_stats(position_errors_m(
        FILTERS[name](epochs, walk.geometry, FusionConfig(n_particles=1000, integrity=IntegrityConfig(code_gate=gate))),
        walk.truth)).p95_m for gate in (True, False)}
    assert errors[True] <= 1.05 * pdr_at_fix95, (errors, pdr_at_fix95)
    assert errors[False] > errors[True] + 1.0, (errors, pdr_at_fix95)


def test_integrity_config_is_checked():
    with pytest.raises(ValueError, match="readmit_window"):
        IntegrityConfig(window=5, readmit_window=10)
    with pytest.raises(ValueError, match="false_alarm"):
        IntegrityConfig(false_alarm=0.0)
    with pytest.raises(ValueError, match="rate_sigma_mps"):
        IntegrityConfig(rate_sigma_mps=-0.1)
    with pytest.raises(ValueError, match="code_calibration_epochs"):
        IntegrityConfig(code_calibration_epochs=0)


@pytest.mark.parametrize("reference", [True, False])
def test_a_dragged_filter_does_not_take_the_direct_path_for_a_late_one(reference):
    """The walker heads straight for a tower 3 km east, the PDR is exact and the first path is the direct one (its
    code range the range plus 1000 m). From epoch 40 the filter's posterior sits 6 m nearer the tower (dragged by
    something else): against that prior the direct path looks 6 m late. Against the PDR alone it does not, so with
    ``code_pdr_reference`` the monitor keeps it; without, it drops every epoch from there on."""
    geometry = Geometry(0.0, 0.0, 3000.0, 0.0)
    monitor = IntegrityMonitor(geometry, ModelNoise(), config=IntegrityConfig(code_pdr_reference=reference))
    control = StepControl(dt_s=0.5)
    state = np.array([0.0, 0.0, 0.0, np.pi / 2.0, 1.2])
    no_origin = np.zeros(2, dtype=bool)
    for n in range(100):
        if n:
            monitor.predict(control)
            state = propagate(state, control)
        true_range = float(geometry.range_m(state[0], state[1]))
        monitor.assess(np.array([np.nan, true_range]), no_origin, np.array([np.nan, 1000.0 + true_range]))
        dragged = state + np.array([6.0, 0.0, 0.0, 0.0, 0.0]) * (n >= 40)
        monitor.posterior(dragged, np.diag([1.0, 1.0, 1e-6, 1e-4, 1e-2]))
    assert monitor.late_epochs[1] == (0 if reference else 59)
