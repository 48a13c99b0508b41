"""The receive path's speed-ups keep its output: ``--jobs N`` is bit-identical to one thread,
read-ahead yields the stream as it was (errors where they happened), decoding into a
buffer equals decoding, the block writer writes every row, the folded PN595 acquisition
metric equals the direct one, and ``dtmbnav receive`` imports only the receiver."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from receiver_signals import make_signal

from dtmbnav.cli import EXIT_OK, main
from dtmbnav_core import gb20600, iqformat, schema
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.interrupt import DeferredStop
from dtmbnav_core.records import FRAME_COLUMN_DTYPES, PATH_COLUMN_DTYPES, FrameBatch, PathBatch
from receiver import writer
from receiver.acquisition import differential_grid_metric, window_length
from receiver.capture import open_capture, rails_to_samples
from receiver.derotate import rotation_table
from receiver.parallel import FRAME_BLOCK, BatchWindows, FrameWorkers
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from receiver.reader import read_ahead

CARRIER = 666e6
REPO = Path(__file__).resolve().parents[1]


def receive(x, config):
    """Rows and the inspected bodies of ``x`` received with ``config`` (in 200k-sample chunks)."""
    bodies = []
    config.inspect = lambda stage, arrays: bodies.append(arrays["bodies"]) if stage == "body" else None
    rx = Receiver(SYMBOL_RATE_HZ, CARRIER, config)
    rows = FrameBatch.concatenate(list(receive_stream((x[i:i + 200_000] for i in range(0, len(x), 200_000)),
                                                      SYMBOL_RATE_HZ, CARRIER, receiver=rx)))
    return rows, np.concatenate(bodies), rx


@pytest.mark.parametrize("mode,rotating", [(PnMode.PN420, True), (PnMode.PN595, False), (PnMode.PN945, True)])
def test_threads_give_bit_identical_frames(mode, rotating):
    """Multipath, a drifting clock, a noise gap (loss of lock, re-acquisition) and a partial last block."""
    first = make_signal(int(0.06 * SYMBOL_RATE_HZ), pn_mode=mode, rotating=rotating, cfo_hz=3000.0, snr_db=12,
                        start_symbol=123_457, echo=(5.3, 0.3j), sampling_offset_ppm=3)
    gap = int(0.02 * SYMBOL_RATE_HZ)
    noise = (0.3 * np.random.default_rng(2).standard_normal(gap)).astype(np.complex64)
    second = make_signal(int(0.04 * SYMBOL_RATE_HZ), pn_mode=mode, rotating=rotating, cfo_hz=3000.0, snr_db=12,
                         start_symbol=123_457, first_sample=len(first) + gap)
    x = np.concatenate([first, noise, second])
    batch = FRAME_BLOCK + FRAME_BLOCK // 2          # a whole block and a partial one per batch
    one, bodies_one, rx_one = receive(x, ReceiverConfig(clock_offset_hz=3000.0, batch_frames=batch, jobs=1))
    many, bodies_many, rx_many = receive(x, ReceiverConfig(clock_offset_hz=3000.0, batch_frames=batch, jobs=3))
    assert len(one) > 2 * batch and len(rx_one.acquisitions) == 2
    for name, column in one.columns().items():
        assert np.array_equal(column, getattr(many, name), equal_nan=True), name
    assert np.array_equal(bodies_one, bodies_many)
    assert rx_one.attributes() == rx_many.attributes()
    # The threads ran blocks ahead of their batch (FrameWorkers.prefetch); one thread runs none ahead.
    assert rx_many._workers.prefetch_hits > 0
    assert rx_one._workers.prefetch_hits == 0


@pytest.mark.parametrize("mode", [PnMode.PN420, PnMode.PN945])
@pytest.mark.parametrize("padded", [False, True])
def test_compiled_block_equals_the_staged_block(mode, padded):
    """frame_block_kernel (the blocks run ahead on the pool) gives every output of the staged block bit for bit.

    Arbitrary samples and windows: the parity is of the arithmetic, not of the frames. ``padded``: the stream's
    first block, whose taps reach before the first sample (zeros there).
    """
    rng = np.random.default_rng(7)
    m = mode.value
    count, taps, span = FRAME_BLOCK - 5, (40, m.preamble), (m.postamble, m.preamble)
    x = (rng.standard_normal(40 * m.frame_length) + 1j * rng.standard_normal(40 * m.frame_length)).astype(np.complex64)
    first_sample = 1000
    starts = (first_sample + (10 if padded else 500) + m.frame_length * np.arange(count)
              + rng.integers(-3, 4, count)).astype(np.int64)
    phases = rng.integers(-(m.period // 2), m.period // 2 + 1, count + 1).astype(np.int64)
    headers = np.stack([gb20600.header_symbols(mode, int(p)) for p in phases]).astype(np.complex64)
    cfo_hz = 2345.6
    windows = BatchWindows(lambda a, b: x[a - first_sample: b - first_sample], starts, phases, headers,
                           cfo_hz / SYMBOL_RATE_HZ, rotation_table(cfo_hz, m.frame_length + 200), first_sample)
    workers = FrameWorkers(1, *taps, tap_threshold=4.0)
    staged = workers._block(mode, windows, 0, count, True, span)
    compiled = workers._compiled_block(mode, windows, 0, count, True, span)
    for name in ("taps", "raw_taps", "snr_db", "noise_power", "peak_metric", "centroid"):
        assert np.array_equal(getattr(staged[0], name), getattr(compiled[0], name), equal_nan=True), name
    # SI carriers, bodies, the path span's taps and noise floor
    for a, b in [*zip(staged[1:3], compiled[1:3]), *zip(staged[3], compiled[3])]:
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_cli_jobs_give_the_same_file(tmp_path):
    capture = REPO / "captures" / "park-loop-cw.sigmf-meta"
    outputs = []
    for jobs in (1, 2):
        out = tmp_path / f"rx{jobs}.h5"
        assert main(["-q", "receive", str(capture), "-o", str(out), "--jobs", str(jobs)]) == EXIT_OK
        outputs.append(out)
    with h5py.File(outputs[0]) as a, h5py.File(outputs[1]) as b:
        ga, gb = a[schema.RECEIVER_FRAMES], b[schema.RECEIVER_FRAMES]
        assert len(ga["t_s"]) > 2000
        for name in FRAME_COLUMN_DTYPES:
            assert np.array_equal(ga[name][:], gb[name][:], equal_nan=True), name
        pa, pb = a[schema.RECEIVER_PATHS], b[schema.RECEIVER_PATHS]   # the path tracker runs after the threads
        assert len(pa["t_s"]) > 0
        for name in PATH_COLUMN_DTYPES:
            assert np.array_equal(pa[name][:], pb[name][:], equal_nan=True), name


def test_jobs_must_be_positive(capsys):
    with pytest.raises(ValueError, match="jobs"):
        ReceiverConfig(jobs=0)
    with pytest.raises(SystemExit) as exit_info:
        main(["receive", "x.ci8", "-o", "y.h5", "--jobs", "0"])
    assert exit_info.value.code == 2 and "--jobs" in capsys.readouterr().err


@settings(max_examples=30, deadline=None)
@given(sizes=st.lists(st.integers(0, 5), max_size=12), depth=st.integers(1, 4), fail_at=st.integers(-1, 12))
def test_read_ahead_yields_the_stream_and_its_error_in_place(sizes, depth, fail_at):
    blocks = [np.full(n, i, dtype=np.complex64) for i, n in enumerate(sizes)]

    def source():
        for i, block in enumerate(blocks):
            if i == fail_at:
                raise ValueError(f"bad block {i}")
            yield block

    got = []
    if 0 <= fail_at < len(blocks):
        with pytest.raises(ValueError, match=f"bad block {fail_at}"):
            got.extend(read_ahead(source(), depth))
        assert len(got) == fail_at
    else:
        got.extend(read_ahead(source(), depth))
        assert len(got) == len(blocks)
    for a, b in zip(got, blocks):
        assert np.array_equal(a, b)


def test_read_ahead_stops_reading_when_the_consumer_stops():
    read = []

    def source():
        for i in range(1000):
            read.append(i)
            yield np.zeros(1, np.complex64)

    stream = read_ahead(source(), depth=2)
    next(stream)
    stream.close()
    # The producer may have been one hand-off ahead when it was told to stop; never much further.
    assert len(read) <= 5


def test_read_ahead_hands_on_every_block_it_read_when_a_stop_is_requested():
    """SIGTERM while blocks wait in the queue: they were read (from a pipe: gone from it), so they are received."""
    read = []

    def source():
        for i in range(1000):
            read.append(i)
            yield np.full(1, i, np.complex64)

    with DeferredStop() as stop:
        blocks = stop.until_stopped(read_ahead(source(), depth=3))
        received = [next(blocks)]
        deadline = time.monotonic() + 10
        while len(read) < 4 and time.monotonic() < deadline:  # the queue fills behind the consumer
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGTERM)
        received += list(blocks)
    assert stop.signum == signal.SIGTERM
    assert 4 <= len(read) < 1000  # the reading stopped ...
    assert [int(b[0].real) for b in received] == read  # ... and every block it had read was handed on, in order


@pytest.mark.parametrize("fmt", ["cu8", "ci8", "ci16", "cf32"])
def test_decode_into_a_buffer_equals_decode(fmt):
    f = iqformat.get_format(fmt)
    rng = np.random.default_rng(3)
    if f.is_integer:
        info = np.iinfo(f.dtype)
        rails = rng.integers(info.min, info.max + 1, 2000).astype(f.dtype)
    else:
        rails = rng.standard_normal(2000).astype(f.dtype)
    out = np.full(1000, np.nan, dtype=np.complex64)
    assert iqformat.decode(rails.tobytes(), f, out=out) is out
    assert np.array_equal(out.view(np.uint32), iqformat.decode(rails.tobytes(), f).view(np.uint32))
    # The reference formula of the format (docs/conventions.md), in float64.
    expected = (rails.astype(np.float64) - f.decode_offset) / f.scale
    # cu8's centre 127.4 has no exact float32: the subtraction rounds once, to within a float32 ulp of 1.
    atol = 2.0 ** -23 if f.decode_offset % 1 else 0.0
    assert np.allclose(out.view(np.float32), expected, rtol=1e-7, atol=atol)
    with pytest.raises(ValueError, match="out must be complex64"):
        iqformat.decode(rails.tobytes(), f, out=np.empty(999, np.complex64))


@pytest.mark.parametrize("fmt", ["cu8", "ci8", "ci16"])
def test_rails_to_samples_equals_decode(fmt):
    f = iqformat.get_format(fmt)
    info = np.iinfo(f.dtype)
    rails = np.random.default_rng(4).integers(info.min, info.max + 1, 5000).astype(f.dtype)
    out = np.empty(2500, dtype=np.complex64)
    rails_to_samples(rails, np.float32(f.decode_offset), np.float32(1.0 / f.scale), out.view(np.float32))
    assert np.array_equal(out.view(np.uint32), iqformat.decode(rails, f).view(np.uint32))


def test_reused_read_blocks_never_overwrite_samples_still_held(tmp_path):
    """A block is decoded into again only once nothing refers to it (a view of it counts)."""
    rails = np.random.default_rng(5).integers(-128, 128, 2 * 50 * 1000).astype(np.int8)
    path = tmp_path / "cap.ci8"
    path.write_bytes(rails.tobytes())
    expected = iqformat.decode(rails, "ci8")
    chunks = open_capture(path, sample_format="ci8", sample_rate_hz=1e6).chunks(1000)
    held = next(chunks)[100:200]                 # a view into the first block, kept while 49 more are read
    for i, chunk in enumerate(chunks, start=1):
        assert np.array_equal(chunk, expected[1000 * i: 1000 * (i + 1)])
    assert np.array_equal(held, expected[100:200])


@settings(max_examples=20, deadline=None)
@given(sizes=st.lists(st.integers(0, 30), min_size=1, max_size=10), block=st.integers(1, 40))
def test_frame_sink_writes_every_row_in_blocks(sizes, block, tmp_path_factory):
    path = tmp_path_factory.mktemp("sink") / "rx.h5"
    rng = np.random.default_rng(len(sizes))
    batches = [FrameBatch(**{name: rng.integers(0, 100, n).astype(dtype) for name, dtype in FRAME_COLUMN_DTYPES.items()})
               for n in sizes]
    path_rows = [PathBatch(**{name: rng.integers(0, 100, 2 * n).astype(dtype)
                              for name, dtype in PATH_COLUMN_DTYPES.items()}) for n in sizes]
    saved = writer.WRITE_ROWS
    writer.WRITE_ROWS = block
    try:
        sink = writer.FrameSink(path)
        for batch, rows in zip(batches, path_rows):
            sink.append(batch)
            sink.append_paths(rows)
        sink.close({"pn_mode": "PN420"}, {"carrier_hz": 666e6})
    finally:
        writer.WRITE_ROWS = saved
    whole, whole_paths = FrameBatch.concatenate(batches), PathBatch.concatenate(path_rows)
    assert sink.frames == len(whole) and sink.paths == len(whole_paths)
    with h5py.File(path) as h5:
        group = h5[schema.RECEIVER_FRAMES]
        for name in FRAME_COLUMN_DTYPES:
            assert np.array_equal(group[name][:], getattr(whole, name)), name
        group = h5[schema.RECEIVER_PATHS]
        for name in PATH_COLUMN_DTYPES:
            assert np.array_equal(group[name][:], getattr(whole_paths, name)), name


def test_receive_path_imports_only_the_receiver():
    """``dtmbnav receive``: no simulator, fusion stage, plotting, pyfftw or scipy subpackage at import.

    (``import numba`` loads the top-level ``scipy`` package itself; its subpackages are what cost.)
    """
    code = ("import sys, dtmbnav.cli, dtmbnav.chain.receive, receiver.pipeline; "
            "print(' '.join(m for m in sys.modules if m.split('.')[0] in ('sim', 'matplotlib', 'pyfftw', 'dask') "
            "or m.startswith('fusion.') or m.startswith('scipy.') and m.split('.')[1] in "
            "('signal', 'fft', 'fftpack', 'linalg', 'stats', 'interpolate', 'ndimage', 'spatial', 'optimize')))")
    loaded = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert loaded.stdout.split() == []


@pytest.mark.parametrize("extra", [0, 1234])
def test_folded_pn595_metric_equals_correlating_then_folding(extra):
    """Folding the lag-1 products before correlating (linearity) gives the direct correlation's fold."""
    mode = PnMode.PN595
    x = make_signal(window_length(16) + extra, pn_mode=mode, rotating=False, cfo_hz=2000.0, snr_db=5,
                    start_symbol=123_457)
    header = gb20600.header_symbols(mode, 0)
    pattern = np.real(np.conj(header[:-1]) * header[1:]) / np.abs(header[0]) ** 2
    diff = np.conj(x[:-1].astype(np.complex128)) * x[1:]
    corr = np.correlate(diff, pattern, mode="valid")               # corr[n] = sum_j diff[n + j] pattern[j]
    frame = mode.value.frame_length
    frames = (len(corr) - frame) // frame + 1
    direct = corr[: frames * frame].reshape(frames, frame).sum(axis=0)
    rho, lag_sum = differential_grid_metric(x, mode)
    assert np.max(np.abs(lag_sum - direct)) < 1e-9 * np.max(np.abs(direct))
    offset = (int(np.argmax(rho)) + 123_457) % frame     # the peak sits on the frame starts
    assert min(offset, frame - offset) <= 2
