"""A capture tuned beside the DTMB channel (a zero-IF SDR keeping its DC spike out of the band).

The simulator records the channel at ``-tuning_offset_hz`` from DC and says
where the channel is (SigMF ``dtmbnav:channel_hz`` and an annotation); the
receiver shifts the input back before resampling. Checked here: the shift
kernel against numpy and its chunk invariance, a short walk at 10 Msps tuned
1.5 MHz off ranging as the same walk tuned on the channel, the same capture
received without the channel's centre, and an offset outside the recorded
band refused.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav.evaluation.accuracy import match_truth
from dtmbnav.cli import EXIT_OK, EXIT_USAGE, main
from dtmbnav_core import schema
from dtmbnav_core.h5io import read_columns
from receiver.capture import open_capture
from receiver.mixer import MIX_BLOCK, StreamMixer, max_channel_offset_hz
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from sim.scenario import load_scenario
from sim.simulate import simulate

RATE = 10e6
OFFSET = 1.5e6          # capture centre minus channel centre
STILL_S = 1.5           # standstill before the walk starts, s
SECONDS = 3.0


def _reference(x, first, offset_hz, rate):
    n = first + np.arange(len(x), dtype=np.float64)
    return x * np.exp(-2j * np.pi * ((n * (offset_hz / rate)) % 1.0))


def test_mixer_matches_numpy():
    rng = np.random.default_rng(3)
    x = (rng.standard_normal(3 * MIX_BLOCK + 17) + 1j * rng.standard_normal(3 * MIX_BLOCK + 17)).astype(np.complex64)
    mixer = StreamMixer(-1.5e6, RATE)
    mixer.position = 10**9 + 5   # far into a stream: the float64 phase still holds
    got = mixer.process(x)
    assert got.dtype == np.complex64
    np.testing.assert_allclose(got, _reference(x, 10**9 + 5, -1.5e6, RATE), rtol=0, atol=2e-5)


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(1, 3 * MIX_BLOCK), min_size=1, max_size=6), offset=st.floats(-4.9e6, 4.9e6))
def test_mixer_is_chunk_invariant(cuts, offset):
    """A stream cut anywhere gives the same shifted samples."""
    rng = np.random.default_rng(5)
    x = (rng.standard_normal(4 * MIX_BLOCK) + 1j * rng.standard_normal(4 * MIX_BLOCK)).astype(np.complex64)
    whole = StreamMixer(offset, RATE).process(x)
    mixer = StreamMixer(offset, RATE)
    bounds = np.cumsum([0, *cuts])
    bounds = np.unique(np.clip(np.r_[bounds, len(x)], 0, len(x)))
    parts = [mixer.process(x[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    assert np.array_equal(np.concatenate(parts), whole)


def test_offset_outside_the_band_is_refused_by_the_receiver():
    with pytest.raises(ValueError, match="outside the recorded band"):
        Receiver(RATE, 666e6, ReceiverConfig(channel_offset_hz=max_channel_offset_hz(RATE) + 1.0))
    with pytest.raises(ValueError, match="channel_offset_hz"):
        ReceiverConfig(channel_offset_hz=float("nan"))


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """The same 3 s (standstill, then walking) at 10 Msps, tuned on the channel and 1.5 MHz above it."""
    base = load_scenario("park-loop-cw")
    start = base.walk.start_still_s - STILL_S
    out = {}
    for name, tuning in (("on", 0.0), ("off", OFFSET)):
        # No thermal noise and 16-bit samples: the two captures then differ only by the tuning, not by which
        # noise lands on the SI carriers, so their range errors can be compared at 5 %.
        scn = base.replace(receiver={"sample_rate_hz": RATE, "tuning_offset_hz": tuning, "cn_db": float("inf"),
                                     "sample_format": "ci16"})
        folder = tmp_path_factory.mktemp(name)
        result = simulate(scn, folder, seconds=SECONDS, start_s=start)
        out[name] = result
    return out


def _range_error_p95(rx_path, truth_path):
    """95th percentile of the range-change error against the truth's over the walking part, m."""
    frames = read_columns(rx_path, schema.RECEIVER_FRAMES)
    truth = read_columns(truth_path, schema.TRUTH_FRAMES)

    class Rows:
        t_s = frames["t_s"]

    class Truth:
        t_s = truth["t_s"]

    j = match_truth(Rows, Truth)
    true_change = truth["range_m"][j] - truth["range_m"][j[0]]
    walking = frames["t_s"] >= STILL_S
    return float(np.percentile(np.abs(frames["range_change_m"] - true_change)[walking], 95))


def test_off_centre_capture_records_the_channel(captures):
    meta = json.loads(captures["off"].capture_path.read_text())
    channel = load_scenario("park-loop-cw").tower.carrier_hz
    assert meta["captures"][0]["core:frequency"] == channel + OFFSET
    assert meta["global"]["dtmbnav:channel_hz"] == channel
    (note,) = meta["annotations"]
    assert note["core:freq_lower_edge"] + note["core:freq_upper_edge"] == pytest.approx(2 * channel)
    on = json.loads(captures["on"].capture_path.read_text())
    assert "dtmbnav:channel_hz" not in on["global"] and not on.get("annotations")
    assert open_capture(captures["off"].capture_path).channel_hz == channel


def test_off_centre_capture_ranges_like_an_on_channel_one(captures, tmp_path):
    """Received with the channel's centre (from the SigMF key, and from --channel): the same range error."""
    channel = load_scenario("park-loop-cw").tower.carrier_hz
    common = ["--static-window", "1.0", "--no-paths"]
    on_rx, off_rx, given_rx = tmp_path / "on.h5", tmp_path / "off.h5", tmp_path / "given.h5"
    assert main(["-q", "receive", str(captures["on"].capture_path), "-o", str(on_rx), *common]) == EXIT_OK
    assert main(["-q", "receive", str(captures["off"].capture_path), "-o", str(off_rx), *common]) == EXIT_OK
    # --channel overrides the file's record (the same value here: the same output).
    assert main(["-q", "receive", str(captures["off"].capture_path), "-o", str(given_rx), "--channel",
                 str(channel), *common]) == EXIT_OK
    import h5py

    with h5py.File(off_rx, "r") as f:
        attrs = dict(f[schema.RECEIVER_FRAMES].attrs)
    assert attrs["carrier_hz"] == channel and attrs["channel_hz"] == channel
    assert attrs["channel_offset_hz"] == pytest.approx(-OFFSET)
    with h5py.File(on_rx, "r") as f:
        assert "channel_offset_hz" not in f[schema.RECEIVER_FRAMES].attrs
    on = _range_error_p95(on_rx, captures["on"].truth_path)
    off = _range_error_p95(off_rx, captures["off"].truth_path)
    assert abs(off - on) <= 0.05 * on, (on, off)
    assert np.array_equal(read_columns(off_rx, schema.RECEIVER_FRAMES)["range_change_m"],
                          read_columns(given_rx, schema.RECEIVER_FRAMES)["range_change_m"], equal_nan=True)


def test_off_centre_capture_without_the_channel_finds_no_lock(captures):
    """Taken as tuned on the channel, the signal lies 1.5 MHz away, far outside the +-60 kHz search: no lock,
    and no frames (never a wrong range)."""
    source = open_capture(captures["off"].capture_path)
    rx = Receiver(source.sample_rate_hz, source.center_hz, ReceiverConfig(static_window_s=1.0, track_paths=False))
    chunks = source.chunks(1 << 19)
    head = [next(chunks) for _ in range(3)]      # 0.16 s: several acquisition windows
    rows = list(receive_stream(head, source.sample_rate_hz, source.center_hz, receiver=rx))
    assert sum(len(r) for r in rows) == 0 and not rx.acquisitions


def test_channel_outside_the_recorded_band_is_refused(captures, tmp_path, capsys):
    centre = open_capture(captures["off"].capture_path).center_hz
    out = tmp_path / "rx.h5"
    code = main(["-q", "receive", str(captures["off"].capture_path), "-o", str(out), "--channel", str(centre + 5e6)])
    assert code == EXIT_USAGE and not out.exists()
    assert "--channel" in capsys.readouterr().err


def test_a_swapped_off_centre_capture_is_received_with_its_orientation_given(captures, tmp_path, capsys):
    """A front end that swaps I and Q mirrors the channel's place too: with --conjugate the capture is
    conjugated before the shift, giving the unswapped capture's rows (swapping I and Q is conjugating and
    turning by 90 deg, which no frequency or range sees); without it the receiver says that it took the
    orientation as normal."""
    import shutil

    off = captures["off"].capture_path
    swapped = tmp_path / off.name
    shutil.copy(off, swapped)
    data = np.fromfile(off.with_suffix(".sigmf-data"), dtype=np.int16).reshape(-1, 2)[:, ::-1]
    data.tofile(swapped.with_suffix(".sigmf-data"))
    common = ["--static-window", "1.0", "--no-paths"]
    straight_rx, swapped_rx = tmp_path / "straight.h5", tmp_path / "swapped.h5"
    assert main(["-q", "receive", str(off), "-o", str(straight_rx), *common]) == EXIT_OK
    assert main(["-q", "receive", str(swapped), "-o", str(swapped_rx), "--conjugate", *common]) == EXIT_OK
    straight, mirrored = (read_columns(p, schema.RECEIVER_FRAMES) for p in (straight_rx, swapped_rx))
    assert len(straight["t_s"]) > 1000
    assert np.array_equal(straight["t_s"], mirrored["t_s"])
    np.testing.assert_allclose(mirrored["cfo_hz"], straight["cfo_hz"], atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(mirrored["range_change_m"], straight["range_change_m"], atol=1e-4, equal_nan=True)
    capsys.readouterr()
    main(["receive", str(swapped), "-o", str(tmp_path / "auto.h5"), *common])
    assert "orientation is taken as normal" in capsys.readouterr().err
