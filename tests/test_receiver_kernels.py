"""Receiver kernels: numba/pyfftw versions equal their plain-numpy references, and
the body recovery and estimators are right on signals with known answers."""

import numpy as np
import pytest

from receiver.body import (ChannelEstimator, body_phases, derotate_segments, derotate_segments_reference,
                           recover_bodies, recover_bodies_reference, rotation_table)
from receiver.cfo import cfo_from_theta, si_carrier_numbers, si_theta_kernel, si_theta_reference
from receiver.gb20600 import BODY_LENGTH, SYMBOL_RATE_HZ, PnMode
from receiver.ofdm import OfdmDemodulator, si_carriers_reference
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from receiver.records import FrameBatch
from receiver.reference import receive_reference
from receiver.resample import StreamResampler, polyphase_reference
from receiver.tracking import LockMonitor, timing_loop_kernel, timing_loop_reference
from receiver_signals import make_signal
from sim.frames import FrameConfig, FrameSource

RNG = np.random.default_rng(7)


def crandn(*shape):
    return (RNG.standard_normal(shape) + 1j * RNG.standard_normal(shape)).astype(np.complex64)


@pytest.mark.parametrize("rate", [10e6, 16e6, 20e6, 12.5e6])
def test_resampler_matches_reference_and_keeps_time(rate):
    rs = StreamResampler(rate)
    x = crandn(3_000)
    chunked = np.concatenate([rs.process(x[i:i + 123]) for i in range(0, len(x), 123)])
    ref = polyphase_reference(x, rs._h, rs.up, rs.down, len(chunked))
    assert np.max(np.abs(chunked - ref)) < 1e-4
    # A tone stays a tone of the same frequency and phase at the new rate (no time offset).
    f = 1.1e6
    n = np.arange(200_000)
    y = StreamResampler(rate).process(np.exp(2j * np.pi * f * n / rate).astype(np.complex64))
    m = np.arange(len(y))[3000:-3000]
    assert np.max(np.abs(y[m] - np.exp(2j * np.pi * f * m / SYMBOL_RATE_HZ))) < 1e-3


def test_resampler_rejects_bad_rates():
    with pytest.raises(ValueError, match="sample_rate_hz"):
        StreamResampler(-1.0)
    with pytest.raises(ValueError, match="no rational ratio"):
        StreamResampler(1000.0)   # would need up = 7560


def test_derotation_matches_reference():
    buf = crandn(20_000)
    starts = np.array([100, 5000, 12_345], dtype=np.int64)
    cycles = 4321.0 / SYMBOL_RATE_HZ
    out = np.zeros((3, 600), np.complex64)
    derotate_segments(buf, 50, starts, 600, cycles, rotation_table(4321.0, 600), out)
    ref = derotate_segments_reference(buf, 50, starts, 600, cycles)
    assert np.max(np.abs(out - ref)) < 1e-4


@pytest.mark.parametrize("mode", list(PnMode))
def test_body_recovery_gives_circular_channel(mode):
    """After tail removal and cyclic reconstruction the FFT of a multipath body is sqrt(N) H(k) X(k)."""
    m = mode.value
    src = FrameSource(FrameConfig(pn_mode=mode, seed=3))
    taps_before, taps_after = 16, 48
    lags = {-3: 0.25 - 0.1j, 0: 1.0, 5: 0.5j, 30: -0.2}
    frames = np.arange(4, 8)
    tx = src.symbols(0, (frames[-1] + 3) * m.frame_length)
    rx = np.zeros_like(tx)
    for lag, g in lags.items():
        rx += g * np.roll(tx, lag)
    cfo = 1234.0
    rx = (rx * np.exp(2j * np.pi * cfo / SYMBOL_RATE_HZ * np.arange(len(rx)))).astype(np.complex64)
    taps = np.zeros((len(frames), taps_before + taps_after), np.complex64)
    for lag, g in lags.items():
        taps[:, lag + taps_before] = g
    config = FrameConfig(pn_mode=mode)
    now = np.array([src.header(config.header_phase(f)) for f in frames], np.complex64)
    nxt = np.array([src.header(config.header_phase(f + 1)) for f in frames], np.complex64)
    starts = frames * m.frame_length
    cycles = cfo / SYMBOL_RATE_HZ
    phases = body_phases(starts, m.header_length, taps_before, cycles)
    out = np.zeros((len(frames), BODY_LENGTH), np.complex64)
    recover_bodies(rx, 0, starts, m.header_length, rotation_table(cfo, BODY_LENGTH + 64), phases, taps, taps_before,
                   now, nxt, out)
    ref = recover_bodies_reference(rx, 0, starts, m.header_length, cycles, taps, taps_before, now, nxt)
    assert np.max(np.abs(out * phases[:, None] - ref)) < 2e-3
    k = np.arange(BODY_LENGTH)
    h = sum(g * np.exp(-2j * np.pi * k * lag / BODY_LENGTH) for lag, g in lags.items())
    for i, f in enumerate(frames):
        expected = np.sqrt(BODY_LENGTH) * h * src.carriers(f)   # the coarse CFO is removed exactly
        got = np.fft.fft(ref[i])
        assert np.max(np.abs(got - expected)) < 1e-6 * np.sqrt(BODY_LENGTH) * 100


@pytest.mark.parametrize("mode", list(PnMode))
def test_channel_estimate_finds_paths_and_matches_reference(mode):
    m = mode.value
    src = FrameSource(FrameConfig(pn_mode=mode, seed=5))
    tx = src.symbols(0, 12 * m.frame_length)
    lags = {0: 1.0, 7: 0.4j}
    rx = sum(g * np.roll(tx, lag) for lag, g in lags.items())
    rx = (rx + 0.05 * crandn(len(rx))).astype(np.complex64)   # SNR 26 dB
    est = ChannelEstimator(mode, 8)
    frames = np.arange(2, 10)
    starts = frames * m.frame_length
    phases = np.array([FrameConfig(pn_mode=mode).header_phase(f) for f in frames])
    derotate_segments(rx, 0, starts + est.window_offset, est.window_length, 0.0, rotation_table(0.0, 1000), est.windows)
    ch = est.estimate(len(frames), phases)
    ref = est.estimate_reference(est.windows[: len(frames)].astype(np.complex128), phases)
    assert np.max(np.abs(ch.raw_taps - ref.raw_taps)) < 1e-4
    assert np.allclose(ch.snr_db, ref.snr_db, atol=0.01)
    assert np.array_equal(ch.taps != 0, ref.taps != 0)
    for lag, g in lags.items():
        assert np.all(np.abs(ch.taps[:, lag + 16] - g) < 0.03)
    assert np.all(np.abs(ch.snr_db - 10 * np.log10(1.16 / 0.005)) < 1.5)
    assert np.all(ch.peak_metric > 0.9)
    assert np.allclose(ch.centroid, 7 * 0.16 / 1.16, atol=0.1)


def test_ofdm_matches_numpy():
    ofdm = OfdmDemodulator(4)
    bodies = crandn(4, BODY_LENGTH)
    ofdm.bodies[:] = bodies
    assert np.max(np.abs(ofdm.si_carriers(4) - si_carriers_reference(bodies))) < 1e-3


def test_si_theta_kernel_and_cfo_sign():
    k = si_carrier_numbers().astype(np.float64)
    assert sorted(k) == list(range(-18, 18))
    x = crandn(36)
    f, step = 250.0, 4200
    frames = np.array([x * np.exp(2j * np.pi * f * i * step / SYMBOL_RATE_HZ) for i in range(5)], np.complex64)
    delta = RNG.uniform(-0.5, 0.5, 4)
    shifted = frames[1:] * np.exp(2j * np.pi * k[None, :] * delta[:, None] / BODY_LENGTH)
    theta = si_theta_kernel(frames[0], shifted.astype(np.complex64), k, 0.0, delta)
    assert np.allclose(theta, si_theta_reference(frames[0], shifted, k, 0.0, delta), rtol=1e-5)
    # Received carrier above nominal -> positive CFO, whatever the window offsets.
    assert np.allclose(cfo_from_theta(theta, np.full(4, step), 0.0, 1000.0), 1000.0 + f, atol=0.05)


def test_timing_loop_kernel_and_ramp_tracking():
    period = 4200.0 * (1 + 3e-6)
    measured = 1000.0 + period * np.arange(2000) + RNG.normal(0, 0.05, 2000)
    valid = np.ones(2000, bool)
    a = timing_loop_kernel(measured, valid, 1000.0, 4200.0, 0.05, 0.001)
    b = timing_loop_reference(measured, valid, 1000.0, 4200.0, 0.05, 0.001)
    assert np.allclose(a[0], b[0]) and np.allclose(a[1], b[1]) and np.isclose(a[3], b[3])
    assert abs(a[3] - period) < 1e-3          # the loop learns the sampling offset
    assert np.std(a[0][-500:] - (1000.0 + period * np.arange(1500, 2000))) < 0.05


def test_lock_monitor_counts_runs_across_batches():
    mon = LockMonitor(threshold=0.2, loss_frames=5)
    assert mon.check(np.array([0.9, 0.1, 0.1, 0.1])) is None
    assert mon.check(np.array([0.1, 0.9, 0.1])) is None      # run broken
    assert mon.check(np.array([0.1, 0.1, 0.1, 0.1, 0.5])) == 0  # 1 carried + 4 = 5
    assert mon.check(np.array([0.9, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1])) == 1


@pytest.mark.parametrize("mode", [PnMode.PN420, PnMode.PN595, PnMode.PN945])
def test_batched_pipeline_equals_numpy_reference(mode):
    x = make_signal(int(7.56e6 * 0.06), pn_mode=mode, cfo_hz=3000.0, snr_db=15, start_symbol=123_457,
                    echo=(5.3, 0.3j), sampling_offset_ppm=3)
    rx = Receiver(7.56e6, 666e6, ReceiverConfig(clock_offset_hz=0.0, batch_frames=16))
    got = FrameBatch.concatenate(list(receive_stream([x], 7.56e6, 666e6, receiver=rx)))
    ref = receive_reference(x, rx.acquisitions[0], len(got), batch_frames=16)
    assert len(got) > 90
    assert np.array_equal(np.rint(got.t_s * SYMBOL_RATE_HZ), ref.window_start)
    assert np.nanmax(np.abs(got.cfo_hz - ref.cfo_hz)) < 1e-3
    assert np.nanmax(np.abs(got.cfo_pn_hz - ref.cfo_pn_hz)) < 1e-3
    assert np.allclose(got.snr_db, ref.snr_db, atol=0.01)
