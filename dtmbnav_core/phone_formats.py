"""The phone log formats, defined once: Google GnssLogger's text log and the Sensor Logger app's CSV export.

``dtmbnav sensors`` reads them (``dtmbnav/field/phone_logs.py``), the simulator writes them
(``sim/phone_log_writer.py``) and the tests build their samples with that writer: all three take
the row types, headers, column names, units and time bases from here.

GnssLogger (``gnss_log_<yyyy_MM_dd_HH_mm_ss>.txt``, GnssLogger v3). Comma-separated rows, each
starting with its row type; lines starting with ``#`` are comments: a preamble (the app's version,
the phone), then one ``# <type>,<column>,...`` header line per row type (:data:`GNSSLOGGER_HEADERS`,
the app's LOGGING_FORMAT), which names the row's fields after the type. Versions of the app add,
drop and reorder columns, so a reader goes by these names, never by position. Time bases:
``utcTimeMillis`` (sensor rows) and ``UnixTimeMillis`` (``Fix``, ``Status``) are the phone's UTC
clock, ms since the Unix epoch; ``elapsedRealtimeNanos`` is its monotonic clock since boot, ns,
which the sensor rows and the fixes share. The motion sensors (:data:`GNSSLOGGER_SENSOR_ROWS`) come
as calibrated rows (``Accel``, ``Gyro``, ``Mag``) or uncalibrated ones (``Uncal*``) whose reading less
the bias (or drift) the phone estimated is the calibrated one (Android's ``SensorEvent``).

Sensor Logger (a folder, or its zip archive, of CSV files with a header row each). The axis files
(:data:`SENSOR_LOGGER_AXIS_FILES`) have the columns :data:`SENSOR_LOGGER_AXIS_HEADER`: ``time``, ns
since the Unix epoch on the phone's UTC clock; ``seconds_elapsed``, s since the recording's start;
then ``z,y,x``. ``TotalAcceleration.csv`` is the specific force (Android only), ``Accelerometer.csv``
the acceleration without gravity and ``Gravity.csv`` the gravity (they add up to the specific
force). ``Location.csv`` holds the fixes (:data:`SENSOR_LOGGER_LOCATION_HEADER`), ``Metadata.csv``
one row on the recording (:data:`SENSOR_LOGGER_METADATA_HEADER`); a field holding a comma (the
device name) is quoted. On iOS, unless "Standardise Units & Frames" is on, acceleration and gravity
carry the opposite sign to Android's.

Units and axes, both formats: Android's device frame (x to the right of the screen, y up the
screen, z out of it; the project's phone frame, ``docs/conventions.md``); the accelerometer's
specific force in m/s^2 (+9.81 on z lying face up), the gyroscope's right-handed rates in rad/s,
the magnetometer in uT; latitude and longitude in WGS84 degrees, altitude in m above the WGS84
ellipsoid, the horizontal accuracy in m (the radius of 68 % confidence, :mod:`dtmbnav_core.phone`).
"""

from __future__ import annotations

from dataclasses import dataclass

#: The motion sensors of a phone log.
SENSORS = ("accelerometer", "gyroscope", "magnetometer")

# --- GnssLogger -----------------------------------------------------------------------------------------

#: A sensor row's time on the phone's UTC clock (ms since the Unix epoch) and on its monotonic clock (ns).
UTC_MILLIS = "utcTimeMillis"
ELAPSED_NANOS = "elapsedRealtimeNanos"


@dataclass(frozen=True)
class SensorRows:
    """One GnssLogger row type of a motion sensor.

    Attributes
    ----------
    row_type : str
        The row type, e.g. ``"UncalAccel"``.
    sensor : str
        ``"accelerometer"``, ``"gyroscope"`` or ``"magnetometer"``.
    values : tuple of str
        The x, y, z columns (m/s^2, rad/s or uT).
    bias : tuple of str or None
        An uncalibrated row type's x, y, z bias (or drift) columns, same unit; None for a calibrated one.
    """

    row_type: str
    sensor: str
    values: tuple[str, str, str]
    bias: tuple[str, str, str] | None = None

    @property
    def header(self) -> tuple[str, ...]:
        """The row type's columns: the two times, the values, the bias."""
        return (UTC_MILLIS, ELAPSED_NANOS, *self.values, *(self.bias or ()))


def _axes(prefix: str, unit: str) -> tuple[str, str, str]:
    """GnssLogger's column names of three axes: ``<prefix>X<unit>``, ..."""
    return f"{prefix}X{unit}", f"{prefix}Y{unit}", f"{prefix}Z{unit}"


#: The row types of each motion sensor, in order of preference: the calibrated rows when the log has them.
GNSSLOGGER_SENSOR_ROWS: dict[str, tuple[SensorRows, SensorRows]] = {
    "accelerometer": (SensorRows("Accel", "accelerometer", _axes("Accel", "Mps2")),
                      SensorRows("UncalAccel", "accelerometer", _axes("UncalAccel", "Mps2"), _axes("Bias", "Mps2"))),
    "gyroscope": (SensorRows("Gyro", "gyroscope", _axes("Gyro", "RadPerSec")),
                  SensorRows("UncalGyro", "gyroscope", _axes("UncalGyro", "RadPerSec"), _axes("Drift", "RadPerSec"))),
    "magnetometer": (SensorRows("Mag", "magnetometer", _axes("Mag", "MicroT")),
                     SensorRows("UncalMag", "magnetometer", _axes("UncalMag", "MicroT"), _axes("Bias", "MicroT"))),
}
#: The same row types, by name.
GNSSLOGGER_SENSOR_ROW_TYPES = {rows.row_type: rows for choices in GNSSLOGGER_SENSOR_ROWS.values() for rows in choices}
#: The header (columns after the row type) of each GnssLogger row type, as GnssLogger v3 writes it.
GNSSLOGGER_HEADERS: dict[str, tuple[str, ...]] = {
    "Raw": (UTC_MILLIS, "TimeNanos", "LeapSecond", "TimeUncertaintyNanos", "FullBiasNanos", "BiasNanos",
            "BiasUncertaintyNanos", "DriftNanosPerSecond", "DriftUncertaintyNanosPerSecond",
            "HardwareClockDiscontinuityCount", "Svid", "TimeOffsetNanos", "State", "ReceivedSvTimeNanos",
            "ReceivedSvTimeUncertaintyNanos", "Cn0DbHz", "PseudorangeRateMetersPerSecond",
            "PseudorangeRateUncertaintyMetersPerSecond", "AccumulatedDeltaRangeState", "AccumulatedDeltaRangeMeters",
            "AccumulatedDeltaRangeUncertaintyMeters", "CarrierFrequencyHz", "CarrierCycles", "CarrierPhase",
            "CarrierPhaseUncertainty", "MultipathIndicator", "SnrInDb", "ConstellationType", "AgcDb",
            "BasebandCn0DbHz", "FullInterSignalBiasNanos", "FullInterSignalBiasUncertaintyNanos",
            "SatelliteInterSignalBiasNanos", "SatelliteInterSignalBiasUncertaintyNanos", "CodeType",
            "ChipsetElapsedRealtimeNanos"),
    **{row_type: rows.header for row_type, rows in GNSSLOGGER_SENSOR_ROW_TYPES.items()},
    "OrientationDeg": (UTC_MILLIS, ELAPSED_NANOS, "yawDeg", "rollDeg", "pitchDeg"),
    "Fix": ("Provider", "LatitudeDegrees", "LongitudeDegrees", "AltitudeMeters", "SpeedMps", "AccuracyMeters",
            "BearingDegrees", "UnixTimeMillis", "SpeedAccuracyMps", "BearingAccuracyDegrees", ELAPSED_NANOS,
            "VerticalAccuracyMeters", "MockLocation"),
    "Nav": ("Svid", "Type", "Status", "MessageId", "Sub-messageId", "Data(Bytes)"),
    "Status": ("UnixTimeMillis", "SignalCount", "SignalIndex", "ConstellationType", "Svid", "CarrierFrequencyHz",
               "Cn0DbHz", "AzimuthDegrees", "ElevationDegrees", "UsedInFix", "HasAlmanacData", "HasEphemerisData",
               "BasebandCn0DbHz"),
    "Agc": (UTC_MILLIS, "TimeNanos", "LeapSecond", "TimeUncertaintyNanos", "FullBiasNanos", "BiasNanos",
            "BiasUncertaintyNanos", "DriftNanosPerSecond", "DriftUncertaintyNanosPerSecond",
            "HardwareClockDiscontinuityCount", "AgcDb", "CarrierFrequencyHz", "ConstellationType"),
}
#: Every row type GnssLogger writes: those above, and those whose rows hold no fixed columns (an NMEA
#: sentence, an antenna's correction arrays). A file whose first line is a comment or one of these rows is
#: taken for a GnssLogger log.
GNSSLOGGER_ROW_TYPES = (*GNSSLOGGER_HEADERS, "NMEA", "GnssAntennaInfo")
#: The Fix columns a reader uses, by meaning: the current name first, then those of older versions of the app.
FIX_COLUMNS = {
    "provider": ("Provider",),
    "lat": ("LatitudeDegrees", "Latitude"),
    "lon": ("LongitudeDegrees", "Longitude"),
    "height": ("AltitudeMeters", "Altitude"),
    "accuracy": ("AccuracyMeters", "Accuracy"),
    "unix_ms": ("UnixTimeMillis", "(UTC)TimeInMs"),
    "elapsed_ns": (ELAPSED_NANOS,),
}
#: The Status columns that give a fix's C/N0: the fix's UTC time (ms), a signal's C/N0 (dB-Hz), and whether
#: the fix used it (``1``).
STATUS_COLUMNS = ("UnixTimeMillis", "Cn0DbHz", "UsedInFix")
#: How far (ms, on the UTC clock) the Status report that gives a fix its C/N0 may be from the fix: half the
#: 1 s between GnssLogger's fixes and between its status reports, so a fix takes the report of its own epoch.
CN0_JOIN_WINDOW_MS = 500
#: Fix providers in order of preference: the GNSS chipset's own fixes, then the fused and network ones.
PROVIDERS = ("gps", "flp", "nlp")

# --- Sensor Logger --------------------------------------------------------------------------------------

TOTAL_ACCELERATION = "TotalAcceleration.csv"
ACCELEROMETER = "Accelerometer.csv"
GRAVITY = "Gravity.csv"
GYROSCOPE = "Gyroscope.csv"
MAGNETOMETER = "Magnetometer.csv"
LOCATION = "Location.csv"
METADATA = "Metadata.csv"
#: The files of three axes (the app's capitals vary between versions: readers match names case-insensitively).
SENSOR_LOGGER_AXIS_FILES = (TOTAL_ACCELERATION, ACCELEROMETER, GRAVITY, GYROSCOPE, MAGNETOMETER)
#: A sample's time on the phone's UTC clock (ns since the Unix epoch) and since the recording's start (s).
SENSOR_LOGGER_TIME = "time"
SENSOR_LOGGER_ELAPSED = "seconds_elapsed"
#: The value columns of an axis file, x, y, z (the file holds them in the order z, y, x).
SENSOR_LOGGER_AXES = ("x", "y", "z")
SENSOR_LOGGER_AXIS_HEADER = (SENSOR_LOGGER_TIME, SENSOR_LOGGER_ELAPSED, "z", "y", "x")
SENSOR_LOGGER_LOCATION_HEADER = (SENSOR_LOGGER_TIME, SENSOR_LOGGER_ELAPSED, "bearingAccuracy", "speedAccuracy",
                                 "verticalAccuracy", "horizontalAccuracy", "speed", "bearing", "altitude", "longitude",
                                 "latitude")
#: The Location.csv columns a reader uses, by meaning (a negative accuracy: none given).
LOCATION_COLUMNS = {"lat": "latitude", "lon": "longitude", "height": "altitude", "accuracy": "horizontalAccuracy"}
SENSOR_LOGGER_METADATA_HEADER = ("version", "device name", "recording epoch time", "recording time",
                                 "recording timezone", "platform", "appVersion", "device id", "sensors",
                                 "sampleRateMs", "standardisation", "platform version")
#: The Metadata.csv columns a reader uses: the platform (``android`` or ``ios``), and whether units and frames
#: were standardised (``true``; older versions spell the column the American way).
METADATA_PLATFORM = "platform"
METADATA_STANDARDISATION = ("standardisation", "standardization")
