"""Phone logs in the formats ``dtmbnav sensors`` reads, written from known samples, for the tests.

Written with the simulator's writer (:mod:`sim.phone_log_writer`), whose formats are
:mod:`dtmbnav_core.phone_formats`, on a phone clock that agrees with the samples' (their times are the
log's own, s after its start):

- :func:`gnsslogger_lines`: a GnssLogger text log: the accelerometer as ``UncalAccel`` rows with a
  bias, the gyroscope as calibrated ``Gyro`` rows, the magnetometer as ``UncalMag`` rows with a bias,
  GPS and FLP ``Fix`` rows, ``Status`` rows of the satellites used (and of one not used), and rows
  of types the reader skips (``Raw``, ``Nav``, ``OrientationDeg``, ``Agc``);
- :func:`write_sensor_logger`: a Sensor Logger CSV export (axis files, ``Location.csv``, ``Metadata.csv``);
- :func:`static_log`: a short log of a phone lying still, for the bad-input cases.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dtmbnav_core.phone import PhoneClock
from dtmbnav_core.phone_formats import (
    ACCELEROMETER,
    ELAPSED_NANOS,
    GNSSLOGGER_SENSOR_ROW_TYPES,
    GRAVITY,
    GYROSCOPE,
    LOCATION,
    MAGNETOMETER,
    METADATA,
    TOTAL_ACCELERATION,
    UTC_MILLIS,
)
from dtmbnav_core.records import GeodeticFixes
from sim.phone_log_writer import (
    BOOT_ELAPSED_NS,
    axis_csv,
    fix_rows,
    gnsslogger_rows,
    gnsslogger_stamps,
    gnsslogger_text,
    location_csv,
    metadata_csv,
    sensor_rows,
)

#: The samples' clock: the phone's, which agrees with theirs.
CLOCK = PhoneClock()
#: UTC of a GnssLogger log's time 0, ns since the Unix epoch; its elapsed-realtime is the writer's.
GNSSLOGGER_T0_NS = 1_663_164_600_000_000_000
BOOT_NS = BOOT_ELAPSED_NS
#: UTC minus elapsed realtime of a GnssLogger log, ns.
UTC_OFFSET_NS = GNSSLOGGER_T0_NS - BOOT_NS
#: UTC of a Sensor Logger log's time 0, ns since the Unix epoch.
SENSOR_LOGGER_T0_NS = 1_698_501_144_401_773_000
ACC_BIAS = (0.05, -0.03, 0.02)
MAG_BIAS = (12.0, -7.5, 3.25)
#: C/N0 of the signals a fix uses, about the fix's mean, dB-Hz; and of one signal it does not use.
USED_CN0_SPREAD = (-5.0, 0.0, 5.0)
UNUSED_CN0 = 45.0
#: The header lines written, by row type, in their default order.
ROW_TYPES = ("UncalAccel", "Gyro", "UncalMag", "Fix", "Status", "Raw", "Nav", "OrientationDeg", "Agc")
#: Rows the reader skips are written every this many seconds.
UNRELATED_INTERVAL_S = 0.25
#: A device name with a comma, as Sensor Logger's Metadata.csv quotes it.
DEVICE_NAME = "Pixel 7, work phone"


@dataclass(frozen=True)
class Stream:
    """One sensor's samples: times (s on the log's clock) and values (N x 3, project units)."""

    t_s: np.ndarray
    values: np.ndarray


def fixes_of(t_s: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray, height_m: np.ndarray,
             accuracy_m: np.ndarray, cn0_dbhz: np.ndarray | None = None) -> GeodeticFixes:
    """Fixes at ``t_s`` (s); their mean C/N0 (dB-Hz) 30 + the fix's index unless given."""
    cn0 = 30.0 + np.arange(len(t_s)) if cn0_dbhz is None else cn0_dbhz
    return GeodeticFixes(np.asarray(t_s, dtype=np.float64), lat_deg, lon_deg, height_m, accuracy_m, cn0)


def elapsed_ns(t_s: float | np.ndarray) -> np.ndarray:
    """A GnssLogger log's ``elapsedRealtimeNanos`` at ``t_s`` s after its start."""
    return gnsslogger_stamps(np.asarray(t_s, dtype=np.float64), CLOCK, GNSSLOGGER_T0_NS)[1]


def _status_rows(fixes: GeodeticFixes) -> tuple[np.ndarray, list[str]]:
    """A ``Status`` row per signal of each fix: those it used (C/N0 about the fix's mean) and one it did not."""
    cn0 = np.column_stack([fixes.cn0_dbhz + spread for spread in USED_CN0_SPREAD] + [np.full(len(fixes.t_s),
                                                                                              UNUSED_CN0)])
    count = cn0.shape[1]
    utc_ms, elapsed = (np.repeat(stamp, count) for stamp in gnsslogger_stamps(fixes.t_s, CLOCK, GNSSLOGGER_T0_NS))
    index = np.tile(np.arange(count), len(fixes.t_s))
    return elapsed, gnsslogger_rows("Status", {
        "UnixTimeMillis": utc_ms, "SignalCount": str(count), "SignalIndex": index, "ConstellationType": "1",
        "Svid": index + 3, "Cn0DbHz": cn0.ravel(), "AzimuthDegrees": "120.0", "ElevationDegrees": "45.0",
        "UsedInFix": (index < len(USED_CN0_SPREAD)).astype(int), "HasAlmanacData": "1", "HasEphemerisData": "1"})


def _unrelated_rows(t_end_s: float) -> list[tuple[np.ndarray, list[str]]]:
    """Rows of types the reader skips, every :data:`UNRELATED_INTERVAL_S` (a ``Nav`` row's data bytes are
    comma-separated: more fields than its header names, as the app writes them)."""
    t = np.arange(0.0, t_end_s, UNRELATED_INTERVAL_S)
    utc_ms, elapsed = gnsslogger_stamps(t, CLOCK, GNSSLOGGER_T0_NS)
    return [(elapsed, rows) for rows in (
        gnsslogger_rows("OrientationDeg", {UTC_MILLIS: utc_ms, ELAPSED_NANOS: elapsed, "yawDeg": 201.0,
                                           "rollDeg": -5.0, "pitchDeg": -52.0}),
        gnsslogger_rows("Raw", {UTC_MILLIS: utc_ms, "TimeNanos": 32083712000000, "LeapSecond": 18,
                                "FullBiasNanos": -1347710845896978382, "BiasNanos": 0.8, "Svid": 10,
                                "Cn0DbHz": 29.6, "ChipsetElapsedRealtimeNanos": elapsed}),
        gnsslogger_rows("Nav", {"Svid": np.full(len(t), 3), "Type": "769", "Status": "1", "MessageId": "-1",
                                "Sub-messageId": "14", "Data(Bytes)": "116,5,-126,11"}),
        gnsslogger_rows("Agc", {UTC_MILLIS: utc_ms, "TimeNanos": 4105000000, "AgcDb": 19.7,
                                "CarrierFrequencyHz": 1176450000, "ConstellationType": 1}))]


def gnsslogger_lines(acc: Stream, gyro: Stream, mag: Stream | None, fixes: GeodeticFixes,
                     row_types: tuple[str, ...] = ROW_TYPES, flp: bool = True) -> list[str]:
    """The lines of a GnssLogger log of these samples (no line endings).

    ``row_types``: the header lines to write, in that order. ``flp``: also write fused-provider fixes
    0.4 s after the GPS ones (the reader keeps only the GPS fixes).
    """
    rows = GNSSLOGGER_SENSOR_ROW_TYPES
    blocks = [sensor_rows(rows["UncalAccel"], acc.t_s, acc.values + ACC_BIAS, CLOCK, GNSSLOGGER_T0_NS, ACC_BIAS),
              sensor_rows(rows["Gyro"], gyro.t_s, gyro.values, CLOCK, GNSSLOGGER_T0_NS)]
    if mag is not None:
        blocks.append(sensor_rows(rows["UncalMag"], mag.t_s, mag.values + MAG_BIAS, CLOCK, GNSSLOGGER_T0_NS,
                                  MAG_BIAS))
    blocks += [fix_rows(fixes, CLOCK, GNSSLOGGER_T0_NS), _status_rows(fixes), *_unrelated_rows(float(acc.t_s[-1]))]
    if flp:
        blocks.append(fix_rows(replace(fixes, t_s=fixes.t_s + 0.4), CLOCK, GNSSLOGGER_T0_NS, provider="FLP"))
    return gnsslogger_text(blocks, row_types).splitlines()


def write_lines(path: Path, lines: list[str], newline: str = "\n") -> Path:
    path.write_bytes((newline.join(lines) + newline).encode())
    return path


def write_sensor_logger(folder: Path, acc: Stream, gyro: Stream, mag: Stream | None, fixes: GeodeticFixes,
                        gravity_split: bool = False, ios: bool = False, device_name: str = DEVICE_NAME) -> Path:
    """A Sensor Logger export of these samples in ``folder``.

    By default ``TotalAcceleration.csv`` holds the specific force and ``Accelerometer.csv`` a decoy
    (the acceleration less a constant gravity, as Android's linear acceleration). With
    ``gravity_split`` there is no TotalAcceleration.csv: ``Accelerometer.csv`` and ``Gravity.csv`` add up to
    the specific force (with iOS's opposite sign where ``ios``). ``Metadata.csv`` names the device
    ``device_name`` (by default one with a comma, which the file quotes).
    """
    folder.mkdir(parents=True, exist_ok=True)

    def axes(name: str, stream: Stream) -> None:
        (folder / name).write_text(axis_csv(stream.t_s, stream.values, CLOCK, SENSOR_LOGGER_T0_NS))

    gravity = np.tile([0.0, 0.0, 9.80665], (len(acc.t_s), 1))
    sign = -1.0 if ios else 1.0
    if gravity_split:
        axes(ACCELEROMETER, Stream(acc.t_s, sign * (acc.values - gravity)))
        axes(GRAVITY, Stream(acc.t_s, sign * gravity))
    else:
        axes(TOTAL_ACCELERATION, acc)
        axes(ACCELEROMETER, Stream(acc.t_s, acc.values - gravity))
    axes(GYROSCOPE, gyro)
    if mag is not None:
        axes(MAGNETOMETER, mag)
    (folder / LOCATION).write_text(location_csv(fixes, CLOCK, SENSOR_LOGGER_T0_NS))
    (folder / METADATA).write_text(metadata_csv(SENSOR_LOGGER_T0_NS, {"Accelerometer": 0.01, "Gyroscope": 0.01},
                                                platform="ios" if ios else "android", device_name=device_name))
    (folder / "Annotation.csv").write_text("")  # an empty file of a sensor the reader does not use
    return folder


def static_log(seconds: float = 2.0, rate_hz: float = 50.0) -> tuple[Stream, Stream, Stream, GeodeticFixes]:
    """A phone lying still, face up, for ``seconds``: gravity, no rotation, a constant field; a fix a second."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    acc = Stream(t, np.tile([0.01, -0.02, 9.80665], (len(t), 1)))
    gyro = Stream(t + 0.002, np.tile([0.001, -0.002, 0.0005], (len(t), 1)))
    mag = Stream(t + 0.004, np.tile([-18.0, 2.0, -42.0], (len(t), 1)))
    fix_t = np.arange(0.0, seconds, 1.0)
    n = len(fix_t)
    return acc, gyro, mag, fixes_of(fix_t, np.full(n, 30.5), np.full(n, 114.3), np.full(n, 20.0), np.full(n, 3.5))
