"""``receive rtl_tcp://``: the protocol's bytes, and a simulated capture replayed by an in-process rtl_tcp server.

The replayed stream gives the frames that ``receive`` gives on the file (faster than real time); a
connection the server drops mid-stream is a GAP-flagged gap on the host's clock with every frame before it
kept; a stop request keeps what was received; a missing or foreign server is a clear error.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
import time

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_OK, EXIT_USAGE, main
from dtmbnav_core import rtltcp, schema
from dtmbnav_core.records import FrameFlag
from receiver import rtl_tcp
from receiver.capture import open_capture
from sim.rtl_tcp_replay import RtlTcpReplay

RATE_HZ = 2.4e6
SECONDS = 1.2
#: An f_s given to both runs of a comparison: the range then does not depend on which frames a run has.
CLOCK_OFFSET = ["--clock-offset", "19.4"]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """1.2 s of the tiny walk at an RTL-SDR's 2.4 Msps cu8: (SigMF meta path, its cu8 bytes, centre Hz)."""
    out = tmp_path_factory.mktemp("rtl-tcp")
    assert main(["-q", "simulate", "tests/data/tiny-walk.toml", "--seconds", str(SECONDS), "--start", "2.4",
                 "--rate", str(RATE_HZ), "--format", "cu8", "-o", str(out)]) == EXIT_OK
    meta = out / "tiny-walk.sigmf-meta"
    source = open_capture(meta)
    return meta, (out / "tiny-walk.sigmf-data").read_bytes(), source.center_hz


@pytest.fixture()
def policy(monkeypatch):
    """The CLI's link policy for a replay at ``pace``: nothing to settle, quick reconnects."""
    def set_pace(pace: float, reconnects: int = 1) -> None:
        monkeypatch.setattr(rtl_tcp, "DEFAULT_POLICY", rtl_tcp.LinkPolicy(
            settle_s=0.0, reconnects=reconnects, backoff_s=0.01, time_scale=pace))
    return set_pace


def frames(path) -> tuple[dict[str, np.ndarray], dict]:
    with h5py.File(path, "r") as f:
        group = f[schema.RECEIVER_FRAMES]
        return {k: group[k][()] for k in group}, dict(group.attrs)


def receive_file(tmp_path, meta, *extra) -> dict[str, np.ndarray]:
    out = tmp_path / "file.h5"
    assert main(["-q", "receive", str(meta), "-o", str(out), *extra]) == EXIT_OK
    return frames(out)[0]


def test_greeting_and_command_bytes():
    """rtl_tcp.c's dongle_info_t and struct command: big-endian uint32s after "RTL0" / the command byte."""
    assert rtltcp.Greeting(5, 29).encode() == b"RTL0\x00\x00\x00\x05\x00\x00\x00\x1d"
    greeting = rtltcp.Greeting.decode(b"RTL0\x00\x00\x00\x01\x00\x00\x00\x0e")
    assert (greeting.tuner_type, greeting.gain_count, greeting.tuner_name) == (1, 14, "E4000")
    with pytest.raises(rtltcp.NotRtlTcp, match="RTL0"):
        rtltcp.Greeting.decode(b"HTTP/1.1 200")
    assert rtltcp.encode_command(rtltcp.Command.SET_FREQUENCY, 666_000_000) == b"\x01\x27\xb2\x5a\x80"
    assert rtltcp.encode_command(rtltcp.Command.SET_FREQ_CORRECTION, -3) == b"\x05\xff\xff\xff\xfd"
    assert rtltcp.decode_command(b"\x05\xff\xff\xff\xfd") == (rtltcp.Command.SET_FREQ_CORRECTION, -3)
    with pytest.raises(ValueError, match="32 bits"):
        rtltcp.encode_command(rtltcp.Command.SET_SAMPLE_RATE, 1 << 32)
    # Automatic gain is gain mode 0 alone; a manual gain is mode 1 and the gain in tenths of a dB.
    assert rtl_tcp.settings_commands(2.4e6, 666e6) == [
        (rtltcp.Command.SET_FREQ_CORRECTION, 0), (rtltcp.Command.SET_SAMPLE_RATE, 2_400_000),
        (rtltcp.Command.SET_FREQUENCY, 666_000_000), (rtltcp.Command.SET_GAIN_MODE, 0)]
    assert rtl_tcp.settings_commands(2.4e6, 666e6, gain_db=40.2, ppm=-7)[::4] == [
        (rtltcp.Command.SET_FREQ_CORRECTION, -7), (rtltcp.Command.SET_GAIN, 402)]
    assert rtl_tcp.parse_url("rtl_tcp://sdr.local") == ("sdr.local", 1234)
    assert rtl_tcp.parse_url("rtl_tcp://[::1]:1235") == ("::1", 1235)
    assert rtl_tcp.parse_url("capture.sigmf-meta") is None
    with pytest.raises(ValueError, match="port"):
        rtl_tcp.parse_url("rtl_tcp://host:port")


@given(command=st.sampled_from(rtltcp.Command), value=st.integers(0, (1 << 32) - 1),
       tuner=st.integers(0, (1 << 32) - 1), gains=st.integers(0, (1 << 32) - 1))
def test_codec_round_trips(command, value, tuner, gains):
    """Every command's 5 bytes and every greeting's 12 read back as written (a signed command's value signed)."""
    if command in rtltcp.SIGNED_COMMANDS:
        value -= 1 << 31
    data = rtltcp.encode_command(command, value)
    assert len(data) == 5 and data[0] == command
    assert rtltcp.decode_command(data) == (command, value)
    assert rtltcp.Greeting.decode(rtltcp.Greeting(tuner, gains).encode()) == rtltcp.Greeting(tuner, gains)


def test_replayed_stream_gives_the_frames_of_the_file(capture, policy, tmp_path):
    """At 20 times real time: the frames of ``receive`` on the file, all of them, and the settings asked for."""
    meta, data, centre = capture
    policy(20.0)
    out = tmp_path / "live.h5"
    with RtlTcpReplay(data, RATE_HZ, pace=20.0) as server:
        assert main(["-q", "receive", server.url, "--rate", "2400000", "--center", f"{centre:.0f}", "--gain", "40.2",
                     "--ppm", "-3", "-o", str(out)]) == EXIT_OK
    live, attrs = frames(out)
    reference = receive_file(tmp_path, meta)
    assert len(live["t_s"]) == len(reference["t_s"]) > 0.9 * SECONDS * 1800
    for name, column in reference.items():
        np.testing.assert_array_equal(live[name], column, err_msg=name)
    assert server.commands == [(rtltcp.Command.SET_FREQ_CORRECTION, -3), (rtltcp.Command.SET_SAMPLE_RATE, 2_400_000),
                               (rtltcp.Command.SET_FREQUENCY, round(centre)), (rtltcp.Command.SET_GAIN_MODE, 1),
                               (rtltcp.Command.SET_GAIN, 402)]
    assert attrs["outages"] == 0 and attrs["rtl_tcp_tuner"] == "R820T" and "rtl_tcp_end" in attrs
    assert abs(attrs[schema.START_UTC_NS_ATTR] - time.time_ns()) < 60e9


def test_dropped_connection_is_a_flagged_gap_on_the_host_clock(capture, policy, tmp_path):
    """The server drops the connection 0.4 s in and accepts again 0.3 s later: the samples of the outage are
    zeros on the stream's clock, the first frame after it is flagged GAP (an outage longer than the receiver
    bridges, receiver.drops.MAX_BRIDGE_S), every frame before it is the file's, and the frames after it are the
    file's on its clock."""
    meta, data, centre = capture
    # First: the receiver's kernels are then loaded, and the live run keeps pace from its first sample (a
    # receiver that falls behind holds the server back, and a reconnect skips what it held back).
    reference = receive_file(tmp_path, meta, *CLOCK_OFFSET)
    policy(1.0)
    out = tmp_path / "live.h5"
    with RtlTcpReplay(data, RATE_HZ, pace=1.0, drop_after_s=0.4, outage_s=0.3) as server:
        assert main(["-q", "receive", server.url, "--rate", "2400000", "--center", f"{centre:.0f}", "-o", str(out),
                     *CLOCK_OFFSET]) == EXIT_OK
    live, attrs = frames(out)
    (outage,) = server.outages
    assert server.connections == 2 and len(server.commands) == 8
    assert attrs["outages"] == 1 and attrs["outage_sample_index"][0] == outage.at_byte // 2
    lost = outage.lost_samples
    assert lost > 0.29 * RATE_HZ
    assert abs(attrs["outage_lost_samples"][0] - lost) < 0.002 * RATE_HZ   # the host's clock, within 2 ms
    gap_t = outage.at_byte / 2 / RATE_HZ
    before = reference["t_s"] < gap_t - 0.01
    for name, column in reference.items():
        np.testing.assert_array_equal(live[name][:before.sum()], column[before], err_msg=name)
    (first_after,) = np.flatnonzero(live["flags"] & FrameFlag.GAP)
    assert gap_t < live["t_s"][first_after] < gap_t + lost / RATE_HZ + 0.05
    assert np.all(live["segment_id"][first_after:] == live["segment_id"][0] + 1)
    # After the gap: the file's frames (the same frame numbers), at their times within the fill's error.
    after = {int(f): i for i, f in enumerate(reference["frame_index"])}
    rows = [after[int(f)] for f in live["frame_index"][first_after:]]
    assert rows == list(range(rows[0], len(reference["t_s"])))
    err = live["t_s"][first_after:] - reference["t_s"][rows]
    assert np.max(np.abs(err)) < 0.002 + 1e-6


def test_stop_request_keeps_what_was_received(capture, policy, tmp_path):
    """SIGINT during a live run: exit 130, the frames of the samples received written, and why it ended."""
    _meta, data, centre = capture
    policy(1.0)
    out = tmp_path / "live.h5"
    with RtlTcpReplay(data, RATE_HZ, pace=1.0, loop=True) as server:
        def interrupt() -> None:
            while server.sent_bytes < 0.6 * 2 * RATE_HZ:   # the receiver is well under way
                time.sleep(0.01)
            os.kill(os.getpid(), signal.SIGINT)
        threading.Thread(target=interrupt, daemon=True).start()
        code = main(["-q", "receive", server.url, "--rate", "2400000", "--center", f"{centre:.0f}", "-o", str(out)])
        sent_s = server.sent_bytes / 2 / RATE_HZ
    assert code == 128 + signal.SIGINT
    live, attrs = frames(out)
    assert "SIGINT" in attrs[schema.ENDED_EARLY_ATTR]
    assert 0.5 < live["t_s"][-1] < sent_s and not np.any(live["flags"] & FrameFlag.GAP)


def test_refused_and_foreign_servers_are_clear_errors(capsys, tmp_path):
    with socket.socket() as probe:   # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out = tmp_path / "x.h5"
    args = ["--rate", "2400000", "--center", "666000000", "-o", str(out)]
    assert main(["-q", "receive", f"rtl_tcp://127.0.0.1:{port}", *args]) == EXIT_BAD_INPUT
    assert f"127.0.0.1:{port}" in capsys.readouterr().err and not out.exists()
    with pytest.raises(rtl_tcp.RtlTcpError, match="rtl_tcp must be running there"):
        rtl_tcp.RtlTcpSource("127.0.0.1", port, sample_rate_hz=RATE_HZ, center_hz=666e6).open()
    with RtlTcpReplay(b"\x80" * 64, RATE_HZ, greeting=b"SSH-2.0-OpenSSH_9.6\r\n") as server:
        assert main(["-q", "receive", server.url, *args]) == EXIT_BAD_INPUT
    assert "not an rtl_tcp server" in capsys.readouterr().err and not out.exists()
    with pytest.raises(SystemExit) as usage:
        main(["-q", "receive", "rtl_tcp://127.0.0.1", "--center", "666e6", "-o", str(out)])
    assert usage.value.code == EXIT_USAGE
    assert "needs --rate and --center" in capsys.readouterr().err
