"""The path tracker (receiver/paths/): pulse model, kernels against their numpy twins, and
tracking on constructed signals with known answers (close paths, a weak first path, a forced
cycle slip, two towers), no paths from noise or from the SI carriers alone, and the output."""

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from receiver_signals import SignalPath, frame_start_samples, make_paths_signal

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.h5io import read_columns
from dtmbnav_core.records import FrameBatch, PathBatch, PathFlag
from receiver import CLOCK_PATHS
from receiver.capture import open_capture
from receiver.channel_estimate import ChannelEstimator
from receiver.paths import (
    PULSE_OVERSAMPLING,
    PathConfig,
    PathTracker,
    detection_threshold,
    fit_paths_kernel,
    fit_paths_reference,
    pulse_tables,
    resampler_response,
    slip_kernel,
    slip_reference,
)
from receiver.pipeline import Receiver, ReceiverConfig, receive_file
from receiver.ranging import PathRanging
from sim.transmitter import srrc_pulse

START = 123_457
CARRIER = 666e6
WAVELENGTH = SPEED_OF_LIGHT_MPS / CARRIER
RNG = np.random.default_rng(14)


def run_receiver(x, config=None, chunk=1 << 18):
    """Frames and path rows of a receiver run over ``x`` (7.56 Msps)."""
    rx = Receiver(SYMBOL_RATE_HZ, CARRIER, config or ReceiverConfig(clock_offset_hz=0.0))
    frames, paths = [], []
    for i in range(0, len(x), chunk):
        frames += rx.process(x[i:i + chunk])
        paths.append(rx.pop_paths())
    frames += rx.finish()
    paths.append(rx.pop_paths())
    return FrameBatch.concatenate(frames), PathBatch.concatenate(paths), rx


def path_arrivals(rows: PathBatch, n_samples: int) -> np.ndarray:
    """Each row's path arrival minus the transmitted frame start on the receiver's sample axis, samples."""
    starts = frame_start_samples(PnMode.PN420, START, n_samples)
    arrival = (rows.t_s + rows.delay_s) * SYMBOL_RATE_HZ
    j = np.clip(np.searchsorted(starts, arrival - 100.0), 0, len(starts) - 1)
    return arrival - starts[j]


def settled(rows: PathBatch, after_s: float) -> PathBatch:
    """The rows from ``after_s`` on (the tracker has converged)."""
    return rows.select(rows.t_s >= after_s)


# ---- pulse model and kernels -----------------------------------------------------------------

def test_pulse_table_is_the_transmitters_srrc_made_periodic():
    period = 255
    g, dg = pulse_tables(period)
    x = np.linspace(-30.0, 30.0, 2401)
    periodic = sum(srrc_pulse(x + j * period) for j in (-2, -1, 0, 1, 2))
    grid = np.arange(period * PULSE_OVERSAMPLING) / PULSE_OVERSAMPLING
    table = np.interp(np.mod(x, period), grid, g[:-1], period=period)
    assert np.max(np.abs(table - periodic)) < 2e-3 * periodic.max()
    slope = np.interp(np.mod(x, period), grid, dg[:-1], period=period)
    numeric = (srrc_pulse(x + 1e-4) - srrc_pulse(x - 1e-4)) / 2e-4
    assert np.max(np.abs(slope - numeric)) < 1e-2 * np.abs(numeric).max()


def test_resampler_response_is_flat_in_band_and_closes_beyond_nyquist():
    response = resampler_response(189, 250)     # 10 Msps -> 7.56 Msps
    assert resampler_response(1, 1) is None
    values = response(np.array([0.0, 0.2, 0.4, 0.6, 0.8]))
    np.testing.assert_allclose(values[:3], 1.0, atol=2e-3)
    assert np.all(np.abs(values[3:]) < 1e-2)


def fit_inputs(n_frames=40, n_paths=3):
    g, dg = pulse_tables(255)
    true_delay = np.array([-2.3, -1.75, 6.4])[:n_paths]
    offsets = np.where(np.arange(n_frames) < 23, 0.0, 1.0)
    lag_axis = -83 + np.arange(165)
    amps = (RNG.standard_normal((n_frames, n_paths)) + 1j * RNG.standard_normal((n_frames, n_paths)))
    x = np.mod(lag_axis[None, None, :] - (true_delay[None, :, None] - offsets[:, None, None]), 255)
    grid = np.arange(255 * PULSE_OVERSAMPLING) / PULSE_OVERSAMPLING
    shapes = np.interp(x, grid, g[:-1], period=255)
    taps = np.einsum("fp,fpl->fl", amps, shapes) + 0.01 * (RNG.standard_normal((n_frames, 165))
                                                             + 1j * RNG.standard_normal((n_frames, 165)))
    return taps.astype(np.complex64), offsets, g, dg, true_delay


def test_fit_kernel_equals_its_numpy_reference():
    taps, offsets, g, dg, true_delay = fit_inputs()
    start_delay = true_delay + np.array([0.1, -0.08, 0.05])
    rate = np.array([1e-3, -2e-3, 0.0])
    d1, r1 = start_delay.copy(), rate.copy()
    amps, lags, var = (np.zeros((len(taps), 3), complex), np.zeros((len(taps), 3)), np.zeros((len(taps), 3)))
    resid = np.zeros(taps.shape[1])
    steps = np.array([0.2, 0.2, 0.01])
    fit_paths_kernel(taps, offsets, -83, d1, r1, steps, g, dg, PULSE_OVERSAMPLING, 16, 0.3, 0.02, 0.05, amps, lags, var,
                     resid)
    d2, r2 = start_delay.copy(), rate.copy()
    ref = fit_paths_reference(taps, offsets, -83, d2, r2, steps, g, dg, PULSE_OVERSAMPLING, 16, 0.3, 0.02, 0.05)
    for got, want in zip((amps, lags, var, resid), ref):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(d1, d2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1, r2, rtol=0, atol=1e-12)


def test_fit_kernel_equals_its_numpy_reference_when_the_paths_drift_fast():
    """A crystal 10 ppm off moves every path 0.042 samples per frame: runs shorter than the update block."""
    taps, offsets, g, dg, true_delay = fit_inputs()
    rate = np.array([0.042, 0.041, 0.043])
    d1, r1, d2, r2 = true_delay.copy(), rate.copy(), true_delay.copy(), rate.copy()
    amps, lags, var = (np.zeros((len(taps), 3), complex), np.zeros((len(taps), 3)), np.zeros((len(taps), 3)))
    resid = np.zeros(taps.shape[1])
    steps = np.full(3, 0.2)
    fit_paths_kernel(taps, offsets, -83, d1, r1, steps, g, dg, PULSE_OVERSAMPLING, 16, 0.3, 0.02, 0.05, amps, lags, var,
                     resid)
    ref = fit_paths_reference(taps, offsets, -83, d2, r2, steps, g, dg, PULSE_OVERSAMPLING, 16, 0.3, 0.02, 0.05)
    for got, want in zip((amps, lags, var, resid), ref):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-8)
    # Each frame is its own run: its lags move by the rate from frame to frame.
    np.testing.assert_allclose(np.diff(lags[:16, 0]), 0.042, atol=1e-6)


def test_fit_kernel_converges_on_paths_half_a_chip_apart():
    taps, offsets, g, dg, true_delay = fit_inputs(n_frames=400, n_paths=2)
    delay = true_delay + np.array([0.15, -0.15])       # start 0.2 chip apart instead of 0.55
    rate = np.zeros(2)
    amps, lags, var = (np.zeros((400, 2), complex), np.zeros((400, 2)), np.zeros((400, 2)))
    fit_paths_kernel(taps, offsets, -83, delay, rate, np.full(2, 0.2), g, dg, PULSE_OVERSAMPLING, 16, 0.3, 0.0, 0.05, amps,
                     lags, var, np.zeros(165))
    np.testing.assert_allclose(delay, true_delay, atol=0.01)


def _slip_run(cfo, dt, sigma, cut=None, alpha=10.0):
    """slip_kernel over the frames, in one batch or two cut at ``cut``, and its twin in one."""
    n = len(cfo)
    bridged, slips = np.empty(n), np.zeros(n, bool)
    state = (np.nan, 0.0, 0.0)
    for part in ((slice(0, n),) if cut is None else (slice(0, cut), slice(cut, n))):
        column, flags = np.empty(part.stop - part.start), np.zeros(part.stop - part.start, bool)
        state = slip_kernel(cfo[part], dt[part], sigma[part], *state, alpha, 6.0, 0.05, column, flags)
        bridged[part], slips[part] = column, flags
    return bridged, slips, state, slip_reference(cfo, dt, sigma, np.nan, 0.0, 0.0, alpha, 6.0, 0.05)


def _slip_frames(n=300):
    cfo = 3.0 + 0.2 * RNG.standard_normal(n)
    return cfo, np.full(n, 5.556e-4), np.full(n, 0.01)


def test_slip_kernel_equals_its_reference():
    cfo, dt, sigma = _slip_frames()
    cfo[100:104] += 0.25 / 5.556e-4                      # one cycle over four frames
    cfo[200] = np.nan
    bridged, slips, state, ref = _slip_run(cfo, dt, sigma)
    np.testing.assert_array_equal(bridged, ref[0])
    np.testing.assert_array_equal(slips, ref[1])
    assert state == pytest.approx(ref[2:])
    assert list(np.flatnonzero(slips)) == [100, 101, 102, 103]


def test_a_lasting_frequency_step_is_one_slip_not_a_flag_that_never_clears():
    # 150 Hz more from frame 100 on (0.083 cycles a frame, an outlier against the old reference) for 2000
    # frames, 1.1 s: the reference (time constant 0.1 s) restarts after 180 frames and the flags stop there.
    cfo, dt, sigma = _slip_frames(2300)
    cfo[100:] += 150.0
    bridged, slips, state, ref = _slip_run(cfo, dt, sigma)
    np.testing.assert_array_equal(slips, ref[1])
    flagged = np.flatnonzero(slips)
    assert flagged[0] == 100 and flagged[-1] == 100 + int(np.ceil(0.1 / 5.556e-4)) - 1
    assert np.all(np.diff(flagged) == 1)                 # one run: one slip
    np.testing.assert_array_equal(bridged[flagged[-1] + 1:], cfo[flagged[-1] + 1:])
    assert state[0] == pytest.approx(153.0, abs=0.5)      # the reference now follows the new frequency


@settings(max_examples=60, deadline=None)
@given(cut=st.integers(1, 599), step_at=st.integers(0, 599), step_hz=st.sampled_from([0.0, 150.0, -400.0]))
def test_slip_kernel_is_the_same_wherever_the_batches_are_cut(cut, step_at, step_hz):
    cfo, dt, sigma = _slip_frames(600)
    cfo[step_at:] += step_hz
    cfo[350:354] += 0.25 / 5.556e-4
    bridged, slips, state, ref = _slip_run(cfo, dt, sigma, cut=cut)
    np.testing.assert_array_equal(bridged, ref[0])
    assert state == pytest.approx(ref[2:])
    # Flags are written per batch: a run that crosses the cut and reaches half a cycle after it is flagged
    # from the cut on, the earlier frames of that run (already written) stay unflagged; all else is equal.
    np.testing.assert_array_equal(slips[cut:], ref[1][cut:])
    missed = np.flatnonzero(ref[1][:cut] & ~slips[:cut])
    assert not np.any(slips[:cut] & ~ref[1][:cut])
    assert len(missed) == 0 or (np.all(ref[1][missed[0]:cut]) and slips[cut])


def test_slip_kernel_flags_a_run_crossing_the_cut_from_the_cut_on():
    cfo, dt, sigma = _slip_frames(600)
    cfo[350:354] += 0.25 / 5.556e-4                      # half a cycle after two frames
    assert list(np.flatnonzero(_slip_run(cfo, dt, sigma, cut=351)[1])) == [351, 352, 353]


def test_detection_threshold_has_its_false_alarm_rate():
    frames, pfa = 64, 1e-3
    draws = RNG.exponential(size=(400_000, frames)).mean(axis=1)
    assert np.mean(draws > detection_threshold(frames, pfa)) == pytest.approx(pfa, rel=0.15)


def test_path_ranging_is_eq_11_per_path_from_its_first_row():
    ranging = PathRanging(CARRIER)
    t = np.arange(6) * 0.5e-3
    rows = PathBatch(t_s=np.repeat(t, 2), frame_index=np.repeat(np.arange(6), 2), path_id=np.tile([3, 7], 6),
                     tower_id=np.zeros(12, np.int32), delay_s=np.zeros(12), delay_rate=np.zeros(12, np.float32),
                     cfo_hz=np.tile([110.0, 90.0], 6), doppler_hz=np.full(12, np.nan),
                     range_change_m=np.full(12, np.nan), snr_db=np.zeros(12, np.float32),
                     flags=np.where(np.arange(12) < 2, PathFlag.BORN, 0).astype(np.uint8))
    rows.cfo_hz[6] = np.nan                              # path 3 misses its phase pair on frame 3: held
    ranging.push(rows)
    assert len(ranging.release(None, 1.0)) == 0          # f_s not known yet: rows wait
    out = ranging.release(100.0, t[3])
    assert len(out) == 8
    out_rest = ranging.release(100.0, 1.0)
    both = PathBatch.concatenate([out, out_rest])
    np.testing.assert_allclose(both.range_change_m[both.path_id == 3], -WAVELENGTH * 10.0 * t)
    np.testing.assert_allclose(both.range_change_m[both.path_id == 7], WAVELENGTH * 10.0 * t)


def _path_rows(path_id, t, cfo_hz, snr_db, flags=0):
    n = len(t)
    return PathBatch(t_s=t, frame_index=np.arange(n), path_id=np.full(n, path_id, np.int32),
                     tower_id=np.zeros(n, np.int32), delay_s=np.zeros(n), delay_rate=np.zeros(n, np.float32),
                     cfo_hz=np.asarray(cfo_hz, float), doppler_hz=np.full(n, np.nan),
                     range_change_m=np.full(n, np.nan), snr_db=np.full(n, snr_db, np.float32),
                     flags=np.full(n, flags, np.uint8))


def test_steadiest_path_offset_is_the_mean_frequency_of_the_path_whose_phase_wanders_least():
    ranging = PathRanging(CARRIER)
    t = np.arange(0.0, 2.0, 1e-3)
    assert ranging.steadiest_path_offset_hz(0.0, 2.0) is None                  # nothing tracked
    beat = 0.3 * np.cos(2 * np.pi * 0.4 * t)                                   # a composite's beat: 0.3 Hz swings
    ranging.push(_path_rows(1, t, 5.0 + beat, 30.0))                           # the strongest, but it wanders
    ranging.push(_path_rows(2, t, np.where(t < 1.0, 5.0, 5.02), 0.0))          # weak, steady: its mean is 5.01
    ranging.push(_path_rows(3, t[t > 1.6], np.full((t > 1.6).sum(), 9.0), 0.0))   # constant, but 20 % of the window
    slipped = _path_rows(4, t, np.full(len(t), 7.0), 0.0)
    slipped.flags[500] = PathFlag.CYCLE_SLIP                                   # constant, but slipped
    ranging.push(slipped)
    assert ranging.steadiest_path_offset_hz(0.0, 2.0) == pytest.approx(5.01, abs=1e-3)
    assert ranging.steadiest_path_offset_hz(0.0, 1.0) == pytest.approx(5.0, abs=1e-9)   # the window only
    # a steady path held for half the window beats one that bends over the whole of it
    ranging.push(_path_rows(5, t[t >= 1.0], np.full((t >= 1.0).sum(), 4.0), 0.0))
    assert ranging.steadiest_path_offset_hz(0.0, 2.0) == pytest.approx(4.0, abs=1e-9)


def test_clock_path_steadiest_takes_f_s_from_the_steady_path_not_the_wandering_first_path():
    # Standing still: every path carries only the clock's 1.5 Hz; the first path, 20 dB under a wall
    # reflection 2 chips later, also turns 0.3 extra cycles during the 2 s static window (scatter merged
    # with it), which the first path's own f_s would take for clock and integrate for the rest of the capture.
    clock_hz = 1.5
    first = SignalPath(0.3, 10 ** (-20 / 20), clock_hz, lambda t: 0.3 * np.clip(t / 2.0, 0.0, 1.0))
    wall = SignalPath(2.3, 1.0, clock_hz)
    x = make_paths_signal(int(3.0 * SYMBOL_RATE_HZ), [first, wall], start_symbol=START, snr_db=15)
    estimates = {}
    for clock_path in CLOCK_PATHS:
        _, _, rx = run_receiver(x, ReceiverConfig(static_window_s=2.0, paths=PathConfig(clock_path=clock_path)))
        estimates[clock_path] = rx.first_path_ranging.clock_offset_hz
    assert estimates["steadiest"] == pytest.approx(clock_hz, abs=0.01)
    assert estimates["first"] - clock_hz > 0.1          # the wander, over the part of the window the path was held
    with pytest.raises(ValueError, match="clock_path"):
        PathConfig(clock_path="loudest")


# ---- tracking constructed signals ------------------------------------------------------------

def test_two_paths_half_a_chip_apart_10_db_apart_with_their_own_dopplers():
    paths = [SignalPath(0.3, 1.0, 5.0), SignalPath(0.8, 10 ** (-10 / 20) * np.exp(1j), -3.0)]
    n = int(2.5 * SYMBOL_RATE_HZ)
    _, rows, _ = run_receiver(make_paths_signal(n, paths, start_symbol=START, snr_db=15))
    rows = settled(rows, 1.6)
    ids = np.unique(rows.path_id)
    assert len(ids) == 2
    for pid, truth in zip(sorted(ids, key=lambda p: np.mean(rows.delay_s[rows.path_id == p])), paths):
        q = rows.select(rows.path_id == pid)
        assert np.max(np.abs(path_arrivals(q, n) - truth.delay)) < 0.1
        assert np.mean(q.cfo_hz) == pytest.approx(truth.doppler_hz, abs=0.05)


def test_a_direct_path_20_db_below_a_reflection_two_chips_later_is_the_first_path():
    direct, reflection = SignalPath(0.3, 10 ** (-20 / 20), 2.0), SignalPath(2.3, 1.0, -1.5)
    n = int(2.5 * SYMBOL_RATE_HZ)
    frames, rows, _ = run_receiver(make_paths_signal(n, [direct, reflection], start_symbol=START, snr_db=15))
    # The reflection may serve as first path until the direct path has matured; from then on the
    # direct path is the first path, at its delay.
    first = settled(rows.select((rows.flags & PathFlag.FIRST_PATH) > 0), 1.5)
    assert len(first) > 1000 and len(np.unique(first.path_id)) == 1
    assert np.max(np.abs(path_arrivals(first, n) - direct.delay)) < 0.1
    # From the frame it becomes the first path, the first-path range follows the direct path's Doppler.
    on = np.flatnonzero(frames.first_path_id == first.path_id[0])
    range_m = frames.first_path_range_change_m[on] - frames.first_path_range_change_m[on[0]]
    expected = -WAVELENGTH * direct.doppler_hz * (frames.t_s[on] - frames.t_s[on[0]])
    assert np.max(np.abs(range_m - expected)) < 0.02


def test_a_forced_one_cycle_phase_jump_is_flagged_as_a_slip_and_bridged():
    # One extra carrier cycle within 2.2 ms (four frames) at t = 1.5 s.
    path = SignalPath(0.3, 1.0, 2.0, lambda t: np.clip((t - 1.5) / 0.0022, 0.0, 1.0))
    n = int(2.0 * SYMBOL_RATE_HZ)
    frames, rows, _ = run_receiver(make_paths_signal(n, [path], start_symbol=START, snr_db=15))
    slipped = rows.t_s[(rows.flags & PathFlag.CYCLE_SLIP) > 0]
    assert len(slipped) >= 1 and np.all(np.abs(slipped - 1.501) < 0.003)
    # Bridged: the first-path range ignores the slip and keeps following the 2 Hz Doppler.
    on = np.isfinite(frames.first_path_cfo_hz)
    t = frames.t_s[on]
    range_m = frames.first_path_range_change_m[on]
    expected = range_m[0] - WAVELENGTH * 2.0 * (t - t[0])
    assert np.max(np.abs(range_m - expected)) < 0.02


def test_two_towers_give_a_clock_free_range_difference():
    # Tower B 40 chips after tower A; both see the receiver clock's frequency wander (a 30 Hz/s ramp,
    # far beyond a TCXO's), which the difference of their first paths cancels.
    def clock(t):
        return 15.0 * t ** 2

    towers = [SignalPath(0.4, 1.0, 3.0, clock), SignalPath(1.9, 0.4, 3.5, clock),
              SignalPath(40.6, 10 ** (-4 / 20), -2.0, clock)]
    n = int(2.5 * SYMBOL_RATE_HZ)
    frames, rows, _ = run_receiver(make_paths_signal(n, towers, start_symbol=START, snr_db=15))
    assert sorted(set(rows.tower_id)) == [0, 1]
    on = np.isfinite(frames.range_difference_change_1_m)
    assert on.sum() > 1000 and np.all(frames.tower_count[on] == 2)
    t = frames.t_s[on]
    expected = -WAVELENGTH * (-2.0 - 3.0) * (t - t[0])
    assert np.max(np.abs(frames.range_difference_change_1_m[on] - expected)) < 0.02


def test_a_second_tower_nearly_as_strong_stays_inside_the_frame_timing_span():
    # The frame timing follows the taps' power centroid, which tower B (44 chips later, 1 dB weaker)
    # pulls 19 samples after tower A: the channel estimate must still hold A (with 16 samples before
    # the timing it held B alone, a header metric of 0.36, and in a fading SFN the lock was lost).
    towers = [SignalPath(0.4, 1.0, 3.0), SignalPath(44.6, 10 ** (-1 / 20), -2.0)]
    frames, rows, _ = run_receiver(make_paths_signal(int(3.0 * SYMBOL_RATE_HZ), towers, start_symbol=START, snr_db=15))
    assert np.all(frames.segment_id == 0) and np.percentile(frames.peak_metric, 1) > 0.9
    late = frames.t_s > 2.0
    assert np.all(np.isfinite(frames.range_difference_change_1_m[late]))


# ---- no paths where there is no signal -------------------------------------------------------

def feed_header_windows(tracker: PathTracker, windows: np.ndarray, batch: int = 128) -> tuple[int, int]:
    """Run header windows ``(F, P)`` through the channel estimator and the tracker; (path rows, first paths)."""
    mode = PnMode.PN420
    m = mode.value
    est = ChannelEstimator(mode, batch)
    rows = firsts = 0
    for lo in range(0, len(windows), batch):
        count = min(batch, len(windows) - lo)
        index = np.arange(lo, lo + count)
        est.windows[:count] = windows[lo: lo + count]
        est.estimate(count, np.asarray(gb20600.header_phase(mode, index), dtype=np.int64))
        taps, noise = est.span_taps(count, tracker.taps_before, tracker.taps_after)
        out = tracker.update(taps, noise, index * m.frame_length, index, np.zeros(count), index * m.frame_duration_s,
                             0.0)
        rows += len(out.rows)
        firsts += int(np.count_nonzero(out.first_path["first_path_id"] >= 0))
    return rows, firsts


def test_sixty_seconds_of_noise_give_no_path():
    frames = int(60.0 / PnMode.PN420.value.frame_duration_s)
    tracker = PathTracker(PnMode.PN420, CARRIER, PathConfig(guard_span=False))   # header windows: no views
    rows = firsts = 0
    for lo in range(0, frames, 8192):       # noise made in pieces: memory stays small
        count = min(8192, frames - lo)
        noise = (RNG.standard_normal((count, 255)) + 1j * RNG.standard_normal((count, 255))).astype(np.complex64)
        r, f = feed_header_windows(tracker, noise)
        rows, firsts = rows + r, firsts + f
    assert rows == 0 and firsts == 0 and not any(p.confirmed for p in tracker.paths)


def test_si_carriers_alone_give_no_path():
    # A capture holding only the 36 SI carriers (the same symbols every frame, no header, no data),
    # plus noise at C/N 15 dB: the header windows see tones (whose correlation with the PN is a
    # smooth function of the lag, like a DC offset's), not a PN sequence.
    m = PnMode.PN420.value
    frames = 3000
    n = (np.arange(frames) * m.frame_length + m.preamble)[:, None] + np.arange(m.period)[None, :]
    x = np.zeros(n.shape, complex)
    for symbol, k in zip(gb20600.si_symbols(15), gb20600.si_bins()):
        x += symbol * np.exp(2j * np.pi * k * n / gb20600.BODY_LENGTH) / np.sqrt(gb20600.SI_LENGTH)
    x += (RNG.standard_normal(n.shape) + 1j * RNG.standard_normal(n.shape)) * np.sqrt(10 ** (-1.5) / 2)
    rows, firsts = feed_header_windows(PathTracker(PnMode.PN420, CARRIER, PathConfig(guard_span=False)),
                                       x.astype(np.complex64))
    assert rows == 0 and firsts == 0


def test_signal_then_noise_end_to_end(tmp_path):
    """Paths while the signal lasts; none from the noise after it (the lock is lost)."""
    signal = make_paths_signal(int(1.6 * SYMBOL_RATE_HZ), [SignalPath(0.3, 1.0, 1.0), SignalPath(3.2, 0.5, -2.0)],
                               start_symbol=START, snr_db=15)
    noise = RNG.standard_normal(int(1.5 * SYMBOL_RATE_HZ)) + 1j * RNG.standard_normal(int(1.5 * SYMBOL_RATE_HZ))
    x = np.concatenate([signal, (noise * np.sqrt(10 ** (-1.5) / 2)).astype(np.complex64)])
    path = tmp_path / "cap.cf32"
    x.astype(np.complex64).tofile(path)
    out = tmp_path / "rx.h5"
    source = open_capture(path, sample_format="cf32", sample_rate_hz=SYMBOL_RATE_HZ, center_hz=CARRIER)
    receive_file(source, out, ReceiverConfig(static_window_s=0.5), progress=False)
    rows = read_columns(out, "receiver/paths")
    frames = read_columns(out, "receiver/frames")
    assert set(rows) == set(PathBatch.__dataclass_fields__)
    assert len(np.unique(rows["path_id"])) == 2 and rows["t_s"].max() < 1.6
    assert np.all(np.isfinite(rows["range_change_m"])) and np.all(np.isfinite(rows["doppler_hz"]))
    assert frames["first_path_id"].max() >= 0 and np.all(frames["first_path_id"][frames["t_s"] > 1.61] == -1)
    with h5py.File(out, "r") as f:
        attrs = dict(f["receiver/paths"].attrs)
    assert attrs["taps_before"] == 83 and attrs["taps_after"] == 82 and "units" in attrs
    assert attrs["doppler_frames"] == 0 and attrs["doppler_margin"] == 0.25   # nested settings, flattened
    assert np.isfinite(attrs["clock_offset_hz"])


def test_path_tracking_can_be_switched_off():
    x = make_paths_signal(int(0.5 * SYMBOL_RATE_HZ), [SignalPath(0.3, 1.0, 1.0)], start_symbol=START)
    frames, rows, rx = run_receiver(x, ReceiverConfig(clock_offset_hz=0.0, track_paths=False))
    assert len(frames) > 500 and len(rows) == 0 and np.all(np.isnan(frames.first_path_cfo_hz))
    assert rx.attributes()["path_tracking"] is False
    with pytest.raises(ValueError, match="cyclic header"):
        PathTracker(PnMode.PN595, CARRIER)
    with pytest.raises(ValueError, match="cyclic"):
        PathTracker(PnMode.PN420, CARRIER, PathConfig(taps_after=100))


def test_capture_shorter_than_the_static_window_is_ranged_once():
    x = make_paths_signal(int(1.5 * SYMBOL_RATE_HZ), [SignalPath(0.3, 1.0, 1.0), SignalPath(2.6, 0.4, -1.0)],
                          start_symbol=START)
    frames, rows, rx = run_receiver(x, ReceiverConfig(static_window_s=10.0))
    assert len(frames) > 2000 and np.all(np.diff(frames.frame_index) == 1)
    assert np.all(np.isfinite(frames.first_path_range_change_m)) and len(rows) > 0
    # Standing still with a 1 Hz Doppler: f_s absorbs it, and the path's own f_s too.
    assert rx.first_path_ranging.clock_offset_hz == pytest.approx(1.0, abs=0.05)
    assert np.max(np.abs(frames.first_path_range_change_m)) < 0.05


@pytest.mark.parametrize("frames, pfa", [(1, 0.1), (8, 1e-3), (64, 1e-6), (300, 1e-9)])
def test_detection_threshold_is_the_gamma_quantile(frames, pfa):
    from scipy.stats import gamma

    assert detection_threshold(frames, pfa) == pytest.approx(gamma.isf(pfa, a=frames, scale=1.0 / frames), rel=1e-9)
