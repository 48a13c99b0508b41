"""Samples the front end dropped (receiver.drops): found in the frame timing, counted, kept out of t_s."""

from __future__ import annotations

import numpy as np
import pytest
from receiver_signals import make_signal

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from dtmbnav_core.records import FrameBatch, FrameFlag
from receiver.drops import profile_shift
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream

START = 123_457      # transmitted symbol at receiver sample 0
FRAME = 4200         # PN420


def _receive(x: np.ndarray) -> tuple[FrameBatch, Receiver]:
    rx = Receiver(SYMBOL_RATE_HZ, 666e6, ReceiverConfig(clock_offset_hz=2500.0, track_paths=False))
    rows = FrameBatch.concatenate(list(receive_stream([x[i: i + 100_000] for i in range(0, len(x), 100_000)],
                                                      SYMBOL_RATE_HZ, 666e6, receiver=rx)))
    return rows, rx


def test_profile_shift_finds_an_earlier_profile():
    taps = np.zeros(96, complex)
    taps[48], taps[53] = 1.0, 0.4j
    lag, gain = profile_shift(taps, np.roll(taps, -3), 8)
    assert lag == -3 and gain > 2


@pytest.mark.parametrize("lost", [1, 7, 300, 5000])
def test_a_drop_is_counted_and_t_s_stays_on_the_real_clock(lost):
    """A standing receiver, a 2.5 kHz offset: one run of samples cut out of the stream at 0.2 s."""
    x = make_signal(int(0.4 * SYMBOL_RATE_HZ), cfo_hz=2500.0, snr_db=15, start_symbol=START)
    at = int(0.2 * SYMBOL_RATE_HZ) + 1234
    full, _ = _receive(x)
    cut, rx = _receive(np.concatenate([x[:at], x[at + lost:]]))
    assert rx.drops.samples == [lost]
    # Every frame after the drop keeps the time the uncut stream gives it, to a sample.
    after = cut.t_s > at / SYMBOL_RATE_HZ + 0.01
    matched = np.searchsorted(full.frame_index, cut.frame_index[after])
    assert np.array_equal(full.frame_index[matched], cut.frame_index[after])
    assert np.max(np.abs(cut.t_s[after] - full.t_s[matched])) * SYMBOL_RATE_HZ <= 1.0
    # One frame flagged DROP, the segment continues, and the range bridges the drop.
    assert np.count_nonzero(cut.flags & FrameFlag.DROP) == 1 and cut.segment_id.max() == 0
    assert np.max(np.abs(cut.range_change_m[after] - full.range_change_m[matched])) < 0.05


def test_a_drop_beyond_the_in_lock_limit_is_not_taken_into_the_grid():
    """49 samples behind an echo 20 samples late: the echo leaves the window and the centroid understates the
    step; the lock must end at the drop and the re-acquisition count it, not the loop follow it."""
    x = make_signal(int(0.4 * SYMBOL_RATE_HZ), cfo_hz=2500.0, snr_db=15, start_symbol=START, echo=(20.0, 0.5))
    at = int(0.2 * SYMBOL_RATE_HZ) + 1234
    full, _ = _receive(x)
    cut, rx = _receive(np.concatenate([x[:at], x[at + 49:]]))
    assert rx.drops.samples == [49] and cut.segment_id.max() == 0
    # The re-acquisition's first batch sits where the acquisition put the window (on the main path); the timing
    # loop then pulls it onto the taps' centroid, which the echo moves by 4 samples (docs/schema.md, t_s). From
    # there t_s is the uncut stream's.
    after = cut.t_s > at / SYMBOL_RATE_HZ + 0.1
    matched = np.searchsorted(full.frame_index, cut.frame_index[after])
    assert np.max(np.abs(cut.t_s[after] - full.t_s[matched])) * SYMBOL_RATE_HZ <= 1.0 + 1e-6  # a window's rounding


def test_no_drop_is_found_in_an_uncut_stream():
    x = make_signal(int(0.3 * SYMBOL_RATE_HZ), cfo_hz=2500.0, snr_db=0, start_symbol=START, echo=(5.3, 0.5j))
    rows, rx = _receive(x)
    assert len(rows) > 400 and rx.drops.samples == [] and not np.any(rows.flags & FrameFlag.DROP)


def _rows(cfo_hz: list[float], first_t_s: float, flags: dict[int, int]) -> FrameBatch:
    n = len(cfo_hz)
    nan = np.full(n, np.nan)
    flag = np.zeros(n, np.uint8)
    for k, bits in flags.items():
        flag[k] = bits
    return FrameBatch(t_s=first_t_s + np.arange(n) * 5.6e-4, sample_index=np.arange(n), frame_index=np.arange(n),
                      pn_phase=np.zeros(n, np.int32), cfo_hz=np.asarray(cfo_hz, float), cfo_pn_hz=nan.copy(),
                      doppler_hz=nan.copy(), velocity_mps=nan.copy(), range_change_m=nan.copy(),
                      snr_db=np.zeros(n, np.float32), si_snr_db=np.zeros(n, np.float32),
                      peak_metric=np.ones(n, np.float32), flags=flag, segment_id=np.zeros(n, np.int32))


def test_a_drop_is_bridged_with_the_median_of_the_frames_before_it_each_counted_once():
    """Two drops: the second is bridged with the median of the trusted frames since the stream began, once each."""
    from receiver.ranging import RangeIntegrator

    ranging = RangeIntegrator(666e6, clock_offset_hz=0.0)
    first = _rows([0.0] * 5 + [np.nan] + [10.0] * 5, 0.0, {5: FrameFlag.DROP})
    [out] = ranging.push(first)
    # The first drop's frame moves the range by the median of the five frames before it (0 Hz): no change.
    assert out.range_change_m[5] == out.range_change_m[4]
    second = _rows([np.nan, 10.0], 0.1, {0: FrameFlag.DROP})
    [out2] = ranging.push(second)
    # Trusted before it: five frames at 0 Hz and five at 10 Hz, each once: a 5 Hz median over the 0.1 s gap.
    gap_s = 0.1 - float(first.t_s[-1])
    assert out2.range_change_m[0] - out.range_change_m[-1] == pytest.approx(-ranging.wavelength_m * 5.0 * gap_s)
