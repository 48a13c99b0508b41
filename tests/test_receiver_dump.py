"""``dtmbnav receive --dump``: the stages' intermediate outputs, frame by frame, without changing the result."""

import h5py
import numpy as np
import pytest
from test_cli import _assert_same_frames, _frames

from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_OK, EXIT_USAGE, main
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode


def _dump(path) -> tuple[dict, dict]:
    with h5py.File(path, "r") as f:
        stages = {stage: {name: f[stage][name][()] for name in f[stage]} for stage in f}
        return stages, {stage: dict(f[stage].attrs) for stage in f} | {"/": dict(f.attrs)}


def test_dump_over_a_window_leaves_the_result_alone(tiny_sim, tiny_rx, tmp_path):
    capture = str(tiny_sim / "tiny-walk.sigmf-meta")
    out, dump = tmp_path / "rx.h5", tmp_path / "dump.h5"
    argv = ["-q", "receive", capture, "-o", str(out), "--dump", str(dump), "--dump-window", "0.1:0.2",
            "--dump-stages", "channel,tracking,body,paths"]
    assert main(argv) == EXIT_OK
    _assert_same_frames(_frames(out)[0], _frames(tiny_rx)[0])       # dumping changes nothing it dumps from
    stages, attrs = _dump(dump)
    assert attrs["/"]["complete"] and attrs["/"]["stages"] == "channel,tracking,body,paths"
    assert set(stages) == {"channel", "tracking", "body", "paths"}
    start = stages["tracking"]["window_start"]
    # Every frame whose window starts in [0.1, 0.2) s of the stream, in order, the same rows in every stage.
    assert np.all((start >= 0.1 * SYMBOL_RATE_HZ) & (start < 0.2 * SYMBOL_RATE_HZ)) and np.all(np.diff(start) > 0)
    frame_length = PnMode.PN420.value.frame_length
    assert len(start) == pytest.approx(0.1 * SYMBOL_RATE_HZ / frame_length, abs=2)
    for stage in stages.values():
        np.testing.assert_array_equal(stage["window_start"], start)
        np.testing.assert_array_equal(stage["frame_index"], stages["tracking"]["frame_index"])
    assert stages["body"]["bodies"].shape == (len(start), 3780)
    # The path tracker's span: the header's cyclic extension around the window start (PN420: -83..82).
    assert stages["paths"]["taps"].shape == (len(start), 165) and attrs["paths"]["lag0"] == -83
    # The timing the tracker smoothed is where the frames were cut, to the sample.
    np.testing.assert_allclose(stages["tracking"]["smoothed"], start, atol=1.0)


def test_dump_stages_default_and_bad_options(tiny_sim, tmp_path, capsys):
    capture = str(tiny_sim / "tiny-walk.sigmf-meta")
    dump = tmp_path / "dump.h5"
    assert main(["-q", "receive", capture, "-o", str(tmp_path / "rx.h5"), "--dump", str(dump)]) == EXIT_OK
    stages, _ = _dump(dump)
    assert set(stages) == {"channel", "tracking", "paths"}                 # no bodies unless asked for
    for argv, message in [(["--dump", str(dump), "--dump-stages", "channel,cir"], "channel, tracking, body"),
                          (["--dump-window", "0:1"], "need --dump FILE"),
                          (["--dump", str(dump), "--dump-window", "2:1"], "START:STOP")]:
        assert _exit_code(["-q", "receive", capture, "-o", str(tmp_path / "rx2.h5"), *argv]) == EXIT_USAGE
        assert message in capsys.readouterr().err


def _exit_code(argv: list[str]) -> int:
    """The exit status of ``dtmbnav ARGV`` (argparse's own errors exit, the others return it)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def test_doppler_map_of_a_dump(tiny_sim, tmp_path, capsys):
    capture = str(tiny_sim / "tiny-walk.sigmf-meta")
    dump = tmp_path / "dump.h5"
    assert main(["-q", "receive", capture, "-o", str(tmp_path / "rx.h5"), "--dump", str(dump),
                 "--dump-stages", "paths"]) == EXIT_OK
    capsys.readouterr()
    assert main(["doppler-map", str(dump), "--at", "0.25", "--seconds", "0.2"]) == EXIT_OK
    out = capsys.readouterr().out.splitlines()
    assert "paths stage, 0.2 s around 0.25 s" in out[0]
    strongest = out[2].split()
    assert float(strongest[1]) == 0.0                  # lines are listed strongest first, relative to it
    assert _exit_code(["-q", "doppler-map", str(dump), "--at", "30"]) == EXIT_BAD_INPUT
    assert "no paths frame in" in capsys.readouterr().err
