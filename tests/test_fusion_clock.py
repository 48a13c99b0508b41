"""The free-running clock state: its noise from the Allan deviation, its observation at standstills, its worth."""

import numpy as np
import pytest
from fusion_synth import clock_range_m, exact_ranges, park_like_walk

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import RangeSeries
from fusion import particle_filter as pf
from fusion.integrity import IntegrityConfig
from fusion.metrics import error_stats, place_pdr, position_errors_m
from fusion.model import ClockModel
from fusion.observations import aggregate_ranges, build_epochs, epoch_times
from fusion.run import FILTERS, FusionConfig

TCXO = {"allan_deviation": 1.6e-9, "allan_tau_s": 100.0}  # docs/paths.md: a TCXO at 100 s
PAUSES = ((40.0, 8.0), (90.0, 8.0), (150.0, 8.0), (200.0, 8.0))  # a stop every 30-50 s of walking


def test_clock_process_noise_has_the_allan_deviation_it_is_given():
    """A rate drawn with the model's per-step covariance has the given Allan deviation at the given tau."""
    clock = ClockModel("free-running", **TCXO)
    step_s = 0.5
    rng = np.random.default_rng(0)
    rate = np.cumsum(rng.standard_normal(400_000) * np.sqrt(clock.process_covariance(step_s)[1, 1]))
    y = rate / SPEED_OF_LIGHT_MPS                                  # fractional frequency
    per_tau = int(TCXO["allan_tau_s"] / step_s)
    means = y[: len(y) // per_tau * per_tau].reshape(-1, per_tau).mean(axis=1)
    adev = np.sqrt(0.5 * np.mean(np.diff(means) ** 2))
    assert adev == pytest.approx(TCXO["allan_deviation"], rel=0.15)  # 2000 averages: about 3 % of scatter
    # A disciplined clock's states (an option) carry its holdover wander: the preset's 1e-12 at 1 s; without
    # them (the default), nothing. A free-running clock always has them.
    assert ClockModel(state=True).has_state and not ClockModel(state=True).free_running
    assert ClockModel().rate_psd_m2ps3() == pytest.approx(SPEED_OF_LIGHT_MPS**2 * 3.0 * 1e-24)
    assert not ClockModel().has_state and ClockModel("free-running").has_state
    np.testing.assert_array_equal(ClockModel().process_covariance(1.0), np.zeros((2, 2)))


def test_a_standstill_observes_the_clock_rate():
    """Standing 20 s: the particle filter's clock rate ends within its stated uncertainty of the true one, which the
    standstill shrinks below what the steps alone leave."""
    walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=2, pauses=((60.0, 20.0),))
    ranges = exact_ranges(walk)
    clock_m = clock_range_m(ranges.t_s, seed=4, **TCXO)
    drifting = RangeSeries(ranges.t_s, ranges.range_change_m + clock_m, ranges.snr_db, ranges.valid)
    true_rate = np.gradient(clock_m, ranges.t_s)
    config = FusionConfig(clock_model="free-running", clock_allan_deviation=TCXO["allan_deviation"],
                          clock_allan_tau_s=TCXO["allan_tau_s"])
    errors, sigmas = {}, {}
    for label, standstills in (("standstills", config.standstills), ("steps only", None)):
        epochs = build_epochs(walk.pdr, aggregate_ranges(drifting, epoch_times(walk.pdr.t_s, 0.0, standstills)),
                              walk.initial_heading_rad)
        f = pf.ParticleFilter(walk.geometry, n_particles=1000, seed=1, clock=config.clock())
        f.initialise(*epochs.initial_heading_speed())
        after_pause = int(np.searchsorted(epochs.t_s, walk.pdr.t_s[np.argmax(np.diff(walk.pdr.t_s)) + 1]))
        for n in range(after_pause):
            f.predict(epochs.control(n))
            f.update(epochs.observation(n))
        errors[label] = abs(f.clock_rate_mps - np.interp(epochs.t_s[after_pause - 1], ranges.t_s, true_rate))
        rate = f.linear.shape[1] - 1
        sigmas[label] = np.sqrt(f.linear_cov[rate, rate] + np.cov(f.linear[:, rate], aweights=f.weights))
    for label, error in errors.items():
        assert error < 3 * sigmas[label], (errors, sigmas)
    assert sigmas["standstills"] < sigmas["steps only"], sigmas
    assert errors["standstills"] < errors["steps only"], errors


@pytest.mark.parametrize("name", ["pf", "ukf", "adaptive-kf", "rank-kf"])
def test_clock_drift_before_the_first_epoch_does_not_move_the_start(name):
    """A free-running clock drifted 1.7 m of range between the capture start and the first epoch (the range is a
    change since the capture start): every filter still stands at the fix through the first standstill."""
    walk = park_like_walk(seed=0)
    ranges = exact_ranges(walk)
    drifting = RangeSeries(ranges.t_s, ranges.range_change_m - np.minimum(ranges.t_s, 1.0) * 1.7, ranges.snr_db,
                           ranges.valid)
    config = FusionConfig(n_particles=1000, clock_model="free-running", clock_allan_deviation=TCXO["allan_deviation"],
                          clock_allan_tau_s=TCXO["allan_tau_s"])
    t = epoch_times(walk.pdr.t_s, 0.0, config.standstills)
    epochs = build_epochs(walk.pdr, aggregate_ranges(drifting, t), walk.initial_heading_rad)
    track = FILTERS[name](epochs, walk.geometry, config)
    error_m = position_errors_m(track, walk.truth)
    assert error_m[0] < 0.3, error_m[:3]                   # the first step: the walker set off from P0


@pytest.mark.parametrize("name", ["pf", "ukf"])
def test_the_clock_state_keeps_a_tcxo_range_from_dragging_the_track(name):
    """Walks with stops and a TCXO-drifting range: with the clock state the 95 % error stays below the PDR's
    and far below the filter's without it (integrity monitor off there: the filter as it was)."""
    with_clock, without = [], []
    for seed in range(3):
        walk = park_like_walk(gain=1.1, drift_dps=0.2, seed=seed, laps=2, pauses=PAUSES)
        ranges = exact_ranges(walk)
        drifting = RangeSeries(ranges.t_s, ranges.range_change_m + clock_range_m(ranges.t_s, seed=seed, **TCXO),
                               ranges.snr_db, ranges.valid)
        pdr95 = error_stats(position_errors_m(place_pdr(walk.pdr, 0.0, 0.0, walk.initial_heading_rad),
                                              walk.truth)).p95_m
        for errors, config in ((with_clock, FusionConfig(n_particles=1000, clock_model="free-running",
                                                         clock_allan_deviation=TCXO["allan_deviation"],
                                                         clock_allan_tau_s=TCXO["allan_tau_s"])),
                               (without, FusionConfig(n_particles=1000, clock_state=False,
                                                      integrity=IntegrityConfig(enabled=False)))):
            t = epoch_times(walk.pdr.t_s, 0.0, config.standstills if config.clock().free_running else None)
            epochs = build_epochs(walk.pdr, aggregate_ranges(drifting, t), walk.initial_heading_rad)
            track = FILTERS[name](epochs, walk.geometry, config)
            errors.append(error_stats(position_errors_m(track, walk.truth)).p95_m / pdr95)
    assert max(with_clock) < 1.0, with_clock
    assert np.mean(with_clock) < 0.6 * np.mean(without), (with_clock, without)


def test_the_disciplined_clock_state_takes_a_holdover_drift():
    """Three laps (280 s) with a disciplined clock's holdover drift, a rate ramp to 0.024 m/s (3 m of range at
    250 s, three times the 1e-12 preset's sigma there): the UKF with the clock states ends at least 0.15 m closer to
    the truth (95 %) than without them on every walk, and on the exact range they cost it under 0.1 m."""
    for seed in range(3):
        walk = park_like_walk(gain=1.05, drift_dps=0.1, seed=seed, laps=3)
        ranges = exact_ranges(walk)
        drift_m = 0.5 * (2.0 * 3.0 / 250.0**2) * np.maximum(ranges.t_s - 10.0, 0.0) ** 2
        drifting = RangeSeries(ranges.t_s, ranges.range_change_m + drift_m, ranges.snr_db, ranges.valid)
        p95 = {}
        for label, series in (("drift", drifting), ("exact", ranges)):
            epochs = build_epochs(walk.pdr, aggregate_ranges(series, epoch_times(walk.pdr.t_s, 0.0)),
                                  walk.initial_heading_rad)
            for state in (True, False):
                track = FILTERS["ukf"](epochs, walk.geometry, FusionConfig(clock_state=state))
                p95[label, state] = error_stats(position_errors_m(track, walk.truth)).p95_m
        assert p95["drift", True] < p95["drift", False] - 0.15, p95
        assert p95["exact", True] < p95["exact", False] + 0.1, p95
