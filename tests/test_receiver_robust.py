"""What real front ends do to a capture: kHz-level tuner offsets, swapped I/Q, dropouts, interference,
and narrowband (RTL-SDR) rates.

Each test builds the impairment into a simulated capture (sim.rf) or a
symbol-rate test signal and checks the receiver's output against the truth.
The narrowband figures over 40 s of walking come from
``python -m dtmbnav.evaluation.accuracy --narrowband``; here a few seconds.
"""

from dataclasses import replace

import numpy as np
import pytest
from dtmbnav.evaluation.accuracy import accuracy, match_truth, run_capture
from receiver_signals import make_signal

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from dtmbnav_core.records import FrameBatch, FrameFlag
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from sim.devices import HACKRF_PHASE_NOISE
from sim.frames import FrameConfig, FrameSource
from sim.frontend import PHASE_BLOCK, PhaseNoise, rotate_kernel
from sim.scenario import load_scenario

CARRIER = 666e6
START = 123_457      # transmitted symbol at receiver sample 0


def receive(x, config, rate=SYMBOL_RATE_HZ):
    rx = Receiver(rate, CARRIER, config)
    rows = FrameBatch.concatenate(list(receive_stream([x], rate, CARRIER, receiver=rx)))
    return rows, rx


def walking_segment(seconds=0.4, **receiver):
    """A piece of the park-loop walk (line of sight, C/N 15 dB), received with f_s = the tuner offset
    (the clock's own offset is taken out of the comparison, :func:`range_error_m`)."""
    scn = load_scenario("park-loop-cw")
    start = scn.walk.start_still_s + 5.0
    bulk = receiver.get("bulk_cfo_hz", 0.0)
    return run_capture(scn, start_s=start, seconds=seconds, config=ReceiverConfig(clock_offset_hz=bulk), **receiver)


def range_error_m(run):
    """Largest error of the range change against the truth's since the first frame, m."""
    f, tr = run.frames, run.truth
    j = match_truth(f, tr)
    # f_s was given as the tuner offset; the (GNSS-disciplined) clock's own offset integrates too.
    clock = tr.clock_offset_hz[j] * run.receiver.ranging.wavelength_m
    true_change = tr.range_m[j] - tr.range_m[j[0]] - np.cumsum(np.r_[0.0, clock[1:] * np.diff(f.t_s)])
    return float(np.max(np.abs(f.range_change_m - true_change)))


@pytest.mark.slow
@pytest.mark.parametrize("mode,offset_hz", [("PN420", 40e3), ("PN420", 20e3), ("PN945", -40e3), ("PN595", 40e3)])
def test_tuner_offset_of_tens_of_khz_locks_and_ranges(mode, offset_hz):
    """A HackRF/PlutoSDR crystal 20-60 ppm off at UHF: the PN ambiguity is resolved, the range is right.

    A CFO left wrong by 0.5 Hz would already move the range by 0.1 m over these 0.4 s; the issue's range
    target is 0.5 m (95 %).
    """
    run = walking_segment(pn_mode=mode, bulk_cfo_hz=offset_hz)
    rx, f = run.receiver, run.frames
    assert len(rx.acquisitions) == 1 and rx.si_index == 15
    assert abs(rx.acquisitions[0].coarse_cfo_hz - offset_hz) < 500.0      # inside the SI estimator's +-900 Hz
    assert len(f) > 0.9 * len(run.truth.t_s)
    assert range_error_m(run) < 0.1
    assert not np.any(f.flags & FrameFlag.LOW_QUALITY)


def test_offset_outside_the_search_is_named():
    x = make_signal(int(0.04 * SYMBOL_RATE_HZ), snr_db=15, cfo_hz=25e3, start_symbol=START)
    rows, rx = receive(x, ReceiverConfig(clock_offset_hz=0.0, cfo_search_hz=10e3))
    assert len(rows) == 0 and not rx.acquisitions
    assert any("outside the search" in note for note in rx.notes())
    rows, rx = receive(x, ReceiverConfig(clock_offset_hz=25e3))
    assert len(rows) > 40 and abs(rx.acquisitions[0].coarse_cfo_hz - 25e3) < 300.0


@pytest.mark.slow
def test_conjugated_capture_is_detected_and_gives_the_right_range_sign():
    """Swapped I/Q without --conjugate: the SI word decodes only conjugated; the output is what --conjugate gives."""
    run = walking_segment(seconds=0.6, iq_conjugate=True, bulk_cfo_hz=3000.0)
    rx, f = run.receiver, run.frames
    assert rx.conjugated and rx.si_index == 15
    assert any("I and Q are swapped" in note for note in rx.notes())
    assert rx.attributes()["conjugate_iq"] and rx.attributes()["iq_orientation"] == "auto"
    # The walker closes on or leaves the tower over this stretch: the sign of the range change is the truth's.
    j = match_truth(f, run.truth)
    true_change = run.truth.range_m[j[-1]] - run.truth.range_m[j[0]]
    assert abs(true_change) > 0.3
    assert np.sign(f.range_change_m[-1]) == np.sign(true_change)
    assert range_error_m(run) < 0.1
    given = run_capture(run.scenario, start_s=run.start_s, seconds=0.6,
                        config=ReceiverConfig(clock_offset_hz=3000.0, iq_orientation="conjugate"))
    for name, column in f.columns().items():
        assert np.array_equal(column, getattr(given.frames, name), equal_nan=True), name


def test_orientation_at_low_snr():
    """At 5 dB: a normal capture stays as it is; its conjugate is conjugated back, to the same rows."""
    x = make_signal(int(0.06 * SYMBOL_RATE_HZ), snr_db=5, cfo_hz=-700.0, start_symbol=START)
    config = ReceiverConfig(clock_offset_hz=-700.0)
    rows, rx = receive(x, config)
    assert not rx.conjugated and rx.si_index == 15 and not rx.notes()
    rows_c, rx_c = receive(np.conj(x), config)
    assert rx_c.conjugated and rx_c.si_index == 15
    for name, column in rows.columns().items():
        assert np.array_equal(column, getattr(rows_c, name), equal_nan=True), name


def test_a_conjugated_stream_with_threads_gives_the_rows_of_one_thread():
    """Blocks are prefetched before the orientation is decided (from the unconjugated samples); the rows after
    the stream is conjugated and locked again are those of one thread."""
    x = np.conj(make_signal(int(0.3 * SYMBOL_RATE_HZ), snr_db=12, cfo_hz=-700.0, start_symbol=START))
    config = ReceiverConfig(clock_offset_hz=-700.0)
    rows, rx = receive(x, config)
    rows_2, rx_2 = receive(x, replace(config, jobs=2))
    assert rx.conjugated and rx_2.conjugated and len(rows) > 400
    assert rx_2._workers.prefetch_hits > 0
    for name, column in rows.columns().items():
        assert np.array_equal(column, getattr(rows_2, name), equal_nan=True), name


def test_dropout_adds_no_range_jump():
    """A standing receiver and a 2 s dropout: the range is held across the gap, a new segment starts."""
    before, gap, after = int(0.06 * SYMBOL_RATE_HZ), int(2.0 * SYMBOL_RATE_HZ), int(0.06 * SYMBOL_RATE_HZ)
    # The receiver stands still: its CFO is f_s (2 Hz off, as a measured f_s is), whatever the frame.
    first = make_signal(before, cfo_hz=3002.0, snr_db=15, start_symbol=START)
    second = make_signal(after, cfo_hz=3002.0, snr_db=15, start_symbol=START, first_sample=before + gap)
    noise = (0.18 * (np.array([1, 1j]) @ np.random.default_rng(5).standard_normal((2, gap)))).astype(np.complex64)
    config = ReceiverConfig(clock_offset_hz=3000.0, batch_frames=32, pn_mode="PN420")
    rows, rx = receive(np.concatenate([first, noise, second]), config)
    g = int(np.flatnonzero(rows.flags & FrameFlag.GAP)[0])
    assert len(rx.acquisitions) == 2 and rows.t_s[g] - rows.t_s[g - 1] > 1.9
    assert np.all(rows.segment_id[:g] == 0) and np.all(rows.segment_id[g:] == 1)
    step = np.diff(rows.range_change_m)
    per_frame = np.std(np.delete(step, g - 1))
    assert abs(step[g - 1]) < 1e-9 < per_frame
    # Inside each segment the 2 Hz left in the CFO integrates as it should (-lambda * 2 Hz * t).
    wavelength = rx.ranging.wavelength_m
    for seg in (0, 1):
        rows_seg = rows.select(rows.segment_id == seg)
        drift = rows_seg.range_change_m - rows_seg.range_change_m[0]
        assert np.allclose(drift, -wavelength * 2.0 * (rows_seg.t_s - rows_seg.t_s[0]), atol=0.01)


def test_interference_on_the_si_carriers_is_flagged():
    """Noise on the 72 kHz of the SI carriers only (data folded by aliasing acts so): the header does not see it,
    so the SI SNR does not explain the CFO's scatter, and the frames are flagged LOW_QUALITY."""
    n = int(0.06 * SYMBOL_RATE_HZ)
    x = make_signal(n, snr_db=20, cfo_hz=1000.0, start_symbol=START)
    clean, rx_clean = receive(x, ReceiverConfig(clock_offset_hz=1000.0))
    assert rx_clean.scatter_flagged == 0 and not np.any(clean.flags & FrameFlag.LOW_QUALITY)
    rng = np.random.default_rng(7)
    spectrum = np.fft.fft(rng.standard_normal(n) + 1j * rng.standard_normal(n))
    freq = np.fft.fftfreq(n, 1.0 / SYMBOL_RATE_HZ)
    band = np.abs(freq) < 40e3
    hum = np.fft.ifft(np.where(band, spectrum, 0.0))
    hum *= np.sqrt(3.0 * band.mean() / np.mean(np.abs(hum) ** 2))   # 3x the signal's power in that band
    rows, rx = receive((x + hum).astype(np.complex64), ReceiverConfig(clock_offset_hz=1000.0))
    flagged = (rows.flags & FrameFlag.LOW_QUALITY) > 0
    assert flagged[1:].mean() > 0.9 and rx.scatter_flagged == np.count_nonzero(flagged)
    assert any("LOW_QUALITY" in note for note in rx.notes())


def test_si_range_of_a_standing_receiver_stays_bounded_in_noise_and_lo_phase_noise():
    """2 s standing at a body SNR of 5 dB, f_s given: the SI phase is bounded noise, so the range must not wander.

    Summed frame-pair angles (eq. 6 as written) random-walk with the noise's second-order terms, to several
    times the per-frame noise over 1000 frames, and a HackRF's LO phase noise redraws that walk (issue 44: the
    twin with the same thermal noise ends up centimetres apart). Phases measured against the SI reference
    (receiver.cfo, "Telescoping") telescope: the range moves by the per-frame noise alone, whatever the lag,
    and the LO phase noise adds little more than its own phase.
    """
    n, lag = int(2.0 * SYMBOL_RATE_HZ), 1000
    rng = np.random.default_rng(3)
    clean = FrameSource(FrameConfig(seed=3)).symbols(START, START + n) * np.exp(
        2j * np.pi * 3000.0 * np.arange(n) / SYMBOL_RATE_HZ)
    noise = np.sqrt(10 ** (-5 / 10) / 2) * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    lo = PhaseNoise([list(point) for point in HACKRF_PHASE_NOISE], SYMBOL_RATE_HZ, seed=3, stream_id=0)
    lo_phase = np.concatenate([lo.block(b) for b in range(-(-n // PHASE_BLOCK))])[:n]
    ranges = []
    for signal in (clean, rotate_kernel(clean, lo_phase)):
        rows, _ = receive((signal + noise).astype(np.complex64), ReceiverConfig(clock_offset_hz=3000.0,
                                                                               track_paths=False))
        ranges.append(rows.range_change_m)
    plain, with_lo = ranges
    per_frame = np.std(np.diff(plain))
    assert np.std(plain[lag:] - plain[:-lag]) < 2 * per_frame < 0.02
    assert np.max(np.abs(with_lo - plain)) < 0.003


@pytest.mark.slow
def test_narrowband_capture_ranges_like_a_wideband_one():
    """An RTL-SDR's 2.4 Msps: 2 s standing (f_s over 1.5 s) then 3 s of walking; the issue's accuracy targets.

    Velocity RMSE of 1 s means <= 0.05 m/s and range 95 % <= 0.5 m, which the 40 s walks at 2.048, 2.4
    and 3.2 Msps meet by a wide margin (README, ``python -m dtmbnav.evaluation.accuracy --narrowband``); over
    3 s the range error has less time to grow. (Every narrowband rate is received in
    tests/test_receiver_rates.py.)
    """
    rate = 2.4e6
    scn = load_scenario("park-loop-cw")
    still = scn.walk.start_still_s
    run = run_capture(scn, start_s=still - 2.0, seconds=5.0, config=ReceiverConfig(static_window_s=1.5),
                      sample_rate_hz=rate)
    acc = accuracy(run, 2.0, 5.0)
    assert acc.velocity_rmse_1s_mps < 0.05 and acc.range_error_p95_m < 0.5
    f, attrs = run.frames, run.receiver.attributes()
    assert not np.any(f.flags & (FrameFlag.GAP | FrameFlag.LOW_QUALITY))
    assert attrs["narrowband"] and attrs["bandwidth_hz"] == rate and "narrowband" in attrs["notes"]


def test_narrowband_si_carriers_keep_their_snr():
    """The SI SNR of a band-limited capture is that of the whole channel: the same carriers, the same noise density."""
    scn = load_scenario("park-loop-cw")
    snr = {}
    for rate in (7.56e6, 2.4e6):
        run = run_capture(scn, start_s=3.0, seconds=0.15, config=ReceiverConfig(clock_offset_hz=0.0),
                          sample_rate_hz=rate, sample_format="cf32")
        snr[rate] = float(np.median(run.frames.si_snr_db))
    assert snr[2.4e6] == pytest.approx(snr[7.56e6], abs=0.5)


def test_segment_change_is_a_new_origin_for_the_fusion():
    """A re-acquisition 10 ms long, between two step epochs: the next epoch has no range, the range
    returns only after the settling time, as a new origin (the filters re-anchor there); a file without
    segment_id is one segment."""
    from receiver.observables import ranges_from_frames
    from fusion.observations import AggregationConfig, aggregate_ranges

    t = np.arange(0.0, 12.0, 1.0 / 1800.0)
    t = t[(t < 6.24) | (t >= 6.25)]
    frames = {"t_s": t, "range_change_m": 0.1 * t, "snr_db": np.full(len(t), 15.0, np.float32),
              "si_snr_db": np.full(len(t), 15.0, np.float32), "flags": np.zeros(len(t), np.uint8),
              "segment_id": (t >= 6.25).astype(np.int32)}
    epochs = np.arange(0.5, 11.6, 0.5)
    config = AggregationConfig()
    aggregated = aggregate_ranges(ranges_from_frames(frames), epochs, config)
    kept = np.isfinite(aggregated.range_change_m)
    assert np.all(kept[epochs < 6.25])
    assert not np.any(kept[(epochs > 6.25) & (epochs < 6.25 + config.settle_s)])
    assert np.all(kept[epochs > 6.5 + config.settle_s])
    assert np.flatnonzero(aggregated.new_origin).tolist() == [np.flatnonzero(kept & (epochs > 6.25))[0]]
    del frames["segment_id"]
    old = ranges_from_frames(frames)
    assert np.all(old.segment_id == 0)
    aggregated = aggregate_ranges(old, epochs, config)
    assert np.all(np.isfinite(aggregated.range_change_m)) and not np.any(aggregated.new_origin)


@pytest.mark.parametrize("rate", [2.048e6, 2.4e6, 3.2e6])
def test_simulated_front_end_filters_before_it_samples(rate):
    """The simulator's narrowband capture is the band-limited centre of the channel: the pulse through its
    anti-alias filter is flat over the passband and at least the stopband attenuation down from fs / 2 on,
    so nothing folds onto the SI carriers; at and above the symbol rate the pulse is the SRRC itself."""
    from sim.frontend import (
        ANTI_ALIAS_PASSBAND,
        ANTI_ALIAS_STOPBAND_DB,
        anti_alias_pulse,
    )
    from sim.transmitter import pulse_table

    table = pulse_table(16)
    assert anti_alias_pulse(table, SYMBOL_RATE_HZ) is table
    pulse = anti_alias_pulse(table, rate)
    osr = pulse.oversampling
    # The pulse in time order: column j holds times i / osr + span - 1 - j.
    fine = np.concatenate([pulse.polyphase[:-1, j] for j in range(2 * pulse.span - 1, -1, -1)])
    freq = np.fft.rfftfreq(8 * len(fine), 1.0 / osr) * SYMBOL_RATE_HZ
    gain_db = 20 * np.log10(np.abs(np.fft.rfft(fine, 8 * len(fine))) / osr + 1e-300)
    srrc_db = 20 * np.log10(np.abs(np.fft.rfft(np.concatenate(
        [table.polyphase[:-1, j] for j in range(2 * table.span - 1, -1, -1)]), 8 * len(fine))) / osr + 1e-300)
    passband = freq <= ANTI_ALIAS_PASSBAND * rate / 2
    assert np.max(np.abs(gain_db[passband] - srrc_db[passband])) < 0.1
    stopband = (freq >= rate / 2) & (freq <= SYMBOL_RATE_HZ)
    assert np.max(gain_db[stopband]) < srrc_db[0] - ANTI_ALIAS_STOPBAND_DB
