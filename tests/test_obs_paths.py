"""Observation-level path tracker: what it separates and merges, and its ranges against the true geometry."""

import numpy as np
import pytest
from fusion_synth import loop_truth
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.channel import Channel
from sim.obs_paths import (ObsPathConfig, first_path_kernel, first_path_reference, pulse_gain_table,
                           simulate_obs_paths)
from sim.obs_range import exact_range
from sim.scenario import load_scenario

CONFIG = ObsPathConfig()
SURVIVAL = 10.0 ** (CONFIG.survival_snr_db / 10.0)
WEAK = 10.0 ** (-CONFIG.weak_power_db / 10.0)
PULSE = pulse_gain_table()


def first_path(power_db, delay_chips, phase_rad=None, snr_db=30.0):
    """The kernel on one time: paths of the given power (dB), delay (chips) and phase; tap SNR relative to 0 dB."""
    power = 10.0 ** (np.asarray(power_db, float) / 10.0)
    phase = np.zeros(len(power)) if phase_rad is None else np.asarray(phase_rad, float)
    coef = (np.sqrt(power) * np.exp(1j * phase))[:, None]
    tap_snr = (power * 10.0 ** (snr_db / 10.0))[:, None]
    delay = np.asarray(delay_chips, float)[:, None]
    identity, amplitude, _, _ = first_path_kernel(coef, delay, tap_snr, SURVIVAL, WEAK, CONFIG.min_separation_chips,
                                                  CONFIG.weak_separation_chips, PULSE, np.array([-1, 0]))
    return int(identity[0]), complex(amplitude[0])


def test_a_path_half_a_chip_before_one_8_db_stronger_is_tracked_apart():
    identity, amplitude = first_path([-8.0, 0.0], [10.0, 10.5], [1.0, 0.0])
    assert identity == 0
    assert amplitude == pytest.approx(10.0 ** (-8.0 / 20.0) * np.exp(1j))


def test_a_direct_path_22_db_under_a_reflection_under_a_chip_later_merges_into_it():
    # The street corner (docs/paths.md): the fit sits on the reflection, whose phase the first path then follows.
    identity, amplitude = first_path([-22.0, 0.0], [10.0, 10.6], [2.0, 0.0])
    assert identity == 1
    g = np.interp(-0.6, np.linspace(-4.0, 4.0, len(PULSE)), PULSE)
    assert amplitude == pytest.approx(1.0 + 10.0 ** (-22.0 / 20.0) * g * np.exp(2j), rel=1e-3)
    assert abs(np.angle(amplitude)) < 0.1


def test_a_direct_path_20_db_under_a_reflection_two_chips_later_is_the_first_path():
    identity, amplitude = first_path([-20.0, 0.0], [10.0, 12.0])
    assert identity == 0 and abs(amplitude) == pytest.approx(0.1, rel=1e-3)


def test_paths_closer_than_the_separation_are_one_path_and_a_path_below_survival_is_none():
    identity, amplitude = first_path([0.0, 0.0], [10.0, 10.2], [0.0, np.pi / 2])
    g = np.interp(0.2, np.linspace(-4.0, 4.0, len(PULSE)), PULSE)
    assert identity == 0 and amplitude == pytest.approx(1.0 + 1j * g, rel=1e-3)
    # The earlier path is below the survival SNR: the later one is the first path.
    assert first_path([-40.0, 0.0], [5.0, 10.0], snr_db=40.0)[0] == 1
    assert first_path([0.0], [5.0], snr_db=CONFIG.survival_snr_db - 1.0) == (-1, 0j)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 8), st.integers(-1, 5), st.integers(0, 1), st.integers(0, 2**31 - 1))
def test_kernel_matches_its_numpy_reference(n_paths, n_times, held, swallowed, seed):
    held = min(held, n_paths - 1)
    rng = np.random.default_rng(seed)
    coef = (rng.standard_normal((n_paths, n_times)) + 1j * rng.standard_normal((n_paths, n_times))) * \
        10.0 ** (rng.uniform(-3.0, 0.0, (n_paths, 1)))
    delay = rng.uniform(0.0, 3.0, (n_paths, n_times))
    tap_snr = np.abs(coef) ** 2 * 10.0 ** rng.uniform(0.0, 3.0)
    args = (SURVIVAL, WEAK, CONFIG.min_separation_chips, CONFIG.weak_separation_chips, PULSE)
    k_held, r_held = np.array([held, swallowed]), np.array([held, swallowed])
    k_id, k_amp, k_broken, k_anchor = first_path_kernel(coef, delay, tap_snr, *args, k_held)
    r_id, r_amp, r_broken, r_anchor = first_path_reference(coef, delay, tap_snr, *args, r_held)
    np.testing.assert_array_equal(k_id, r_id)
    np.testing.assert_array_equal(k_broken, r_broken)
    np.testing.assert_array_equal(k_anchor, r_anchor)
    np.testing.assert_array_equal(k_held, r_held)
    np.testing.assert_allclose(k_amp, r_amp, rtol=1e-9, atol=1e-12)


@pytest.fixture(scope="module")
def park():
    scn = load_scenario("park-loop-cw")
    truth = loop_truth(scn)
    return scn, truth, simulate_obs_paths(scn, truth)


def test_line_of_sight_first_path_follows_the_direct_path(park):
    scn, truth, paths = park
    fp = paths.first_path
    exact = exact_range(scn, truth)
    np.testing.assert_array_equal(fp.t_s, exact.t_s)
    assert fp.valid.mean() > 0.98 and not fp.valid[fp.t_s < CONFIG.confirm_s].any()
    # One run from the first report: a single origin (its start), the age growing with time.
    assert np.count_nonzero(fp.slip) == 1 and fp.slip[np.argmax(fp.valid)]
    first = np.argmax(fp.valid)
    error = (fp.range_change_m - exact.range_change_m)[fp.valid]
    error -= error[0]
    # Centimetres over the whole loop (the diffuse taps within a chip ripple the phase; the clock is disciplined).
    assert np.abs(error).max() < 0.2
    assert np.abs(error).max() > 1e-3   # not the exact range
    np.testing.assert_allclose(fp.path_age_s[fp.valid], fp.t_s[fp.valid] - fp.t_s[first])
    # Per-sample SNR of the unobstructed direct path: near the C/N (the header is boosted above the body).
    assert np.median(fp.snr_db[fp.valid]) == pytest.approx(scn.receiver.cn_db, abs=3.0)
    # The code range is the direct path's range up to a constant, with decimetres of error at this SNR.
    code_error = (fp.code_range_m - exact.range_change_m)[fp.valid]
    code_error -= np.median(code_error)
    assert 0.01 < np.std(code_error) < 0.3 and np.abs(code_error).max() < 1.5
    assert np.isnan(fp.code_range_m[~fp.valid & (fp.t_s < CONFIG.confirm_s)]).all()


def test_the_output_does_not_depend_on_the_block_length(park):
    scn, truth, paths = park
    other = simulate_obs_paths(scn, truth, block_samples=1000)
    for name in ("range_change_m", "snr_db", "valid", "slip", "path_age_s", "code_range_m"):
        np.testing.assert_array_equal(getattr(other.first_path, name), getattr(paths.first_path, name))


def test_tower_difference_cancels_a_free_running_clock():
    scn = load_scenario("sfn-park")
    truth = loop_truth(scn)
    paths = simulate_obs_paths(scn, truth)
    channel = Channel(scn, truth, np.random.default_rng(0))
    t = paths.first_path.t_s
    r0, r1 = channel.direct(t, 0).range_m, channel.direct(t, 1).range_m
    single = (paths.first_path.range_change_m - (r0 - r0[0]))[paths.first_path.valid]
    difference = paths.differences[1]
    d_err = (difference.range_change_m - (r1 - r0 - (r1 - r0)[np.argmax(difference.valid)]))[difference.valid]
    # The single-tower first path carries the TCXO's drift (metres); the difference only centimetres.
    assert np.ptp(single) > 5.0
    assert np.abs(d_err).max() < 0.1
    assert difference.valid.mean() > 0.98


def test_a_held_first_path_is_swallowed_by_a_reflection_that_closes_in_and_restarts_when_it_leaves():
    # The street corner over three times: a wall reflection 17 dB above the diffracted direct path moves from
    # 1 chip behind it to 0.5 chip (the fit cannot separate them: the phase follows the wall) and back to 0.8.
    power_db = np.array([-22.0, -5.0])
    coef = (10.0 ** (power_db / 20.0) * np.exp(1j * np.array([0.0, 2.0])))[:, None] * np.ones((1, 3))
    delay = np.array([[10.0, 10.0, 10.0], [11.0, 10.5, 10.8]])
    tap_snr = np.abs(coef) ** 2 * 1e4
    held = np.array([-1, 0])
    identity, amplitude, broken, anchor = first_path_kernel(coef, delay, tap_snr, SURVIVAL, WEAK,
                                                         CONFIG.min_separation_chips, CONFIG.weak_separation_chips,
                                                         PULSE, held)
    assert identity.tolist() == [0, 0, 0]           # one path to the tracker throughout: no new origin there
    assert anchor.tolist() == [0, 1, 0]             # the fit finds the wall's delay while it swallows the path
    assert abs(np.angle(amplitude[0])) < 1e-9       # the direct path alone
    assert abs(np.angle(amplitude[1]) - 2.0) < 0.1  # swallowed: the wall's phase
    assert broken.tolist() == [False, False, True]  # separated again: its phase restarts
    assert abs(np.angle(amplitude[2])) < 1e-9
    assert held.tolist() == [0, 0]
