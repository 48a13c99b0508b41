"""The simulator's SDR front-end impairments (``sim.frontend`` steps 2 to 9) against their physics and truth.

Each impairment is measured from the generated capture with receiver-side
statistics (the rails' second moments for the IQ imbalance, the mean for the
LO leakage and the ADC's DC, the level set of the codes, a Welch PSD of the
LO's phase) or compared, sample by sample, with the same capture without it
(same seed: everything else is identical). Drops are checked against the
no-drop capture at the receiver indices :meth:`sim.rf.CaptureGenerator.drops`
names; every impairment is chunk-, thread- and segment-invariant; at their
defaults the capture is the old front end's.
"""

from __future__ import annotations

import itertools
import math

import h5py
import numpy as np
import pytest
from scipy.signal import welch

from dtmbnav_core import gb20600, schema
from dtmbnav_core.h5io import read_columns
from dtmbnav_core.iqformat import encode, get_format
from dtmbnav_core.records import Track
from sim.frames import FrameConfig
from sim.frontend import (AGC_MAX_STEPS, IMPAIRMENT_DEFAULTS, FrontEnd, PhaseNoise, agc_schedule, check_impairments,
                          drop_schedule, iq_imbalance, mean_signal_power)
from sim.rf import STREAM_NOISE, CaptureGenerator
from sim.scenario import ClockConfig, FrontEndConfig, Scenario, load_scenario

RS = gb20600.SYMBOL_RATE_HZ
TOWER = np.array([2000.0, 2200.0])
PROFILE = [[1e3, -80.0], [1e4, -95.0], [1e5, -110.0], [1e6, -135.0]]
#: Every impairment on (drops included).
ALL = {"phase_noise_dbc_hz": PROFILE, "iq_gain_db": 0.7, "iq_phase_deg": -2.5, "lo_leakage_dbc": -25.0,
       "lo_leakage_phase_deg": 30.0, "agc_step_db": 1.5, "agc_steps_per_minute": 6000.0, "adc_bits": 6,
       "adc_dc_lsb": [-0.5, 0.25], "drops_per_minute": 3000.0, "drop_samples": [50, 4000]}


def walking(seconds: float = 2.0) -> Track:
    """A walk at 1.4 m/s towards the tower."""
    t = np.arange(0.0, seconds, 0.01)
    unit = TOWER / np.hypot(*TOWER)
    return Track(t, unit[0] * 1.4 * t, unit[1] * 1.4 * t, np.full_like(t, np.arctan2(unit[0], unit[1])),
                 np.full_like(t, 1.4))


def generator(seconds: float = 0.02, *, quiet: bool = False, **receiver) -> CaptureGenerator:
    """The default scenario (noise, ground ray, diffuse, ci8 at 7.56 Msps), or a direct path only with ``quiet``."""
    scn = Scenario()
    if quiet:
        scn = scn.replace(channel={"ground_reflection": False, "rician_k_db": None},
                          receiver={"clock": ClockConfig("custom", 0.0, 0.0)})
    grid = receiver.pop("grid_step_s", None)
    start_s = receiver.pop("start_s", 0.0)
    return CaptureGenerator(scn.replace(receiver=receiver), walking(), seconds=seconds, start_s=start_s,
                            grid_step_s=grid)


def capture(gen: CaptureGenerator, chunk: int = 1 << 20, jobs: int = 1, quantised: bool = False) -> np.ndarray:
    stream = gen.quantised_chunks(chunk, jobs=jobs) if quantised else gen.chunks(chunk, jobs=jobs)
    return np.concatenate(list(stream))


# ---------------------------------------------------------------- defaults

def test_defaults_run_the_old_front_end():
    explicit = generator(**IMPAIRMENT_DEFAULTS)
    plain = generator()
    fe = plain.frontend
    assert fe.phase_noise is None and fe.iq_imbalance is None and fe.leakage is None and fe.adc is None
    assert len(fe.agc_steps[0]) == 0 and len(plain.drops()) == 0 and plain.capture_samples == plain.num_samples
    rails = capture(plain, 7_777, quantised=True)
    assert capture(explicit, 1 << 20, quantised=True).tobytes() == rails.tobytes()
    # The old front end: noise added, the fixed gain, rounded to the format.
    n = plain.num_samples
    old = ((plain.clean_samples(0, n) + fe.noise(0, n)) * fe.agc_gain).astype(np.complex64)
    assert encode(old, "ci8").tobytes() == rails.tobytes()


# ---------------------------------------------------------------- validation

@pytest.mark.parametrize(("receiver", "message"), [
    ({"sample_format": "ci16", "adc_bits": 20}, "scenario receiver.adc_bits must be 2..16 for ci16, got 20"),
    ({"adc_bits": 1}, "receiver.adc_bits must be 2..8 for ci8"),
    ({"sample_format": "cf32", "adc_bits": 25}, "receiver.adc_bits must be 2..24 for cf32"),
    ({"adc_bits": 7.5}, "receiver.adc_bits"),
    ({"adc_dc_lsb": [0.5]}, "receiver.adc_dc_lsb"),
    ({"adc_dc_lsb": [0.5, float("nan")]}, "receiver.adc_dc_lsb[1]"),
    ({"drop_samples": [0, 10]}, "receiver.drop_samples"),
    ({"drop_samples": [100, 10]}, "receiver.drop_samples"),
    ({"drop_samples": [1.5, 10]}, "receiver.drop_samples"),
    ({"drops_per_minute": -1.0}, "receiver.drops_per_minute must be >= 0"),
    ({"agc_steps_per_minute": float("inf")}, "receiver.agc_steps_per_minute"),
    ({"iq_gain_db": float("nan")}, "receiver.iq_gain_db"),
    ({"iq_phase_deg": 90.0}, "receiver.iq_phase_deg"),
    ({"lo_leakage_dbc": float("inf")}, "receiver.lo_leakage_dbc"),
    ({"phase_noise_dbc_hz": []}, "receiver.phase_noise_dbc_hz"),
    ({"phase_noise_dbc_hz": [[1e4, -90.0], [1e3, -80.0]]}, "receiver.phase_noise_dbc_hz"),
    ({"phase_noise_dbc_hz": [[-1e3, -80.0]]}, "receiver.phase_noise_dbc_hz"),
    ({"phase_noise_dbc_hz": [[1e3, -80.0, 1.0]]}, "receiver.phase_noise_dbc_hz[0]"),
])
def test_bad_impairments_are_refused_by_name(receiver, message):
    fmt = receiver.pop("sample_format", "ci8")
    config = FrontEndConfig(**receiver)
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace(".", r"\.")):
        check_impairments(config, fmt)
    with pytest.raises(ValueError, match="receiver"):
        FrontEnd(config, 1.0, 7.56e6, fmt, 1, 2)


def test_edge_values_are_accepted():
    check_impairments(FrontEndConfig(adc_bits=24, drop_samples=[5, 5]), "cf32")
    check_impairments(FrontEndConfig(adc_bits=2, phase_noise_dbc_hz=[[1e3, -80.0]]), "cu8")


# ---------------------------------------------------------------- IQ imbalance, LO leakage

def test_iq_imbalance_convention_and_rail_moments():
    gain_db, phase_deg = 1.0, 3.0
    rng = np.random.default_rng(1)
    z = rng.standard_normal(50) + 1j * rng.standard_normal(50)
    g, phi = 10 ** (gain_db / 20), math.radians(phase_deg)
    mu, nu = (1 + g * np.exp(-1j * phi)) / 2, (1 - g * np.exp(1j * phi)) / 2
    np.testing.assert_allclose(iq_imbalance(z, gain_db, phase_deg), mu * z + nu * np.conj(z), rtol=0, atol=1e-14)
    # Noise-dominated capture (circular): E[Q^2] / E[I^2] = g^2, E[IQ] / sqrt(E[I^2] E[Q^2]) = -sin(phi).
    # Over 756 000 samples the moments scatter by about 0.01 dB and 0.1 deg.
    y = capture(generator(0.1, cn_db=-30.0, sample_format="cf32", iq_gain_db=gain_db, iq_phase_deg=phase_deg))
    i, q = y.real.astype(np.float64), y.imag.astype(np.float64)
    ii, qq, iq = np.mean(i * i), np.mean(q * q), np.mean(i * q)
    assert 10 * np.log10(qq / ii) == pytest.approx(gain_db, abs=0.06)
    assert math.degrees(-math.asin(iq / math.sqrt(ii * qq))) == pytest.approx(phase_deg, abs=0.4)
    # Sample by sample it is the balanced capture's samples through the convention.
    plain = capture(generator(0.005, sample_format="cf32"))
    imbalanced = capture(generator(0.005, sample_format="cf32", iq_gain_db=gain_db, iq_phase_deg=phase_deg))
    np.testing.assert_allclose(imbalanced, iq_imbalance(plain, gain_db, phase_deg), rtol=0, atol=1e-6)


@pytest.mark.parametrize("conjugate", [False, True])
def test_lo_leakage_tone_at_dc(conjugate):
    dbc, phase_deg = -10.0, 40.0
    kw = {"sample_rate_hz": 2.4e6, "sample_format": "cf32", "cn_db": 20.0, "iq_conjugate": conjugate}
    gen = generator(0.05, quiet=True, lo_leakage_dbc=dbc, lo_leakage_phase_deg=phase_deg, **kw)
    fe = gen.frontend
    # The capture's signal power: the direct path through the anti-alias filter (below the symbol rate).
    clean = gen.clean_samples(0, gen.num_samples)
    assert fe.signal_power_passed < 0.9 * gen.signal_power
    assert np.mean(np.abs(clean) ** 2) == pytest.approx(fe.signal_power_passed, rel=0.03)
    # The capture's DC less the signal's own (its PN headers' mean, rotating from frame to frame).
    signal_dc = np.mean(clean)
    tone = np.mean(capture(gen).astype(np.complex128)) / fe.agc_gain - (np.conj(signal_dc) if conjugate else signal_dc)
    assert 10 * np.log10(abs(tone) ** 2 / fe.signal_power_passed) == pytest.approx(dbc, abs=0.5)
    assert math.degrees(np.angle(tone)) == pytest.approx(-phase_deg if conjugate else phase_deg, abs=3.0)
    # Exactly a constant added to the capture without leakage.
    diff = capture(generator(0.005, quiet=True, lo_leakage_dbc=dbc, lo_leakage_phase_deg=phase_deg, **kw)) \
        - capture(generator(0.005, quiet=True, **kw))
    expected = fe.leakage * fe.agc_gain
    np.testing.assert_allclose(diff, np.conj(expected) if conjugate else expected, rtol=0, atol=1e-5)


# ---------------------------------------------------------------- ADC

def test_adc_bits_and_dc_give_the_level_set_and_mean():
    gen = generator(0.02, sample_format="cu8", adc_bits=6, adc_dc_lsb=[-0.5, 0.25])
    codes = capture(gen, quantised=True).astype(np.int64)
    without_dc = capture(generator(0.02, sample_format="cu8", adc_bits=6), quantised=True).astype(np.int64)
    lsb = 256 // 2 ** 6
    assert np.all((codes - 128) % lsb == 0) and codes.min() >= 0 and codes.max() <= 128 + 127 // lsb * lsb
    assert len(np.unique(codes)) > 20
    # The DC in LSB, added before rounding: the rails' means move by it (the dither is the signal and noise).
    shift = codes.reshape(-1, 2).mean(axis=0) - without_dc.reshape(-1, 2).mean(axis=0)
    np.testing.assert_allclose(shift, [-0.5 * lsb, 0.25 * lsb], atol=0.05)


def test_rtl_sdr_bytes_centre_on_127_5():
    # Noise only (the signal has a small DC of its own): the rails' mean scatters by about 0.04 codes.
    gen = generator(0.1, cn_db=-30.0, sample_format="cu8", adc_bits=8, adc_dc_lsb=[-0.5, -0.5])
    np.testing.assert_allclose(capture(gen, quantised=True).reshape(-1, 2).mean(axis=0), [127.5, 127.5], atol=0.15)


@pytest.mark.parametrize(("fmt", "bits", "step"), [("ci16", 12, 16), ("cf32", 10, 2 / 1024), ("ci8", 5, 8)])
def test_adc_levels_and_clipping_at_full_scale(fmt, bits, step):
    # No backoff: the rails' RMS at full scale, so the ADC clips often.
    rails = capture(generator(0.005, sample_format=fmt, adc_bits=bits, agc_backoff_db=0.0), quantised=True)
    levels = rails.astype(np.float64) / step
    np.testing.assert_array_equal(levels, np.rint(levels))
    top = 2 ** (bits - 1)
    assert levels.min() == -top and levels.max() == top - 1
    assert np.mean(levels == top - 1) > 0.01


# ---------------------------------------------------------------- AGC steps

def test_agc_steps_at_the_scheduled_indices():
    step_db = 2.0
    gen = generator(0.03, sample_format="cf32", agc_step_db=step_db, agc_steps_per_minute=12000.0)
    plain = generator(0.03, sample_format="cf32")
    steps, levels = gen.frontend.agc_steps
    assert len(steps) >= 3 and np.all(np.abs(np.diff(np.concatenate([[0], levels]))) == 1)
    ratio = (capture(gen, 9_999).astype(np.complex128) / capture(plain).astype(np.complex128))
    expected = np.ones(gen.num_samples)
    for index, level in zip(steps, levels):
        expected[index:] = 10 ** (step_db * level / 20)
    # Instantaneous steps: the gain is the scheduled level's on every sample, changing between index - 1 and index.
    assert steps.max() < gen.num_samples
    np.testing.assert_allclose(ratio, expected, rtol=1e-5, atol=0)


def test_agc_schedule_stays_within_bounds_and_extends():
    steps, levels = agc_schedule(1.0, 1e6, 1e6, 2_000_000, 3, STREAM_NOISE)
    assert len(steps) > 1000 and np.all(np.diff(steps) >= 0)
    assert np.abs(levels).max() == AGC_MAX_STEPS and np.all(np.abs(np.diff(levels)) <= 1)
    # A shorter schedule is the start of the longer one (segments see the full capture's steps).
    short_steps, short_levels = agc_schedule(1.0, 1e6, 1e6, 500_000, 3, STREAM_NOISE)
    np.testing.assert_array_equal(short_steps, steps[: len(short_steps)])
    np.testing.assert_array_equal(short_levels, levels[: len(short_steps)])


# ---------------------------------------------------------------- drops

def _drop_generators(seconds=0.05, **kw):
    drops = generator(seconds, drops_per_minute=6000.0, drop_samples=[50, 4000], **kw)
    return drops, generator(seconds, **kw)


def test_dropped_runs_are_missing_from_the_file():
    gen, plain = _drop_generators(sample_format="ci16")
    drops = gen.drops()
    assert len(drops) >= 2 and drops.samples.dtype == np.int64
    assert tuple(drops.columns()) == schema.DROP_COLUMNS
    full = capture(plain, quantised=True).reshape(-1, 2)
    file = capture(gen, 5_000, quantised=True).reshape(-1, 2)
    assert len(file) == gen.num_samples - drops.samples.sum() == gen.capture_samples
    lost = np.concatenate([np.arange(a, a + n) for a, n in zip(drops.receiver_sample, drops.samples)])
    np.testing.assert_array_equal(file, np.delete(full, lost, axis=0))
    for receiver, at, n in zip(drops.receiver_sample, drops.capture_sample, drops.samples):
        if at > 0:
            np.testing.assert_array_equal(file[at - 1], full[receiver - 1])
        if at < len(file):
            np.testing.assert_array_equal(file[at], full[receiver + n])
    np.testing.assert_array_equal(drops.capture_sample, drops.receiver_sample - (np.cumsum(drops.samples)
                                                                                - drops.samples))
    # The truth stays on the receiver's clock.
    np.testing.assert_array_equal(gen.frame_truth().t_s, plain.frame_truth().t_s)


def test_drops_are_chunk_and_thread_invariant():
    gen, _ = _drop_generators(0.03, grid_step_s=1e-4)
    assert gen.layout.batch_samples < 30_000 and len(gen.drops()) >= 1
    reference = capture(gen, 1 << 20, quantised=True)
    for size in (777, 4_096, 12_345):
        assert capture(gen, size, quantised=True).tobytes() == reference.tobytes()
    again, _ = _drop_generators(0.03, grid_step_s=1e-4)
    assert capture(again, 7_000, jobs=3, quantised=True).tobytes() == reference.tobytes()
    floats = capture(gen, 3_000)
    assert len(floats) == gen.capture_samples


def test_a_segment_drops_the_full_capture_s_runs():
    full, _ = _drop_generators(0.05)
    runs = full.drops()
    # A segment starting inside the first run keeps what is left of it.
    start = int(runs.receiver_sample[0] + runs.samples[0] // 2)
    segment = generator(0.05 - start / 7.56e6 - 1e-4, drops_per_minute=6000.0, drop_samples=[50, 4000],
                        start_s=start / 7.56e6)
    assert segment.first_sample == start
    drops = segment.drops()
    assert drops.receiver_sample[0] == 0 and drops.samples[0] == runs.receiver_sample[0] + runs.samples[0] - start
    whole = capture(full)
    skip = int(runs.capture_sample[0])
    part = capture(segment)
    np.testing.assert_array_equal(part, whole[skip: skip + len(part)])


def test_drop_schedule_lengths_are_log_uniform():
    first, count = drop_schedule(1e5, (10, 10_000), 1e6, 200_000_000, 5, STREAM_NOISE)
    assert len(first) > 1000 and count.min() >= 10 and count.max() <= 10_000
    assert np.all(first[1:] >= first[:-1] + count[:-1])         # runs never overlap
    decades = np.histogram(np.log10(count), bins=[1, 2, 3, 4.0001])[0] / len(count)
    np.testing.assert_allclose(decades, 1 / 3, atol=0.05)


def test_simulate_writes_the_drops_table(tmp_path):
    from sim.simulate import simulate

    scn = load_scenario("park-loop").replace(receiver={"drops_per_minute": 20000.0, "drop_samples": [100, 2000]})
    result = simulate(scn, tmp_path / "drops", seconds=0.02, start_s=5.0)
    drops = read_columns(result.truth_path, schema.TRUTH_DROPS)
    assert set(drops) == set(schema.DROP_COLUMNS) and all(v.dtype == np.int64 for v in drops.values())
    with h5py.File(result.truth_path, "r") as f:
        attrs = dict(f[schema.TRUTH_FRAMES].attrs)
    data = result.capture_path.with_suffix(".sigmf-data")
    samples = data.stat().st_size // get_format(scn.receiver.sample_format).bytes_per_sample
    assert attrs["num_samples"] == samples == attrs["receiver_num_samples"] - drops["samples"].sum()
    assert len(drops["samples"]) >= 1
    # Drops on but none in the segment: an empty table.
    rare = scn.replace(receiver={"drops_per_minute": 1e-6})
    result = simulate(rare, tmp_path / "rare", seconds=0.01, start_s=5.0, with_iq=False)
    drops = read_columns(result.truth_path, schema.TRUTH_DROPS)
    assert all(len(v) == 0 and v.dtype == np.int64 for v in drops.values())
    with h5py.File(result.truth_path, "r") as f:
        assert "receiver_num_samples" not in f[schema.TRUTH_FRAMES].attrs


# ---------------------------------------------------------------- phase noise

def test_phase_noise_psd_follows_the_profile():
    fs = 2.4e6
    fe = FrontEnd(FrontEndConfig(phase_noise_dbc_hz=PROFILE), mean_signal_power(FrameConfig()), fs, "cf32", 7,
                  STREAM_NOISE)
    phi = fe.phase_noise_rad(0, 1 << 21)
    f, psd = welch(phi, fs, nperseg=1 << 14, return_onesided=False)
    for offset in (300.0, 2e3, 5e3, 2e4, 4e4, 1e5, 3e5, 1e6):
        band = (np.abs(f) > offset / 1.1) & (np.abs(f) < offset * 1.1)
        measured = 10 * np.log10(np.mean(psd[band]))
        # Two-sided: L(f) itself (the one-sided S_phi is twice it).
        expected = 10 * np.log10(np.mean(fe.phase_noise.psd_rad2_hz(f[band])))
        assert measured == pytest.approx(expected, abs=1.5), offset


def test_phase_noise_stages_share_the_profile():
    pn = PhaseNoise([[10.0, -40.0], [1e3, -90.0], [1e6, -150.0]], 7.56e6, 1, 2)
    assert len(pn.rates_hz) >= 4 and pn.rates_hz[-1] / 64 <= 10.0
    f = np.geomspace(1.0, 3.78e6, 500)
    total = sum(pn.stage_weight(k, f) for k in range(len(pn.rates_hz)))
    np.testing.assert_allclose(total, 1.0, rtol=0, atol=1e-12)


def test_phase_noise_is_random_access():
    fe = FrontEnd(FrontEndConfig(phase_noise_dbc_hz=PROFILE), 1.0, 2.4e6, "cf32", 7, STREAM_NOISE)
    whole = fe.phase_noise_rad(100_000, 200_000)
    other = FrontEnd(FrontEndConfig(phase_noise_dbc_hz=PROFILE), 1.0, 2.4e6, "cf32", 7, STREAM_NOISE)
    cuts = [0, 1, 70_000, 70_001, 131_072, 200_000]
    # Out of order, from a fresh front end: the same bits.
    parts = {a: other.phase_noise_rad(100_000 + a, b - a) for a, b in reversed(list(itertools.pairwise(cuts)))}
    np.testing.assert_array_equal(np.concatenate([parts[a] for a in cuts[:-1]]), whole)


def test_phase_noise_rotates_the_signal_only():
    kw = {"quiet": True, "sample_format": "cf32", "cn_db": float("inf")}
    gen = generator(0.005, phase_noise_dbc_hz=[[1e3, -60.0], [1e5, -100.0]], **kw)
    z = capture(gen).astype(np.complex128)
    plain = capture(generator(0.005, **kw)).astype(np.complex128)
    phi = gen.frontend.phase_noise_rad(0, gen.num_samples)
    assert np.std(phi) > 0.01
    np.testing.assert_allclose(z, plain * np.exp(1j * phi), rtol=0, atol=2e-6)


# ---------------------------------------------------------------- everything at once

def test_all_impairments_are_chunk_thread_and_segment_invariant():
    kw = dict(ALL, grid_step_s=1e-4)
    gen = generator(0.03, **kw)
    reference = capture(gen, 1 << 20, quantised=True)
    assert len(reference) // 2 == gen.capture_samples < gen.num_samples
    assert capture(gen, 5_555, quantised=True).tobytes() == reference.tobytes()
    again = generator(0.03, **kw)
    assert capture(again, 7_000, jobs=3, quantised=True).tobytes() == reference.tobytes()
    # A segment without drops is the same samples of the full capture without drops.
    no_drops = dict(kw, drops_per_minute=0.0)
    full = capture(generator(0.03, **no_drops))
    segment = capture(generator(0.01, start_s=12_345 / RS, **no_drops))
    np.testing.assert_array_equal(segment, full[12_345: 12_345 + len(segment)])
