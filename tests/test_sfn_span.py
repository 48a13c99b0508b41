"""The path tracker's guard-interval span (``PathConfig.guard_span``, docs/paths.md "The CIR").

The header correlation's views see a path where the coverage model says (all of its header chips
in the window of the view centred on it, the share the window holds elsewhere); the kernels agree
with their numpy twin. On the simulator's captures of a two-tower single-frequency network (the
tiny walk's tower and one 3 dB weaker, 15, 30 or 50 us later in PN420, 60 us in PN945; a
free-running TCXO) the second tower is tracked at its true delay, with no alias one m-sequence period
off, and the change of the tower difference follows the truth; the header's cyclic extension alone
loses such towers or takes them a period off. A single tower is tracked as without the option.
"""

import numpy as np
import pytest
from conftest import TINY_WALK
from receiver_signals import SignalPath, frame_start_samples, make_paths_signal

from dtmbnav.evaluation.accuracy import direct_range_m
from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.iqformat import decode
from dtmbnav_core.records import FrameBatch, PathBatch, PathFlag
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
from sim.channel import DIRECT
from sim.path_truth import PathTruth, path_truth
from sim.rf import CaptureGenerator
from sim.scenario import load_scenario
from sim.walk import simulate_walk

START = 123_457
#: Capture segment of the tiny walk (it stands still until 3 s, then walks 12 m): the towers' first
#: paths have matured by CHECK_FROM_S (capture time), from which the tower difference is scored.
SEGMENT_START_S, SEGMENT_S, CHECK_FROM_S = 1.0, 5.0, 2.5
#: 95th percentile of the error of the tower difference's change, m. Beside the first tower's body
#: chips (noise in the second tower's window: a frame noise of the difference of 5 mm at 30-50 us,
#: 2 mm at 15 us, on tuning seeds) the first tower's partial m-sequence sums there leave a wander
#: that does not average out over a batch; the tuning seeds' 95th percentiles were 4-16 mm.
DIFFERENCE_P95_M = 0.03


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


# ---- two towers of a single-frequency network ------------------------------------------------

def sfn_scenario(later_us: float, pn_mode: str = "PN420"):
    """The tiny walk with a second tower 3 dB weaker whose direct path arrives ``later_us`` after the first's.

    The second tower's transmit delay makes up the difference of the towers' distances from the
    walk's start; the receiver's clock is the free-running TCXO.
    """
    scn = load_scenario(TINY_WALK)
    a = {"x_m": 2000.0, "y_m": 2200.0, "height_m": 150.0, "power_db": 0.0}
    b = {"x_m": -1560.0, "y_m": -4285.0, "height_m": 120.0, "power_db": -3.0}
    extra_m = np.hypot(np.hypot(b["x_m"], b["y_m"]), b["height_m"]) - np.hypot(np.hypot(a["x_m"], a["y_m"]), a["height_m"])
    b["transmit_delay_s"] = later_us * 1e-6 - extra_m / SPEED_OF_LIGHT_MPS
    return scn.replace(towers=[a, b], tower={"pn_mode": pn_mode}, receiver={"clock": {"preset": "free-running"}})


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


def tower_delay_error_chips(rows: PathBatch, truth: PathTruth, tower: int) -> np.ndarray:
    """Tower ``tower``'s first-path delay after tower 0's, minus the truth's, per frame from CHECK_FROM_S, chips."""
    first = rows.select(((rows.flags & PathFlag.FIRST_PATH) > 0) & (rows.t_s >= CHECK_FROM_S))
    zero, other = first.select(first.tower_id == 0), first.select(first.tower_id == tower)
    zero = zero.select(np.isin(zero.frame_index, other.frame_index))
    other = other.select(np.isin(other.frame_index, zero.frame_index))

    def direct(k: int) -> np.ndarray:
        rows_k = (truth.tower_id == k) & (truth.kind == DIRECT)
        return np.interp(other.t_s, truth.t_s[rows_k], truth.delay_s[rows_k])

    return ((other.delay_s - zero.delay_s) - (direct(tower) - direct(0))) * SYMBOL_RATE_HZ


def difference_change_error_m(frames: FrameBatch, truth: PathTruth) -> np.ndarray:
    """Error of the change of the tower difference (tower 1 minus tower 0) since CHECK_FROM_S, m.

    The reference is the mean over the first 10 ms, so one frame's noise does not offset the rest.
    """
    on = frames.t_s >= CHECK_FROM_S
    true = (direct_range_m(truth, 1, frames.t_s) - direct_range_m(truth, 0, frames.t_s))[on]
    measured = frames.range_difference_change_1_m[on]
    ref = frames.t_s[on] < CHECK_FROM_S + 0.01
    return (measured - np.mean(measured[ref])) - (true - np.mean(true[ref]))


@pytest.mark.slow
@pytest.mark.parametrize("later_us,pn_mode", [(15.0, "PN420"), (30.0, "PN420"), (50.0, "PN420"), (60.0, "PN945")])
def test_a_second_tower_beyond_the_cyclic_extension_is_tracked_at_its_true_delay(later_us, pn_mode):
    frames, rows, truth = receive_segment(sfn_scenario(later_us, pn_mode), guard_span=True)
    late = frames.t_s >= CHECK_FROM_S
    assert np.all(frames.tower_count[late] == 2)
    # At its true delay: one m-sequence period (255 or 511 chips) off would be an alias.
    delay_error = tower_delay_error_chips(rows, truth, 1)
    assert len(delay_error) > 0.9 * late.sum() and np.max(np.abs(delay_error)) < 0.5
    error = difference_change_error_m(frames, truth)
    assert np.all(np.isfinite(error)) and np.percentile(np.abs(error), 95) < DIFFERENCE_P95_M


@pytest.mark.slow
def test_the_cyclic_extension_alone_takes_a_tower_30_us_later_one_period_early():
    # What the option is for: the header's cyclic extension (-83..82) holds the tower 30 us (227 chips)
    # later only as its alias at -28, with 110 of its 255 chips.
    _, rows, truth = receive_segment(sfn_scenario(30.0), guard_span=False)
    delay_error = tower_delay_error_chips(rows, truth, 1)
    assert len(delay_error) and np.all(np.abs(delay_error + 255.0) < 0.5)


@pytest.mark.slow
def test_a_single_tower_is_tracked_as_within_the_cyclic_extension():
    scn = load_scenario(TINY_WALK)
    cyclic, _, _ = receive_segment(scn, guard_span=False)
    guard, _, _ = receive_segment(scn, guard_span=True)
    assert np.mean(cyclic.first_path_id == guard.first_path_id) > 0.99
    both = np.isfinite(cyclic.first_path_range_change_m) & np.isfinite(guard.first_path_range_change_m)
    assert both.mean() > 0.9
    assert np.max(np.abs(cyclic.first_path_range_change_m - guard.first_path_range_change_m)[both]) < 0.002
