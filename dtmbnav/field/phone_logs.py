"""Read a phone's own sensor log: Google's GnssLogger text log, or the Sensor Logger app's CSV export.

Both readers return a :class:`PhoneLog`: each motion sensor's samples as logged (times on the log's
own clock in integer nanoseconds, values in the project's units and the phone's own axes) and the
location fixes (WGS84 latitude and longitude, ellipsoidal height). Resampling, the local ENU frame,
the start fix and the file are :mod:`dtmbnav.field.sensors_import`'s.

The formats (row types, headers, columns, units, time bases) are :mod:`dtmbnav_core.phone_formats`'s,
which the simulator's writer shares. Why a reader of our own: ``gnss_lib_py`` parses GnssLogger
logs, but installs pandas, plotly, georinex and more for what is here plain CSV reading. Both formats
are read by the column names of their headers (GnssLogger's ``# Fix,...`` comment lines, Sensor
Logger's first row), never by position, because versions of the apps add, drop and reorder columns.

Parsing (:mod:`dtmbnav_core.text_tables`): a row's fields are those the csv module reads (a quoted
field may hold a comma, as a Sensor Logger device name does); the numbers of the long tables are read
by numpy's C parser, the others cell by cell, with the same values and errors.

Axes and units (:mod:`dtmbnav_core.phone_formats`): Android's device frame is the project's phone
frame (``docs/conventions.md``), so the axes are kept as logged, in the units of ``/imu``. The
Sensor Logger app on iOS, unless its "Standardise Units & Frames" setting is on, logs acceleration
and gravity with the opposite sign; that is undone here.

Timestamps. A sensor's samples must not go back in time: a backwards step is an error naming the
line; a repeated timestamp is dropped (the first sample kept) and reported in :attr:`PhoneLog.notes`.
"""

from __future__ import annotations

import csv
import io
import re
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import repeat
from pathlib import Path
from typing import NoReturn

import numpy as np

from dtmbnav.field import platform
from dtmbnav.field.fix_notes import missing_cn0
from dtmbnav_core import phone_formats as fmt
from dtmbnav_core.constants import GRAVITY_MPS2
from dtmbnav_core.text_tables import (
    Table,
    check_lengths,
    csv_table,
    float_column,
    integer_column,
    parse_numbers,
    read_text,
)

GNSSLOGGER = "GnssLogger"
SENSOR_LOGGER = "Sensor Logger"
NO_FIXES = ("the sensors file gets no fixes, and fuse will need --start X,Y (and --tower X,Y, or 'sensors "
            "--origin LAT,LON' for a tower by latitude and longitude)")  # a log without fixes, for its note
_ROW_TYPE = re.compile(r"[A-Za-z][A-Za-z0-9]*")


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
    fixes : FixSeries or None
        None when the log holds no fix (a GnssLogger log without ``Fix`` rows, an empty ``Location.csv``).
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
    fixes: FixSeries | None
    utc_offset_ns: int
    notes: tuple[str, ...] = ()


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


def _check_lat_lon(table: Table, lat: np.ndarray, lon: np.ndarray) -> None:
    for name, values, limit in (("latitude", lat, 90.0), ("longitude", lon, 180.0)):
        bad = np.flatnonzero(np.abs(values) > limit)
        if bad.size:
            raise ValueError(f"{table.where}:{table.lines[bad[0]]}: {name} {values[bad[0]]} deg is out of range "
                             f"(-{limit:g}..{limit:g})")


# --- GnssLogger -----------------------------------------------------------------------------------------

def looks_like_gnsslogger(text: str) -> bool:
    """The first non-blank line is a comment or a GnssLogger row."""
    first = re.search(r"^.*\S.*$", text, re.MULTILINE)  # found without splitting (or copying) a long log's text
    return first is not None and (first[0].startswith("#") or
                                  first[0].split(",", 1)[0].strip() in fmt.GNSSLOGGER_ROW_TYPES)


def _gnsslogger_header(line: str) -> tuple[str, tuple[str, ...]] | None:
    """``# Type,Name,...`` -> (type, names); None for any other comment line (version, blank).

    Split at every comma, not by the csv module: a comment line is free text, which a stray quote would
    break, and the app quotes no header."""
    fields = [f.strip() for f in line.lstrip("#").split(",")]
    if len(fields) < 2 or not _ROW_TYPE.fullmatch(fields[0]):
        return None
    return fields[0], tuple(fields[1:])


def gnsslogger_tables(path: str | Path, text: str, wanted: Sequence[str]) -> dict[str, Table]:
    """The rows of each ``wanted`` row type of a GnssLogger log, split by its header line.

    Raises
    ------
    ValueError
        A wanted row before its header, two different headers for one row type, or a row whose
        field count differs from its header's (a short last row: a truncated file); the first in
        the file is named, with its line.
    """
    tables: dict[str, Table] = {}
    wanted = set(wanted)
    lines = text.splitlines()
    complete = text.endswith(("\n", "\r"))

    def fail(message: str) -> NoReturn:
        """Raise ``message``, unless a row before its line has a wrong field count: that error comes first."""
        check_lengths(((t, f"{row_type} ") for row_type, t in tables.items()), len(lines), complete, leading=1)
        raise ValueError(message)

    # One pass over the lines, each split once at its first comma (map: no Python call per line).
    for number, (row_type, _, rest) in enumerate(map(str.partition, lines, repeat(",")), 1):
        table = tables.get(row_type)
        comment = row_type.startswith("#")
        if table is None and not comment:  # a row of a type not wanted, or the type padded
            row_type = row_type.strip()
            table = tables.get(row_type)
            if table is None and row_type in wanted:
                fail(f"{path}:{number}: a {row_type} row before any '# {row_type},...' header line")
        if table is not None:
            table.texts.append(rest)
            table.lines.append(number)
            continue
        header = _gnsslogger_header(lines[number - 1]) if comment else None
        if header is None or header[0] not in wanted:
            continue
        row_type, names = header
        if row_type in tables and tables[row_type].header != names:
            fail(f"{path}:{number}: a second, different header for {row_type} rows (the first is on line "
                 f"{tables[row_type].header_line})")
        tables.setdefault(row_type, Table(str(path), names, number))
    check_lengths(((t, f"{row_type} ") for row_type, t in tables.items()), len(lines), complete, leading=1)
    return tables


def _gnsslogger_sensor(tables: dict[str, Table], sensor: str,
                       notes: list[str]) -> tuple[SensorSeries, Table] | None:
    """A sensor's samples (and their rows) from its calibrated rows, else from its uncalibrated rows less
    their bias; None if the log has neither."""
    for rows in fmt.GNSSLOGGER_SENSOR_ROWS[sensor]:
        table = tables.get(rows.row_type)
        if table is None or not table.texts:
            continue
        bias = rows.bias if rows.bias and all(table.index((name,)) is not None for name in rows.bias) else ()
        # The accelerometer's utcTimeMillis too: its rows give the log's UTC offset (_gnsslogger_utc_offset).
        times = (fmt.UTC_MILLIS, fmt.ELAPSED_NANOS) if sensor == "accelerometer" else (fmt.ELAPSED_NANOS,)
        parse_numbers(table, times, rows.values + bias)
        t_ns = integer_column(table, table.need((fmt.ELAPSED_NANOS,)), fmt.ELAPSED_NANOS)
        values = np.column_stack([float_column(table, table.need((name,)), name) for name in rows.values])
        if bias:
            values = values - np.nan_to_num(np.column_stack([
                float_column(table, table.need((name,)), name, empty_ok=True) for name in bias]))
        series = _series(sensor, table.where, f"{rows.row_type} rows", t_ns, values, np.asarray(table.lines), notes)
        return series, table
    return None


def _gnsslogger_utc_offset(table: Table) -> int:
    """UTC minus elapsed realtime, ns: the median over a sensor's rows of ``utcTimeMillis`` less the row's time.

    Without that column the two clocks cannot be tied: the log's UTC start, and fixes without their own
    ``elapsedRealtimeNanos`` (older GnssLogger versions), would have no place on the sensor clock."""
    if table.index((fmt.UTC_MILLIS,)) is None:
        raise ValueError(f"{table.where}: the header (line {table.header_line}) has no {fmt.UTC_MILLIS}: the UTC "
                         "clock cannot be tied to the sensors' clock; log with a GnssLogger version that writes it")
    utc_ms, elapsed = (integer_column(table, table.need((name,)), name) for name in (fmt.UTC_MILLIS, fmt.ELAPSED_NANOS))
    return int(np.median(utc_ms * 1_000_000 - elapsed))


def _status_cn0(tables: dict[str, Table]) -> tuple[np.ndarray, np.ndarray]:
    """Each Status report's UTC time (ms, increasing) and the mean C/N0 of the satellites it says the fix used,
    dB-Hz; empty arrays without Status rows."""
    table = tables.get("Status")
    none = np.zeros(0, dtype=np.int64), np.zeros(0)
    if table is None or not table.texts:
        return none
    columns = [table.index((name,)) for name in fmt.STATUS_COLUMNS]
    if None in columns:
        return none
    sums: dict[int, list[float]] = {}
    for time_text, cn0_text, used_text, number in zip(*(table.cells(c) for c in columns), table.lines):
        if not time_text or not cn0_text or used_text != "1":
            continue
        try:
            sums.setdefault(int(time_text), []).append(float(cn0_text))
        except ValueError:
            raise ValueError(f"{table.where}:{number}: Status row with a malformed UnixTimeMillis or Cn0DbHz") from None
    times = sorted(sums)
    return np.array(times, dtype=np.int64), np.array([float(np.mean(sums[t])) for t in times])


def _nearest_cn0(fix_ms: np.ndarray, status_ms: np.ndarray, status_cn0: np.ndarray) -> np.ndarray:
    """C/N0 of the Status report nearest each fix's UTC time (ms; NaN: none) within :data:`fmt.CN0_JOIN_WINDOW_MS`,
    else NaN: real logs seldom stamp a fix and its report with the same millisecond."""
    if not status_ms.size:
        return np.full(len(fix_ms), np.nan)
    right = np.clip(np.searchsorted(status_ms, fix_ms), 0, len(status_ms) - 1)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(status_ms[left] - fix_ms) <= np.abs(status_ms[right] - fix_ms), left, right)
    close = np.abs(status_ms[nearest] - fix_ms) <= fmt.CN0_JOIN_WINDOW_MS  # False where the fix has no time (NaN)
    return np.where(close, status_cn0[nearest], np.nan)


def _provider_rows(table: Table, notes: list[str]) -> tuple[Table, str]:
    """The Fix rows of the preferred provider present (GNSS, then fused, then network); the others noted."""
    providers = [provider.lower() for provider in table.cells(table.need(fmt.FIX_COLUMNS["provider"]))]
    present = sorted(set(providers))
    chosen = next((p for p in fmt.PROVIDERS if p in present), present[0])
    if len(present) > 1:
        notes.append(f"{table.where}: fixes of provider {chosen.upper()} used; those of "
                     f"{', '.join(p.upper() for p in present if p != chosen)} left out")
    return table.subset([i for i, p in enumerate(providers) if p == chosen]), chosen


def _gnsslogger_fixes(tables: dict[str, Table], utc_offset_ns: int, path: str | Path,
                      notes: list[str]) -> FixSeries | None:
    """The fixes of one provider with their C/N0 (:func:`_nearest_cn0`); None (noted) when the log has none."""
    table = tables.get("Fix")
    if table is None or not table.texts:
        notes.append(f"{path}: no Fix rows (location fixes): {NO_FIXES}")
        return None
    table, provider = _provider_rows(table, notes)
    lat = float_column(table, table.need(fmt.FIX_COLUMNS["lat"]), "latitude")
    lon = float_column(table, table.need(fmt.FIX_COLUMNS["lon"]), "longitude")
    _check_lat_lon(table, lat, lon)
    height_column = table.index(fmt.FIX_COLUMNS["height"])
    height = (float_column(table, height_column, "altitude", empty_ok=True) if height_column is not None
              else np.full(len(lat), np.nan))
    accuracy_column = table.index(fmt.FIX_COLUMNS["accuracy"])
    accuracy = (float_column(table, accuracy_column, "accuracy", empty_ok=True) if accuracy_column is not None
                else np.full(len(lat), np.nan))
    t_ns = _fix_times(table, utc_offset_ns)
    unix_ms = np.array([float(text) if text.isdigit() else np.nan
                        for text in _optional_cells(table, fmt.FIX_COLUMNS["unix_ms"])])
    cn0 = _nearest_cn0(unix_ms, *_status_cn0(tables))
    line = np.asarray(table.lines)
    source = f"{path} (Fix rows, provider {provider.upper()})"
    keep = _ordered(t_ns, line, str(path), f"Fix rows of provider {provider.upper()}", notes)
    notes += missing_cn0(str(path), cn0[keep], f" (no Status report within {fmt.CN0_JOIN_WINDOW_MS} ms)")
    return FixSeries(source=source, t_ns=t_ns[keep], lat_deg=lat[keep], lon_deg=lon[keep], height_m=height[keep],
                     accuracy_m=accuracy[keep], cn0_dbhz=cn0[keep], line=line[keep])


def _optional_cells(table: Table, names: Sequence[str]) -> list[str]:
    """The stripped fields of the first column of ``names`` the header has; empty ones if it has none."""
    column = table.index(names)
    return table.cells(column) if column is not None else [""] * len(table.lines)


def _fix_times(table: Table, utc_offset_ns: int) -> np.ndarray:
    """Each fix's time on the sensors' clock: its elapsed-realtime stamp, else its UTC time less the offset."""
    out = []
    for elapsed, unix_ms, number in zip(_optional_cells(table, fmt.FIX_COLUMNS["elapsed_ns"]),
                                        _optional_cells(table, fmt.FIX_COLUMNS["unix_ms"]), table.lines):
        try:
            if elapsed:
                out.append(int(elapsed))
            elif unix_ms:
                out.append(int(unix_ms) * 1_000_000 - utc_offset_ns)
            else:
                raise ValueError("no time")
        except ValueError:
            raise ValueError(f"{table.where}:{number}: Fix row without a readable time "
                             f"({fmt.FIX_COLUMNS['elapsed_ns'][0]} or {fmt.FIX_COLUMNS['unix_ms'][0]})") from None
    return np.array(out, dtype=np.int64)


def read_gnsslogger(path: str | Path, text: str | None = None) -> PhoneLog:
    """Read a GnssLogger log (``gnss_log_*.txt``; ``text``: its content when already read).

    Times are the rows' ``elapsedRealtimeNanos`` (the phone's monotonic clock, which the sensor rows and
    the fixes share); the UTC offset is the sensor rows' ``utcTimeMillis`` less that. Fixes are those of
    one provider (:data:`fmt.PROVIDERS`), their C/N0 the mean over the Status rows of the satellites used.

    Raises
    ------
    ValueError
        Empty or binary file, malformed rows, no accelerometer, gyroscope or Fix rows, NaN values,
        latitude or longitude out of range, time going back (file and line named).
    """
    text = read_text(path) if text is None else text
    tables = gnsslogger_tables(path, text, [*fmt.GNSSLOGGER_SENSOR_ROW_TYPES, "Fix", "Status"])
    notes: list[str] = []
    found = {sensor: _gnsslogger_sensor(tables, sensor, notes) for sensor in fmt.SENSORS}
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
    end = text.find("\n")  # the first line, cut without splitting (or copying) a long log's text
    first = (text if end < 0 else text[:end]).partition("\r")[0]
    try:
        names = [name.strip() for name in next(csv.reader([first]), [])]
    except csv.Error:  # a NUL character: no CSV header
        return False
    return fmt.SENSOR_LOGGER_TIME in names and fmt.SENSOR_LOGGER_ELAPSED in names


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

    def text(self, name: str, empty_ok: bool = False) -> tuple[str, str]:
        """(the file's path for messages, its text); an empty file is ``""`` where ``empty_ok``, else a ValueError."""
        path = self.paths[name.lower()]
        if self.archive is None:
            where, data = path, Path(path).read_bytes()
        else:
            with zipfile.ZipFile(self.archive) as archive:
                where, data = f"{self.archive}:{path}", archive.read(path)
        return where, ("" if empty_ok and not data.strip() else read_text(where, data))

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


def _sensor_logger_axes(sensor: str, where: str, text: str, notes: list[str]) -> SensorSeries:
    """A Sensor Logger axis file (``time`` ns since the Unix epoch, ``x``, ``y``, ``z``) as a series."""
    table = csv_table(where, text)
    if not table.texts:
        raise ValueError(f"{where}: no samples")
    parse_numbers(table, (fmt.SENSOR_LOGGER_TIME,), fmt.SENSOR_LOGGER_AXES)
    t_ns = integer_column(table, table.need((fmt.SENSOR_LOGGER_TIME,)), fmt.SENSOR_LOGGER_TIME)
    values = np.column_stack([float_column(table, table.need((axis,)), axis) for axis in fmt.SENSOR_LOGGER_AXES])
    return _series(sensor, where, sensor, t_ns, values, np.asarray(table.lines), notes)


def _sign(files: _Export, given: str | None, acc: SensorSeries, mag: SensorSeries | None,
          fixes: FixSeries | None, notes: list[str]) -> str:
    """The platform whose acceleration sign the export carries, in the order :mod:`dtmbnav.field.platform` says."""
    stated = platform.stated_platform(csv_table(*files.text(fmt.METADATA))) if fmt.METADATA in files else None
    sign = platform.check_given(given, stated, files.where)
    if sign is None and fmt.TOTAL_ACCELERATION in files:
        return platform.ANDROID
    if sign is None:
        sign = platform.platform_from_data(acc.values, acc.t_ns, mag and mag.values, mag and mag.t_ns,
                                           fixes and fixes.lat_deg, files.where)
        notes.append(platform.detected_note(files.where, sign))
    return sign


def _sensor_logger_accelerometer(files: _Export, notes: list[str]) -> SensorSeries:
    """The specific force as logged (sign: :func:`_sign`): ``TotalAcceleration.csv`` (Android) when there is one,
    else ``Accelerometer.csv`` plus ``Gravity.csv`` (the app's Accelerometer is the acceleration without gravity)."""
    if fmt.TOTAL_ACCELERATION in files:
        return _sensor_logger_axes("accelerometer", *files.text(fmt.TOTAL_ACCELERATION), notes)
    if fmt.ACCELEROMETER not in files:
        raise ValueError(f"{files.where}: no {fmt.ACCELEROMETER} (nor {fmt.TOTAL_ACCELERATION}); export the "
                         "accelerometer")
    acc = _sensor_logger_axes("accelerometer", *files.text(fmt.ACCELEROMETER), notes)
    values, source = acc.values, acc.source
    if fmt.GRAVITY in files:
        gravity = _sensor_logger_axes("gravity", *files.text(fmt.GRAVITY), notes)
        t_s, g_t_s = (acc.t_ns - acc.t_ns[0]) / 1e9, (gravity.t_ns - acc.t_ns[0]) / 1e9
        values = values + np.column_stack([np.interp(t_s, g_t_s, gravity.values[:, k]) for k in range(3)])
        source = f"{acc.source} + {gravity.source}"
    else:
        mean_norm = float(np.linalg.norm(values, axis=1).mean())
        if mean_norm < 0.5 * GRAVITY_MPS2:
            raise ValueError(f"{acc.source}: acceleration without gravity (mean magnitude {mean_norm:.2f} m/s^2); the "
                             f"PDR needs the specific force: export {fmt.TOTAL_ACCELERATION} or {fmt.GRAVITY} too")
    return SensorSeries("accelerometer", source, acc.t_ns, values, acc.line)


def _sensor_logger_fixes(files: _Export, notes: list[str]) -> FixSeries | None:
    """``Location.csv``: latitude, longitude, ellipsoidal height, horizontal accuracy (negative: not given);
    None (noted) when it holds no fix (empty, or its header alone: the phone got none)."""
    if fmt.LOCATION not in files:
        raise ValueError(f"{files.where}: no {fmt.LOCATION} (location fixes); export the location too")
    name, text = files.text(fmt.LOCATION, empty_ok=True)
    table = csv_table(name, text) if text else None
    if table is None or not table.texts:
        notes.append(f"{name}: no fixes: {NO_FIXES}")
        return None
    t_ns = integer_column(table, table.need((fmt.SENSOR_LOGGER_TIME,)), fmt.SENSOR_LOGGER_TIME)
    lat = float_column(table, table.need((fmt.LOCATION_COLUMNS["lat"],)), "latitude")
    lon = float_column(table, table.need((fmt.LOCATION_COLUMNS["lon"],)), "longitude")
    _check_lat_lon(table, lat, lon)
    height_column, accuracy_column = (table.index((fmt.LOCATION_COLUMNS[key],)) for key in ("height", "accuracy"))
    height = (float_column(table, height_column, "altitude", empty_ok=True) if height_column is not None
              else np.full(len(lat), np.nan))
    accuracy = (float_column(table, accuracy_column, fmt.LOCATION_COLUMNS["accuracy"], empty_ok=True)
                if accuracy_column is not None else np.full(len(lat), np.nan))
    accuracy = np.where(accuracy < 0, np.nan, accuracy)
    line = np.asarray(table.lines)
    keep = _ordered(t_ns, line, name, "fixes", notes)
    cn0 = np.full(keep.size, np.nan)  # the app logs none
    notes += missing_cn0(name, cn0, " (Sensor Logger logs none)")
    return FixSeries(source=name, t_ns=t_ns[keep], lat_deg=lat[keep], lon_deg=lon[keep], height_m=height[keep],
                     accuracy_m=accuracy[keep], cn0_dbhz=cn0, line=line[keep])


def read_sensor_logger(paths: Sequence[str | Path], given_platform: str | None = None) -> PhoneLog:
    """Read a Sensor Logger CSV export (a folder, its zip archive, or the CSV files).

    Times are the files' ``time`` column, ns since the Unix epoch (UTC), so the UTC offset is 0.
    ``given_platform`` (``--platform``): the platform whose acceleration sign the export carries, where
    ``Metadata.csv`` does not say it (:func:`_sign`); iOS's is reversed to Android's.

    Raises
    ------
    ValueError
        No accelerometer, gyroscope or location file, malformed rows, NaN values, latitude or
        longitude out of range, time going back (file and line named); a platform not known.
    """
    files = sensor_logger_export(paths)
    notes: list[str] = []
    acc = _sensor_logger_accelerometer(files, notes)
    if fmt.GYROSCOPE not in files:
        raise ValueError(f"{files.where}: no {fmt.GYROSCOPE}; export the gyroscope")
    gyro = _sensor_logger_axes("gyroscope", *files.text(fmt.GYROSCOPE), notes)
    mag = (_sensor_logger_axes("magnetometer", *files.text(fmt.MAGNETOMETER), notes) if fmt.MAGNETOMETER in files
           else None)
    fixes = _sensor_logger_fixes(files, notes)
    if _sign(files, given_platform, acc, mag, fixes, notes) == platform.IOS:
        acc = replace(acc, values=-acc.values)
        notes.append(f"{files.where}: iOS acceleration frame: its sign reversed to Android's")
    return PhoneLog(format=SENSOR_LOGGER, sources=files.sources(), accelerometer=acc, gyroscope=gyro,
                    magnetometer=mag, fixes=fixes, utc_offset_ns=0, notes=tuple(notes))


# --- either -----------------------------------------------------------------------------------------------

def read_phone_log(paths: Sequence[str | Path], given_platform: str | None = None) -> PhoneLog:
    """Read a phone log of either format, told apart by its content.

    One GnssLogger text log; or a Sensor Logger export as a folder, a zip archive, or its CSV files, whose
    acceleration sign ``given_platform`` may state (:func:`read_sensor_logger`).

    Raises
    ------
    ValueError
        A missing or empty input, an unknown format, or the reader's errors.
    """
    if not paths:
        raise ValueError("no log given")
    first = Path(paths[0])
    if len(paths) == 1 and (first.is_dir() or (first.is_file() and zipfile.is_zipfile(first))):
        return read_sensor_logger(paths, given_platform)
    text = read_text(first)
    if looks_like_sensor_logger_csv(text):
        return read_sensor_logger(paths, given_platform)
    if looks_like_gnsslogger(text):
        if len(paths) > 1:
            raise ValueError(f"{first}: a GnssLogger log holds every sensor: give it alone")
        return read_gnsslogger(first, text)
    head = io.StringIO(text).readline().strip()[:60]
    raise ValueError(f"{first}: unknown format (first line {head!r}): expected a GnssLogger log (lines of "
                     "'# Fix,...' headers and Fix/Accel/Gyro rows) or a Sensor Logger export (a folder or zip of "
                     "Accelerometer.csv, Gyroscope.csv, ... with a 'time,seconds_elapsed,...' header)")
