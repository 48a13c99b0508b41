"""Read a phone's own sensor log: Google's GnssLogger text log, or the Sensor Logger app's CSV export.

Both readers return a :class:`PhoneLog`: each motion sensor's samples as logged (times on the log's
own clock in integer nanoseconds, values in the project's units and the phone's own axes) and the
location fixes (WGS84 latitude and longitude, ellipsoidal height). Resampling, the local ENU frame,
the start fix and the file are :mod:`dtmbnav.sensors_import`'s.

Why a reader of our own: ``gnss_lib_py`` parses GnssLogger logs, but installs pandas, plotly,
georinex and more for what is here plain CSV reading. Both formats are read by the column names of
their headers (GnssLogger's ``# Fix,...`` comment lines, Sensor Logger's first row), never by
position, because versions of the apps add, drop and reorder columns.

Axes and units. Android reports every motion sensor in the device frame, x to the right of the
screen, y up the screen (towards the top of the phone), z out of the screen: the project's phone
frame (``docs/conventions.md``), so the axes are kept as logged. Accelerometers report the specific
force (+9.81 m/s^2 on z lying face up), gyroscopes right-handed rates in rad/s, magnetometers uT,
the units of ``/imu``. The Sensor Logger app on iOS, unless its "Standardise Units & Frames" setting
is on, logs acceleration and gravity with the opposite sign; that is undone here.

Timestamps. A sensor's samples must not go back in time: a backwards step is an error naming the
line; a repeated timestamp is dropped (the first sample kept) and reported in :attr:`PhoneLog.notes`.
"""

from __future__ import annotations

import io
import re
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dtmbnav_core.constants import GRAVITY_MPS2

GNSSLOGGER = "GnssLogger"
SENSOR_LOGGER = "Sensor Logger"
SENSORS = ("accelerometer", "gyroscope", "magnetometer")

#: GnssLogger row types of each motion sensor, in order of preference: (row type, value columns, bias columns).
#: The calibrated rows are taken when the log has them; an uncalibrated reading minus the bias (or drift)
#: the phone estimated is the calibrated one (Android's ``SensorEvent`` documentation).
GNSSLOGGER_SENSORS: dict[str, tuple[tuple[str, tuple[str, ...], tuple[str, ...] | None], ...]] = {
    "accelerometer": (("Accel", ("AccelXMps2", "AccelYMps2", "AccelZMps2"), None),
                      ("UncalAccel", ("UncalAccelXMps2", "UncalAccelYMps2", "UncalAccelZMps2"),
                       ("BiasXMps2", "BiasYMps2", "BiasZMps2"))),
    "gyroscope": (("Gyro", ("GyroXRadPerSec", "GyroYRadPerSec", "GyroZRadPerSec"), None),
                  ("UncalGyro", ("UncalGyroXRadPerSec", "UncalGyroYRadPerSec", "UncalGyroZRadPerSec"),
                   ("DriftXRadPerSec", "DriftYRadPerSec", "DriftZRadPerSec"))),
    "magnetometer": (("Mag", ("MagXMicroT", "MagYMicroT", "MagZMicroT"), None),
                     ("UncalMag", ("UncalMagXMicroT", "UncalMagYMicroT", "UncalMagZMicroT"),
                      ("BiasXMicroT", "BiasYMicroT", "BiasZMicroT"))),
}
#: Names of the Fix columns used, current first, then those of older versions of the app.
FIX_COLUMNS = {
    "provider": ("Provider",),
    "lat": ("LatitudeDegrees", "Latitude"),
    "lon": ("LongitudeDegrees", "Longitude"),
    "height": ("AltitudeMeters", "Altitude"),
    "accuracy": ("AccuracyMeters", "Accuracy"),
    "unix_ms": ("UnixTimeMillis", "(UTC)TimeInMs"),
    "elapsed_ns": ("elapsedRealtimeNanos",),
}
#: Fix providers in order of preference: the GNSS chipset's own fixes, then the fused and network ones.
PROVIDERS = ("gps", "flp", "nlp")
#: Every row type GnssLogger writes (the unused ones are skipped); a file whose first row is one of
#: these, or a comment line, is taken for a GnssLogger log.
GNSSLOGGER_ROW_TYPES = ("Raw", "Fix", "Status", "Nav", "NMEA", "Agc", "OrientationDeg", "GnssAntennaInfo",
                        "Accel", "UncalAccel", "Gyro", "UncalGyro", "Mag", "UncalMag")
_ROW_TYPE = re.compile(r"[A-Za-z][A-Za-z0-9]*")

#: Sensor Logger file of each motion sensor (the accelerometer's is chosen by :func:`_sensor_logger_accelerometer`).
SENSOR_LOGGER_FILES = {"gyroscope": "Gyroscope.csv", "magnetometer": "Magnetometer.csv"}
TOTAL_ACCELERATION = "TotalAcceleration.csv"
ACCELEROMETER = "Accelerometer.csv"
GRAVITY = "Gravity.csv"
LOCATION = "Location.csv"
METADATA = "Metadata.csv"


@dataclass(frozen=True)
class SensorSeries:
    """One motion sensor's samples as logged.

    Attributes
    ----------
    sensor : str
        ``"accelerometer"``, ``"gyroscope"`` or ``"magnetometer"``.
    source : str
        Where the samples come from (file, and row type), for messages and the file's attributes.
    t_ns : ndarray of int64
        Sample times on the log's clock, ns, increasing.
    values : ndarray, shape (N, 3)
        Specific force m/s^2, angular rate rad/s, or magnetic flux density uT; phone axes.
    line : ndarray of int64
        Line of each sample in its file (1-based), for messages.
    """

    sensor: str
    source: str
    t_ns: np.ndarray
    values: np.ndarray
    line: np.ndarray


@dataclass(frozen=True)
class FixSeries:
    """Location fixes as logged.

    Attributes
    ----------
    source : str
        File (and provider) of the fixes.
    t_ns : ndarray of int64
        Fix times on the log's clock, ns, increasing.
    lat_deg, lon_deg : ndarray
        WGS84 latitude and longitude, deg.
    height_m : ndarray
        Height above the WGS84 ellipsoid, m; NaN where the log gives none.
    accuracy_m : ndarray
        Stated horizontal accuracy, m: the radius of 68 % confidence on Android; NaN where none is given.
    cn0_dbhz : ndarray
        Mean C/N0 of the satellites used in the fix, dB-Hz; NaN where the log does not say.
    line : ndarray of int64
        Line of each fix in its file (1-based).
    """

    source: str
    t_ns: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    accuracy_m: np.ndarray
    cn0_dbhz: np.ndarray
    line: np.ndarray


@dataclass(frozen=True)
class PhoneLog:
    """What a phone log holds, read and checked.

    Attributes
    ----------
    format : str
        :data:`GNSSLOGGER` or :data:`SENSOR_LOGGER`.
    sources : tuple of str
        The files read.
    accelerometer, gyroscope : SensorSeries
    magnetometer : SensorSeries or None
        None when the log has no magnetometer.
    fixes : FixSeries
    utc_offset_ns : int
        UTC time (ns since the Unix epoch) minus the log's clock, ns.
    notes : tuple of str
        Warnings found while reading (repeated timestamps dropped, providers left out, ...).
    """

    format: str
    sources: tuple[str, ...]
    accelerometer: SensorSeries
    gyroscope: SensorSeries
    magnetometer: SensorSeries | None
    fixes: FixSeries
    utc_offset_ns: int
    notes: tuple[str, ...] = ()


# --- text tables --------------------------------------------------------------------------------------

@dataclass
class _Table:
    """Rows of one row type (GnssLogger) or one CSV file, split into fields, with their header's names."""

    where: str
    header: tuple[str, ...]
    header_line: int
    rows: list[list[str]] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)

    def index(self, names: Sequence[str]) -> int | None:
        """Column of the first of ``names`` the header has (case-insensitive), None if none."""
        lowered = [h.lower() for h in self.header]
        for name in names:
            if name.lower() in lowered:
                return lowered.index(name.lower())
        return None

    def need(self, names: Sequence[str]) -> int:
        """Column of the first of ``names`` the header has; ValueError naming the header otherwise."""
        column = self.index(names)
        if column is None:
            also = f" (or {', '.join(names[1:])})" if len(names) > 1 else ""
            raise ValueError(f"{self.where}: the header (line {self.header_line}) has no column {names[0]}{also}")
        return column


def read_text(path: str | Path, data: bytes | None = None) -> str:
    """A log's text (UTF-8, a byte-order mark dropped); ValueError for a missing, empty or binary file."""
    if data is None:
        path = Path(path)
        if not path.exists():
            raise ValueError(f"{path}: no such file")
        if not path.is_file():
            raise ValueError(f"{path}: not a file")
        data = path.read_bytes()
    if not data.strip():
        raise ValueError(f"{path}: empty file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a text log (byte {exc.start} is not UTF-8)") from None


def _check_length(table: _Table, fields: list[str], number: int, last: bool, label: str, leading: int = 0) -> None:
    """A row must have as many fields as its header names; a short last row is a truncated file.

    ``leading`` fields (a GnssLogger row's type) come before those the table keeps and are counted too.
    """
    if len(fields) == len(table.header):
        return
    have, want = len(fields) + leading, len(table.header) + leading
    if last and len(fields) < len(table.header):
        raise ValueError(f"{table.where}:{number}: truncated {label}row: {have} of the header's {want} fields (the "
                         "file ends inside it)")
    raise ValueError(f"{table.where}:{number}: {label}row has {have} fields, its header (line {table.header_line}) "
                     f"names {want}")


def _values(table: _Table, column: int, name: str, empty_ok: bool = False) -> np.ndarray:
    """A column as float64; an empty field is NaN where ``empty_ok``, else (like NaN or inf) a ValueError."""
    out = np.empty(len(table.rows), dtype=np.float64)
    for i, row in enumerate(table.rows):
        text = row[column]
        if text == "" and empty_ok:
            out[i] = np.nan
            continue
        try:
            out[i] = float(text)
        except ValueError:
            what = "empty" if text == "" else f"not a number: {text!r}"
            raise ValueError(f"{table.where}:{table.lines[i]}: {name} is {what}") from None
        if not np.isfinite(out[i]):
            raise ValueError(f"{table.where}:{table.lines[i]}: {name} is {text} (NaN and inf are refused)")
    return out


def _integers(table: _Table, column: int, name: str) -> np.ndarray:
    """A column of whole numbers (timestamps) as int64, read exactly; ValueError naming the line otherwise."""
    out = np.empty(len(table.rows), dtype=np.int64)
    for i, row in enumerate(table.rows):
        text = row[column]
        try:
            out[i] = int(text)
        except ValueError:
            what = "empty" if text == "" else f"not a whole number: {text!r}"
            raise ValueError(f"{table.where}:{table.lines[i]}: {name} is {what}") from None
    return out


def _ordered(t_ns: np.ndarray, line: np.ndarray, where: str, what: str, notes: list[str]) -> np.ndarray:
    """Indices of the samples to keep: a repeated time is dropped (noted), a time going back is a ValueError.

    ``where`` is the file, ``what`` the samples (e.g. ``Gyro rows``), for the messages.
    """
    step = np.diff(t_ns)
    back = np.flatnonzero(step < 0)
    if back.size:
        i = back[0]
        raise ValueError(f"{where}:{line[i + 1]}: {what}: time goes back ({t_ns[i + 1]} ns after {t_ns[i]} ns on "
                         f"line {line[i]}); samples must be in time order")
    repeated = np.flatnonzero(step == 0) + 1
    if repeated.size:
        notes.append(f"{where}: {what}: {repeated.size} sample(s) with a repeated timestamp dropped (first on line "
                     f"{line[repeated[0]]})")
    return np.delete(np.arange(len(t_ns)), repeated)


def _series(sensor: str, where: str, what: str, t_ns: np.ndarray, values: np.ndarray, line: np.ndarray,
            notes: list[str]) -> SensorSeries:
    """A sensor's samples in time order (repeated times dropped); ``what`` names them in ``where``."""
    keep = _ordered(t_ns, line, where, what, notes)
    source = f"{where} ({what})" if what != sensor else where
    return SensorSeries(sensor=sensor, source=source, t_ns=t_ns[keep], values=values[keep], line=line[keep])


def _check_lat_lon(table: _Table, lat: np.ndarray, lon: np.ndarray) -> None:
    for name, values, limit in (("latitude", lat, 90.0), ("longitude", lon, 180.0)):
        bad = np.flatnonzero(np.abs(values) > limit)
        if bad.size:
            raise ValueError(f"{table.where}:{table.lines[bad[0]]}: {name} {values[bad[0]]} deg is out of range "
                             f"(-{limit:g}..{limit:g})")


# --- GnssLogger -----------------------------------------------------------------------------------------

def looks_like_gnsslogger(text: str) -> bool:
    """The first non-blank line is a comment or a GnssLogger row."""
    for line in io.StringIO(text):
        if line.strip():
            return line.startswith("#") or line.split(",", 1)[0].strip() in GNSSLOGGER_ROW_TYPES
    return False


def _gnsslogger_header(line: str) -> tuple[str, tuple[str, ...]] | None:
    """``# Type,Name,...`` -> (type, names); None for any other comment line (version, blank)."""
    fields = [f.strip() for f in line.lstrip("#").split(",")]
    if len(fields) < 2 or not _ROW_TYPE.fullmatch(fields[0]):
        return None
    return fields[0], tuple(fields[1:])


def gnsslogger_tables(path: str | Path, text: str, wanted: Sequence[str]) -> dict[str, _Table]:
    """The rows of each ``wanted`` row type of a GnssLogger log, split by its header line.

    Raises
    ------
    ValueError
        A wanted row before its header, two different headers for one row type, or a row whose
        field count differs from its header's (a short last row: a truncated file); file and line named.
    """
    tables: dict[str, _Table] = {}
    lines = text.splitlines()
    complete = text.endswith(("\n", "\r"))
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        if line.startswith("#"):
            header = _gnsslogger_header(line)
            if header is None or header[0] not in wanted:
                continue
            row_type, names = header
            if row_type in tables and tables[row_type].header != names:
                raise ValueError(f"{path}:{number}: a second, different header for {row_type} rows (the first is "
                                 f"on line {tables[row_type].header_line})")
            tables.setdefault(row_type, _Table(str(path), names, number))
            continue
        row_type, _, rest = line.partition(",")
        row_type = row_type.strip()
        if row_type not in wanted:
            continue
        table = tables.get(row_type)
        if table is None:
            raise ValueError(f"{path}:{number}: a {row_type} row before any '# {row_type},...' header line")
        fields = [f.strip() for f in rest.split(",")]
        _check_length(table, fields, number, number == len(lines) and not complete, f"{row_type} ", leading=1)
        table.rows.append(fields)
        table.lines.append(number)
    return tables


def _gnsslogger_sensor(tables: dict[str, _Table], sensor: str,
                       notes: list[str]) -> tuple[SensorSeries, _Table] | None:
    """A sensor's samples (and their rows) from its calibrated rows, else from its uncalibrated rows less
    their bias; None if the log has neither."""
    for row_type, value_names, bias_names in GNSSLOGGER_SENSORS[sensor]:
        table = tables.get(row_type)
        if table is None or not table.rows:
            continue
        t_ns = _integers(table, table.need(("elapsedRealtimeNanos",)), "elapsedRealtimeNanos")
        values = np.column_stack([_values(table, table.need((name,)), name) for name in value_names])
        if bias_names is not None and all(table.index((name,)) is not None for name in bias_names):
            bias = np.column_stack([_values(table, table.need((name,)), name, empty_ok=True) for name in bias_names])
            values = values - np.nan_to_num(bias)
        series = _series(sensor, table.where, f"{row_type} rows", t_ns, values, np.asarray(table.lines), notes)
        return series, table
    return None


def _gnsslogger_utc_offset(table: _Table) -> int:
    """UTC minus elapsed realtime, ns: the median over a sensor's rows of ``utcTimeMillis`` less the row's time."""
    utc_ms = _integers(table, table.need(("utcTimeMillis",)), "utcTimeMillis")
    elapsed = _integers(table, table.need(("elapsedRealtimeNanos",)), "elapsedRealtimeNanos")
    return int(np.median(utc_ms * 1_000_000 - elapsed))


def _status_cn0(tables: dict[str, _Table]) -> dict[int, float]:
    """Mean C/N0 of the satellites used in each fix, by the fix's UTC time (ms), from the Status rows."""
    table = tables.get("Status")
    if table is None or not table.rows:
        return {}
    columns = [table.index((name,)) for name in ("UnixTimeMillis", "Cn0DbHz", "UsedInFix")]
    if None in columns:
        return {}
    sums: dict[int, list[float]] = {}
    for row, number in zip(table.rows, table.lines):
        time_text, cn0_text, used_text = (row[c] for c in columns)
        if not time_text or not cn0_text or used_text != "1":
            continue
        try:
            sums.setdefault(int(time_text), []).append(float(cn0_text))
        except ValueError:
            raise ValueError(f"{table.where}:{number}: Status row with a malformed UnixTimeMillis or Cn0DbHz") from None
    return {t: float(np.mean(v)) for t, v in sums.items()}


def _provider_rows(table: _Table, notes: list[str]) -> tuple[_Table, str]:
    """The Fix rows of the preferred provider present (GNSS, then fused, then network); the others noted."""
    providers = [row[table.need(FIX_COLUMNS["provider"])].lower() for row in table.rows]
    present = sorted(set(providers))
    chosen = next((p for p in PROVIDERS if p in present), present[0])
    if len(present) > 1:
        notes.append(f"{table.where}: fixes of provider {chosen.upper()} used; those of "
                     f"{', '.join(p.upper() for p in present if p != chosen)} left out")
    keep = [i for i, p in enumerate(providers) if p == chosen]
    subset = _Table(table.where, table.header, table.header_line, [table.rows[i] for i in keep],
                    [table.lines[i] for i in keep])
    return subset, chosen


def _gnsslogger_fixes(tables: dict[str, _Table], utc_offset_ns: int, path: str | Path,
                      notes: list[str]) -> FixSeries:
    table = tables.get("Fix")
    if table is None or not table.rows:
        raise ValueError(f"{path}: no Fix rows (location fixes); log with the location provider on")
    table, provider = _provider_rows(table, notes)
    lat = _values(table, table.need(FIX_COLUMNS["lat"]), "latitude")
    lon = _values(table, table.need(FIX_COLUMNS["lon"]), "longitude")
    _check_lat_lon(table, lat, lon)
    height_column = table.index(FIX_COLUMNS["height"])
    height = (_values(table, height_column, "altitude", empty_ok=True) if height_column is not None
              else np.full(len(lat), np.nan))
    accuracy_column = table.index(FIX_COLUMNS["accuracy"])
    accuracy = (_values(table, accuracy_column, "accuracy", empty_ok=True) if accuracy_column is not None
                else np.full(len(lat), np.nan))
    t_ns = _fix_times(table, utc_offset_ns)
    unix_column = table.index(FIX_COLUMNS["unix_ms"])
    cn0_by_time = _status_cn0(tables)
    cn0 = np.array([cn0_by_time.get(int(row[unix_column]), np.nan) if unix_column is not None
                    and row[unix_column].isdigit() else np.nan for row in table.rows])
    line = np.asarray(table.lines)
    source = f"{path} (Fix rows, provider {provider.upper()})"
    keep = _ordered(t_ns, line, str(path), f"Fix rows of provider {provider.upper()}", notes)
    return FixSeries(source=source, t_ns=t_ns[keep], lat_deg=lat[keep], lon_deg=lon[keep], height_m=height[keep],
                     accuracy_m=accuracy[keep], cn0_dbhz=cn0[keep], line=line[keep])


def _fix_times(table: _Table, utc_offset_ns: int) -> np.ndarray:
    """Each fix's time on the sensors' clock: its elapsed-realtime stamp, else its UTC time less the offset."""
    elapsed_column = table.index(FIX_COLUMNS["elapsed_ns"])
    unix_column = table.index(FIX_COLUMNS["unix_ms"])
    out = np.empty(len(table.rows), dtype=np.int64)
    for i, row in enumerate(table.rows):
        try:
            if elapsed_column is not None and row[elapsed_column]:
                out[i] = int(row[elapsed_column])
            elif unix_column is not None and row[unix_column]:
                out[i] = int(row[unix_column]) * 1_000_000 - utc_offset_ns
            else:
                raise ValueError("no time")
        except ValueError:
            raise ValueError(f"{table.where}:{table.lines[i]}: Fix row without a readable time "
                             f"({FIX_COLUMNS['elapsed_ns'][0]} or {FIX_COLUMNS['unix_ms'][0]})") from None
    return out


def read_gnsslogger(path: str | Path, text: str | None = None) -> PhoneLog:
    """Read a GnssLogger log (``gnss_log_*.txt``; ``text``: its content when already read).

    Times are the rows' ``elapsedRealtimeNanos`` (the phone's monotonic clock, which the sensor rows and
    the fixes share); the UTC offset is the sensor rows' ``utcTimeMillis`` less that. Fixes are those of
    one provider (:data:`PROVIDERS`), their C/N0 the mean over the Status rows of the satellites used.

    Raises
    ------
    ValueError
        Empty or binary file, malformed rows, no accelerometer, gyroscope or Fix rows, NaN values,
        latitude or longitude out of range, time going back (file and line named).
    """
    text = read_text(path) if text is None else text
    wanted = [row_type for choices in GNSSLOGGER_SENSORS.values() for row_type, _, _ in choices] + ["Fix", "Status"]
    tables = gnsslogger_tables(path, text, wanted)
    notes: list[str] = []
    found = {sensor: _gnsslogger_sensor(tables, sensor, notes) for sensor in SENSORS}
    for sensor, rows in (("accelerometer", "Accel or UncalAccel"), ("gyroscope", "Gyro or UncalGyro")):
        if found[sensor] is None:
            raise ValueError(f"{path}: no {sensor} rows ({rows}); log with the motion sensors on")
    acc, acc_rows = found["accelerometer"]
    utc_offset_ns = _gnsslogger_utc_offset(acc_rows)
    fixes = _gnsslogger_fixes(tables, utc_offset_ns, path, notes)
    mag = found["magnetometer"][0] if found["magnetometer"] is not None else None
    return PhoneLog(format=GNSSLOGGER, sources=(str(path),), accelerometer=acc, gyroscope=found["gyroscope"][0],
                    magnetometer=mag, fixes=fixes, utc_offset_ns=utc_offset_ns, notes=tuple(notes))


# --- Sensor Logger ----------------------------------------------------------------------------------------

def looks_like_sensor_logger_csv(text: str) -> bool:
    """The first line is a Sensor Logger header (it names ``time`` and ``seconds_elapsed``)."""
    names = [name.strip() for name in io.StringIO(text).readline().split(",")]
    return "time" in names and "seconds_elapsed" in names


@dataclass(frozen=True)
class _Export:
    """The CSV files of a Sensor Logger export, read only when asked for (an export holds many files).

    ``paths`` maps each file's name in lower case (the app's capitals vary between versions) to its path.
    """

    where: str
    paths: dict[str, str]
    archive: str | None = None

    def __contains__(self, name: str) -> bool:
        return name.lower() in self.paths

    def text(self, name: str) -> tuple[str, str]:
        """(the file's path for messages, its text)."""
        path = self.paths[name.lower()]
        if self.archive is None:
            return path, read_text(path)
        with zipfile.ZipFile(self.archive) as archive:
            return f"{self.archive}:{path}", read_text(f"{self.archive}:{path}", archive.read(path))

    def sources(self) -> tuple[str, ...]:
        return tuple(path if self.archive is None else f"{self.archive}:{path}" for path in self.paths.values())


def sensor_logger_export(paths: Sequence[str | Path]) -> _Export:
    """The CSV files of a Sensor Logger export: a folder, a zip archive, or the CSV files themselves,
    by their names as the app writes them (``Accelerometer.csv``, ...)."""
    if len(paths) == 1 and Path(paths[0]).is_dir():
        folder = Path(paths[0])
        return _Export(str(folder), {p.name.lower(): str(p) for p in sorted(folder.iterdir())
                                     if p.suffix.lower() == ".csv" and p.is_file()})
    if len(paths) == 1 and zipfile.is_zipfile(paths[0]):
        with zipfile.ZipFile(paths[0]) as archive:
            members = [m for m in sorted(archive.namelist()) if m.lower().endswith(".csv")]
        return _Export(str(paths[0]), {Path(m).name.lower(): m for m in members}, archive=str(paths[0]))
    for path in paths:
        if not Path(path).is_file():
            raise ValueError(f"{path}: {'not a file' if Path(path).exists() else 'no such file'}")
    return _Export(", ".join(str(p) for p in paths), {Path(p).name.lower(): str(p) for p in paths})


def csv_table(where: str, text: str) -> _Table:
    """A CSV file's rows split by its header (first line); ValueError for a row of another length."""
    lines = text.splitlines()
    complete = text.endswith(("\n", "\r"))
    table = _Table(where, tuple(name.strip() for name in lines[0].split(",")), 1)
    for number, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]
        _check_length(table, fields, number, number == len(lines) and not complete, "")
        table.rows.append(fields)
        table.lines.append(number)
    return table


def _sensor_logger_axes(sensor: str, where: str, text: str, notes: list[str]) -> SensorSeries:
    """A Sensor Logger axis file (``time`` ns since the Unix epoch, ``x``, ``y``, ``z``) as a series."""
    table = csv_table(where, text)
    if not table.rows:
        raise ValueError(f"{where}: no samples")
    t_ns = _integers(table, table.need(("time",)), "time")
    values = np.column_stack([_values(table, table.need((axis,)), axis) for axis in "xyz"])
    return _series(sensor, where, sensor, t_ns, values, np.asarray(table.lines), notes)


def _ios_frames(files: _Export) -> bool:
    """True when ``Metadata.csv`` says iOS without "Standardise Units & Frames": acceleration and gravity
    then carry the opposite sign to Android's."""
    if METADATA not in files:
        return False
    table = csv_table(*files.text(METADATA))
    platform, standard = table.index(("platform",)), table.index(("standardisation", "standardization"))
    if not table.rows or platform is None:
        return False
    row = table.rows[0]
    return row[platform].lower() == "ios" and (standard is None or row[standard].lower() not in ("true", "1"))


def _sensor_logger_accelerometer(files: _Export, notes: list[str]) -> SensorSeries:
    """The specific force: ``TotalAcceleration.csv`` (Android, gravity included) when there is one, else
    ``Accelerometer.csv`` plus ``Gravity.csv`` (the app's Accelerometer is the acceleration without gravity)."""
    if TOTAL_ACCELERATION in files:
        return _sensor_logger_axes("accelerometer", *files.text(TOTAL_ACCELERATION), notes)
    if ACCELEROMETER not in files:
        raise ValueError(f"{files.where}: no {ACCELEROMETER} (nor {TOTAL_ACCELERATION}); export the accelerometer")
    acc = _sensor_logger_axes("accelerometer", *files.text(ACCELEROMETER), notes)
    values, source = acc.values, acc.source
    if GRAVITY in files:
        gravity = _sensor_logger_axes("gravity", *files.text(GRAVITY), notes)
        t_s, g_t_s = (acc.t_ns - acc.t_ns[0]) / 1e9, (gravity.t_ns - acc.t_ns[0]) / 1e9
        values = values + np.column_stack([np.interp(t_s, g_t_s, gravity.values[:, k]) for k in range(3)])
        source = f"{acc.source} + {gravity.source}"
    else:
        mean_norm = float(np.linalg.norm(values, axis=1).mean())
        if mean_norm < 0.5 * GRAVITY_MPS2:
            raise ValueError(f"{acc.source}: acceleration without gravity (mean magnitude {mean_norm:.2f} m/s^2); the "
                             f"PDR needs the specific force: export {TOTAL_ACCELERATION} or {GRAVITY} too")
    if _ios_frames(files):
        values = -values
        notes.append(f"{files.where}: iOS acceleration frame (Metadata.csv): its sign reversed to Android's")
    return SensorSeries("accelerometer", source, acc.t_ns, values, acc.line)


def _sensor_logger_fixes(files: _Export, notes: list[str]) -> FixSeries:
    """``Location.csv``: latitude, longitude, ellipsoidal height, horizontal accuracy (negative: not given)."""
    if LOCATION not in files:
        raise ValueError(f"{files.where}: no {LOCATION} (location fixes); export the location too")
    name, text = files.text(LOCATION)
    table = csv_table(name, text)
    if not table.rows:
        raise ValueError(f"{name}: no fixes")
    t_ns = _integers(table, table.need(("time",)), "time")
    lat = _values(table, table.need(("latitude",)), "latitude")
    lon = _values(table, table.need(("longitude",)), "longitude")
    _check_lat_lon(table, lat, lon)
    height_column, accuracy_column = table.index(("altitude",)), table.index(("horizontalAccuracy",))
    height = (_values(table, height_column, "altitude", empty_ok=True) if height_column is not None
              else np.full(len(lat), np.nan))
    accuracy = (_values(table, accuracy_column, "horizontalAccuracy", empty_ok=True)
                if accuracy_column is not None else np.full(len(lat), np.nan))
    accuracy[accuracy < 0] = np.nan
    line = np.asarray(table.lines)
    keep = _ordered(t_ns, line, name, "fixes", notes)
    return FixSeries(source=name, t_ns=t_ns[keep], lat_deg=lat[keep], lon_deg=lon[keep], height_m=height[keep],
                     accuracy_m=accuracy[keep], cn0_dbhz=np.full(keep.size, np.nan), line=line[keep])


def read_sensor_logger(paths: Sequence[str | Path]) -> PhoneLog:
    """Read a Sensor Logger CSV export (a folder, its zip archive, or the CSV files).

    Times are the files' ``time`` column, ns since the Unix epoch (UTC), so the UTC offset is 0.

    Raises
    ------
    ValueError
        No accelerometer, gyroscope or location file, malformed rows, NaN values, latitude or
        longitude out of range, time going back (file and line named).
    """
    files = sensor_logger_export(paths)
    notes: list[str] = []
    acc = _sensor_logger_accelerometer(files, notes)
    gyro_file, mag_file = SENSOR_LOGGER_FILES["gyroscope"], SENSOR_LOGGER_FILES["magnetometer"]
    if gyro_file not in files:
        raise ValueError(f"{files.where}: no {gyro_file}; export the gyroscope")
    gyro = _sensor_logger_axes("gyroscope", *files.text(gyro_file), notes)
    mag = _sensor_logger_axes("magnetometer", *files.text(mag_file), notes) if mag_file in files else None
    fixes = _sensor_logger_fixes(files, notes)
    return PhoneLog(format=SENSOR_LOGGER, sources=files.sources(), accelerometer=acc, gyroscope=gyro,
                    magnetometer=mag, fixes=fixes, utc_offset_ns=0, notes=tuple(notes))


# --- either -----------------------------------------------------------------------------------------------

def read_phone_log(paths: Sequence[str | Path]) -> PhoneLog:
    """Read a phone log of either format, told apart by its content.

    One GnssLogger text log; or a Sensor Logger export as a folder, a zip archive, or its CSV files.

    Raises
    ------
    ValueError
        A missing or empty input, an unknown format, or the reader's errors.
    """
    if not paths:
        raise ValueError("no log given")
    first = Path(paths[0])
    if len(paths) == 1 and (first.is_dir() or (first.is_file() and zipfile.is_zipfile(first))):
        return read_sensor_logger(paths)
    text = read_text(first)
    if looks_like_sensor_logger_csv(text):
        return read_sensor_logger(paths)
    if looks_like_gnsslogger(text):
        if len(paths) > 1:
            raise ValueError(f"{first}: a GnssLogger log holds every sensor: give it alone")
        return read_gnsslogger(first, text)
    head = io.StringIO(text).readline().strip()[:60]
    raise ValueError(f"{first}: unknown format (first line {head!r}): expected a GnssLogger log (lines of "
                     "'# Fix,...' headers and Fix/Accel/Gyro rows) or a Sensor Logger export (a folder or zip of "
                     "Accelerometer.csv, Gyroscope.csv, ... with a 'time,seconds_elapsed,...' header)")
