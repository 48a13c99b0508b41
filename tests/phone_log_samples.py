"""Phone logs in the formats ``dtmbnav sensors`` reads, written from known samples, for the tests.

- :func:`gnsslogger_lines`: a GnssLogger text log (header comment lines, then rows in time order):
  the accelerometer as ``UncalAccel`` rows with a bias, the gyroscope as calibrated ``Gyro`` rows, the
  magnetometer as ``UncalMag`` rows with a bias, GPS and FLP ``Fix`` rows, ``Status`` rows of the
  satellites used, and rows of types the reader skips (``Raw``, ``Nav``, ``OrientationDeg``, ``Agc``);
- :func:`write_sensor_logger`: a Sensor Logger CSV export (``time,seconds_elapsed,z,y,x`` files,
  ``Location.csv``, ``Metadata.csv``);
- :func:`static_log`: a short log of a phone lying still, for the bad-input cases.

Column names follow the apps' own headers (GnssLogger's LOGGING_FORMAT, the Sensor Logger export).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Elapsed-realtime of the log's time 0 and UTC minus elapsed-realtime, ns (any plausible values).
BOOT_NS = 65_972_055_195_160
UTC_OFFSET_NS = 1_663_164_600_000_000_000
#: Unix time of a Sensor Logger log's time 0, ns.
SENSOR_LOGGER_T0_NS = 1_698_501_144_401_773_000
ACC_BIAS = (0.05, -0.03, 0.02)
MAG_BIAS = (12.0, -7.5, 3.25)
GPS_CN0 = (31.0, 36.0, 41.0)

USED_HEADERS = [
    ("# UncalAccel,utcTimeMillis,elapsedRealtimeNanos,UncalAccelXMps2,UncalAccelYMps2,UncalAccelZMps2,BiasXMps2,"
     "BiasYMps2,BiasZMps2"),
    "# Gyro,utcTimeMillis,elapsedRealtimeNanos,GyroXRadPerSec,GyroYRadPerSec,GyroZRadPerSec",
    ("# UncalMag,utcTimeMillis,elapsedRealtimeNanos,UncalMagXMicroT,UncalMagYMicroT,UncalMagZMicroT,BiasXMicroT,"
     "BiasYMicroT,BiasZMicroT"),
    ("# Fix,Provider,LatitudeDegrees,LongitudeDegrees,AltitudeMeters,SpeedMps,AccuracyMeters,BearingDegrees,"
     "UnixTimeMillis,SpeedAccuracyMps,BearingAccuracyDegrees,elapsedRealtimeNanos,VerticalAccuracyMeters,MockLocation"),
    ("# Status,UnixTimeMillis,SignalCount,SignalIndex,ConstellationType,Svid,CarrierFrequencyHz,Cn0DbHz,"
     "AzimuthDegrees,ElevationDegrees,UsedInFix,HasAlmanacData,HasEphemerisData,BasebandCn0DbHz"),
]
UNRELATED_HEADERS = [
    "# Raw,utcTimeMillis,TimeNanos,LeapSecond,TimeUncertaintyNanos,FullBiasNanos,BiasNanos,Svid,Cn0DbHz",
    "# Nav,Svid,Type,Status,MessageId,Sub-messageId,Data(Bytes)",
    "# OrientationDeg,utcTimeMillis,elapsedRealtimeNanos,yawDeg,rollDeg,pitchDeg",
    "# Agc,utcTimeMillis,TimeNanos,LeapSecond,AgcDb,CarrierFrequencyHz,ConstellationType",
    "# GnssAntennaInfo,CarrierFrequencyMHz,PhaseCenterOffsetXMm",
]
PREAMBLE = ["# ", "# Header Description:", "# ", "# Version: v3.0.6.4 Platform: 13 Manufacturer: Google Model: Pixel",
            "# "]


@dataclass(frozen=True)
class Stream:
    """One sensor's samples: times (s on the log's clock) and values (N x 3, project units)."""

    t_s: np.ndarray
    values: np.ndarray


@dataclass(frozen=True)
class Fixes:
    """Fixes: times (s), WGS84 latitude and longitude (deg), ellipsoidal height (m), accuracy (m)."""

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    accuracy_m: np.ndarray


def num(value: float) -> str:
    """A float as the shortest text that reads back to it."""
    return repr(float(value))


def elapsed_ns(t_s: float) -> int:
    return BOOT_NS + round(t_s * 1e9)


def utc_ms(t_s: float) -> int:
    return round((elapsed_ns(t_s) + UTC_OFFSET_NS) / 1e6)


def _sensor_rows(kind: str, stream: Stream, bias: tuple[float, ...] | None) -> list[tuple[float, str]]:
    rows = []
    for t, v in zip(stream.t_s, stream.values):
        fields = [kind, str(utc_ms(t)), str(elapsed_ns(t))]
        if bias is None:
            fields += [num(x) for x in v]
        else:
            fields += [num(x + b) for x, b in zip(v, bias)] + [num(b) for b in bias]
        rows.append((float(t), ",".join(fields)))
    return rows


def _fix_rows(fixes: Fixes, provider: str, shift_s: float = 0.0) -> list[tuple[float, str]]:
    rows = []
    for t, lat, lon, h, acc in zip(fixes.t_s + shift_s, fixes.lat_deg, fixes.lon_deg, fixes.height_m,
                                   fixes.accuracy_m):
        fields = ["Fix", provider, num(lat), num(lon), num(h), "0.5", num(acc), "12.5", str(utc_ms(t)), "", "",
                  str(elapsed_ns(t)), "4.0", "0"]
        rows.append((float(t), ",".join(fields)))
    return rows


def _status_rows(fixes: Fixes) -> list[tuple[float, str]]:
    rows = []
    for t in fixes.t_s:
        signals = [(cn0, 1) for cn0 in GPS_CN0] + [(20.0, 0)]
        for index, (cn0, used) in enumerate(signals):
            fields = ["Status", str(utc_ms(t)), str(len(signals)), str(index), "1", str(index + 3), "", num(cn0),
                      "120.0", "45.0", str(used), "1", "1", ""]
            rows.append((float(t), ",".join(fields)))
    return rows


def _unrelated_rows(t_end_s: float) -> list[tuple[float, str]]:
    rows = []
    for t in np.arange(0.0, t_end_s, 0.25):
        rows.append((float(t), f"OrientationDeg,{utc_ms(t)},{elapsed_ns(t)},201.0,-5.0,-52.0"))
        rows.append((float(t), f"Raw,{utc_ms(t)},32083712000000,18,,-1347710845896978382,0.8,10,29.6"))
        rows.append((float(t), "Nav,3,769,1,-1,14,116,5,-126,11"))
        rows.append((float(t), f"Agc,{utc_ms(t)},4105000000,,19.7,1176450000,1"))
    return rows


def gnsslogger_lines(acc: Stream, gyro: Stream, mag: Stream | None, fixes: Fixes,
                     headers: list[str] | None = None, flp: bool = True) -> list[str]:
    """The lines of a GnssLogger log of these samples (no line endings).

    ``headers``: the header comment lines in the order to write them (default: the used row types'
    then the unrelated ones'). ``flp``: also write fused-provider fixes 0.4 s after the GPS ones
    (the reader keeps only the GPS fixes).
    """
    rows = _sensor_rows("UncalAccel", acc, ACC_BIAS) + _sensor_rows("Gyro", gyro, None)
    if mag is not None:
        rows += _sensor_rows("UncalMag", mag, MAG_BIAS)
    rows += _fix_rows(fixes, "GPS") + _status_rows(fixes) + _unrelated_rows(float(acc.t_s[-1]))
    if flp:
        rows += _fix_rows(fixes, "FLP", shift_s=0.4)
    rows.sort(key=lambda row: row[0])
    return PREAMBLE + (headers if headers is not None else USED_HEADERS + UNRELATED_HEADERS) + ["# "] + \
        [line for _, line in rows]


def write_lines(path: Path, lines: list[str], newline: str = "\n") -> Path:
    path.write_bytes((newline.join(lines) + newline).encode())
    return path


def _axis_csv(stream: Stream, t0_ns: int) -> str:
    lines = ["time,seconds_elapsed,z,y,x"]
    for t, (x, y, z) in zip(stream.t_s, stream.values):
        lines.append(f"{t0_ns + round(t * 1e9)},{num(t)},{num(z)},{num(y)},{num(x)}")
    return "\n".join(lines) + "\n"


def write_sensor_logger(folder: Path, acc: Stream, gyro: Stream, mag: Stream | None, fixes: Fixes,
                        gravity_split: bool = False, ios: bool = False) -> Path:
    """A Sensor Logger export of these samples in ``folder``.

    By default ``TotalAcceleration.csv`` holds the specific force and ``Accelerometer.csv`` a decoy
    (the acceleration less a constant gravity, as Android's linear acceleration). With
    ``gravity_split`` there is no TotalAcceleration.csv: ``Accelerometer.csv`` and ``Gravity.csv`` add up to
    the specific force (with iOS's opposite sign where ``ios``).
    """
    folder.mkdir(parents=True, exist_ok=True)
    t0 = SENSOR_LOGGER_T0_NS
    gravity = np.tile([0.0, 0.0, 9.80665], (len(acc.t_s), 1))
    sign = -1.0 if ios else 1.0
    if gravity_split:
        (folder / "Accelerometer.csv").write_text(_axis_csv(Stream(acc.t_s, sign * (acc.values - gravity)), t0))
        (folder / "Gravity.csv").write_text(_axis_csv(Stream(acc.t_s, sign * gravity), t0))
    else:
        (folder / "TotalAcceleration.csv").write_text(_axis_csv(acc, t0))
        (folder / "Accelerometer.csv").write_text(_axis_csv(Stream(acc.t_s, acc.values - gravity), t0))
    (folder / "Gyroscope.csv").write_text(_axis_csv(gyro, t0))
    if mag is not None:
        (folder / "Magnetometer.csv").write_text(_axis_csv(mag, t0))
    lines = [("time,seconds_elapsed,bearingAccuracy,speedAccuracy,verticalAccuracy,horizontalAccuracy,speed,bearing,"
              "altitude,longitude,latitude")]
    for t, lat, lon, h, accuracy in zip(fixes.t_s, fixes.lat_deg, fixes.lon_deg, fixes.height_m, fixes.accuracy_m):
        lines.append(f"{t0 + round(t * 1e9)},{num(t)},45,1.5,3.7,{num(accuracy)},1.4,0,{num(h)},{num(lon)},"
                     f"{num(lat)}")
    (folder / "Location.csv").write_text("\n".join(lines) + "\n")
    platform = "ios" if ios else "android"
    (folder / "Metadata.csv").write_text(
        "version,device name,recording epoch time,recording time,recording timezone,platform,appVersion,device id,"
        f"sensors,sampleRateMs,standardisation,platform version\n3,TestPhone,{t0},x,UTC,{platform},1.64,id,"
        "Accelerometer|Gyroscope,10|10,false,14\n")
    (folder / "Annotation.csv").write_text("")  # an empty file of a sensor the reader does not use
    return folder


def static_log(seconds: float = 2.0, rate_hz: float = 50.0) -> tuple[Stream, Stream, Stream, Fixes]:
    """A phone lying still, face up, for ``seconds``: gravity, no rotation, a constant field; a fix a second."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    acc = Stream(t, np.tile([0.01, -0.02, 9.80665], (len(t), 1)))
    gyro = Stream(t + 0.002, np.tile([0.001, -0.002, 0.0005], (len(t), 1)))
    mag = Stream(t + 0.004, np.tile([-18.0, 2.0, -42.0], (len(t), 1)))
    fix_t = np.arange(0.0, seconds, 1.0)
    n = len(fix_t)
    fixes = Fixes(fix_t, np.full(n, 30.5), np.full(n, 114.3), np.full(n, 20.0), np.full(n, 3.5))
    return acc, gyro, mag, fixes
