"""Replay a recorded phone log as the phone would send it live, at real-time pace (times a pace factor).

Two forms, those :mod:`dtmbnav.field.phone_stream` receives:

- :func:`replay_push`: Sensor Logger's HTTP push: the log cut into batches of ``batch_s`` of its time
  (the app's batch period), each POSTed as the app's JSON message (``messageId`` counting up, one
  ``sessionId``) when its last sample's time has come. A Sensor Logger export is sent file by file as
  the app names its readings (``TotalAcceleration.csv`` as ``totalacceleration``, ``Gravity.csv`` as
  ``gravity``, ...); a GnssLogger log as the importer reads it (the specific force as
  ``totalacceleration``, UTC times).
- :func:`replay_gnsslogger`: a GnssLogger text log's lines appended to a file as the app writes them,
  each when its time (``elapsedRealtimeNanos``; a row without one: the row before it) has come.

The input is whatever ``dtmbnav sensors`` reads: a GnssLogger log, or a Sensor Logger export (folder or
zip); ``dtmbnav simulate --phone-log gnsslogger|sensorlogger`` writes either for a simulated walk.
``pace`` above 1 replays faster (the tests); ``math.inf``: as fast as it goes.
"""

from __future__ import annotations

import json
import math
import threading
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dtmbnav.field import phone_logs
from dtmbnav_core import phone_formats as fmt

#: Default batch period, s (the app's is set under Settings > Data Streaming).
BATCH_S = 0.5


@dataclass
class ReplayReport:
    """What a replay sent: batches (or lines) and the push's refusals (HTTP status: count)."""

    sent: int = 0
    refused: dict[int, int] | None = None


def _reading(name: str, t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> list[tuple[int, dict]]:
    """(time ns, reading) of each sample; a NaN value (none given) is left out."""
    out = []
    for i, t in enumerate(t_ns):
        values = {k: float(v[i]) for k, v in columns.items() if math.isfinite(v[i])}
        out.append((int(t), {"name": name, "time": int(t), "values": values}))
    return out


def _axes(name: str, series: phone_logs.SensorSeries, offset_ns: int = 0) -> list[tuple[int, dict]]:
    return _reading(name, series.t_ns + offset_ns, dict(zip(fmt.SENSOR_LOGGER_AXES, series.values.T)))


def _location(fixes: phone_logs.FixSeries | None, offset_ns: int = 0) -> list[tuple[int, dict]]:
    if fixes is None:
        return []
    keys = fmt.LOCATION_COLUMNS
    return _reading("location", fixes.t_ns + offset_ns, {
        keys["lat"]: fixes.lat_deg, keys["lon"]: fixes.lon_deg, keys["height"]: fixes.height_m,
        keys["accuracy"]: fixes.accuracy_m})


def push_readings(paths: Sequence[str | Path]) -> list[tuple[int, dict]]:
    """Every reading the phone would push for this log, (UTC ns, reading), in time order."""
    first = Path(paths[0])
    if first.is_file() and phone_logs.looks_like_gnsslogger(first.read_text(errors="replace")[:4096]):
        log = phone_logs.read_gnsslogger(first)
        offset = log.utc_offset_ns
        readings = [*_axes("totalacceleration", log.accelerometer, offset), *_axes("gyroscope", log.gyroscope, offset),
                    *(_axes("magnetometer", log.magnetometer, offset) if log.magnetometer else []),
                    *_location(log.fixes, offset)]
    else:
        files = phone_logs.sensor_logger_export([str(p) for p in paths])
        readings, notes = [], []
        for name in fmt.SENSOR_LOGGER_AXIS_FILES:
            if name in files:
                series = phone_logs._sensor_logger_axes(name, *files.text(name), notes)
                readings += _axes(Path(name).stem.lower(), series)
        readings += _location(phone_logs._sensor_logger_fixes(files, notes))
    readings.sort(key=lambda r: r[0])
    return readings


def push_batches(readings: list[tuple[int, dict]], batch_s: float = BATCH_S,
                 session_id: str | None = None) -> list[tuple[int, dict]]:
    """The readings cut into the app's messages of ``batch_s`` each: (the last reading's time ns, message)."""
    if not readings:
        return []
    session_id = session_id or str(uuid.uuid4())
    t = np.array([r[0] for r in readings], dtype=np.int64)
    index = (t - t[0]) // int(batch_s * 1e9)
    out = []
    for message_id, k in enumerate(np.unique(index)):
        chosen = np.flatnonzero(index == k)
        out.append((int(t[chosen[-1]]), {"messageId": message_id, "sessionId": session_id,
                                          "deviceId": "dtmbnav-replay", "payload": [readings[i][1] for i in chosen]}))
    return out


def post(url: str, message: dict | bytes, timeout_s: float = 5.0) -> int:
    """POST one message (a dict as JSON, or raw bytes); the HTTP status."""
    body = message if isinstance(message, bytes) else json.dumps(message).encode()
    request = urllib.request.Request(url, data=body, headers={"Content-Type": "application/json"}, method="POST")
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as response:
            return response.status
    except urllib.error.HTTPError as exc:
        return exc.code


def _wait(t_log_s: float, start: float, pace: float, stop: threading.Event | None) -> bool:
    """Sleep until log time ``t_log_s`` is due at ``pace``; False if ``stop`` was set."""
    if math.isfinite(pace):
        delay = start + t_log_s / pace - time.monotonic()
        if delay > 0:
            if stop is not None:
                return not stop.wait(delay)
            time.sleep(delay)
    return stop is None or not stop.is_set()


def replay_push(paths: Sequence[str | Path], url: str, pace: float = 1.0, batch_s: float = BATCH_S,
                stop: threading.Event | None = None) -> ReplayReport:
    """POST the log's batches to ``url`` at ``pace`` times real time (module docstring); refusals are counted."""
    batches = push_batches(push_readings(paths), batch_s)
    report = ReplayReport(refused={})
    start = time.monotonic()
    for t_ns, message in batches:
        if not _wait((t_ns - batches[0][0]) / 1e9, start, pace, stop):
            break
        status = post(url, message)
        report.sent += 1
        if status != 200:
            report.refused[status] = report.refused.get(status, 0) + 1
    return report


def _line_times(lines: list[str]) -> list[float]:
    """Each GnssLogger line's time, s after the log's first: its ``elapsedRealtimeNanos``, else the line before's."""
    columns: dict[str, int] = {}
    times, last = [], math.nan
    for line in lines:
        fields = line.split(",")
        if line.startswith("#"):
            names = [f.strip() for f in line.lstrip("#").split(",")]
            if fmt.ELAPSED_NANOS in names[1:]:
                columns[names[0]] = names[1:].index(fmt.ELAPSED_NANOS) + 1
        elif fields[0].strip() in columns and len(fields) > columns[fields[0].strip()]:
            try:
                last = int(fields[columns[fields[0].strip()]]) / 1e9
            except ValueError:
                pass
        times.append(last)
    first = next((t for t in times if math.isfinite(t)), 0.0)
    return [0.0 if not math.isfinite(t) else t - first for t in times]


def replay_gnsslogger(source: str | Path, target: str | Path, pace: float = 1.0, chunk_s: float = 0.2,
                      stop: threading.Event | None = None) -> ReplayReport:
    """Append ``source``'s lines to ``target`` (created) at ``pace`` times real time, ``chunk_s`` of log time a
    write, as the app flushes its log (module docstring)."""
    lines = Path(source).read_text(encoding="utf-8-sig").splitlines(keepends=True)
    times = _line_times(lines)
    report = ReplayReport()
    start = time.monotonic()
    with open(target, "w", encoding="utf-8") as out:
        i = 0
        while i < len(lines):
            due = (math.floor(times[i] / chunk_s) + 1) * chunk_s
            j = i
            while j < len(lines) and times[j] < due:
                j += 1
            if not _wait(times[j - 1], start, pace, stop):
                break
            out.write("".join(lines[i:j]))
            out.flush()
            report.sent += j - i
            i = j
    return report
