"""Write a simulated walk's IMU and GNSS as a phone app writes them: GnssLogger's text log or Sensor Logger's CSV export.

``dtmbnav simulate --phone-log FORMAT`` writes, beside the capture, what the phone carried on the walk
would have logged, so that the field path (``dtmbnav sensors``, ``dtmbnav/phone_logs.py``) runs on
simulated walks without reading any simulator file. Formats (:data:`dtmbnav_core.phone.PHONE_LOG_FORMATS`):

- ``gnsslogger``: Google's GnssLogger text log ``gnss_log_<yyyy_MM_dd_HH_mm_ss>.txt``: the app's
  ``#`` preamble and one ``# Type,...`` header line per row type (its LOGGING_FORMAT), then the rows in
  time order: ``UncalAccel``, ``UncalGyro`` and ``UncalMag`` (bias and drift columns 0: the simulated
  values are the phone's calibrated output) at every IMU sample, a ``Fix`` row (provider ``GPS``) and a
  ``Status`` row per fix. Sensor rows carry ``utcTimeMillis`` (the phone's UTC clock, ms) and
  ``elapsedRealtimeNanos`` (its monotonic clock, which starts at :data:`BOOT_ELAPSED_NS`); a fix
  carries both too (``UnixTimeMillis``, ``elapsedRealtimeNanos``). The simulator models the fix's mean
  C/N0 only, so its ``Status`` row is one GPS L1 signal of that C/N0, used in the fix.
- ``sensorlogger``: the Sensor Logger app's export, a folder ``<yyyy-MM-dd_HH-mm-ss>`` of CSV files:
  ``TotalAcceleration.csv`` (the specific force), ``Accelerometer.csv`` and ``Gravity.csv`` (the
  specific force split, as Android's linear acceleration and gravity sensors, into its moving average
  over :data:`GRAVITY_WINDOW_S` and the rest), ``Gyroscope.csv``, ``Magnetometer.csv`` (columns
  ``time`` in ns since the Unix epoch on the phone's UTC clock, ``seconds_elapsed`` since the
  recording's start on the phone's clock, then ``z,y,x``), ``Location.csv`` and ``Metadata.csv``
  (platform ``android``, units and frames as Android reports them).

Both: every IMU sample as simulated (the scenario's ``imu.rate_hz``; the default 100 Hz is Sensor
Logger's default rate, GnssLogger logs the sensors at their own rate), every fix of the GNSS log
(``gnss.rate_hz``, 1 Hz by default). A sample with a non-finite value (a gap the IMU model left) is
not written; an IMU without a magnetometer (its ``mag_ut`` None, NaN, or zeros throughout as in
``/imu``) writes no ``UncalMag`` rows and no ``Magnetometer.csv``. Axes: the IMU's phone frame is Android's device frame
(``docs/conventions.md``); units m/s^2, rad/s, uT, as Android's.

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

Numbers are written as the shortest text that reads back to the same float.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter1d

from dtmbnav_core.geodetic import to_lat_lon_height
from dtmbnav_core.h5io import atomic_folder, atomic_path
from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS, PHONE_LOG_FORMATS, PhoneClock
from dtmbnav_core.records import GnssLog, ImuLog
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
#: GnssLogger's header of each row type written (its LOGGING_FORMAT), by row type.
GNSSLOGGER_HEADERS = {
    "Fix": ("Provider", "LatitudeDegrees", "LongitudeDegrees", "AltitudeMeters", "SpeedMps", "AccuracyMeters",
            "BearingDegrees", "UnixTimeMillis", "SpeedAccuracyMps", "BearingAccuracyDegrees", "elapsedRealtimeNanos",
            "VerticalAccuracyMeters", "MockLocation"),
    "Status": ("UnixTimeMillis", "SignalCount", "SignalIndex", "ConstellationType", "Svid", "CarrierFrequencyHz",
               "Cn0DbHz", "AzimuthDegrees", "ElevationDegrees", "UsedInFix", "HasAlmanacData", "HasEphemerisData",
               "BasebandCn0DbHz"),
    "UncalAccel": ("utcTimeMillis", "elapsedRealtimeNanos", "UncalAccelXMps2", "UncalAccelYMps2", "UncalAccelZMps2",
                   "BiasXMps2", "BiasYMps2", "BiasZMps2"),
    "UncalGyro": ("utcTimeMillis", "elapsedRealtimeNanos", "UncalGyroXRadPerSec", "UncalGyroYRadPerSec",
                  "UncalGyroZRadPerSec", "DriftXRadPerSec", "DriftYRadPerSec", "DriftZRadPerSec"),
    "UncalMag": ("utcTimeMillis", "elapsedRealtimeNanos", "UncalMagXMicroT", "UncalMagYMicroT", "UncalMagZMicroT",
                 "BiasXMicroT", "BiasYMicroT", "BiasZMicroT"),
}
#: The ImuLog column of each GnssLogger sensor row type.
GNSSLOGGER_SENSOR_ROWS = {"UncalAccel": "acc_mps2", "UncalGyro": "gyro_radps", "UncalMag": "mag_ut"}
#: Sensor Logger's axis files: the ImuLog column each is written from.
SENSOR_LOGGER_AXIS_FILES = {"TotalAcceleration.csv": "acc_mps2", "Gyroscope.csv": "gyro_radps",
                            "Magnetometer.csv": "mag_ut"}
SENSOR_LOGGER_AXIS_HEADER = ("time", "seconds_elapsed", "z", "y", "x")
SENSOR_LOGGER_LOCATION_HEADER = ("time", "seconds_elapsed", "bearingAccuracy", "speedAccuracy", "verticalAccuracy",
                                 "horizontalAccuracy", "speed", "bearing", "altitude", "longitude", "latitude")
SENSOR_LOGGER_METADATA_HEADER = ("version", "device name", "recording epoch time", "recording time",
                                 "recording timezone", "platform", "appVersion", "device id", "sensors",
                                 "sampleRateMs", "standardisation", "platform version")


@dataclass(frozen=True)
class PhoneFixes:
    """The walk's fixes as the phone reports them.

    Attributes
    ----------
    t_s : ndarray
        Fix time, s since the scenario's start (true time).
    lat_deg, lon_deg : ndarray
        WGS84 latitude and longitude, deg.
    height_m : ndarray
        Height above the WGS84 ellipsoid, m.
    accuracy_m : ndarray
        Stated horizontal accuracy (68 % radius), m.
    cn0_dbhz : ndarray
        Mean C/N0 of the satellites used, dB-Hz.
    """

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    accuracy_m: np.ndarray
    cn0_dbhz: np.ndarray


def phone_fixes(scenario: Scenario, gnss: GnssLog) -> PhoneFixes:
    """The simulated fixes on WGS84 about the scenario's origin, at the phone's height (module docstring)."""
    lat, lon, height = to_lat_lon_height(gnss.x_m, gnss.y_m, scenario.channel.antenna_height_m,
                                         scenario.origin.point)
    accuracy = ACCURACY_RADIUS_SIGMAS * fix_sigma_m(scenario.gnss, gnss.cn0_dbhz)
    return PhoneFixes(t_s=np.asarray(gnss.t_s, dtype=np.float64), lat_deg=lat, lon_deg=lon, height_m=height,
                      accuracy_m=accuracy, cn0_dbhz=np.asarray(gnss.cn0_dbhz, dtype=np.float64))


def _text(value: float) -> str:
    """A float as the shortest text that reads back to it."""
    return repr(float(value))


def imu_samples(imu: ImuLog) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each ImuLog sensor column's samples with finite values, as (times s, N x 3 values); the magnetometer
    left out where the IMU has none (None, no finite sample, or zeros throughout: the ``/imu`` convention).

    Raises
    ------
    ValueError
        The accelerometer or the gyroscope has no finite non-zero sample.
    """
    out = {}
    for column in ("acc_mps2", "gyro_radps", "mag_ut"):
        values = getattr(imu, column)
        values = np.full((len(imu.t_s), 3), np.nan) if values is None else np.asarray(values, dtype=np.float64)
        finite = np.isfinite(values).all(axis=1)
        if np.any(values[finite]):
            out[column] = (np.asarray(imu.t_s, dtype=np.float64)[finite], values[finite])
        elif column != "mag_ut":
            raise ValueError(f"phone log: the IMU's {column} has no finite non-zero sample")
    return out


def _utc_ms(utc_ns: np.ndarray) -> np.ndarray:
    """UTC stamps in ns to whole ms (rounded half up)."""
    return (utc_ns + 500_000) // 1_000_000


def _start_stamp(clock: PhoneClock, start_utc_ns: int) -> tuple[int, datetime.datetime]:
    """The phone's UTC at the log's start: ns since the Unix epoch, and as a date and time (whole seconds)."""
    utc_ns = int(clock.utc_ns(np.zeros(1), start_utc_ns)[0])
    return utc_ns, datetime.datetime.fromtimestamp(utc_ns // 1_000_000_000, tz=datetime.UTC)


# --- GnssLogger ------------------------------------------------------------------------------------------

def gnsslogger_text(imu: ImuLog, fixes: PhoneFixes, clock: PhoneClock, start_utc_ns: int) -> str:
    """The text of a GnssLogger log of the walk (module docstring)."""
    times: list[np.ndarray] = []
    rows: list[list[str]] = []
    samples = imu_samples(imu)
    for row_type, column in GNSSLOGGER_SENSOR_ROWS.items():
        if column not in samples:
            continue
        t_s, values = samples[column]
        elapsed = BOOT_ELAPSED_NS + clock.elapsed_ns(t_s)
        utc_ms = _utc_ms(clock.utc_ns(t_s, start_utc_ns))
        rows.append([f"{row_type},{ms},{ns},{_text(x)},{_text(y)},{_text(z)},0.0,0.0,0.0"
                     for ms, ns, (x, y, z) in zip(utc_ms, elapsed, values)])
        times.append(elapsed)
    elapsed = BOOT_ELAPSED_NS + clock.elapsed_ns(fixes.t_s)
    utc_ms = _utc_ms(clock.utc_ns(fixes.t_s, start_utc_ns))
    rows.append([f"Fix,GPS,{_text(lat)},{_text(lon)},{_text(h)},,{_text(acc)},,{ms},,,{ns},,0"
                 for lat, lon, h, acc, ms, ns in zip(fixes.lat_deg, fixes.lon_deg, fixes.height_m, fixes.accuracy_m,
                                                     utc_ms, elapsed)])
    rows.append([f"Status,{ms},1,0,1,1,{_text(GPS_L1_HZ)},{_text(cn0)},,,1,1,1,"
                 for ms, cn0 in zip(utc_ms, fixes.cn0_dbhz)])
    times += [elapsed, elapsed]
    order = np.argsort(np.concatenate(times), kind="stable")
    lines = [line for block in rows for line in block]
    headers = [line for row_type, names in GNSSLOGGER_HEADERS.items() for line in (f"# {row_type},{','.join(names)}",
                                                                                      "# ")]
    return "\n".join([*GNSSLOGGER_PREAMBLE, *headers, *(lines[i] for i in order)]) + "\n"


def write_gnsslogger(out_dir: str | Path, imu: ImuLog, fixes: PhoneFixes, clock: PhoneClock,
                     start_utc_ns: int) -> Path:
    """Write the GnssLogger log into ``out_dir`` (atomically), named by the phone's UTC at its start; its path."""
    _, start = _start_stamp(clock, start_utc_ns)
    path = Path(out_dir) / f"gnss_log_{start:%Y_%m_%d_%H_%M_%S}.txt"
    with atomic_path(path) as tmp:
        tmp.write_text(gnsslogger_text(imu, fixes, clock, start_utc_ns))
    return path


# --- Sensor Logger ----------------------------------------------------------------------------------------

def _csv(header: tuple[str, ...], rows: list[str]) -> str:
    return "\n".join([",".join(header), *rows]) + "\n"


def _axis_csv(t_s: np.ndarray, values: np.ndarray, clock: PhoneClock, start_utc_ns: int) -> str:
    """A Sensor Logger axis file: ``time`` (phone UTC, ns), ``seconds_elapsed`` (phone clock, s), ``z,y,x``."""
    utc = clock.utc_ns(t_s, start_utc_ns)
    elapsed = clock.elapsed_s(t_s)
    return _csv(SENSOR_LOGGER_AXIS_HEADER, [f"{ns},{_text(s)},{_text(z)},{_text(y)},{_text(x)}"
                                            for ns, s, (x, y, z) in zip(utc, elapsed, values)])


def sensor_logger_files(imu: ImuLog, fixes: PhoneFixes, clock: PhoneClock, start_utc_ns: int) -> dict[str, str]:
    """The files of a Sensor Logger export of the walk, name -> text (module docstring)."""
    files: dict[str, str] = {}
    intervals_s: dict[str, float] = {}  # each file's sample interval, for Metadata.csv
    samples = imu_samples(imu)
    for name, column in SENSOR_LOGGER_AXIS_FILES.items():
        if column not in samples:
            continue
        t_s, values = samples[column]
        files[name] = _axis_csv(t_s, values, clock, start_utc_ns)
        intervals_s[name.removesuffix(".csv")] = interval = float(np.median(np.diff(t_s)))
        if column == "acc_mps2":
            gravity = uniform_filter1d(values, max(1, round(GRAVITY_WINDOW_S / interval)), axis=0, mode="nearest")
            files["Gravity.csv"] = _axis_csv(t_s, gravity, clock, start_utc_ns)
            files["Accelerometer.csv"] = _axis_csv(t_s, values - gravity, clock, start_utc_ns)
            intervals_s["Accelerometer"] = intervals_s["Gravity"] = interval
    utc = clock.utc_ns(fixes.t_s, start_utc_ns)
    files["Location.csv"] = _csv(SENSOR_LOGGER_LOCATION_HEADER, [
        f"{ns},{_text(s)},,,,{_text(acc)},,,{_text(h)},{_text(lon)},{_text(lat)}"
        for ns, s, acc, h, lon, lat in zip(utc, clock.elapsed_s(fixes.t_s), fixes.accuracy_m, fixes.height_m,
                                           fixes.lon_deg, fixes.lat_deg)])
    intervals_s["Location"] = float(np.median(np.diff(fixes.t_s))) if len(fixes.t_s) > 1 else 1.0
    start_ns, start = _start_stamp(clock, start_utc_ns)
    sensors = sorted(intervals_s)
    files["Metadata.csv"] = _csv(SENSOR_LOGGER_METADATA_HEADER, [",".join([
        "3", "dtmbnav simulator", str(_utc_ms(start_ns)), f"{start:%Y-%m-%d_%H-%M-%S}", "UTC", "android", "1.64",
        "simulated", "|".join(sensors), "|".join(str(round(intervals_s[s] * 1000)) for s in sensors), "false",
        "14"])])
    return files


def write_sensor_logger(out_dir: str | Path, imu: ImuLog, fixes: PhoneFixes, clock: PhoneClock,
                        start_utc_ns: int) -> Path:
    """Write the Sensor Logger export into a folder of ``out_dir`` named by the phone's UTC at the recording's
    start (atomically: all its files or none); the folder's path."""
    _, start = _start_stamp(clock, start_utc_ns)
    folder = Path(out_dir) / f"{start:%Y-%m-%d_%H-%M-%S}"
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
