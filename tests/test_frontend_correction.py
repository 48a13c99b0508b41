"""Front-end corrector (receiver.frontend_correction): the estimates recover a known DC offset and I/Q
imbalance, the corrected output rejects the image, the numba kernel equals its numpy twin, and the output
is bit-identical whatever the chunking."""

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from receiver.frontend_correction import (ACC_SIZE, BLOCK, FORGET_TIME_S, MAX_CORRECTABLE_GAIN_DB, FrontEndCorrector,
                                          correct_blocks_reference, frontend_warnings, image_rejection_db)

FS = 7.56e6


def impair(z: np.ndarray, gain_db: float, phase_deg: float, dc: complex = 0j) -> np.ndarray:
    """The front end's convention: ``y = dc + I + j g (Q cos(phi) - I sin(phi))`` (complex64)."""
    g, phi = 10.0 ** (gain_db / 20.0), np.radians(phase_deg)
    return (dc + z.real + 1j * g * (z.imag * np.cos(phi) - z.real * np.sin(phi))).astype(np.complex64)


def multicarrier(n: int, rng: np.random.Generator, cfo_hz: float = 23e3, rms: float = 0.1) -> np.ndarray:
    """An OFDM-like signal: QPSK on the central 3780 of 4096 carriers per symbol, shifted by a CFO, plus AWGN."""
    symbols = -(-n // 4096)
    used = np.arange(-1890, 1890) % 4096
    grid = np.zeros((symbols, 4096), dtype=np.complex128)
    grid[:, used] = rng.choice([-1.0, 1.0], (symbols, len(used))) + 1j * rng.choice([-1.0, 1.0], (symbols, len(used)))
    x = np.fft.ifft(grid, axis=1).ravel()[:n]
    x *= np.exp(2j * np.pi * cfo_hz / FS * np.arange(n))
    x += 0.1 * (rng.standard_normal(n) + 1j * rng.standard_normal(n)) * np.sqrt(np.mean(np.abs(x) ** 2) / 2)
    return x * (rms / np.sqrt(np.mean(np.abs(x) ** 2)))


def run(y: np.ndarray, cuts=(), **kwargs) -> tuple[np.ndarray, FrontEndCorrector]:
    """The whole stream through a corrector, cut at ``cuts``; the output and the corrector."""
    fc = FrontEndCorrector(FS, **kwargs)
    bounds = [0, *cuts, len(y)]
    parts = [fc.process(y[a:b]) for a, b in pairwise(bounds)]
    return np.concatenate([*parts, fc.flush()]), fc


@pytest.fixture(scope="module")
def impaired():
    """1e6 samples of the multicarrier signal (and the ideal), with 1 dB, 5 deg and a DC offset."""
    rng = np.random.default_rng(11)
    z = multicarrier(1_000_000, rng)
    return z, impair(z, 1.0, 5.0, 0.012 - 0.007j)


@pytest.mark.parametrize("gain_db, phase_deg, dc", [(1.0, 5.0, 0.012 - 0.007j), (-0.7, -2.5, -0.03j),
                                                    (0.0, 0.0, 0.0), (2.5, 12.0, 0.05 + 0.05j)])
def test_estimates_recover_the_configured_impairment(gain_db, phase_deg, dc):
    z = multicarrier(1_000_000, np.random.default_rng(3))
    out, fc = run(impair(z, gain_db, phase_deg, dc))
    est = fc.estimate()
    assert abs(est.iq_gain_db - gain_db) < 0.05
    assert abs(est.iq_phase_deg - phase_deg) < 0.3
    assert abs(est.dc_offset - dc) < 1e-3
    if gain_db or phase_deg:
        assert est.image_rejection_db == pytest.approx(image_rejection_db(gain_db, phase_deg), abs=1.0)
    else:
        assert est.image_rejection_db > 50.0
    assert est.signal_rms == pytest.approx(0.1 * np.sqrt((1 + 10 ** (gain_db / 10)) / 2), rel=0.01)
    assert est.samples == len(z) and fc.emitted == fc.position == len(z)
    # The output is the ideal signal of the convention (the I rail at its own scale), up to the estimation noise.
    assert np.sqrt(np.mean(np.abs(out - z) ** 2)) < 0.01 * 0.1
    # One history row per block, the last a partial one.
    blocks = -(-len(z) // BLOCK)
    assert np.array_equal(est.block_start, BLOCK * np.arange(blocks))
    for column in (est.dc_i, est.dc_q, est.gain_db, est.phase_deg, est.rms):
        assert column.shape == (blocks,)
    assert est.gain_db[-1] == est.iq_gain_db and est.dc_i[-1] == est.dc_offset.real
    assert set(est.history_columns()) == {"block_start", "dc_i", "dc_q", "iq_gain_db", "iq_phase_deg", "signal_rms"}


def test_a_tones_image_is_rejected_after_correction():
    """A tone at +100 kHz: its image at -100 kHz drops from the front end's IRR to the noise."""
    n = 1 << 20
    rng = np.random.default_rng(5)
    k = round(100e3 / FS * n)                       # on an FFT bin: no leakage between the two
    t = np.arange(n)
    z = 0.3 * np.exp(2j * np.pi * k * t / n) + 0.003 * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    y = impair(z, 1.0, 5.0, 0.02 + 0.01j)

    def image_db(x):
        spectrum = np.abs(np.fft.fft(x)) ** 2
        return 10 * np.log10(spectrum[-k] / spectrum[k])

    before = image_db(y)
    assert before == pytest.approx(-image_rejection_db(1.0, 5.0), abs=0.5)
    out, _ = run(y)
    assert image_db(out) < -40.0
    assert abs(np.mean(out)) < 1e-3       # the DC tone is gone too


@pytest.mark.parametrize("remove_dc, correct_iq", [(True, True), (True, False), (False, True)])
def test_kernel_matches_the_numpy_reference(impaired, remove_dc, correct_iq):
    _, y = impaired
    y = y[: 3 * BLOCK + 4321]
    out, fc = run(y, cuts=(1000, BLOCK + 7), remove_dc=remove_dc, correct_iq=correct_iq)
    acc = np.zeros(ACC_SIZE)
    ref, rows = correct_blocks_reference(y, acc, fc.decay_per_sample, remove_dc, correct_iq, segment=fc.segment)
    assert np.allclose(out, ref, rtol=0, atol=2e-6)
    est = fc.estimate()
    assert np.allclose(np.column_stack([est.dc_i, est.dc_q, est.gain_db, est.phase_deg, est.rms]), rows,
                       rtol=1e-9, atol=1e-9)
    assert np.allclose(fc._acc, acc, rtol=1e-9)
    if not remove_dc:      # the DC stays (moved to the corrected Q rail's scale)
        assert abs(np.mean(out)) > 0.01


def test_only_dc_is_removed_without_iq_correction(impaired):
    _, y = impaired
    y = y[:BLOCK]
    out, fc = run(y, correct_iq=False)
    assert np.allclose(out, y - fc.estimate().dc_offset, rtol=0, atol=1e-7)


STREAM = impair(multicarrier(3 * BLOCK + 1234, np.random.default_rng(2)), 0.8, -4.0, 0.01 + 0.02j)
ONE_SHOT, ONE_SHOT_FC = run(STREAM)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, len(STREAM)), max_size=12))
def test_output_is_bit_identical_whatever_the_chunking(cuts):
    """Random cut points, repeated ones giving zero-length chunks: the same bits as one call."""
    out, fc = run(STREAM, sorted(cuts))
    assert np.array_equal(out, ONE_SHOT)
    a, b = fc.estimate(), ONE_SHOT_FC.estimate()
    for name in ("block_start", "dc_i", "dc_q", "gain_db", "phase_deg", "rms"):
        assert np.array_equal(getattr(a, name), getattr(b, name))


def test_reruns_are_identical():
    cuts = (5, BLOCK - 1, BLOCK, 2 * BLOCK + 17)
    first, fc1 = run(STREAM, cuts)
    second, fc2 = run(STREAM, cuts)
    assert np.array_equal(first, second)
    assert np.array_equal(fc1._acc, fc2._acc)


def test_flush_returns_the_partial_block():
    y = STREAM[: 2 * BLOCK + 5000]
    fc = FrontEndCorrector(FS)
    head = fc.process(y)
    assert len(head) == 2 * BLOCK and fc.emitted == 2 * BLOCK and fc.position == len(y)
    tail = fc.flush()
    assert len(tail) == 5000
    ref, _ = correct_blocks_reference(y, np.zeros(ACC_SIZE), fc.decay_per_sample, True, True, segment=fc.segment)
    assert np.allclose(np.concatenate([head, tail]), ref, rtol=0, atol=2e-6)
    assert list(fc.estimate().block_start) == [0, BLOCK, 2 * BLOCK]
    assert len(fc.flush()) == 0
    with pytest.raises(RuntimeError, match="after flush"):
        fc.process(y[:10])


def test_a_stream_shorter_than_a_block_comes_out_at_flush():
    fc = FrontEndCorrector(FS)
    assert len(fc.process(STREAM[:1000])) == 0
    assert fc.estimate().samples == 0 and np.isnan(fc.estimate().iq_gain_db)
    assert frontend_warnings(fc.estimate()) == []
    out = fc.flush()
    assert len(out) == 1000 and out.dtype == np.complex64
    assert fc.estimate().samples == 1000


def test_zero_length_chunks():
    fc = FrontEndCorrector(FS)
    empty = fc.process(np.zeros(0, dtype=np.complex64))
    assert empty.dtype == np.complex64 and len(empty) == 0 and fc.position == 0
    fc.process(STREAM[:100])
    assert len(fc.process(np.zeros(0, dtype=np.complex128))) == 0 and fc.position == 100
    assert len(FrontEndCorrector(FS).flush()) == 0


def test_complex128_input_is_taken_as_complex64():
    out, _ = run(STREAM.astype(np.complex128))
    assert out.dtype == np.complex64 and np.array_equal(out, ONE_SHOT)


@pytest.mark.parametrize("bad", [np.zeros((2, 10), np.complex64), np.zeros(10, np.float32), np.arange(10)])
def test_bad_chunks_are_refused(bad):
    with pytest.raises(ValueError, match="1-D complex"):
        FrontEndCorrector(FS).process(bad)


@pytest.mark.parametrize("where", [310, BLOCK - 10, BLOCK + 5, 2 * BLOCK + 700, 3 * BLOCK + 1000])
@pytest.mark.parametrize("value", [np.nan, np.inf, complex(0, -np.inf)])
def test_nan_and_inf_are_refused_and_leave_the_corrector_as_it_was(where, value):
    """After a first chunk of 300 samples, a chunk with one bad sample: in the pending block's completion, a
    whole block, or the tail; the error names it, and the stream goes on as if the chunk had not come."""
    first, rest = STREAM[:300], STREAM[300:]
    bad = rest.copy()
    bad[where - 300] = value
    fc = FrontEndCorrector(FS)
    out = [fc.process(first)]
    with pytest.raises(ValueError, match=f"NaN or inf in the input at sample {where}"):
        fc.process(bad)
    out += [fc.process(rest), fc.flush()]
    assert np.array_equal(np.concatenate(out), ONE_SHOT)


def test_a_short_bad_chunk_is_caught_before_its_block_completes():
    fc = FrontEndCorrector(FS)
    fc.process(STREAM[:300])
    bad = STREAM[300:400].copy()
    bad[50] = np.nan
    with pytest.raises(ValueError, match="sample 350"):
        fc.process(bad)
    assert fc.position == 300


def test_bad_sample_rates_are_refused():
    for rate in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="sample_rate_hz"):
            FrontEndCorrector(rate)


def test_forgetting_is_a_time_constant():
    """The per-block factor follows the rate: the same number of seconds of memory at any rate."""
    for rate in (2.4e6, 7.56e6, 20e6):
        fc = FrontEndCorrector(rate)
        assert np.exp(-BLOCK * fc.decay_per_sample) == pytest.approx(np.exp(-BLOCK / rate / FORGET_TIME_S))


def test_an_agc_gain_step_leaves_the_iq_estimate_alone(impaired):
    """A gain step scales both rails (and the DC with them): gain and phase hold across it."""
    _, y = impaired
    stepped = y.copy()
    stepped[len(y) // 2:] *= 2.0
    _, fc = run(stepped)
    est = fc.estimate()
    assert np.all(np.abs(est.gain_db[2:] - 1.0) < 0.1)
    assert np.all(np.abs(est.phase_deg[2:] - 5.0) < 0.5)


def test_warnings_say_what_is_large():
    z = multicarrier(4 * BLOCK, np.random.default_rng(4))
    _, clean = run(impair(z, 0.1, 0.5, 0.0001))
    assert frontend_warnings(clean.estimate()) == []
    _, bad = run(impair(z, 1.0, 5.0, 0.01))
    lines = frontend_warnings(bad.estimate())
    assert len(lines) == 2 and "DC offset" in lines[0] and "removed" in lines[0]
    assert "I/Q imbalance" in lines[1] and "corrected" in lines[1]
    _, kept = run(impair(z, 1.0, 5.0, 0.01), remove_dc=False, correct_iq=False)
    lines = frontend_warnings(kept.estimate())
    assert "not removed" in lines[0] and "not corrected" in lines[1]


def test_a_non_circular_input_is_not_corrected():
    """A real-valued capture (Q rail nearly empty) is no front end's imbalance: only its DC comes off."""
    rng = np.random.default_rng(8)
    y = (0.1 * rng.standard_normal(BLOCK) + 0.02 + 1e-4j * rng.standard_normal(BLOCK)).astype(np.complex64)
    out, fc = run(y)
    est = fc.estimate()
    assert est.iq_gain_db < -MAX_CORRECTABLE_GAIN_DB
    assert np.allclose(out, y - est.dc_offset, rtol=0, atol=1e-7)
    assert "left uncorrected" in frontend_warnings(est)[-1]
    dead = np.zeros(BLOCK, np.complex64)
    dead.real = y.real
    _, fc = run(dead)
    assert np.isnan(fc.estimate().iq_gain_db)
    assert "not estimated" in frontend_warnings(fc.estimate())[-1]


def test_image_rejection_of_a_perfect_front_end_is_infinite():
    assert image_rejection_db(0.0, 0.0) == np.inf
    assert np.isnan(image_rejection_db(np.nan, np.nan))
    # Small errors: IRR ~ 4 / (eps^2 + phi^2) with eps the amplitude error.
    eps, phi = 10 ** (0.2 / 20) - 1, np.radians(1.0)
    assert image_rejection_db(0.2, 1.0) == pytest.approx(10 * np.log10(4 / (eps**2 + phi**2)), abs=0.2)


def test_history_can_be_popped():
    fc = FrontEndCorrector(FS)
    fc.process(STREAM[: 2 * BLOCK])
    first = fc.estimate(pop=True)
    assert list(first.block_start) == [0, BLOCK]
    fc.process(STREAM[2 * BLOCK:])
    fc.flush()
    second = fc.estimate(pop=True)
    assert list(second.block_start) == [2 * BLOCK, 3 * BLOCK]
    assert second.iq_gain_db == ONE_SHOT_FC.estimate().iq_gain_db
    assert len(fc.estimate().block_start) == 0


def with_headers(z: np.ndarray, rng: np.random.Generator, period: int = 4200, length: int = 420) -> np.ndarray:
    """``z`` with PN420-like headers: every ``period`` samples, ``length`` chips of +-(1 + j) at twice the
    body's power and no carrier offset (their ``y^2`` then never turns)."""
    out = z.copy()
    rms = np.sqrt(np.mean(np.abs(z) ** 2) / 2.0)
    for start in range(0, len(z) - length, period):
        out[start: start + length] = rng.choice([-1.0, 1.0], length) * (1 + 1j) * rms * np.sqrt(2.0)
    return out


def plain_moments(y: np.ndarray) -> tuple[float, float]:
    """(E2)-(E3) over every sample, headers included: gain dB and phase deg."""
    i, q = y.real - y.real.mean(), y.imag - y.imag.mean()
    p_i, p_q, c = np.mean(i * i), np.mean(q * q), np.mean(i * q)
    return 10 * np.log10(p_q / p_i), np.degrees(np.arcsin(-c / np.sqrt(p_i * p_q)))


@pytest.mark.parametrize("gain_db, phase_deg", [(0.0, 0.0), (1.0, 5.0)])
def test_the_headers_are_left_out_of_the_imbalance(gain_db, phase_deg):
    """Headers that do not turn read as degrees of imbalance in the plain moments; (E6) leaves them out."""
    rng = np.random.default_rng(5)
    y = impair(with_headers(multicarrier(1_000_000, rng, cfo_hz=0.0), rng), gain_db, phase_deg)
    assert abs(plain_moments(y)[1] - phase_deg) > 5.0          # what the headers do to all samples' moments
    _, fc = run(y)
    est = fc.estimate()
    assert abs(est.iq_gain_db - gain_db) < 0.05 and abs(est.iq_phase_deg - phase_deg) < 0.3
    if gain_db == 0.0:
        assert est.image_rejection_db > 40.0 and not frontend_warnings(est)
