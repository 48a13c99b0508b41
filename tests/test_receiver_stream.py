"""Streaming receiver on symbol-rate test signals: acquisition in every header mode,
CFO against the known offset, chunk-size invariance, no lock on noise, gap and
re-acquisition, SI word, output files and clear errors."""

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from receiver_signals import frame_start_samples, make_signal

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.h5io import read_columns
from dtmbnav_core.records import FrameBatch, FrameFlag
from receiver.acquisition import acquire, window_length
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from receiver.ranging import RangeIntegrator
from receiver.writer import FrameSink

START = 123_457      # transmitted symbol at receiver sample 0 (mid-frame, mid-superframe)
CARRIER = 666e6


def receive(x, config=None, chunk=1 << 18, rate=SYMBOL_RATE_HZ):
    rx = Receiver(rate, CARRIER, config or ReceiverConfig(clock_offset_hz=0.0))
    rows = FrameBatch.concatenate(list(receive_stream((x[i:i + chunk] for i in range(0, len(x), chunk)), rate,
                                                      CARRIER, receiver=rx)))
    return rows, rx


@pytest.mark.parametrize("mode,rotating", [(PnMode.PN420, True), (PnMode.PN420, False), (PnMode.PN595, False),
                                           (PnMode.PN945, True), (PnMode.PN945, False)])
def test_acquisition_mode_grid_superframe_and_bulk_cfo(mode, rotating):
    x = make_signal(window_length(16), pn_mode=mode, rotating=rotating, cfo_hz=5000.0, snr_db=10,
                    start_symbol=START, echo=(5.3, 0.5j))
    acq = acquire(x, 1000)
    flen = mode.value.frame_length
    assert acq is not None and acq.mode is mode and acq.rotating == rotating
    assert acq.frame_start == 1000 + (-START) % flen
    if rotating:
        assert acq.frame_in_superframe == (-(-START // flen)) % mode.value.frames_per_superframe
    assert abs(acq.coarse_cfo_hz - 5000.0) < 100.0     # well inside the SI estimator's +-864 Hz


def test_noise_gives_no_lock_and_no_frames():
    rng = np.random.default_rng(3)
    noise = ((rng.standard_normal(600_000) + 1j * rng.standard_normal(600_000)) / np.sqrt(2)).astype(np.complex64)
    assert acquire(noise[: window_length(16)], 0) is None
    rows, rx = receive(noise)
    assert len(rows) == 0 and rx.acquisitions == [] and rx.attributes()["pn_mode"] == "none"


@pytest.mark.parametrize("mode", list(PnMode))
def test_cfo_tracks_a_doppler_ramp(mode):
    """Per-frame CFO (SI and PN) follows a 5 kHz offset with a 40 Hz/s ramp, with a sampling offset."""
    x = make_signal(int(0.12 * SYMBOL_RATE_HZ), pn_mode=mode, cfo_hz=5000.0, cfo_rate_hz_per_s=40.0, snr_db=15,
                    start_symbol=START, sampling_offset_ppm=2.0, echo=(3.0, 0.3))
    rows, rx = receive(x)
    starts = frame_start_samples(mode, START, len(x), 2.0)
    assert rx.pn_mode is mode and len(rows) >= len(starts) - 3
    # Frame times match the transmitted frame starts (the main path) to a sample.
    assert np.max(np.min(np.abs(rows.t_s[:, None] * SYMBOL_RATE_HZ - starts[None, :]), axis=1)) <= 1.5
    mid_t = rows.t_s - 0.5 * np.diff(rows.t_s, prepend=np.nan)     # CFO of a pair: at the midpoint
    truth = 5000.0 + 40.0 * mid_t
    err_si, err_pn = rows.cfo_hz - truth, rows.cfo_pn_hz - truth
    n = np.isfinite(err_si).sum()
    sigma_si = 8.5 * (1.0 if mode is not PnMode.PN595 else 1.2)   # 36 carriers at 15 dB: ~8.5 Hz per pair
    assert abs(np.nanmean(err_si)) < 4 * sigma_si / np.sqrt(n) + 0.5
    assert np.nanstd(err_si) < 1.3 * sigma_si
    assert abs(np.nanmean(err_pn)) < 1.0 and np.nanstd(err_pn) < np.nanstd(err_si)
    assert rx.si_index == 15
    assert np.all(rows.snr_db[1:] > 12) and np.all(rows.snr_db < 18)


def test_velocity_and_range_signs():
    """A carrier 10 Hz above f_s is closing: positive velocity, shrinking range of c/fc * 10 m/s."""
    x = make_signal(int(0.1 * SYMBOL_RATE_HZ), cfo_hz=1010.0, snr_db=20, start_symbol=START)
    rows, _ = receive(x, ReceiverConfig(clock_offset_hz=1000.0))
    v = 10.0 * SPEED_OF_LIGHT_MPS / CARRIER
    assert abs(np.nanmean(rows.velocity_mps) - v) < 0.1 * v
    expected = -v * (rows.t_s - rows.t_s[0])
    assert np.max(np.abs(rows.range_change_m - expected)) < 0.01
    # A front end that swaps I and Q flips every frequency; the option flips it back.
    rows_c, _ = receive(np.conj(x), ReceiverConfig(clock_offset_hz=1000.0, iq_orientation="conjugate"))
    assert np.allclose(rows_c.cfo_hz[1:], rows.cfo_hz[1:], atol=1e-6)


def test_static_window_calibrates_f_s():
    x = make_signal(int(0.15 * SYMBOL_RATE_HZ), cfo_hz=2345.0, snr_db=15, start_symbol=START)
    rows, rx = receive(x, ReceiverConfig(static_window_s=0.05))
    assert abs(rx.ranging.clock_offset_hz - 2345.0) < 1.0
    calibration = (rows.flags & FrameFlag.CALIBRATION) > 0
    assert calibration[:50].all() and not calibration[-50:].any()
    assert abs(np.nanmean(rows.doppler_hz)) < 1.0


def test_si_word_is_identified():
    x = make_signal(int(0.08 * SYMBOL_RATE_HZ), si_index=10, snr_db=5, start_symbol=START, cfo_hz=-700.0)
    _, rx = receive(x)
    assert rx.si_index == 10


@pytest.mark.parametrize("echo", [None, (10.0, -0.9), (3.0, 0.7j)])
def test_si_snr_follows_the_channel_on_the_si_carriers(echo):
    """A flat channel: SI SNR = body SNR. An echo: the SI slice sees |H(f_k)|^2, not the band's sum of path powers."""
    from dtmbnav_core.gb20600 import bin_frequency_hz, si_bins

    x = make_signal(int(0.05 * SYMBOL_RATE_HZ), cfo_hz=2000.0, snr_db=20, start_symbol=START, echo=echo)
    rows, _ = receive(x, ReceiverConfig(clock_offset_hz=2000.0))
    delay, gain = echo or (0.0, 0.0)
    f_k = bin_frequency_hz(np.asarray(si_bins()))
    h_si = np.mean(np.abs(1.0 + gain * np.exp(-2j * np.pi * f_k * delay / SYMBOL_RATE_HZ)) ** 2)
    assert len(rows) > 50
    assert np.median(rows.si_snr_db) == pytest.approx(20.0 + 10 * np.log10(h_si), abs=1.0)
    assert np.median(rows.snr_db) == pytest.approx(20.0 + 10 * np.log10(1 + abs(gain) ** 2), abs=1.0)


SIGNAL = make_signal(int(0.09 * SYMBOL_RATE_HZ), cfo_hz=4000.0, snr_db=12, start_symbol=START, sampling_offset_ppm=4.0)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.integers(1, 200_000), min_size=1, max_size=8))
def test_chunk_size_invariance(cuts):
    """Per-frame results are identical whatever the chunking."""
    config = ReceiverConfig(clock_offset_hz=4000.0, batch_frames=32)
    whole, _ = receive(SIGNAL, config, chunk=len(SIGNAL))
    edges = np.unique(np.clip(np.cumsum(cuts), 0, len(SIGNAL)))
    rx = Receiver(SYMBOL_RATE_HZ, CARRIER, config)
    parts = list(receive_stream(np.split(SIGNAL, edges), SYMBOL_RATE_HZ, CARRIER, receiver=rx))
    chunked = FrameBatch.concatenate(parts)
    for name, column in whole.columns().items():
        assert np.array_equal(column, getattr(chunked, name), equal_nan=True), name


def test_chunk_size_invariance_with_resampling():
    rate = 10e6
    x = make_signal(int(0.05 * rate), cfo_hz=-3000.0, snr_db=15, start_symbol=START, sampling_offset_ppm=1e6 * (rate / SYMBOL_RATE_HZ - 1))
    config = ReceiverConfig(clock_offset_hz=-3000.0, batch_frames=16)
    a, rx = receive(x, config, chunk=len(x), rate=rate)
    b, _ = receive(x, config, chunk=77_777, rate=rate)
    assert len(a) > 60 and rx.resampler.up == 189 and rx.resampler.down == 250
    for name, column in a.columns().items():
        assert np.array_equal(column, getattr(b, name), equal_nan=True), name
    # sample_index counts input samples.
    assert np.allclose(a.sample_index, np.floor(a.t_s * rate), atol=1)


def test_gap_flag_and_reacquisition_after_2s_dropout():
    before = int(0.06 * SYMBOL_RATE_HZ)
    gap = int(2.0 * SYMBOL_RATE_HZ)
    after = int(0.06 * SYMBOL_RATE_HZ)
    first = make_signal(before, cfo_hz=3000.0, snr_db=15, start_symbol=START)
    second = make_signal(after, cfo_hz=3000.0, snr_db=15, start_symbol=START, first_sample=before + gap)
    rng = np.random.default_rng(5)
    noise = (0.18 * (rng.standard_normal(gap) + 1j * rng.standard_normal(gap))).astype(np.complex64)
    x = np.concatenate([first, noise, second])
    rows, rx = receive(x, ReceiverConfig(clock_offset_hz=3000.0, batch_frames=32), chunk=1 << 20)
    assert len(rx.acquisitions) == 2
    gap_rows = np.flatnonzero(rows.flags & FrameFlag.GAP)
    assert len(gap_rows) == 1
    g = gap_rows[0]
    assert before / SYMBOL_RATE_HZ + 1.99 < rows.t_s[g] < (before + gap) / SYMBOL_RATE_HZ + 0.02
    assert np.all(rows.t_s[:g] < before / SYMBOL_RATE_HZ + 0.001)
    # The frame counter keeps counting frame periods across the gap and agrees with the superframe.
    flen = 4200
    elapsed = np.rint((rows.t_s[g] - rows.t_s[g - 1]) * SYMBOL_RATE_HZ / flen)
    assert rows.frame_index[g] - rows.frame_index[g - 1] == elapsed
    tx_frame = np.rint((rows.t_s * SYMBOL_RATE_HZ + START) / flen).astype(int)
    assert np.all((tx_frame - rows.frame_index) % 225 == 0)
    assert np.isnan(rows.cfo_hz[g]) and np.isfinite(rows.range_change_m).all()


def test_files_roundtrip(tmp_path):
    x = make_signal(int(0.04 * SYMBOL_RATE_HZ), snr_db=15, start_symbol=START)
    rows, rx = receive(x)
    path = tmp_path / "rx.h5"
    sink = FrameSink(path, tmp_path / "rx.csv")
    half = len(rows) // 2  # written in two batches: the resizable columns must join them
    sink.append(rows.select(slice(0, half)))
    sink.append(rows.select(slice(half, None)))
    sink.close(rx.attributes())
    assert sink.frames == len(rows)
    back = read_columns(path, "receiver/frames")
    assert set(back) == set(rows.columns())
    assert np.array_equal(back["t_s"], rows.t_s)
    with h5py.File(path, "r") as f:
        attrs = f["receiver/frames"].attrs
        assert attrs["pn_mode"] == "PN420" and attrs["si_index"] == 15 and attrs["clock_offset_hz"] == 0.0
        assert attrs["resample_up"] == 1 and "units" in attrs
    table = np.genfromtxt(tmp_path / "rx.csv", delimiter=",", names=True)
    assert np.allclose(table["t_s"], rows.t_s) and len(table) == len(rows)


def test_clear_errors():
    with pytest.raises(ValueError, match="sample_rate_hz"):
        Receiver(0.0, CARRIER)
    with pytest.raises(ValueError, match="carrier_hz"):
        Receiver(SYMBOL_RATE_HZ, -1.0)
    with pytest.raises(ValueError, match="batch_frames"):
        ReceiverConfig(batch_frames=0)
    with pytest.raises(ValueError, match="header mode"):
        ReceiverConfig(pn_mode="PN123")
    with pytest.raises(ValueError, match="complex"):
        Receiver(SYMBOL_RATE_HZ, CARRIER).process(np.zeros(10, np.float32))
    # A static window with no usable CFO (every frame weak) cannot give f_s.
    n = 5
    weak = FrameBatch(t_s=np.arange(n) * 5.6e-4, sample_index=np.arange(n), frame_index=np.arange(n),
                      pn_phase=np.zeros(n, np.int32), cfo_hz=np.full(n, 10.0), cfo_pn_hz=np.full(n, 10.0),
                      doppler_hz=np.full(n, np.nan), velocity_mps=np.full(n, np.nan),
                      range_change_m=np.full(n, np.nan), snr_db=np.zeros(n, np.float32), si_snr_db=np.zeros(n, np.float32),
                      peak_metric=np.zeros(n, np.float32), flags=np.full(n, FrameFlag.LOW_QUALITY, np.uint8),
                      segment_id=np.zeros(n, np.int32))
    ranging = RangeIntegrator(CARRIER, None, static_window_s=1.0)
    assert ranging.push(weak) == []
    with pytest.raises(ValueError, match="static window"):
        ranging.flush()
    with pytest.raises(ValueError, match="static_window_s"):
        RangeIntegrator(CARRIER, None, static_window_s=0.0)
