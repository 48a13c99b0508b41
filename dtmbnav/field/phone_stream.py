"""A phone's sensors as they arrive: Sensor Logger's HTTP push, or a GnssLogger text log read while it grows.

Both sources give :class:`PhoneChunk` s through one small interface (:class:`PhoneStream`): ``poll()``
returns what settled since the last poll (None: nothing new), ``close()`` stops the source and returns
the rest. A chunk's ``imu`` is the three motion sensors resampled onto the file importer's uniform grid
(:data:`~dtmbnav.field.sensors_import.DEFAULT_RATE_HZ`), t_s on the stream's clock: s since the grid's
first sample, whose UTC is ``t0_utc_ns``; the grid runs on across chunks, so the chunks put end to end
are the ``/imu`` that ``dtmbnav sensors`` builds from the same log (:mod:`dtmbnav.field.sensors_import`:
the same first sample, where every sensor has begun; the same grid times, the same linear interpolation,
bit for bit), held back only until the samples on both sides of a grid time have arrived. Two
differences, both reported: a stretch longer than :data:`MAX_BRIDGE_S` without samples of a sensor
is a :class:`~dtmbnav.field.sensors_import.Gap` in ``chunk.gaps`` and its grid times are left out (a
file, read whole, is interpolated across; live, nothing is invented); and a sample that comes after
the grid has passed its time (or repeats one) is dropped and counted (the file importer refuses a log
whose times go back). The units, signs and axes are the importers' (:mod:`dtmbnav.field.phone_logs`).

Sensor Logger's HTTP push (Kelvin Choi's app, Settings > Data Streaming > HTTP Push). What its author
documents (``PUSHING.md``, ``UNITS.md`` and ``README.md`` of github.com/tszheichoi/awesome-sensor-logger):
each recording streams, once per batch period, a POST whose JSON body is ``{"messageId": n,
"sessionId": ..., "deviceId": ..., "payload": [reading, ...]}``; ``messageId`` counts up within a
session; a reading is ``{"name": ..., "time": t, "values": {...}}`` with ``time`` in ns since the Unix
epoch (UTC, the CSV export's ``time``), ``name`` the sensor in lower case, ``values`` the CSV file's
columns: ``x``, ``y``, ``z`` for ``accelerometer`` (Android: without gravity), ``gravity``,
``gyroscope`` (rad/s), ``magnetometer`` (uT), and ``latitude``, ``longitude``, ``altitude`` (m above the
WGS84 ellipsoid), ``horizontalAccuracy`` (m; negative: none) for ``location``. The schema in
``PUSHING.md`` does not list ``totalacceleration``, but receivers written for the app's Android pushes
read the specific force from it (the CSV export's ``TotalAcceleration.csv``). So the specific force is
taken as the CSV importer takes it: ``totalacceleration`` where the stream has it, else
``accelerometer`` plus ``gravity`` interpolated at its times, else ``accelerometer`` alone if its mean
magnitude shows it holds gravity; chosen on the first batch that holds an acceleration. The push
carries no platform: an iPhone must have "Standardise Units & Frames" on (Android's sign), or the
caller says ``platform="ios"`` and the sign is reversed as the importer does. The server is the
standard library's ``http.server`` (a thread per request): a phone posting a batch or two a second
needs no framework, and the real-data path installs nothing. Batches are released in ``messageId``
order: one that comes early waits for the missing ones at most :data:`REORDER_WAIT_S`, then they are
counted lost. Malformed JSON or a reading without its fields: a 400 naming the fault, counted in
:attr:`StreamStats.rejected_batches`, and the stream goes on. At most ``max_batches`` wait between the
server and ``poll()``: past that, a batch gets a 503 and is counted (:attr:`StreamStats.overflow_batches`),
never dropped silently.

GnssLogger's log read while the app writes it (``tail -f``): new complete lines are read at each poll
(a partial last line waits for its end), split by the ``#`` header lines read so far, and read by the
importer's own functions (calibrated rows where the first rows of a sensor have them, else the
uncalibrated ones less their bias; ``elapsedRealtimeNanos`` as the clock; the fixes of the preferred
provider seen so far, their C/N0 from the Status rows read in the same poll).
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

from dtmbnav.field import phone_logs
from dtmbnav.field.phone_grid import Collector, PhoneChunk, PhoneStream, StreamStats, _Series
from dtmbnav.field.platform import ANDROID, IOS
from dtmbnav.field.sensors_import import DEFAULT_RATE_HZ
from dtmbnav_core import phone_formats as fmt
from dtmbnav_core.constants import GRAVITY_MPS2
from dtmbnav_core.records import GeodeticFixes
from dtmbnav_core.resampling import interpolate
from dtmbnav_core.text_tables import Table

__all__ = ["BatchError", "GnssLoggerTail", "GeodeticFixes", "PhoneChunk", "PhoneStream", "SensorLoggerPush", "StreamStats",
           "parse_batch"]

#: How long a batch that came before a lower ``messageId`` waits for it (wall clock), s.
REORDER_WAIT_S = 1.0
#: Batches that may wait between the HTTP server and ``poll()`` (a few minutes of a batch a second).
MAX_BATCHES = 256
#: Largest request body taken, bytes (a second of every sensor at 500 Hz is well under 1 MiB).
MAX_BODY_BYTES = 8 << 20
#: Most bytes of a growing GnssLogger log read per poll (memory bound; the rest waits for the next poll).
MAX_READ_BYTES = 4 << 20
#: The Sensor Logger readings used, by name.
PUSH_AXES = ("totalacceleration", "accelerometer", "gravity", "gyroscope", "magnetometer")
PUSH_LOCATION = "location"


# --- Sensor Logger's HTTP push ------------------------------------------------------------------------------


class BatchError(ValueError):
    """A pushed batch that cannot be read: the 400's message."""


@dataclass(frozen=True)
class Batch:
    """One pushed message, read: each used sensor's (times ns, N x 3 values) and the location readings."""

    message_id: int | None
    session_id: str | None
    axes: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    location: tuple[np.ndarray, ...] | None = None  # t_ns, lat, lon, height, accuracy


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BatchError(f"{where} is not a number ({type(value).__name__})")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise BatchError(f"{where} is not a finite number")
    return number


def _time_ns(value: object, where: str) -> int:
    """A reading's time, ns since the Unix epoch: a JSON integer as it is, a real number rounded."""
    t = value if isinstance(value, int) and not isinstance(value, bool) else round(_number(value, where))
    if not 0 <= t < 2 ** 63:
        raise BatchError(f"{where} is {t}, not ns since the Unix epoch")
    return t


def parse_batch(body: bytes | str) -> Batch:
    """A pushed batch's JSON (module docstring) read; readings of sensors not used are skipped.

    Raises
    ------
    BatchError
        Not JSON, not an object with a ``payload`` list, or a used reading without its ``time`` or values
        (named, with its index in the payload).
    """
    try:
        message = json.loads(body)
    except (ValueError, RecursionError) as exc:
        raise BatchError(f"not JSON: {str(exc)[:80]}") from None
    if not isinstance(message, dict) or not isinstance(message.get("payload"), list):
        raise BatchError('not a Sensor Logger batch: expected {"messageId", "sessionId", "payload": [...]}')
    message_id = message.get("messageId")
    if message_id is not None and (isinstance(message_id, bool) or not isinstance(message_id, int)):
        raise BatchError(f"messageId is {json.dumps(message_id)[:40]}, not a whole number")
    session = message.get("sessionId")
    rows: dict[str, list[list[float]]] = {}
    for i, reading in enumerate(message["payload"]):
        name = reading.get("name") if isinstance(reading, dict) else None
        name = name.lower() if isinstance(name, str) else None
        if name not in PUSH_AXES and name != PUSH_LOCATION:
            continue
        values = reading.get("values")
        if not isinstance(values, dict):
            raise BatchError(f"payload[{i}] ({name}): no values object")
        t = _time_ns(reading.get("time"), f"payload[{i}] ({name}) time")
        if name == PUSH_LOCATION:
            lat, lon = (_number(values.get(k), f"payload[{i}] (location) {k}") for k in ("latitude", "longitude"))
            if abs(lat) > 90 or abs(lon) > 180:
                raise BatchError(f"payload[{i}] (location): latitude {lat}, longitude {lon} out of range")
            optional = [values.get(fmt.LOCATION_COLUMNS[k]) for k in ("height", "accuracy")]
            height, accuracy = (_number(v, f"payload[{i}] (location)") if v is not None else math.nan
                                for v in optional)
            rows.setdefault(name, []).append([t, lat, lon, height, accuracy if accuracy >= 0 else math.nan])
        else:
            rows.setdefault(name, []).append([t, *(_number(values.get(a), f"payload[{i}] ({name}) {a}")
                                                   for a in fmt.SENSOR_LOGGER_AXES)])
    axes = {name: (np.array([int(r[0]) for r in got], dtype=np.int64), np.array([r[1:] for r in got]))
            for name, got in rows.items() if name != PUSH_LOCATION}
    location = None
    if PUSH_LOCATION in rows:
        got = rows[PUSH_LOCATION]
        location = (np.array([int(r[0]) for r in got], dtype=np.int64),
                    *(np.array([r[k] for r in got]) for k in range(1, 5)))
    return Batch(message_id, session if isinstance(session, str) else None, axes, location)


class _Collected:
    """What both sources say of the stream they collect (``self._io``, a :class:`Collector`)."""

    _io: Collector

    @property
    def t0_utc_ns(self) -> int | None:
        """UTC of chunk time 0, ns since the Unix epoch (None until the grid starts)."""
        return self._io.t0_utc_ns

    @property
    def stats(self) -> StreamStats:
        """What came, was refused, lost or late, so far."""
        return self._io.stats

    def idle_s(self) -> float:
        """Host seconds since data last arrived."""
        return time.monotonic() - self._io.last_data


class SensorLoggerPush(_Collected):
    """Sensor Logger's HTTP push received on ``host:port`` (any path); a :class:`PhoneStream`.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: a free one, see :attr:`url`); the phone must reach it (same network).
    platform : str
        Whose acceleration sign the phone pushes: ``"android"``, or ``"ios"`` for an iPhone without
        "Standardise Units & Frames" (:mod:`dtmbnav.field.platform`).
    rate_hz : float
        The grid's rate, Hz.
    max_batches : int
        Batches that may wait for ``poll()``; past that the phone gets 503s, counted.
    reorder_wait_s : float
        How long a batch waits for those of lower ``messageId`` (wall clock), s.
    """

    def __init__(self, host: str = "0.0.0.0", port: int = 8000, platform: str = ANDROID,
                 rate_hz: float = DEFAULT_RATE_HZ, max_batches: int = MAX_BATCHES,
                 reorder_wait_s: float = REORDER_WAIT_S) -> None:
        if platform not in (ANDROID, IOS):
            raise ValueError(f"platform {platform!r}: expected {ANDROID!r} or {IOS!r}")
        self._sign = -1.0 if platform == IOS else 1.0
        self._reorder_wait_s = reorder_wait_s
        self._io = Collector(rate_hz)
        self._queue: queue.Queue[Batch] = queue.Queue(max_batches)
        self._lock = threading.Lock()  # the server threads' counts and notes
        self._server_notes: list[str] = []
        self._waiting: dict[int, tuple[float, Batch]] = {}
        self._expected: int | None = None
        self._session: str | None = None
        self._acceleration: str | None = None  # the reading the specific force comes from
        self._gravity = _Series()
        self._acc_ref_ns: int | None = None
        self._pending_acc: list[tuple[np.ndarray, np.ndarray]] = []
        self._server = ThreadingHTTPServer((host, port), self._handler())
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, name="sensor-logger-push", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host, port = self._server.server_address[:2]
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{port}/"

    def _handler(self) -> type[BaseHTTPRequestHandler]:
        stream = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                try:
                    length = int(self.headers.get("Content-Length") or 0)
                except ValueError:
                    return stream._refuse(self, 400, "Content-Length is not a number")
                if not 0 <= length <= MAX_BODY_BYTES:
                    return stream._refuse(self, 413, f"batch of {length} bytes (at most {MAX_BODY_BYTES})")
                try:
                    batch = parse_batch(self.rfile.read(length))
                except BatchError as exc:
                    return stream._refuse(self, 400, str(exc))
                try:
                    stream._queue.put(batch, timeout=0.5)
                except queue.Full:
                    with stream._lock:
                        stream._io.stats.overflow_batches += 1
                    return stream._refuse(self, 503, "the receiver is behind: batch refused (counted)")
                self._reply(200, "ok")

            def _reply(self, code: int, text: str) -> None:
                data = (text + "\n").encode()
                self.send_response(code)
                self.send_header("Content-Type", "text/plain; charset=utf-8")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args: object) -> None:  # the stream reports; no line per request on stderr
                pass

        return Handler

    def _refuse(self, handler: BaseHTTPRequestHandler, code: int, why: str) -> None:
        with self._lock:
            if code != 503:
                self._io.stats.rejected_batches += 1
            self._server_notes.append(f"batch refused ({code}): {why}")
        handler._reply(code, why)  # type: ignore[attr-defined]

    def _release(self, final: bool) -> list[Batch]:
        """Batches from the queue in ``messageId`` order (module docstring); those without one as they came."""
        out = []
        while True:
            try:
                batch = self._queue.get_nowait()
            except queue.Empty:
                break
            self._io.last_data = time.monotonic()
            if batch.session_id != self._session:
                if self._session is not None:
                    self._io.notes.append(f"a new recording session {batch.session_id} (was {self._session})")
                self._session, self._expected = batch.session_id, None
            if batch.message_id is None:
                out.append(batch)
            elif self._expected is not None and batch.message_id < self._expected:
                self._io.stats.late_samples += sum(len(t) for t, _ in batch.axes.values())
                self._io.notes.append(f"message {batch.message_id} came after later ones: its samples dropped")
            else:
                self._waiting[batch.message_id] = (time.monotonic(), batch)
        while self._waiting:
            key = min(self._waiting)
            arrived, batch = self._waiting[key]
            # the first batch, and one after a hole, wait for earlier ones (the receiver may start mid-session)
            if key != self._expected and not final and time.monotonic() - arrived < self._reorder_wait_s:
                break
            if self._expected is not None and key > self._expected:
                self._io.stats.lost_messages += key - self._expected
                self._io.notes.append(f"messages {self._expected}..{key - 1} never came (lost)")
            del self._waiting[key]
            self._expected = key + 1
            out.append(batch)
        return out

    def _take(self, batch: Batch) -> None:
        self._io.stats.batches += 1
        if self._acceleration is None and batch.axes.keys() & {"totalacceleration", "accelerometer"}:
            self._acceleration = ("totalacceleration" if "totalacceleration" in batch.axes else
                                  "accelerometer+gravity" if "gravity" in batch.axes else "accelerometer")
            if self._acceleration == "accelerometer":
                norm = float(np.linalg.norm(batch.axes["accelerometer"][1], axis=1).mean())
                if norm < 0.5 * GRAVITY_MPS2:
                    self._io.notes.append(f"acceleration without gravity (mean {norm:.2f} m/s^2) and no gravity "
                                          "reading: turn on TotalAcceleration or Gravity in the app")
                    self._acceleration = None
        for name in ("gyroscope", "magnetometer"):
            if name in batch.axes:
                self._io.grid.add(name, *batch.axes[name])
        if self._acceleration in ("totalacceleration", "accelerometer") and self._acceleration in batch.axes:
            t_ns, values = batch.axes[self._acceleration]
            self._io.grid.add("accelerometer", t_ns, self._sign * values)
        elif self._acceleration == "accelerometer+gravity":
            if "gravity" in batch.axes:
                g = self._gravity
                g.t_ns = np.concatenate((g.t_ns, batch.axes["gravity"][0]))
                g.values = np.concatenate((g.values, batch.axes["gravity"][1]))
            if "accelerometer" in batch.axes:
                self._pending_acc.append(batch.axes["accelerometer"])
        if batch.location is not None:
            t_ns, lat, lon, height, accuracy = batch.location
            self._io.add_fixes(t_ns, lat, lon, height, accuracy, np.full(len(t_ns), np.nan))

    def _add_gravity(self, final: bool) -> None:
        """Accelerometer + gravity at its times, as the CSV importer adds them, once gravity has come past them."""
        if not self._pending_acc or not len(self._gravity.t_ns):
            return
        t_ns = np.concatenate([t for t, _ in self._pending_acc])
        values = np.concatenate([v for _, v in self._pending_acc])
        order = np.argsort(self._gravity.t_ns, kind="stable")
        g_t, g_v = self._gravity.t_ns[order], self._gravity.values[order]
        if self._acc_ref_ns is None:
            self._acc_ref_ns = int(t_ns.min())
        ready = np.ones(len(t_ns), dtype=bool) if final else t_ns <= g_t[-1]
        ref = self._acc_ref_ns
        gravity = interpolate((g_t - ref) / 1e9, g_v, (t_ns[ready] - ref) / 1e9)
        self._io.grid.add("accelerometer", t_ns[ready], self._sign * (values[ready] + gravity))
        waiting = ~ready
        self._pending_acc = [(t_ns[waiting], values[waiting])] if waiting.any() else []
        # keep gravity from its sample just before the earliest acceleration still to come
        earliest = t_ns[waiting].min() if waiting.any() else t_ns.max()
        keep = max(int(np.searchsorted(g_t, earliest, side="right")) - 1, 0)
        self._gravity.t_ns, self._gravity.values = g_t[keep:], g_v[keep:]

    def _step(self, final: bool) -> PhoneChunk | None:
        for batch in self._release(final):
            self._take(batch)
        self._add_gravity(final)
        if self._io.utc_offset_ns is None:
            self._io.utc_offset_ns = 0  # the push's times are UTC
        with self._lock:
            self._io.notes.extend(self._server_notes)
            self._server_notes.clear()
        return self._io.chunk(final)

    def poll(self) -> PhoneChunk | None:
        return self._step(final=False)

    def close(self) -> PhoneChunk | None:
        """Stop listening; the batches still held, and the grid up to the last sample, as the last chunk."""
        self._server.shutdown()
        self._server.server_close()
        self._thread.join()
        return self._step(final=True)


# --- GnssLogger's growing log --------------------------------------------------------------------------------


class GnssLoggerTail(_Collected):
    """A GnssLogger log read while it grows (the file may not exist yet); a :class:`PhoneStream`."""

    def __init__(self, path: str | Path, rate_hz: float = DEFAULT_RATE_HZ) -> None:
        self.path = Path(path)
        self._io = Collector(rate_hz)
        self._offset = 0
        self._line = 0
        self._partial = b""
        self._headers: dict[str, tuple[int, tuple[str, ...]]] = {}  # row type -> its header line, names
        self._rows: dict[str, str] = {}  # sensor -> the row type read
        self._provider: str | None = None
        self._left_out: set[str] = set()
        self._wanted = {*fmt.GNSSLOGGER_SENSOR_ROW_TYPES, "Fix", "Status"}

    def _read_lines(self) -> list[str]:
        try:
            with self.path.open("rb") as f:
                f.seek(self._offset)
                data = f.read(MAX_READ_BYTES)
        except FileNotFoundError:
            return []
        if not data:
            return []
        self._offset += len(data)
        self._io.last_data = time.monotonic()
        data = self._partial + data
        end = data.rfind(b"\n") + 1
        self._partial = data[end:]
        return data[:end].decode("utf-8-sig" if self._line == 0 else "utf-8", errors="replace").splitlines()

    def _tables(self, lines: list[str]) -> dict[str, Table]:
        """This poll's rows by row type, under the header lines read so far (a row before its header: counted)."""
        tables: dict[str, Table] = {}
        for text in lines:
            self._line += 1
            if text.startswith("#"):
                header = phone_logs._gnsslogger_header(text)
                if header is not None and header[0] in self._wanted:
                    self._headers.setdefault(header[0], (self._line, header[1]))
                continue
            row_type, _, rest = text.partition(",")
            row_type = row_type.strip()
            if row_type not in self._wanted:
                continue
            if row_type not in self._headers:
                self._io.stats.bad_rows += 1
                self._io.notes.append(f"{self.path}:{self._line}: a {row_type} row before its header: skipped")
                continue
            if row_type not in tables:
                line, names = self._headers[row_type]
                tables[row_type] = Table(str(self.path), names, line)
            if rest.count(",") + 1 != len(tables[row_type].header) and '"' not in rest:
                self._io.stats.bad_rows += 1
                self._io.notes.append(f"{self.path}:{self._line}: {row_type} row of the wrong field count: skipped")
                continue
            tables[row_type].texts.append(rest)
            tables[row_type].lines.append(self._line)
        return tables

    def _read(self, read: Callable[[Table], object], table: Table) -> list[object]:
        """``read`` of the whole table, else of each row alone, the bad ones counted (a row is never a crash)."""
        try:
            return [read(table)]
        except ValueError:
            pass
        out = []
        for i in range(len(table.texts)):
            try:
                out.append(read(table.subset([i])))
            except ValueError as exc:
                self._io.stats.bad_rows += 1
                self._io.notes.append(f"{exc}: row skipped")
        return out

    def _take(self, tables: Mapping[str, Table]) -> None:
        for sensor, choices in fmt.GNSSLOGGER_SENSOR_ROWS.items():
            if sensor not in self._rows:  # the importer's preference, on the first rows of the sensor
                present = [rows.row_type for rows in choices if rows.row_type in tables]
                if not present:
                    continue
                self._rows[sensor] = present[0]
            row_type = self._rows[sensor]
            if row_type not in tables:
                continue

            def series(table: Table, row_type: str = row_type, sensor: str = sensor) -> phone_logs.SensorSeries:
                notes: list[str] = []
                found = phone_logs._gnsslogger_sensor({row_type: table}, sensor, notes)
                if self._io.utc_offset_ns is None and sensor == "accelerometer":
                    self._io.utc_offset_ns = phone_logs._gnsslogger_utc_offset(table)
                return found[0]

            for s in self._read(series, tables[row_type]):
                self._io.grid.add(sensor, s.t_ns, s.values)
        if "Fix" in tables and self._io.utc_offset_ns is None:
            self._io.stats.bad_rows += len(tables["Fix"].texts)
            self._io.notes.append(f"{self.path}: {len(tables['Fix'].texts)} Fix row(s) before any accelerometer row "
                                  "(which ties the UTC clock to the sensors'): skipped")
        elif "Fix" in tables:
            self._fixes(tables)

    def _fixes(self, tables: Mapping[str, Table]) -> None:
        table = tables["Fix"]
        try:
            providers = [p.lower() for p in table.cells(table.need(fmt.FIX_COLUMNS["provider"]))]
        except ValueError as exc:
            self._io.notes.append(str(exc))
            return
        def rank(provider: str) -> tuple[int, str]:  # the importer's order of preference
            return (fmt.PROVIDERS.index(provider) if provider in fmt.PROVIDERS else len(fmt.PROVIDERS), provider)

        best = min({*providers, *([self._provider] if self._provider else [])}, key=rank)
        if best != self._provider:
            self._io.notes.append(f"{self.path}: fixes of provider {best.upper()} used from here on")
            self._provider = best
        others = sorted({p for p in providers if p != best} - self._left_out)
        if others:  # said once a provider
            self._left_out.update(others)
            self._io.notes.append(f"{self.path}: fixes of {', '.join(o.upper() for o in others)} left out (those of "
                                  f"{best.upper()} used)")
        table = table.subset([i for i, p in enumerate(providers) if p == self._provider])
        if not table.texts:
            return
        status = tables.get("Status")

        def fixes(t: Table) -> phone_logs.FixSeries:
            found = phone_logs._gnsslogger_fixes({"Fix": t, **({"Status": status} if status else {})},
                                                 self._io.utc_offset_ns, self.path, [])
            assert found is not None  # t holds rows
            return found

        for f in self._read(fixes, table):
            self._io.add_fixes(f.t_ns, f.lat_deg, f.lon_deg, f.height_m, f.accuracy_m, f.cn0_dbhz)

    def _step(self, final: bool) -> PhoneChunk | None:
        lines = self._read_lines()
        if final and self._partial:
            lines.append(self._partial.decode("utf-8", errors="replace"))
            self._io.notes.append(f"{self.path}: the last line ends without a line break: read as it is")
            self._partial = b""
        if lines:
            self._take(self._tables(lines))
        return self._io.chunk(final)

    def poll(self) -> PhoneChunk | None:
        return self._step(final=False)

    def close(self) -> PhoneChunk | None:
        """The lines written since the last poll (a last line without its break too) and the grid's rest."""
        return self._step(final=True)
