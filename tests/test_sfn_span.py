"""The path tracker's guard-interval span (``PathConfig.guard_span``, docs/paths.md "The CIR").

The header correlation's views see a path where the coverage model says (all of its header chips
in the window of the view centred on it, the share the window holds elsewhere); the kernels agree
with their numpy twin; a constant header phase keeps the tracker to the cyclic extension. On the
simulator's capture of the tiny walk a single tower is tracked as without the span. Towers up to
the guard interval apart, on the tests' own transmitter, are in ``tests/test_sfn_towers_apart.py``.
"""

import numpy as np
import pytest
from conftest import TINY_WALK
from receiver_signals import SignalPath, frame_start_samples, make_paths_signal

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import PnMode
from dtmbnav_core.iqformat import decode
from dtmbnav_core.records import FrameBatch, PathBatch
from receiver.channel_estimate import ChannelEstimator, view_first_lag
from receiver.derotate import derotate_segments, rotation_table
from receiver.paths import (
    PULSE_OVERSAMPLING,
    PathConfig,
    PathTracker,
    fit_paths_reference,
    fit_views_kernel,
    model_residual_kernel,
    pulse_tables,
)
from receiver.pipeline import Receiver, ReceiverConfig
from sim.path_truth import PathTruth, path_truth
from sim.rf import CaptureGenerator
from sim.scenario import load_scenario
from sim.walk import simulate_walk

START = 123_457
#: Capture segment of the tiny walk (it stands still until 3 s, then walks 12 m).
SEGMENT_START_S, SEGMENT_S = 1.0, 5.0


# ---- the views and the kernels ---------------------------------------------------------------

def header_views(x: np.ndarray, mode: PnMode, shifts: tuple[int, ...]) -> np.ndarray:
    """Views ``(F, V, P)`` of every whole frame of a 7.56 Msps stream made with ``start_symbol=START``."""
    m = mode.value
    starts = np.rint(frame_start_samples(mode, START, len(x))).astype(np.int64)
    starts = starts[(starts > m.header_length) & (starts < len(x) - 2 * m.frame_length)]
    frames = (START + starts) // m.frame_length
    phases = np.asarray(gb20600.header_phase(mode, frames % m.frames_per_superframe), dtype=np.int64)
    est = ChannelEstimator(mode, len(starts))
    rot = rotation_table(0.0, m.frame_length)
    derotate_segments(x, 0, starts + est.window_offset, est.window_length, 0.0, rot, est.windows)
    est.estimate(len(starts), phases)
    out = np.zeros((len(starts), len(shifts), m.period), np.complex64)
    est.view_taps(len(starts), x, 0, starts, shifts, phases, 0.0, rot, out)
    return out


def test_a_view_sees_a_path_with_the_share_of_its_header_chips_in_the_window():
    # Tower B 227 chips after A (30 us): the frame's own window holds 110 of B's 255 chips and shows it
    # one period early (lag -28); the view centred on B holds all of them, and 111 of A's (at lag 255).
    mode = PnMode.PN420
    x = make_paths_signal(60_000, [SignalPath(0.0, 1.0), SignalPath(227.0, 0.7)], start_symbol=START, snr_db=None)
    shifts = (0, 227)
    views = header_views(x, mode, shifts)
    level = np.sqrt(np.mean(np.abs(views) ** 2, axis=0))
    for v, shift, seen in ((0, 0, {0: 1.0, -28: 0.7 * 110 / 255}), (1, 227, {227: 0.7, 255: 111 / 255})):
        for lag, amplitude in seen.items():
            assert level[v, lag - shift - view_first_lag(mode)] == pytest.approx(amplitude, rel=0.05)


def test_fit_views_kernel_equals_its_numpy_reference():
    rng = np.random.default_rng(3)
    g, dg = pulse_tables(255)
    frames, period = 48, 255
    lag_axis = np.concatenate([np.arange(-128, 127), 227 + np.arange(-128, 127)]).astype(np.float64)
    column_view = np.repeat([0, 1], period)
    scale = np.array([[1.0, 0.43, 0.0], [0.44, 1.0, 2.0]])
    taps = (rng.standard_normal((frames, 2 * period)) + 1j * rng.standard_normal((frames, 2 * period))).astype(np.complex64)
    offsets = np.repeat([0.0, 1.0, 3.0], 16)
    d1, d2 = np.array([0.3, 227.6, 255.3]), np.array([0.3, 227.6, 255.3])
    r1, r2 = np.array([1e-3, 0.0, 1e-3]), np.array([1e-3, 0.0, 1e-3])
    steps = np.array([0.2, 0.2, 0.0])
    amps, lags, var, res = (np.zeros((frames, 3), complex), np.zeros((frames, 3)), np.zeros((frames, 3)),
                            np.zeros(2 * period))
    fit_views_kernel(taps, offsets, lag_axis, column_view, scale, d1, r1, steps, g, dg, PULSE_OVERSAMPLING, 16, 0.3,
                     0.02, 0.05, amps, lags, var, res)
    ref = fit_paths_reference(taps, offsets, 0, d2, r2, steps, g, dg, PULSE_OVERSAMPLING, 16, 0.3, 0.02, 0.05,
                              lag_axis, column_view, scale)
    for got, want in zip((amps, lags, var, res, d1, r1), (*ref, d2, r2)):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)


def test_model_residual_kernel_leaves_nothing_of_a_signal_made_of_the_model():
    rng = np.random.default_rng(5)
    g, _ = pulse_tables(255)
    frames = 40
    lag_axis = np.concatenate([np.arange(-128, 127), 340 + np.arange(-128, 127)]).astype(np.float64)
    column_view = np.repeat([0, 1], 255)
    scale = np.array([[1.0, 0.3], [0.2, 1.0]])
    amplitudes = rng.standard_normal((frames, 2)) + 1j * rng.standard_normal((frames, 2))
    lags = np.array([2.3, 338.7])[None, :] + 1e-3 * np.arange(frames)[:, None]
    grid = np.arange(len(g) - 1) / PULSE_OVERSAMPLING
    pulses = np.interp(np.mod(lag_axis[None, :, None] - lags[:, None, :], 255), grid, g[:-1], period=255)
    taps = np.einsum("kji,ji,ki->kj", pulses, scale[column_view], amplitudes).astype(np.complex64)
    left = np.zeros(len(lag_axis))
    model_residual_kernel(taps, lag_axis, column_view, scale, amplitudes, lags, g, PULSE_OVERSAMPLING, 16, 0.05, left)
    # The pulses are those of each run's middle frame, at most 8 frames (8e-3 chips) off; the pulse's
    # slope is below pi per chip times its peak: at most (0.025)^2 of the peak power is left.
    assert np.max(left) < 6e-4 * np.max(np.sum(np.abs(taps) ** 2, axis=0))
    still = np.repeat(lags[:1], frames, axis=0)
    taps = np.einsum("kji,ji,ki->kj", pulses[:1].repeat(frames, axis=0), scale[column_view], amplitudes).astype(np.complex64)
    left[:] = 0.0
    model_residual_kernel(taps, lag_axis, column_view, scale, amplitudes, still, g, PULSE_OVERSAMPLING, 16, 0.05, left)
    assert np.max(left) < 1e-9 * np.max(np.sum(np.abs(taps) ** 2, axis=0))


def test_a_constant_header_phase_keeps_the_tracker_to_the_cyclic_extension():
    # Its views' partial m-sequence sums would be the same in every frame: no views, no samples before the span.
    for rotating, views in ((True, (0, 165)), (False, ())):
        tracker = PathTracker(PnMode.PN420, 666e6, PathConfig(guard_span=True), rotating=rotating)
        assert tracker.guard == rotating and tracker.plan_views() == views
        assert tracker.view_lead == (420 - 82 + 1 if rotating else 0)


# ---- one tower on the simulator's capture ----------------------------------------------------

def receive_segment(scn, guard_span: bool) -> tuple[FrameBatch, PathBatch, PathTruth]:
    """Frames, path rows and path truth of the receiver on the segment of ``scn``."""
    gen = CaptureGenerator(scn, simulate_walk(scn).track, seconds=SEGMENT_S, start_s=SEGMENT_START_S)
    rx = Receiver(gen.sample_rate_hz, gen.carrier_hz,
                  ReceiverConfig(static_window_s=2.0, paths=PathConfig(guard_span=guard_span)))
    frames, paths = [], []
    for chunk in gen.chunks(1 << 20):
        frames += rx.process(chunk if gen.sample_format == "cf32" else decode(gen.frontend.quantise(chunk),
                                                                                gen.sample_format))
        paths.append(rx.pop_paths())
    frames += rx.finish()
    paths.append(rx.pop_paths())
    return FrameBatch.concatenate(frames), PathBatch.concatenate(paths), path_truth(gen)


@pytest.mark.slow
def test_a_single_tower_is_tracked_as_within_the_cyclic_extension():
    scn = load_scenario(TINY_WALK)
    cyclic, _, _ = receive_segment(scn, guard_span=False)
    guard, _, _ = receive_segment(scn, guard_span=True)
    assert np.mean(cyclic.first_path_id == guard.first_path_id) > 0.99
    both = np.isfinite(cyclic.first_path_range_change_m) & np.isfinite(guard.first_path_range_change_m)
    assert both.mean() > 0.9
    assert np.max(np.abs(cyclic.first_path_range_change_m - guard.first_path_range_change_m)[both]) < 0.002
