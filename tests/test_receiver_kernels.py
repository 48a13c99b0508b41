"""Receiver kernels: numba versions equal their plain-numpy references, and
the body recovery and estimators are right on signals with known answers."""

import numpy as np
import pytest
from receiver_signals import make_signal

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import BODY_LENGTH, SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.records import FrameBatch
from receiver.body import body_phases, recover_bodies, recover_bodies_reference
from dtmbnav_core.constants import SI_REFERENCE_GAIN
from receiver.cfo import (cfo_from_advance, pn_theta_kernel, pn_theta_reference, si_phase_kernel,
                          si_phase_reference)
from receiver.channel_estimate import (ChannelEstimator, hadamard_slots, m_sequence_correlation_kernel,
                                       walsh_hadamard_inplace)
from receiver.derotate import derotate_segments, derotate_segments_reference, rotation_table
from receiver.ofdm import OfdmDemodulator, dft6, si_carrier_numbers, si_carriers_reference
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from receiver.reference import receive_reference
from receiver.resample import StreamResampler, design_filter, polyphase_reference
from receiver.tracking import LockMonitor, timing_loop_kernel, timing_loop_reference
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


@pytest.mark.parametrize("up, down", [(189, 500), (189, 250), (378, 625), (27, 25)])
def test_resampler_filter_is_scipys_kaiser_firwin(up, down):
    from scipy.signal import firwin

    taps = 2 * 12 * max(up, down) + 1
    ref = up * firwin(taps, 1.0 / max(up, down), window=("kaiser", 8.0))
    assert np.max(np.abs(design_filter(up, down) - ref)) < 1e-6 * np.max(ref)


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
        assert np.all(np.abs(ch.taps[:, lag + est.taps_before] - g) < 0.03)
    assert np.all(np.abs(ch.snr_db - 10 * np.log10(1.16 / 0.005)) < 1.5)
    assert np.all(ch.peak_metric > 0.9)
    assert np.allclose(ch.centroid, 7 * 0.16 / 1.16, atol=0.1)


@pytest.mark.parametrize("size", [4, 8, 256, 512])
def test_walsh_hadamard_matches_sylvester_matrix(size):
    x = crandn(size)
    sylvester = np.array([[1.0]])
    while len(sylvester) < size:
        sylvester = np.block([[sylvester, sylvester], [sylvester, -sylvester]])
    work = x.copy()
    walsh_hadamard_inplace(work)
    assert np.max(np.abs(work - sylvester @ x.astype(np.complex128))) < 1e-5 * np.sqrt(size)


@pytest.mark.parametrize("mode", [PnMode.PN420, PnMode.PN945])
def test_hadamard_slots_turn_every_shift_into_a_hadamard_row(mode):
    chips = gb20600.pn_core(mode)
    p = len(chips)
    sample_slot, shift_slot = hadamard_slots(chips)
    assert sorted(sample_slot) == list(range(1, p + 1)) and sorted(shift_slot) == list(range(1, p + 1))
    parity = np.array([bin(v).count("1") & 1 for v in range(p + 1)])
    for t in (0, 1, 7, p // 2, p - 1):
        assert np.array_equal(parity[shift_slot[t] & sample_slot], np.roll(chips, -t))


def test_hadamard_slots_reject_a_sequence_that_is_not_an_m_sequence():
    chips = gb20600.pn_core(PnMode.PN420).copy()
    with pytest.raises(ValueError, match="period"):
        hadamard_slots(chips[:200])
    chips[10] ^= 1
    with pytest.raises(ValueError, match="m-sequence"):
        hadamard_slots(chips)


@pytest.mark.parametrize("mode", [PnMode.PN420, PnMode.PN945])
def test_m_sequence_correlation_equals_fft_correlation(mode):
    """The Hadamard correlation gives the FFT correlation with each frame's header phase."""
    m = mode.value
    est = ChannelEstimator(mode, 6)
    windows = crandn(6, m.period)
    phases = np.array([0, 1, -1, m.period // 2, -(m.period // 2), 37])
    shifts = (phases + m.preamble) % m.period
    corr = np.empty((6, m.period), np.complex64)
    power_in = np.empty(6)
    m_sequence_correlation_kernel(windows, shifts, est._sample_slot, est._shift_slot, est._hadamard_scale,
                                  np.empty(m.period + 1, np.complex64), corr, power_in)
    refs = np.array([gb20600.header_symbols(mode, int(p))[m.preamble: m.preamble + m.period] for p in phases])
    # corr[s] = sum_n w[n + s] conj(ref[n]) / energy, circularly
    expected = np.array([[np.sum(np.roll(w, -s) * np.conj(r)) for s in range(m.period)] for w, r in zip(windows, refs)])
    expected /= np.sum(np.abs(refs[0]) ** 2)
    assert np.max(np.abs(corr - expected)) < 1e-5 * np.max(np.abs(expected))
    assert np.allclose(power_in, np.mean(np.abs(windows) ** 2, axis=1), rtol=1e-5)


def test_pn_theta_kernel_matches_reference():
    taps = crandn(6, 64)
    prev = crandn(64)
    shift = np.array([0, 1, -1, 2, 0, -3])
    got = pn_theta_kernel(prev, taps, shift)
    assert np.allclose(got, pn_theta_reference(prev, taps, shift), rtol=1e-6, atol=1e-6)
    # A path delayed by one sample more in frame m - 1 is aligned by shift = 1.
    assert np.isclose(pn_theta_kernel(np.roll(taps[0], 1), taps[:1], np.array([1]))[0],
                      np.sum(np.abs(taps[0, :-1].astype(np.complex128)) ** 2), rtol=1e-5)


def test_pruned_si_dft_matches_full_fft_on_random_bodies():
    ofdm = OfdmDemodulator(5)
    bodies = crandn(5, BODY_LENGTH)
    ofdm.bodies[:] = bodies
    ref = si_carriers_reference(bodies)
    got = ofdm.si_carriers(4)     # only the first 4 of the batch
    assert got.shape == (4, 36) and got.dtype == np.complex64
    # Carriers of a unit-power random body have magnitude ~sqrt(3780): float32 rounding is ~1e-6 of that.
    assert np.max(np.abs(got - ref[:4])) < 1e-5 * np.sqrt(BODY_LENGTH)
    phases = np.exp(2j * np.pi * RNG.uniform(size=5)).astype(np.complex64)
    assert np.max(np.abs(ofdm.si_carriers(5, phases) - ref * phases[:, None])) < 1e-5 * np.sqrt(BODY_LENGTH)


def test_pruned_si_dft_recovers_a_transmitted_frames_si_symbols():
    """A body from the transmitter gives back sqrt(3780) times its SI symbols (unitary IDFT)."""
    src = FrameSource(FrameConfig(pn_mode=PnMode.PN420, si_index=15, seed=4))
    body = src.frame_symbols(3)[PnMode.PN420.value.header_length:]
    ofdm = OfdmDemodulator(1)
    ofdm.bodies[0] = body
    got = ofdm.si_carriers(1)[0]
    scale = np.sqrt(BODY_LENGTH)
    assert np.max(np.abs(got - si_carriers_reference(body[None, :])[0])) < 1e-5 * scale
    assert np.max(np.abs(got / scale - gb20600.si_symbols(15))) < 1e-5


def test_dft6_matches_numpy_fft():
    x = crandn(6)
    got = np.array(dft6(*np.column_stack([x.real, x.imag]).ravel()))
    assert np.max(np.abs(got[0::2] + 1j * got[1::2] - np.fft.fft(x))) < 1e-5


def test_si_phase_kernel_and_cfo_sign():
    k = si_carrier_numbers().astype(np.float64)
    assert sorted(k) == list(range(-18, 18))
    x = crandn(36)
    f, step = 250.0, 4200
    frames = np.array([x * np.exp(2j * np.pi * f * i * step / SYMBOL_RATE_HZ) for i in range(9)], np.complex64)
    delta = RNG.uniform(-0.5, 0.5, 9)
    shifted = (frames * np.exp(2j * np.pi * k[None, :] * delta[:, None] / BODY_LENGTH)).astype(np.complex64)
    # The whole run in two batches, the state carried (a lock's first frame pairs with itself), against the
    # one-frame-at-a-time reference.
    ref_state, state = np.zeros(36, complex), np.zeros(36, complex)
    a1, v1, p1 = si_phase_kernel(shifted[0], shifted[:4], k, delta[0], delta[:4], state, 0.0, SI_REFERENCE_GAIN)
    a2, v2, p2 = si_phase_kernel(shifted[3], shifted[4:], k, delta[3], delta[4:], state, p1, SI_REFERENCE_GAIN)
    advance, phase_var = np.concatenate([a1, a2]), np.concatenate([v1, v2])
    phase, expected = 0.0, []
    for i in range(9):
        a, v, phase = si_phase_reference(shifted[max(i - 1, 0)], shifted[i: i + 1], k, delta[max(i - 1, 0)],
                                         delta[i: i + 1], ref_state, phase, SI_REFERENCE_GAIN)
        expected.append((a[0], v[0]))
    assert np.allclose(advance, [e[0] for e in expected], atol=1e-6) and np.isclose(p2, phase, atol=1e-6)
    assert np.allclose(state, ref_state, rtol=1e-5)
    assert np.all(phase_var < 1e-10) and np.allclose(phase_var, [e[1] for e in expected], rtol=1e-3, atol=1e-14)
    assert advance[0] == 0.0    # a lock's first frame: nothing to advance from
    # Received carrier above nominal -> positive CFO, whatever the window offsets.
    assert np.allclose(cfo_from_advance(advance[1:], np.full(8, step), 0.0, 1000.0), 1000.0 + f, atol=0.05)
    # With a gain of 1 the reference is the previous frame: eq. 6's -angle(Theta).
    noisy = (shifted + 0.3 * crandn(9, 36)).astype(np.complex64)
    pairs, _, _ = si_phase_kernel(noisy[0], noisy[1:], k, delta[0], delta[1:], np.zeros(36, complex), 0.0, 1.0)
    theta = np.sum(np.conj(noisy[1:]) * noisy[:-1] * np.exp(2j * np.pi / BODY_LENGTH * np.diff(delta)[:, None] * k),
                   axis=1)
    assert np.allclose(pairs[1:], -np.angle(theta[1:]), atol=1e-5)


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
    bodies = []
    # The reference twins the chain after the front-end corrector (which has its own numpy twin): off here.
    config = ReceiverConfig(clock_offset_hz=0.0, batch_frames=40, remove_dc=False, correct_iq=False,
                            inspect=lambda stage, arrays: bodies.append(arrays["bodies"]) if stage == "body" else None)
    rx = Receiver(7.56e6, 666e6, config)
    got = FrameBatch.concatenate(list(receive_stream([x], 7.56e6, 666e6, receiver=rx)))
    ref = receive_reference(x, rx.acquisitions[0], len(got), batch_frames=40)
    assert len(got) > 90
    assert sum(len(b) for b in bodies) >= len(got)   # every frame's body is inspected (a lost frame is dropped)
    assert np.array_equal(np.rint(got.t_s * SYMBOL_RATE_HZ), ref.window_start)
    assert np.nanmax(np.abs(got.cfo_hz - ref.cfo_hz)) < 1e-3
    assert np.nanmax(np.abs(got.cfo_pn_hz - ref.cfo_pn_hz)) < 1e-3
    assert np.allclose(got.snr_db, ref.snr_db, atol=0.01)
