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


def test_no_drop_is_found_in_an_uncut_stream():
    x = make_signal(int(0.3 * SYMBOL_RATE_HZ), cfo_hz=2500.0, snr_db=0, start_symbol=START, echo=(5.3, 0.5j))
    rows, rx = _receive(x)
    assert len(rows) > 400 and rx.drops.samples == [] and not np.any(rows.flags & FrameFlag.DROP)
