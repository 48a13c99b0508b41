"""``dtmbnav sensors``: a phone's own log -> the project's sensors file (``/imu``, ``/gnss``).

The log is read by :mod:`dtmbnav.field.phone_logs`; this module

- resamples the three motion sensors onto one uniform time grid (default 100 Hz) over the span every
  sensor covers, by linear interpolation of each axis; the grid's first sample is t_s = 0 and its UTC
  time is stored (``start_utc``). Each sensor's own timing is measured on the way: its mean rate,
  its jitter (standard deviation of the sample interval over its mean) and its gaps (intervals
  longer than :data:`~dtmbnav_core.resampling.GAP_INTERVALS` median intervals), reported to the user
  and stored as ``/imu`` attributes (:mod:`dtmbnav_core.resampling`, which the PDR shares);
- keeps the phone's axes (Android's device frame is the project's phone frame, ``docs/conventions.md``)
  and the units (m/s^2, rad/s, uT); a log without a magnetometer gets zeros and
  ``has_magnetometer = False``;
- refuses a sensor sampled below :data:`MIN_RATE_HZ` (its median rate) rather than interpolate a few
  samples into a walk;
- converts the fixes to ENU metres about an origin (the first fix, or one given) with ``pymap3d``,
  keeping each fix's stated accuracy, and the origin as ``/gnss`` attributes;
- makes the start fix P0 of every fix (with a stated accuracy) of the standstill before the walk
  (:func:`dtmbnav_core.start_fix.standstill_start_fix`): from the grid's first sample, where the
  motion sensors begin to show the phone still, to the walk's start, the first moment the
  accelerometer magnitude's standard deviation over :data:`MOTION_WINDOW_S` exceeds
  :data:`MOTION_THRESHOLD_MPS2` (``start_window_s`` keeps only the standstill's last seconds). The
  fixes are weighted by their stated accuracy, and P0's sigma is that of their mean under errors
  correlated over :data:`~dtmbnav_core.start_fix.FIX_ERROR_TAU_S`. Android states a fix's accuracy
  as the radius of 68 % confidence; for a circular normal error that radius is
  sqrt(-2 ln 0.32) = 1.51 sigma, so a fix's per-axis sigma is its accuracy over 1.51;
- writes a log without fixes with an empty ``/gnss`` (no rows, no start fix; the origin only where
  ``origin`` gives one): ``dtmbnav fuse`` then asks for ``--start X,Y``.

Nothing here imports the simulator: the real-data path must run without it.
"""

from __future__ import annotations

import datetime
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtmbnav.field.phone_logs import GNSSLOGGER, FixSeries, PhoneLog, SensorSeries, read_phone_log
from dtmbnav.field.platform import ANDROID
from dtmbnav_core import schema
from dtmbnav_core.geodetic import GeodeticPoint, to_enu
from dtmbnav_core.h5io import atomic_h5
from dtmbnav_core.moving import moving_std
from dtmbnav_core.phone import ACCURACY_CONFIDENCE, ACCURACY_RADIUS_SIGMAS
from dtmbnav_core.records import GnssLog, ImuLog
from dtmbnav_core.resampling import GAP_INTERVALS, interpolate, sample_timing, uniform_grid
from dtmbnav_core.sensors import write_gnss, write_imu
from dtmbnav_core.start_fix import FIX_ERROR_TAU_S, CombinedFix, combine_fixes, standstill_start_fix

#: Default rate of the resampled ``/imu``, Hz.
DEFAULT_RATE_HZ = 100.0
#: Window of the accelerometer-magnitude standard deviation that detects the walk's start, s.
MOTION_WINDOW_S = 1.0
#: Standard deviation of the accelerometer magnitude above which the phone moves with a walker, m/s^2: above
#: a hand-held phone's tremor at rest, below the first step's.
MOTION_THRESHOLD_MPS2 = 0.2
PHONE_FRAME = ("phone (Android device frame, kept as logged): x right, y forward (up the screen, towards the top "
               "of the phone), z out of the screen")
IMU_UNITS = "acc_mps2 m/s^2, gyro_radps rad/s, mag_ut uT"
#: Lowest median sample rate each motion sensor is read at, Hz. Walking puts step cadence at up to ~3 Hz and
#: its harmonics, which the step detector's peaks ride on, at up to ~10 Hz: 20 Hz is their Nyquist rate. The
#: magnetometer gives the heading, which changes far slower. Below these, interpolation onto the grid would
#: invent the walk between samples, so the log is refused.
MIN_RATE_HZ = {"accelerometer": 20.0, "gyroscope": 20.0, "magnetometer": 5.0}


@dataclass(frozen=True)
class Gap:
    """A stretch without samples of one sensor, on the output clock (s since the first ``/imu`` sample)."""

    sensor: str
    start_s: float
    end_s: float


@dataclass(frozen=True)
class SensorTiming:
    """How regularly one sensor was sampled.

    Attributes
    ----------
    sensor : str
    source : str
        Where its samples came from.
    rate_hz : float
        Mean sample rate (gaps left out), Hz.
    jitter : float
        Standard deviation of the sample interval over its mean, gaps left out (0 for a perfectly
        regular sensor).
    gaps : tuple of Gap
        Intervals longer than :data:`~dtmbnav_core.resampling.GAP_INTERVALS` median intervals.
    """

    sensor: str
    source: str
    rate_hz: float
    jitter: float
    gaps: tuple[Gap, ...]


@dataclass(frozen=True)
class ImportedSensors:
    """What ``dtmbnav sensors`` writes, and what the user is told.

    Attributes
    ----------
    imu : ImuLog
        Resampled motion sensors, t_s = 0 at the grid's first sample.
    gnss : GnssLog
        Fixes in ENU (east ``x_m``, north ``y_m``), times on the ``/imu`` clock; no rows for a log without fixes.
    geodetic : dict of str -> ndarray
        The further ``/gnss`` columns (:data:`dtmbnav_core.schema.GNSS_GEODETIC_COLUMNS`).
    start_fix : CombinedFix or None
        P0 and how many fixes made it; None for a log without fixes.
    start_window_s : float or None
        The standstill's last seconds P0 was made of; None: the whole standstill.
    walk_start_s : float
        Detected start of the walk, s (inf when no motion was found).
    origin : GeodeticPoint or None
        None for a log without fixes and no origin given.
    start_utc_ns : int
        UTC of t_s = 0, ns since the Unix epoch.
    rate_hz : float
    timings : tuple of SensorTiming
    has_magnetometer : bool
    log : PhoneLog
        The log as read.
    notes : tuple of str
        Warnings for the user.
    """

    imu: ImuLog
    gnss: GnssLog
    geodetic: dict[str, np.ndarray]
    start_fix: CombinedFix | None
    start_window_s: float | None
    walk_start_s: float
    origin: GeodeticPoint | None
    start_utc_ns: int
    rate_hz: float
    timings: tuple[SensorTiming, ...]
    has_magnetometer: bool
    log: PhoneLog
    notes: tuple[str, ...]


def sensor_timing(series: SensorSeries, t0_ns: int) -> SensorTiming:
    """Rate, jitter and gaps of one sensor; gap times on the clock that starts at ``t0_ns``."""
    timing = sample_timing((series.t_ns - t0_ns) / 1e9)
    gaps = tuple(Gap(series.sensor, start, end) for start, end in timing.gaps_s)
    return SensorTiming(series.sensor, series.source, timing.rate_hz, timing.jitter, gaps)


def common_grid(series: Sequence[SensorSeries], rate_hz: float) -> tuple[int, np.ndarray]:
    """The uniform grid over the span every sensor covers: its first time (log clock, ns) and t_s from it.

    Raises
    ------
    ValueError
        The sensors overlap for less than two grid intervals.
    """
    t0_ns = max(int(s.t_ns[0]) for s in series)
    t1_ns = min(int(s.t_ns[-1]) for s in series)
    t_s = uniform_grid(0.0, (t1_ns - t0_ns) / 1e9, rate_hz) if t1_ns >= t0_ns else np.zeros(0)
    if len(t_s) < 3:
        spans = ", ".join(f"{s.sensor} {(s.t_ns[-1] - s.t_ns[0]) / 1e9:.3f} s" for s in series)
        raise ValueError(f"{series[0].source}: the motion sensors overlap for less than {2 / rate_hz:g} s ({spans})")
    return t0_ns, t_s


def check_rate(series: SensorSeries, grid_rate_hz: float) -> None:
    """Refuse a sensor whose median sample rate is below its :data:`MIN_RATE_HZ`.

    The median interval, not the mean, so that a gap in a fast sensor does not count against it.

    Raises
    ------
    ValueError
        Naming the sensor's source, its measured rate and its sample count and span.
    """
    rate_hz = 1e9 / float(np.median(np.diff(series.t_ns)))
    if rate_hz < MIN_RATE_HZ[series.sensor]:
        span_s = (series.t_ns[-1] - series.t_ns[0]) / 1e9
        raise ValueError(f"{series.source}: {series.sensor} sampled at {rate_hz:.3g} Hz ({len(series.t_ns)} samples "
                         f"over {span_s:.1f} s), below the {MIN_RATE_HZ[series.sensor]:g} Hz a walk needs; it would be "
                         f"interpolated onto the {grid_rate_hz:g} Hz grid: log the sensor at its full rate")


def resample(series: SensorSeries, t0_ns: int, t_s: np.ndarray) -> np.ndarray:
    """A sensor's samples linearly interpolated at ``t_s`` (s after ``t0_ns`` on the log clock), N x 3."""
    return interpolate((series.t_ns - t0_ns) / 1e9, series.values, t_s)


def walk_start_s(t_s: np.ndarray, acc_mps2: np.ndarray, rate_hz: float) -> float:
    """First time the accelerometer magnitude's moving standard deviation exceeds the motion threshold, s;
    inf when it never does."""
    std = moving_std(np.linalg.norm(acc_mps2, axis=1), MOTION_WINDOW_S, rate_hz)
    moving = np.flatnonzero(std > MOTION_THRESHOLD_MPS2)
    return float(t_s[moving[0]]) if moving.size else math.inf


def choose_start_fix(gnss: GnssLog, accuracy_m: np.ndarray, walk_start: float, where: str,
                     notes: list[str], window_s: float | None = None) -> CombinedFix:
    """P0 from the fixes with a stated accuracy from t_s = 0 (the grid's start) to the walk's start (module
    docstring); with none there, as before the standstill was averaged: the last such fix at or before the walk's
    start, else the first (noted).

    Raises
    ------
    ValueError
        No fix states its accuracy.
    """
    usable = np.flatnonzero(np.isfinite(accuracy_m) & (accuracy_m > 0))
    if usable.size == 0:
        raise ValueError(f"{where}: no fix states its horizontal accuracy; the start fix needs one")
    sigma = accuracy_m[usable] / ACCURACY_RADIUS_SIGMAS
    t_s, x_m, y_m = gnss.t_s[usable], gnss.x_m[usable], gnss.y_m[usable]
    combined = standstill_start_fix(t_s, x_m, y_m, sigma, 0.0, walk_start, window_s)
    if combined is not None:
        return combined
    before = np.flatnonzero(t_s <= walk_start)
    i = int(before[-1]) if before.size else 0
    where_from = ("the last before it" if before.size else "the first") + f", at {t_s[i]:.2f} s"
    notes.append(f"{where}: no fix while the phone stood still before the walk (0 to {walk_start:.2f} s): the start "
                 f"fix is one fix, {where_from}")
    return combine_fixes(t_s[i:i + 1], x_m[i:i + 1], y_m[i:i + 1], sigma[i:i + 1])


def _origin_of(fixes: FixSeries | None, origin: GeodeticPoint | None, where: str,
               notes: list[str]) -> GeodeticPoint | None:
    """The given origin, else the first fix; a height not given is the first fix's (0 if it states none). None
    without fixes and origin."""
    if fixes is None:
        if origin is not None and origin.height_m is None:
            notes.append(f"{where}: no fixes: the origin's height is 0 m")
            return origin.with_height(0.0)
        return origin
    height = float(fixes.height_m[0])
    if not math.isfinite(height) and (origin is None or origin.height_m is None):
        notes.append(f"{fixes.source}: the first fix states no altitude: the origin's height is 0 m")
        height = 0.0
    if origin is not None:
        return origin.with_height(height)
    return GeodeticPoint(float(fixes.lat_deg[0]), float(fixes.lon_deg[0]), height)


def fixes_in_enu(fixes: FixSeries, origin: GeodeticPoint, t0_ns: int,
                 notes: list[str]) -> tuple[GnssLog, dict[str, np.ndarray]]:
    """The fixes as ``/gnss`` rows about ``origin`` (times on the ``/imu`` clock) and the geodetic columns.

    A fix without an altitude is placed at the origin's height (noted).
    """
    height = fixes.height_m.copy()
    missing = ~np.isfinite(height)
    if missing.any():
        notes.append(f"{fixes.source}: {int(missing.sum())} fix(es) without an altitude placed at the origin's height")
        height[missing] = origin.height_m
    east, north, up = to_enu(fixes.lat_deg, fixes.lon_deg, height, origin)
    gnss = GnssLog(t_s=(fixes.t_ns - t0_ns) / 1e9, x_m=east, y_m=north, cn0_dbhz=fixes.cn0_dbhz.astype(np.float64))
    geodetic = dict(zip(schema.GNSS_GEODETIC_COLUMNS, (up, fixes.accuracy_m, fixes.lat_deg, fixes.lon_deg,
                                                       fixes.height_m)))
    return gnss, geodetic


def build_sensors(log: PhoneLog, rate_hz: float = DEFAULT_RATE_HZ, origin: GeodeticPoint | None = None,
                  start_window_s: float | None = None) -> ImportedSensors:
    """Resample, convert and make the start fix of a read phone log (nothing is written); ``start_window_s``:
    :func:`choose_start_fix`'s window (None: the whole standstill)."""
    notes = list(log.notes)
    motion = [s for s in (log.accelerometer, log.gyroscope, log.magnetometer) if s is not None]
    for series in motion:
        if len(series.t_ns) < 2:
            raise ValueError(f"{series.source}: {len(series.t_ns)} sample(s); a sensor needs at least two")
        check_rate(series, rate_hz)
    t0_ns, t_s = common_grid(motion, rate_hz)
    timings = tuple(sensor_timing(s, t0_ns) for s in motion)
    acc, gyro = resample(log.accelerometer, t0_ns, t_s), resample(log.gyroscope, t0_ns, t_s)
    has_mag = log.magnetometer is not None
    if has_mag:
        mag = resample(log.magnetometer, t0_ns, t_s)
    else:
        mag = np.zeros_like(acc)
        notes.append(f"{log.sources[0]}: no magnetometer: /imu/mag_ut holds zeros (has_magnetometer False); the PDR's "
                     "attitude will come from the gyro and accelerometer alone")
    imu = ImuLog(t_s=t_s, acc_mps2=acc, gyro_radps=gyro, mag_ut=mag)
    ground = _origin_of(log.fixes, origin, log.sources[0], notes)
    walk_start = walk_start_s(t_s, acc, rate_hz)
    if log.fixes is None:
        gnss = GnssLog(t_s=np.zeros(0), x_m=np.zeros(0), y_m=np.zeros(0), cn0_dbhz=np.zeros(0))
        geodetic = {name: np.zeros(0) for name in schema.GNSS_GEODETIC_COLUMNS}
        fix = None
    else:
        gnss, geodetic = fixes_in_enu(log.fixes, ground, t0_ns, notes)
        if not math.isfinite(walk_start):
            notes.append(f"{log.accelerometer.source}: no walking found (accelerometer never moving); the start fix "
                         "is made of every fix")
        fix = choose_start_fix(gnss, geodetic["accuracy_m"], walk_start, log.fixes.source, notes, start_window_s)
    return ImportedSensors(imu=imu, gnss=gnss, geodetic=geodetic, start_fix=fix, start_window_s=start_window_s,
                           walk_start_s=walk_start,
                           origin=ground, start_utc_ns=t0_ns + log.utc_offset_ns, rate_hz=rate_hz, timings=timings,
                           has_magnetometer=has_mag, log=log, notes=tuple(notes))


def iso_utc(unix_ns: int) -> str:
    """ISO 8601 UTC text of a time in ns since the Unix epoch (microsecond resolution)."""
    seconds, ns = divmod(int(unix_ns), 1_000_000_000)
    moment = datetime.datetime.fromtimestamp(seconds, tz=datetime.UTC) + datetime.timedelta(
        microseconds=ns // 1000)
    return moment.isoformat(timespec="microseconds")


def imu_attrs(result: ImportedSensors) -> dict[str, object]:
    """The ``/imu`` attributes of an imported log: rate, frame, units, UTC start, and each sensor's timing."""
    gaps = [gap for timing in result.timings for gap in timing.gaps]
    attrs: dict[str, object] = {
        "rate_hz": result.rate_hz, "preset": "phone", "frame": PHONE_FRAME, "units": IMU_UNITS,
        schema.START_UTC_ATTR: iso_utc(result.start_utc_ns), schema.START_UTC_NS_ATTR: np.int64(result.start_utc_ns),
        schema.HAS_MAGNETOMETER_ATTR: result.has_magnetometer, "source_format": result.log.format,
        "source": "; ".join(result.log.sources),
        "resampling": "linear interpolation of each sensor onto a uniform grid over the span every sensor covers",
        "gap_definition": f"a sample interval longer than {GAP_INTERVALS:g} times the sensor's median interval",
        "gap_sensors": ",".join(gap.sensor for gap in gaps),
        "gap_start_s": np.array([gap.start_s for gap in gaps], dtype=np.float64),
        "gap_end_s": np.array([gap.end_s for gap in gaps], dtype=np.float64),
    }
    for timing in result.timings:
        attrs[f"{timing.sensor}_source"] = timing.source
        attrs[f"{timing.sensor}_rate_hz"] = timing.rate_hz
        attrs[f"{timing.sensor}_jitter"] = timing.jitter
    return attrs


def gnss_attrs(result: ImportedSensors) -> dict[str, object]:
    """The ``/gnss`` attributes of an imported log: origin (where known), source, accuracy convention, start-fix
    rule."""
    t_s = result.gnss.t_s
    rate = 1.0 / float(np.median(np.diff(t_s))) if len(t_s) > 1 else math.nan
    origin = result.origin
    return {
        **(dict(zip(schema.ORIGIN_ATTRS, (origin.lat_deg, origin.lon_deg, origin.height_m))) if origin else {}),
        "rate_hz": rate, "source": result.log.fixes.source if result.log.fixes else "none: the log has no fixes",
        "frame": "ENU about the origin (pymap3d, WGS84)",
        "accuracy_definition": f"stated horizontal accuracy radius ({ACCURACY_CONFIDENCE:.0%} confidence on Android); "
                               f"start_fix_sigma_m = accuracy / {ACCURACY_RADIUS_SIGMAS:.3f}",
        schema.WALK_START_ATTR: result.walk_start_s,
        "start_fix_rule": start_fix_rule(result.start_window_s),
        **({"start_fix_fixes": np.int64(result.start_fix.n_fixes),
            "start_fix_n_effective": result.start_fix.n_effective} if result.start_fix else {}),
    }


def start_fix_rule(window_s: float | None) -> str:
    """The ``start_fix_rule`` attribute: which fixes made P0, and how its sigma was found."""
    which = "every fix" if window_s is None else f"the fixes of the last {window_s:g} s"
    return (f"{which} with a stated accuracy from the first /imu sample to the walk's start (accelerometer magnitude "
            f"standard deviation over {MOTION_WINDOW_S:g} s above {MOTION_THRESHOLD_MPS2:g} m/s^2), weighted by "
            f"accuracy^-2; sigma that of their mean under errors correlated as exp(-dt / {FIX_ERROR_TAU_S:g} s) "
            "(dtmbnav_core.start_fix)")


def write_sensors(path: str | os.PathLike, result: ImportedSensors) -> None:
    """Write ``/imu`` and ``/gnss`` (with P0; without fixes, no rows and no P0) to a new file, atomically."""
    with atomic_h5(path) as h5:
        write_imu(h5, result.imu, imu_attrs(result))
        write_gnss(h5, result.gnss, result.start_fix.fix if result.start_fix else None, gnss_attrs(result),
                   extra_columns=result.geodetic)


def import_phone_log(paths: Sequence[str | os.PathLike], out_path: str | os.PathLike,
                     rate_hz: float = DEFAULT_RATE_HZ, origin: GeodeticPoint | None = None,
                     platform: str | None = None, start_window_s: float | None = None) -> ImportedSensors:
    """``dtmbnav sensors``: read a phone log, build ``/imu`` and ``/gnss``, write them to ``out_path``.

    ``platform`` (``--platform``, :data:`dtmbnav.field.platform.PLATFORMS`): whose acceleration sign a Sensor
    Logger export carries, where its ``Metadata.csv`` does not say (:mod:`dtmbnav.field.platform`).
    ``start_window_s`` (``--start-window``): only the standstill's last seconds make the start fix
    (:func:`choose_start_fix`; None: all of it).

    Raises
    ------
    ValueError
        Bad input (file and line named); ``platform`` disagreeing with the log; nothing is written.
    """
    log = read_phone_log([str(p) for p in paths], platform)
    if log.format == GNSSLOGGER and platform not in (None, ANDROID):
        raise ValueError(f"{log.sources[0]}: a GnssLogger log (Android's app), but --platform {platform}; drop "
                         "--platform")
    result = build_sensors(log, rate_hz, origin, start_window_s)
    write_sensors(out_path, result)
    return result


def describe(result: ImportedSensors) -> list[str]:
    """Lines for the user: each sensor's rate and jitter, what was written, the origin and the start fix."""
    lines = [f"{result.log.format} log: " + ", ".join(
        f"{t.sensor} {t.rate_hz:.1f} Hz (jitter {t.jitter:.2%})" for t in result.timings)]
    imu_t = result.imu.t_s
    lines.append(f"/imu: {len(imu_t)} samples at {result.rate_hz:g} Hz, {imu_t[-1]:.2f} s from "
                 f"{iso_utc(result.start_utc_ns)}")
    o, combined = result.origin, result.start_fix
    walk = (f"the walk starts at {result.walk_start_s:.2f} s" if math.isfinite(result.walk_start_s)
            else "no walk found")
    if combined is None:
        about = f"about the given origin {o.lat_deg:.8f}, {o.lon_deg:.8f}" if o else "and no geodetic origin"
        lines.append(f"/gnss: no fixes {about}; no start fix ({walk})")
        return lines
    fix = combined.fix
    lines.append(f"/gnss: {len(result.gnss.t_s)} fixes about the origin {o.lat_deg:.8f}, {o.lon_deg:.8f}, "
                 f"{o.height_m:.2f} m; start fix of {combined.n_fixes} fix(es) up to {fix.t_s:.2f} s (as "
                 f"{combined.n_effective:.1f} independent ones): ({fix.x_m:.2f}, {fix.y_m:.2f}) m, sigma "
                 f"{fix.sigma_m:.2f} m ({walk})")
    return lines


def gap_warnings(result: ImportedSensors) -> list[str]:
    """One warning per gap in a sensor's samples."""
    return [f"{gap.sensor}: no samples for {gap.end_s - gap.start_s:.3f} s from {gap.start_s:.3f} s (interpolated "
            "across)" for timing in result.timings for gap in timing.gaps]
