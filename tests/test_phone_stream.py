"""Live phone sources (dtmbnav.field.phone_stream) against the file importer on the same logs.

A log replayed (dtmbnav.simulation.phone_replay) through Sensor Logger's HTTP push, or appended line by
line to a growing GnssLogger log, must give, chunk after chunk, the /imu that ``dtmbnav sensors``
builds from the file: the same grid times and the same values (bit for bit: the same two neighbours
interpolated). Bad batches get a 400 and are counted; a stretch without samples is a reported gap, not
interpolated.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from phone_log_samples import Stream, fixes_of, gnsslogger_lines, write_lines, write_sensor_logger

from dtmbnav.field.phone_grid import MAX_BRIDGE_S
from dtmbnav.field.phone_logs import read_phone_log
from dtmbnav.field.phone_stream import BatchError, GnssLoggerTail, SensorLoggerPush, parse_batch
from dtmbnav.field.sensors_import import build_sensors
from dtmbnav.simulation.phone_replay import post, push_batches, push_readings, replay_gnsslogger, replay_push

SECONDS = 5.0
#: The receiver's wait for a batch of lower messageId, s (short: the replays run 25-50 times real time).
REORDER_WAIT_S = 0.05


def _walk(seed: int = 1) -> tuple[Stream, Stream, Stream, object]:
    """Jittered samples of three sensors at their own rates and offsets, and a fix a second."""
    rng = np.random.default_rng(seed)

    def times(rate: float, offset: float) -> np.ndarray:
        n = int(SECONDS * rate)
        return np.sort(offset + np.arange(n) / rate + rng.uniform(-0.002, 0.002, n))

    acc = Stream(times(100, 0.0), rng.normal(size=(500, 3)) + [0.0, 0.0, 9.8])
    gyro = Stream(times(100, 0.003), rng.normal(size=(500, 3)))
    mag = Stream(times(50, 0.005), rng.normal(size=(250, 3)) * 5 + [-18.0, 2.0, -42.0])
    t = np.arange(0.0, SECONDS, 1.0)
    n = len(t)
    return acc, gyro, mag, fixes_of(t, 30.5 + t * 1e-5, np.full(n, 114.3), np.full(n, 20.0), np.full(n, 3.5))


def _joined(chunks: list) -> tuple[np.ndarray, ...]:
    chunks = [c for c in chunks if c is not None]
    return tuple(np.concatenate([getattr(c.imu, name) for c in chunks])
                 for name in ("t_s", "acc_mps2", "gyro_radps", "mag_ut"))


def _assert_same(chunks: list, reference) -> None:
    t_s, acc, gyro, mag = _joined(chunks)
    imu = reference.imu
    assert len(t_s) == len(imu.t_s)
    np.testing.assert_array_equal(t_s, imu.t_s)
    np.testing.assert_array_equal(acc, imu.acc_mps2)
    np.testing.assert_array_equal(gyro, imu.gyro_radps)
    np.testing.assert_array_equal(mag, imu.mag_ut)


def _drain(stream, worker: threading.Thread) -> list:
    """Poll ``stream`` while ``worker`` replays into it, then close it."""
    worker.start()
    chunks = []
    while worker.is_alive():
        chunks.append(stream.poll())
        time.sleep(0.01)
    worker.join()
    return [*chunks, stream.close()]


@pytest.mark.parametrize("gravity_split", [False, True])
def test_push_replay_gives_the_importers_imu(tmp_path: Path, gravity_split: bool) -> None:
    """TotalAcceleration, or Accelerometer + Gravity (added at the accelerometer's times) as the importer does."""
    export = write_sensor_logger(tmp_path / "export", *_walk(), gravity_split=gravity_split)
    reference = build_sensors(read_phone_log([export]))
    stream = SensorLoggerPush("127.0.0.1", 0, reorder_wait_s=REORDER_WAIT_S)
    report = {}
    worker = threading.Thread(target=lambda: report.update(r=replay_push([export], stream.url, pace=50.0)))
    chunks = _drain(stream, worker)
    assert report["r"].sent > 5 and report["r"].refused == {}
    _assert_same(chunks, reference)
    assert sum(1 for c in chunks if c is not None and len(c.imu.t_s)) > 1  # it came in pieces
    assert stream.t0_utc_ns == reference.start_utc_ns
    fixes = np.concatenate([c.fixes.t_s for c in chunks if c is not None])
    np.testing.assert_allclose(fixes, reference.gnss.t_s, atol=1e-9)
    assert stream.stats.rejected_batches == stream.stats.lost_messages == stream.stats.late_samples == 0


def test_push_batches_out_of_order_are_put_back(tmp_path: Path) -> None:
    export = write_sensor_logger(tmp_path / "export", *_walk(2))
    reference = build_sensors(read_phone_log([export]))
    batches = [message for _, message in push_batches(push_readings([export]), 0.25)]
    batches[2], batches[3] = batches[3], batches[2]
    batches[7], batches[9] = batches[9], batches[7]
    stream = SensorLoggerPush("127.0.0.1", 0, reorder_wait_s=REORDER_WAIT_S)
    chunks = [stream.poll() for message in batches if post(stream.url, message) == 200]
    _assert_same([*chunks, stream.close()], reference)
    assert stream.stats.batches == len(batches) and stream.stats.lost_messages == 0


def test_bad_batches_get_400_counted_and_the_stream_goes_on(tmp_path: Path) -> None:
    export = write_sensor_logger(tmp_path / "export", *_walk(3))
    reference = build_sensors(read_phone_log([export]))
    batches = [message for _, message in push_batches(push_readings([export]))]
    stream = SensorLoggerPush("127.0.0.1", 0, reorder_wait_s=REORDER_WAIT_S)
    bad_reading = {"messageId": 999, "payload": [{"name": "gyroscope", "time": 1, "values": {"x": 1.0, "y": "a"}}]}
    statuses = [post(stream.url, b"{not json"), post(stream.url, b'{"payload": 3}'), post(stream.url, bad_reading)]
    assert statuses == [400, 400, 400]
    assert all(post(stream.url, message) == 200 for message in batches)
    chunks = [stream.poll(), stream.close()]
    _assert_same(chunks, reference)
    assert stream.stats.rejected_batches == 3
    notes = [n for c in chunks if c is not None for n in c.notes]
    assert sum("refused (400)" in n for n in notes) == 3 and any("payload[0] (gyroscope) y" in n for n in notes)


def test_a_silent_stretch_is_a_gap_not_interpolated(tmp_path: Path) -> None:
    """The phone sends nothing from 2 s to 3.5 s: a gap reported, no grid sample inside it, the rest as the file."""
    export = write_sensor_logger(tmp_path / "export", *_walk(4))
    reference = build_sensors(read_phone_log([export]))
    readings = push_readings([export])
    start = readings[0][0]
    kept = [r for r in readings if not 2.0e9 <= r[0] - start < 3.5e9]
    stream = SensorLoggerPush("127.0.0.1", 0, reorder_wait_s=REORDER_WAIT_S)
    for _, message in push_batches(kept):
        assert post(stream.url, message) == 200
    chunks = [stream.poll(), stream.close()]
    t_s, acc, _, _ = _joined(chunks)
    gaps = [g for c in chunks if c is not None for g in c.gaps]
    assert {g.sensor for g in gaps} == {"accelerometer", "gyroscope", "magnetometer"}
    for gap in gaps:
        assert gap.end_s - gap.start_s > MAX_BRIDGE_S
        assert not np.any((t_s > gap.start_s) & (t_s < gap.end_s))
    outside = np.isin(reference.imu.t_s, t_s)
    assert 0.6 * len(reference.imu.t_s) < outside.sum() < len(reference.imu.t_s)
    np.testing.assert_array_equal(acc, reference.imu.acc_mps2[outside])
    assert stream.stats.gaps == len(gaps)


def test_gnsslogger_tail_gives_the_importers_imu_with_partial_lines(tmp_path: Path) -> None:
    acc, gyro, mag, fixes = _walk(5)
    log = write_lines(tmp_path / "gnss_log.txt", gnsslogger_lines(acc, gyro, mag, fixes))
    reference = build_sensors(read_phone_log([log]))
    growing = tmp_path / "growing.txt"
    tail = GnssLoggerTail(growing)
    assert tail.poll() is None  # not written yet
    data = log.read_bytes()
    chunks, partial_seen = [], 0
    with growing.open("wb") as out:
        for i in range(0, len(data), 5000):  # cuts mid-line
            out.write(data[i:i + 5000])
            out.flush()
            partial_seen += not data[i:i + 5000].endswith(b"\n")
            chunks.append(tail.poll())
    chunks.append(tail.close())
    assert partial_seen > 3
    _assert_same(chunks, reference)
    assert abs(tail.t0_utc_ns - reference.start_utc_ns) < 1_000_000  # the UTC offset: a median over fewer rows
    fixes_t = np.concatenate([c.fixes.t_s for c in chunks if c is not None])
    np.testing.assert_array_equal(fixes_t, reference.gnss.t_s)  # GPS only, as the importer
    cn0 = np.concatenate([c.fixes.cn0_dbhz for c in chunks if c is not None])
    assert np.isfinite(cn0).any()
    assert tail.stats.bad_rows == 0


def test_gnsslogger_replay_at_pace_and_a_bad_row(tmp_path: Path) -> None:
    """The replayer appends at pace; a malformed row in the log is counted and skipped, the others kept."""
    acc, gyro, mag, fixes = _walk(6)
    lines = gnsslogger_lines(acc, gyro, mag, fixes)
    row = next(i for i, line in enumerate(lines) if line.startswith("Gyro,"))
    lines[row] = lines[row].replace(",", ",x", 3)
    log = write_lines(tmp_path / "gnss_log.txt", lines)
    growing = tmp_path / "growing.txt"
    tail = GnssLoggerTail(growing)
    worker = threading.Thread(target=lambda: replay_gnsslogger(log, growing, pace=25.0))
    started = time.monotonic()
    chunks = _drain(tail, worker)
    assert time.monotonic() - started > SECONDS / 25.0 * 0.8
    assert tail.stats.bad_rows == 1
    assert any(f":{row + 1}:" in n for c in chunks if c is not None for n in c.notes)
    good = write_lines(tmp_path / "good.txt", lines[:row] + lines[row + 1:])
    _assert_same(chunks, build_sensors(read_phone_log([good])))


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
        st.sampled_from(["name", "time", "values", "payload", "messageId", "x", "y", "z", "latitude", "longitude",
                         "altitude", "horizontalAccuracy", "sessionId"]) | st.text(max_size=4), inner, max_size=5),
    max_leaves=25)
names = st.sampled_from(["accelerometer", "totalacceleration", "gravity", "gyroscope", "magnetometer", "location",
                         "battery"])


@settings(max_examples=60, deadline=None)
@given(st.one_of(json_values, st.fixed_dictionaries({"messageId": json_values, "payload": st.lists(
    st.fixed_dictionaries({"name": names, "time": json_values, "values": json_values}), max_size=4)})))
def test_parse_batch_never_crashes(message: object) -> None:
    """Arbitrary JSON: a Batch or a BatchError, nothing else."""
    try:
        body = json.dumps(message)
    except ValueError:
        return
    try:
        batch = parse_batch(body)
    except BatchError:
        return
    for t_ns, values in batch.axes.values():
        assert t_ns.dtype == np.int64 and values.shape == (len(t_ns), 3) and np.isfinite(values).all()
