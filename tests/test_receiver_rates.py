"""Determinism of the receiver at every supported input rate and at every batch boundary.

A frame's result must come from its own samples only: the same capture gives
bit-identical rows however it is chunked, on however many threads (``jobs``)
and however often it is received, whether or not the work buffers start out
as NaN, and a capture cut short gives a prefix of the full capture's rows. The historical failure: a lock
whose first frame started less than the channel-estimate span after the
start of the buffered samples made the last frame of the first batch read
past the end of its buffer (garbage SI SNR, a CFO that changed from run to
run, a wrong SI word).
"""

import numpy as np
import pyfftw
import pytest
from receiver_signals import make_signal

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from dtmbnav_core.records import FrameBatch, FrameFlag
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from sim.rf import CaptureGenerator
from sim.scenario import load_scenario
from sim.walk import simulate_walk

#: Every input rate the receiver supports: wideband (resampled down, or passed through) and narrowband.
RATES_HZ = (7.56e6, 10e6, 12.5e6, 16e6, 20e6, 2.048e6, 2.4e6, 3.2e6)
CARRIER = 666e6
#: A frame of the test signal starts this many samples into the stream: inside the channel-estimate span.
EDGE_OFFSET = 3


def nan_filled(original):
    """An allocator like ``original`` whose arrays start as NaN (floats) or a sentinel (integers, booleans)."""
    def allocate(*args, **kwargs):
        out = original(*args, **kwargs)
        if out.dtype.kind in "fc":
            out.fill(np.nan)
        elif out.dtype.kind in "iu":
            out.fill(np.iinfo(out.dtype).max)
        elif out.dtype.kind == "b":
            out.fill(True)
        return out
    return allocate


@pytest.fixture
def poison(monkeypatch):
    """Call it to make every work buffer allocated from then on start as NaN (np.empty, np.empty_like, pyfftw)."""
    def apply() -> None:
        for module, name in ((np, "empty"), (np, "empty_like"), (pyfftw, "empty_aligned")):
            monkeypatch.setattr(module, name, nan_filled(getattr(module, name)))
    return apply


def receive(chunks, rate, config):
    rx = Receiver(rate, CARRIER, config)
    return FrameBatch.concatenate(list(receive_stream(chunks, rate, CARRIER, receiver=rx))), rx


def assert_identical(a: FrameBatch, b: FrameBatch) -> None:
    assert len(a) == len(b)
    for name, column in a.columns().items():
        assert np.array_equal(column, getattr(b, name), equal_nan=True), name


def assert_sane(rows: FrameBatch, rx: Receiver) -> None:
    """Every column finite (but the CFO of a lock's first frame), SI SNRs of a 15 dB link, the word sent."""
    first = (rows.flags & FrameFlag.LOCK_START) > 0
    # The path tracker's columns hold their fill (NaN, -1, 0) where it has no first path: finite where it has.
    found = rows.first_path_id >= 0
    for name, column in rows.columns().items():
        finite = np.isfinite(column)
        if name in ("first_path_cfo_hz", "first_path_range_change_m"):
            assert finite[found & ~first].all(), name
        elif name in ("first_path_delay_s", "first_path_snr_db"):
            assert finite[found].all() and not finite[~found].any(), name
        elif name in ("range_difference_change_1_m", "range_difference_change_2_m"):
            assert not finite[rows.tower_count < 2].any(), name  # one tower: no difference
        else:
            assert finite[~first].all() if name in ("cfo_hz", "cfo_pn_hz", "doppler_hz", "velocity_mps") \
                else finite.all(), name
    assert np.all(rows.si_snr_db < 25.0) and np.median(rows.si_snr_db) > 10.0
    assert rx.si_index == 15


def chunked(x: np.ndarray, size: int):
    """Chunks of ``x``, each a view followed in memory by NaN: a read past a chunk's end shows."""
    for i in range(0, len(x), size):
        part = x[i:i + size]
        padded = np.full(len(part) + 4096, np.nan + 1j * np.nan, dtype=np.complex64)
        padded[: len(part)] = part
        yield padded[: len(part)]


CAPTURES: dict[float, np.ndarray] = {}


def capture(rate: float) -> np.ndarray:
    """0.25 s of the park-loop (standing, C/N 15 dB) at ``rate``."""
    if rate not in CAPTURES:
        scn = load_scenario("park-loop-cw")
        gen = CaptureGenerator(scn, simulate_walk(scn).track, seconds=0.25, start_s=2.0, sample_rate_hz=rate,
                               sample_format="cf32")
        CAPTURES[rate] = np.concatenate(list(gen.chunks(1 << 20)))
    return CAPTURES[rate]


@pytest.mark.parametrize("rate", RATES_HZ)
def test_same_capture_received_twice_is_bit_identical(rate, poison):
    """Twice, chunked differently, with NaN-filled work buffers and on 3 threads the second time: the same
    rows, all sane."""
    x = capture(rate)
    config = ReceiverConfig(clock_offset_hz=0.0, batch_frames=64)
    first, rx = receive([x], rate, config)
    poison()
    second, _ = receive(chunked(x, 99_991), rate, ReceiverConfig(clock_offset_hz=0.0, batch_frames=64, jobs=3))
    assert len(first) > 400 and len(rx.acquisitions) == 1
    assert_identical(first, second)
    assert_sane(first, rx)


@pytest.mark.parametrize("batch_frames", [4, 5, 8])
def test_frame_on_every_batch_boundary(batch_frames, poison):
    """Small batches put a frame on a batch boundary every few frames; small chunks put buffers across chunks.

    The signal's first frame starts inside the channel-estimate span of the
    stream's first samples, so the lock must begin on the next frame.
    """
    x = make_signal(int(0.05 * SYMBOL_RATE_HZ), snr_db=15, cfo_hz=1000.0, start_symbol=4200 * 30 - EDGE_OFFSET)
    config = ReceiverConfig(clock_offset_hz=1000.0, batch_frames=batch_frames)
    whole, rx = receive([x], SYMBOL_RATE_HZ, config)
    poison()
    small, _ = receive(chunked(x, 5_003), SYMBOL_RATE_HZ, config)
    assert rx.acquisitions[0].frame_start == 4200 + EDGE_OFFSET
    assert_identical(whole, small)
    assert_sane(whole, rx)


def test_capture_cut_short_gives_a_prefix():
    """Cutting the capture at, just before and just after a frame's last needed sample drops only later frames."""
    x = make_signal(int(0.06 * SYMBOL_RATE_HZ), snr_db=15, cfo_hz=-2000.0, start_symbol=123_457)
    config = ReceiverConfig(clock_offset_hz=-2000.0, batch_frames=8)
    full, _ = receive([x], SYMBOL_RATE_HZ, config)
    # A frame needs its header, body and the next header's first taps_after samples.
    need = SYMBOL_RATE_HZ * full.t_s + 4200 + config.taps_after + 1
    for k in (23, 24, 40):   # after the acquisition window; 23 | 24 is a batch boundary
        for end in (int(need[k]) - 1, int(need[k]), int(need[k]) + 1):
            cut, _ = receive(chunked(x[:end], 7_777), SYMBOL_RATE_HZ, config)
            assert len(cut) == int(np.searchsorted(need, end, side="right"))
            assert_identical(cut, full.select(slice(0, len(cut))))
