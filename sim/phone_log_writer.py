"""Write a simulated walk's IMU and GNSS as a phone app writes them: GnssLogger's text log, Sensor Logger's CSV export.

``dtmbnav simulate --phone-log FORMAT`` writes, beside the capture, what the phone carried on the walk
would have logged, so that the field path (``dtmbnav sensors``, ``dtmbnav/field/phone_logs.py``) runs on
simulated walks without reading any simulator file. Formats (:data:`dtmbnav_core.phone.PHONE_LOG_FORMATS`;
their row types, headers, columns, units and time bases: :mod:`dtmbnav_core.phone_formats`):

- ``gnsslogger``: Google's GnssLogger text log ``gnss_log_<yyyy_MM_dd_HH_mm_ss>.txt``: the app's
  ``#`` preamble and the header line of each row type written, then the rows in time order:
  ``UncalAccel``, ``UncalGyro`` and ``UncalMag`` (bias and drift columns 0: the simulated values
  are the phone's calibrated output) at every IMU sample, a ``Fix`` row (provider ``GPS``) and a
  ``Status`` row per fix. The phone's monotonic clock (``elapsedRealtimeNanos``) starts at
  :data:`BOOT_ELAPSED_NS`. The simulator models the fix's mean C/N0 only, so its ``Status`` row is
  one GPS L1 signal of that C/N0, used in the fix.
- ``sensorlogger``: the Sensor Logger app's export, a folder ``<yyyy-MM-dd_HH-mm-ss>`` of CSV files:
  ``TotalAcceleration.csv`` (the specific force), ``Accelerometer.csv`` and ``Gravity.csv`` (the
  specific force split, as Android's linear acceleration and gravity sensors, into its moving average
  over :data:`GRAVITY_WINDOW_S` and the rest), ``Gyroscope.csv``, ``Magnetometer.csv``,
  ``Location.csv`` and ``Metadata.csv`` (platform ``android``, units and frames as Android reports them).

Both: every IMU sample as simulated (the scenario's ``imu.rate_hz``; the default 100 Hz is Sensor
Logger's default rate, GnssLogger logs the sensors at their own rate), every fix of the GNSS log
(``gnss.rate_hz``, 1 Hz by default). A sample with a non-finite value (a gap the IMU model left) is
not written; an IMU without a magnetometer (its ``mag_ut`` None, NaN, or zeros throughout as in
``/imu``) writes no ``UncalMag`` rows and no ``Magnetometer.csv``. Axes: the IMU's phone frame is
Android's device frame (``docs/conventions.md``); units m/s^2, rad/s, uT, as Android's.

Fixes: the simulated fix (east, north) at the phone's height (``channel.antenna_height_m`` above the
walker's plane) about the scenario's ``[origin]``, as WGS84 latitude, longitude (deg) and height above
the ellipsoid (m); the stated accuracy is the fix error's sigma at its C/N0 (:func:`sim.gnss.fix_sigma_m`)
times :data:`dtmbnav_core.phone.ACCURACY_RADIUS_SIGMAS` (Android's 68 % radius). Speed, bearing and
the other accuracies are not simulated: their fields are empty.

Clock: every stamp is the phone's (:class:`dtmbnav_core.phone.PhoneClock`): the log starts at the
scenario's time 0, whose true UTC is the caller's ``start_utc_ns``; a sample at scenario time ``t``
is stamped ``start_utc_ns + offset + t (1 + drift)`` on the UTC clock and
``BOOT_ELAPSED_NS + t (1 + drift)`` on the monotonic one. The samples are those simulated, at
their simulated instants: the phone's clock only stamps them.

The formats' text (:func:`gnsslogger_rows`, :func:`gnsslogger_text`, :func:`sensor_logger_csv` and
the row builders on them) is also what the tests build their sample logs with. Numbers are written
as the shortest text that reads back to the same float.
"""

from __future__ import annotations

import csv
import datetime
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter1d

from dtmbnav_core.geodetic import to_lat_lon_height
from dtmbnav_core.h5io import atomic_folder, atomic_path
from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS, PHONE_LOG_FORMATS, PhoneClock
from dtmbnav_core.phone_formats import (
    ACCELEROMETER,
    ELAPSED_NANOS,
    GNSSLOGGER_HEADERS,
    GNSSLOGGER_SENSOR_ROW_TYPES,
    GRAVITY,
    GYROSCOPE,
    LOCATION,
    LOCATION_COLUMNS,
    MAGNETOMETER,
    METADATA,
    SENSOR_LOGGER_AXES,
    SENSOR_LOGGER_AXIS_HEADER,
    SENSOR_LOGGER_ELAPSED,
    SENSOR_LOGGER_LOCATION_HEADER,
    SENSOR_LOGGER_METADATA_HEADER,
    SENSOR_LOGGER_TIME,
    TOTAL_ACCELERATION,
    UTC_MILLIS,
    SensorRows,
)
from dtmbnav_core.records import GeodeticFixes, GnssLog, ImuLog
from sim.gnss import fix_sigma_m
from sim.scenario import Scenario

#: The phone's monotonic clock (``elapsedRealtimeNanos``) at the log's start: an hour after it booted, ns.
BOOT_ELAPSED_NS = 3_600_000_000_000
#: Window of the moving average that splits Sensor Logger's gravity from the specific force, s.
GRAVITY_WINDOW_S = 1.0
#: Carrier frequency of the GPS L1 signal of a fix's ``Status`` row, Hz.
GPS_L1_HZ = 1575.42e6
#: GnssLogger's preamble, before the header lines of the row types.
GNSSLOGGER_PREAMBLE = ("# ", "# Header Description:", "# ",
                       "# Version: v3.0.6.4 Platform: 14 Manufacturer: dtmbnav Model: simulator", "# ")
#: The GnssLogger row types the simulator writes, in the order of their header lines.
GNSSLOGGER_WRITTEN = ("Fix", "Status", "UncalAccel", "UncalGyro", "UncalMag")
#: The GnssLogger rows of each ImuLog sensor column: the sensor's uncalibrated row type.
GNSSLOGGER_IMU_ROWS = {column: GNSSLOGGER_SENSOR_ROW_TYPES[row_type] for column, row_type in
                       (("acc_mps2", "UncalAccel"), ("gyro_radps", "UncalGyro"), ("mag_ut", "UncalMag"))}
#: Sensor Logger's axis files written straight from an ImuLog column.
SENSOR_LOGGER_IMU_FILES = {TOTAL_ACCELERATION: "acc_mps2", GYROSCOPE: "gyro_radps", MAGNETOMETER: "mag_ut"}

#: A column of a table to write: an array or a list of texts, one per row, or one value for every row.
Cells = np.ndarray | Sequence[str] | str | float | int


def phone_fixes(scenario: Scenario, gnss: GnssLog) -> GeodeticFixes:
    """The simulated fixes on WGS84 about the scenario's origin, at the phone's height (module docstring)."""
    lat, lon, height = to_lat_lon_height(gnss.x_m, gnss.y_m, scenario.channel.antenna_height_m,
                                         scenario.origin.point)
    accuracy = ACCURACY_RADIUS_SIGMAS * fix_sigma_m(scenario.gnss, gnss.cn0_dbhz)
    return GeodeticFixes(t_s=np.asarray(gnss.t_s, dtype=np.float64), lat_deg=lat, lon_deg=lon, height_m=height,
                      accuracy_m=accuracy, cn0_dbhz=np.asarray(gnss.cn0_dbhz, dtype=np.float64))


def imu_samples(imu: ImuLog) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each ImuLog sensor column's samples with finite values, as (times s, N x 3 values); the magnetometer
    left out where the IMU has none (None, no finite sample, or zeros throughout: the ``/imu`` convention).

    Raises
    ------
    ValueError
        The accelerometer or the gyroscope has no finite non-zero sample.
    """
    out = {}
    for column in GNSSLOGGER_IMU_ROWS:
        values = getattr(imu, column)
        values = np.full((len(imu.t_s), 3), np.nan) if values is None else np.asarray(values, dtype=np.float64)
        finite = np.isfinite(values).all(axis=1)
        if np.any(values[finite]):
            out[column] = (np.asarray(imu.t_s, dtype=np.float64)[finite], values[finite])
        elif column != "mag_ut":
            raise ValueError(f"phone log: the IMU's {column} has no finite non-zero sample")
    return out


def _utc_ms(utc_ns: np.ndarray | int) -> np.ndarray | int:
    """UTC stamps in ns to whole ms (rounded half up)."""
    return (utc_ns + 500_000) // 1_000_000


def _start_utc_ns(clock: PhoneClock, start_utc_ns: int) -> int:
    """The phone's UTC at the log's start, ns since the Unix epoch."""
    return int(clock.utc_ns(np.zeros(1), start_utc_ns)[0])


def _date(utc_ns: int) -> datetime.datetime:
    """A UTC time in ns since the Unix epoch as a date and time (whole seconds), for file names."""
    return datetime.datetime.fromtimestamp(utc_ns // 1_000_000_000, tz=datetime.UTC)


# --- the formats' text -----------------------------------------------------------------------------------

def text_cells(values: Cells, n: int) -> list[str]:
    """A column's ``n`` cells as text: whole numbers as written, other numbers as the shortest text that reads
    back to the same float (``repr``), text as it is; a single value is repeated."""
    if isinstance(values, str):
        return [values] * n
    if np.ndim(values) == 0:
        return text_cells([values], 1) * n
    array = np.asarray(values)
    if len(array) != n:
        raise ValueError(f"a column of {len(array)} cells in a table of {n} rows")
    return list(map(repr if array.dtype.kind == "f" else str, array.tolist()))


def table_cells(header: Sequence[str], columns: Mapping[str, Cells]) -> list[list[str]]:
    """The cells of each column of ``header``, from ``columns`` by name (a column not given: empty cells).

    The table has as many rows as the columns given as arrays or lists (one row where every column is a
    single value).

    Raises
    ------
    ValueError
        A column ``header`` does not name, or columns of different lengths.
    """
    unknown = sorted(set(columns) - set(header))
    if unknown:
        raise ValueError(f"columns {unknown} are not in the header {', '.join(header)}")
    n = next((len(v) for v in columns.values() if not isinstance(v, str) and np.ndim(v) == 1), 1)
    return [text_cells(columns.get(name, ""), n) for name in header]


def gnsslogger_rows(row_type: str, columns: Mapping[str, Cells]) -> list[str]:
    """Rows of one GnssLogger row type: the type, then the fields its header
    (:data:`dtmbnav_core.phone_formats.GNSSLOGGER_HEADERS`) names, from ``columns`` by name
    (:func:`table_cells`). The app does not quote a field, nor does this."""
    cells = table_cells(GNSSLOGGER_HEADERS[row_type], columns)
    return list(map(",".join, zip([row_type] * len(cells[0]), *cells)))


def gnsslogger_text(blocks: Sequence[tuple[np.ndarray, list[str]]], row_types: Sequence[str]) -> str:
    """A GnssLogger log: :data:`GNSSLOGGER_PREAMBLE`, the header line of each of ``row_types`` (each followed by
    an empty comment line, as the app writes them), then the rows of ``blocks``, merged in time order.

    ``blocks``: (times, rows) of each block of rows; the times (on one clock for every block) only order
    the rows, rows of equal times following the order of ``blocks``.
    """
    order = np.argsort(np.concatenate([times for times, _ in blocks]), kind="stable")
    rows = [row for _, block in blocks for row in block]
    headers = [line for row_type in row_types
               for line in (f"# {row_type},{','.join(GNSSLOGGER_HEADERS[row_type])}", "# ")]
    return "\n".join([*GNSSLOGGER_PREAMBLE, *headers, *(rows[i] for i in order.tolist())]) + "\n"


def sensor_logger_csv(header: Sequence[str], columns: Mapping[str, Cells]) -> str:
    """A Sensor Logger CSV file: its header row, then the rows of ``columns`` (:func:`table_cells`), written by
    the csv module so that a field holding a comma is quoted, as the app writes it."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(zip(*table_cells(header, columns)))
    return out.getvalue()


def gnsslogger_stamps(t_s: np.ndarray, clock: PhoneClock, start_utc_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """GnssLogger's stamps of moments ``t_s`` s after the log's start: on the phone's UTC clock (ms since the
    Unix epoch, ``utcTimeMillis``) and on its monotonic clock (ns, ``elapsedRealtimeNanos``)."""
    return _utc_ms(clock.utc_ns(t_s, start_utc_ns)), BOOT_ELAPSED_NS + clock.elapsed_ns(t_s)


def sensor_rows(rows: SensorRows, t_s: np.ndarray, values: np.ndarray, clock: PhoneClock, start_utc_ns: int,
                bias: Sequence[float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, list[str]]:
    """A motion sensor's GnssLogger rows of type ``rows`` at ``t_s`` (s after the log's start): their
    ``elapsedRealtimeNanos`` (ns) and texts.

    ``values`` (N x 3) are the row's own (an uncalibrated row's reading includes its bias); ``bias``, an
    uncalibrated row type's bias (or drift) columns, is the same in every row.
    """
    utc_ms, elapsed_ns = gnsslogger_stamps(t_s, clock, start_utc_ns)
    columns: dict[str, Cells] = {UTC_MILLIS: utc_ms, ELAPSED_NANOS: elapsed_ns, **dict(zip(rows.values, values.T))}
    if rows.bias is not None:
        columns.update(zip(rows.bias, bias))
    return elapsed_ns, gnsslogger_rows(rows.row_type, columns)


def fix_rows(fixes: GeodeticFixes, clock: PhoneClock, start_utc_ns: int,
             provider: str = "GPS") -> tuple[np.ndarray, list[str]]:
    """The ``Fix`` rows of ``fixes`` (speed, bearing and the other accuracies empty): their
    ``elapsedRealtimeNanos`` (ns) and texts."""
    utc_ms, elapsed_ns = gnsslogger_stamps(fixes.t_s, clock, start_utc_ns)
    return elapsed_ns, gnsslogger_rows("Fix", {
        "Provider": provider, "LatitudeDegrees": fixes.lat_deg, "LongitudeDegrees": fixes.lon_deg,
        "AltitudeMeters": fixes.height_m, "AccuracyMeters": fixes.accuracy_m, "UnixTimeMillis": utc_ms,
        ELAPSED_NANOS: elapsed_ns, "MockLocation": "0"})


def axis_csv(t_s: np.ndarray, values: np.ndarray, clock: PhoneClock, start_utc_ns: int) -> str:
    """A Sensor Logger axis file of samples ``values`` (N x 3, x, y, z) at ``t_s`` s after the log's start."""
    return sensor_logger_csv(SENSOR_LOGGER_AXIS_HEADER, {
        SENSOR_LOGGER_TIME: clock.utc_ns(t_s, start_utc_ns), SENSOR_LOGGER_ELAPSED: clock.elapsed_s(t_s),
        **dict(zip(SENSOR_LOGGER_AXES, values.T))})


def location_csv(fixes: GeodeticFixes, clock: PhoneClock, start_utc_ns: int) -> str:
    """Sensor Logger's ``Location.csv`` of ``fixes`` (speed, bearing and the other accuracies empty)."""
    return sensor_logger_csv(SENSOR_LOGGER_LOCATION_HEADER, {
        SENSOR_LOGGER_TIME: clock.utc_ns(fixes.t_s, start_utc_ns), SENSOR_LOGGER_ELAPSED: clock.elapsed_s(fixes.t_s),
        LOCATION_COLUMNS["accuracy"]: fixes.accuracy_m, LOCATION_COLUMNS["height"]: fixes.height_m,
        LOCATION_COLUMNS["lon"]: fixes.lon_deg, LOCATION_COLUMNS["lat"]: fixes.lat_deg})


def metadata_csv(start_utc_ns: int, intervals_s: Mapping[str, float], platform: str = "android",
                 device_name: str = "dtmbnav simulator") -> str:
    """Sensor Logger's ``Metadata.csv`` of a recording that starts at ``start_utc_ns`` (the phone's UTC, ns
    since the Unix epoch) and samples each sensor (its file's name without ``.csv``) every ``intervals_s`` s;
    units and frames not standardised."""
    sensors = sorted(intervals_s)
    return sensor_logger_csv(SENSOR_LOGGER_METADATA_HEADER, {
        "version": "3", "device name": device_name, "recording epoch time": str(_utc_ms(start_utc_ns)),
        "recording time": f"{_date(start_utc_ns):%Y-%m-%d_%H-%M-%S}", "recording timezone": "UTC",
        "platform": platform, "appVersion": "1.64", "device id": "simulated", "sensors": "|".join(sensors),
        "sampleRateMs": "|".join(str(round(intervals_s[s] * 1000)) for s in sensors), "standardisation": "false",
        "platform version": "14"})


# --- GnssLogger ------------------------------------------------------------------------------------------

def gnsslogger_log(imu: ImuLog, fixes: GeodeticFixes, clock: PhoneClock, start_utc_ns: int) -> str:
    """The text of a GnssLogger log of the walk (module docstring)."""
    samples = imu_samples(imu)
    blocks = [sensor_rows(GNSSLOGGER_IMU_ROWS[column], *samples[column], clock, start_utc_ns)
              for column in GNSSLOGGER_IMU_ROWS if column in samples]
    elapsed_ns, fix_block = fix_rows(fixes, clock, start_utc_ns)
    status = gnsslogger_rows("Status", {
        "UnixTimeMillis": gnsslogger_stamps(fixes.t_s, clock, start_utc_ns)[0], "SignalCount": "1",
        "SignalIndex": "0", "ConstellationType": "1", "Svid": "1", "CarrierFrequencyHz": GPS_L1_HZ,
        "Cn0DbHz": fixes.cn0_dbhz, "UsedInFix": "1", "HasAlmanacData": "1", "HasEphemerisData": "1"})
    return gnsslogger_text([*blocks, (elapsed_ns, fix_block), (elapsed_ns, status)], GNSSLOGGER_WRITTEN)


def write_gnsslogger(out_dir: str | Path, imu: ImuLog, fixes: GeodeticFixes, clock: PhoneClock,
                     start_utc_ns: int) -> Path:
    """Write the GnssLogger log into ``out_dir`` (atomically), named by the phone's UTC at its start; its path."""
    path = Path(out_dir) / f"gnss_log_{_date(_start_utc_ns(clock, start_utc_ns)):%Y_%m_%d_%H_%M_%S}.txt"
    with atomic_path(path) as tmp:
        tmp.write_text(gnsslogger_log(imu, fixes, clock, start_utc_ns))
    return path


# --- Sensor Logger ----------------------------------------------------------------------------------------

def sensor_logger_files(imu: ImuLog, fixes: GeodeticFixes, clock: PhoneClock, start_utc_ns: int) -> dict[str, str]:
    """The files of a Sensor Logger export of the walk, name -> text (module docstring)."""
    files: dict[str, str] = {}
    intervals_s: dict[str, float] = {}  # each file's sample interval, for Metadata.csv
    samples = imu_samples(imu)
    for name, column in SENSOR_LOGGER_IMU_FILES.items():
        if column not in samples:
            continue
        t_s, values = samples[column]
        files[name] = axis_csv(t_s, values, clock, start_utc_ns)
        intervals_s[name.removesuffix(".csv")] = interval = float(np.median(np.diff(t_s)))
        if column == "acc_mps2":
            gravity = uniform_filter1d(values, max(1, round(GRAVITY_WINDOW_S / interval)), axis=0, mode="nearest")
            files[GRAVITY] = axis_csv(t_s, gravity, clock, start_utc_ns)
            files[ACCELEROMETER] = axis_csv(t_s, values - gravity, clock, start_utc_ns)
            intervals_s[ACCELEROMETER.removesuffix(".csv")] = intervals_s[GRAVITY.removesuffix(".csv")] = interval
    files[LOCATION] = location_csv(fixes, clock, start_utc_ns)
    intervals_s[LOCATION.removesuffix(".csv")] = float(np.median(np.diff(fixes.t_s))) if len(fixes.t_s) > 1 else 1.0
    files[METADATA] = metadata_csv(_start_utc_ns(clock, start_utc_ns), intervals_s)
    return files


def write_sensor_logger(out_dir: str | Path, imu: ImuLog, fixes: GeodeticFixes, clock: PhoneClock,
                        start_utc_ns: int) -> Path:
    """Write the Sensor Logger export into a folder of ``out_dir`` named by the phone's UTC at the recording's
    start (atomically: all its files or none); the folder's path."""
    folder = Path(out_dir) / f"{_date(_start_utc_ns(clock, start_utc_ns)):%Y-%m-%d_%H-%M-%S}"
    with atomic_folder(folder) as tmp:
        for name, text in sensor_logger_files(imu, fixes, clock, start_utc_ns).items():
            (tmp / name).write_text(text)
    return folder


# --- either -----------------------------------------------------------------------------------------------

WRITERS = {"gnsslogger": write_gnsslogger, "sensorlogger": write_sensor_logger}


def check_format(phone_log: str) -> None:
    """ValueError for a phone log format other than :data:`dtmbnav_core.phone.PHONE_LOG_FORMATS`."""
    if phone_log not in PHONE_LOG_FORMATS:
        raise ValueError(f"unknown phone log format {phone_log!r}; expected one of {', '.join(PHONE_LOG_FORMATS)}")


def write_phone_log(phone_log: str, out_dir: str | Path, scenario: Scenario, imu: ImuLog, gnss: GnssLog,
                    clock: PhoneClock, start_utc_ns: int) -> Path:
    """Write the walk's IMU and GNSS as the phone app ``phone_log`` logs them (module docstring).

    Parameters
    ----------
    phone_log : str
        ``"gnsslogger"`` or ``"sensorlogger"``.
    out_dir : path
        The folder to write into (it must exist).
    scenario : Scenario
        Its origin, GNSS error model and antenna height place the fixes.
    imu, gnss : ImuLog, GnssLog
        The simulated samples and fixes, times in s since the scenario's start.
    clock : PhoneClock
        The phone's clock against the true one.
    start_utc_ns : int
        True UTC of the scenario's time 0 (the log's start), ns since the Unix epoch.

    Returns
    -------
    Path
        The GnssLogger log, or the Sensor Logger export's folder.

    Raises
    ------
    ValueError
        An unknown format, or an accelerometer or gyroscope without a finite non-zero sample.
    """
    check_format(phone_log)
    return WRITERS[phone_log](out_dir, imu, phone_fixes(scenario, gnss), clock, start_utc_ns)
