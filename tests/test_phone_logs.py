"""``dtmbnav sensors``: a phone's own log (GnssLogger, Sensor Logger) into the sensors file.

The logs are written from a known motion, the simulator's IMU and GNSS of the tiny walk, sampled
at uneven times (1 % jitter) and placed on the Earth about a known origin; the imported ``/imu``
must be those samples linearly interpolated onto the uniform grid, the ``/gnss`` fixes pymap3d's
ENU of the logged latitudes and longitudes, and ``dtmbnav pdr`` must walk the result.
"""

from __future__ import annotations

import datetime
import json
import math
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pymap3d
import pytest
from conftest import TINY_WALK
from hypothesis import given, settings
from hypothesis import strategies as st
from phone_log_samples import (
    BOOT_NS,
    ROW_TYPES,
    SENSOR_LOGGER_T0_NS,
    UTC_OFFSET_NS,
    Stream,
    elapsed_ns,
    fixes_of,
    gnsslogger_lines,
    static_log,
    write_lines,
    write_sensor_logger,
)
from scipy.stats import rayleigh

from dtmbnav.cli import EXIT_OK, main
from dtmbnav.field.phone_logs import read_gnsslogger, read_phone_log
from dtmbnav.field.sensors_import import ACCURACY_RADIUS_SIGMAS
from dtmbnav_core import schema
from dtmbnav_core.geodetic import GeodeticPoint, tower_in_sensors_frame
from dtmbnav_core.phone import ACCURACY_CONFIDENCE
from dtmbnav_core.phone_formats import CN0_JOIN_WINDOW_MS, GNSSLOGGER_HEADERS, METADATA
from dtmbnav_core.sensors import read_gnss, read_imu
from dtmbnav_core.start_fix import FIX_ERROR_TAU_S

ROOT = Path(__file__).resolve().parents[1]
ORIGIN = (30.52, 114.36, 25.0)
RATES_HZ = {"accelerometer": 200.0, "gyroscope": 200.0, "magnetometer": 50.0}
OFFSETS_S = {"accelerometer": 0.003, "gyroscope": 0.011, "magnetometer": 0.007}
JITTER = 0.01
COLUMN = {"accelerometer": "acc_mps2", "gyroscope": "gyro_radps", "magnetometer": "mag_ut"}


def _jittered(t_s: np.ndarray, values: np.ndarray, rate_hz: float, offset_s: float,
              rng: np.random.Generator) -> Stream:
    """The signal sampled near ``rate_hz`` with independent timing errors: interval std 1 % of the mean."""
    dt = 1.0 / rate_hz
    t = offset_s + np.arange(0.0, t_s[-1] - offset_s - dt, dt)
    t = t + rng.normal(0.0, JITTER * dt / np.sqrt(2.0), len(t))
    return Stream(t, np.column_stack([np.interp(t, t_s, values[:, k]) for k in range(3)]))


@pytest.fixture(scope="module")
def motion():
    """The tiny walk: its truth, its IMU, and the logged streams and fixes built from them."""
    from sim.gnss import simulate_gnss
    from sim.imu import simulate_imu
    from sim.scenario import load_scenario
    from sim.walk import simulate_walk

    scenario = load_scenario(TINY_WALK)
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    gnss = simulate_gnss(scenario, walk)
    rng = np.random.default_rng(5)
    streams = {sensor: _jittered(imu.t_s, getattr(imu, COLUMN[sensor]), RATES_HZ[sensor], OFFSETS_S[sensor], rng)
               for sensor in RATES_HZ}
    up = 0.5 * np.sin(gnss.t_s)
    lat, lon, height = pymap3d.enu2geodetic(gnss.x_m, gnss.y_m, up, *ORIGIN)
    fixes = fixes_of(gnss.t_s, np.asarray(lat), np.asarray(lon), np.asarray(height),
                     2.5 + 0.1 * np.arange(len(gnss.t_s)))
    return {"walk": walk, "imu": imu, "gnss": gnss, "streams": streams, "fixes": fixes, "up": up}


def _write_gnsslogger(folder: Path, motion, mag: bool = True, **kwargs) -> Path:
    s = motion["streams"]
    lines = gnsslogger_lines(s["accelerometer"], s["gyroscope"], s["magnetometer"] if mag else None, motion["fixes"],
                             **kwargs)
    return write_lines(folder / "gnss_log.txt", lines)


def _import(capsys, *argv: str) -> str:
    """Run ``dtmbnav sensors`` (it must succeed) and return its stderr."""
    code = main(["sensors", *argv])
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    return err


def _grid_start_ns(streams: dict[str, Stream], to_ns) -> int:
    return max(to_ns(s.t_s[0]) for s in streams.values())


def _expected(stream: Stream, to_ns, t0_ns: int, t_s: np.ndarray) -> np.ndarray:
    """The logged samples (times as the log states them, ns) linearly interpolated at the grid."""
    source = np.array([to_ns(t) - t0_ns for t in stream.t_s]) / 1e9
    return np.column_stack([np.interp(t_s, source, stream.values[:, k]) for k in range(3)])


def _check_imu(path: Path, motion, to_ns, sensors=tuple(RATES_HZ)) -> float:
    """``/imu`` is the logged samples interpolated on a uniform 100 Hz grid, and the truth within the
    interpolation error; returns where the grid starts on the simulator's clock, s."""
    streams = {k: v for k, v in motion["streams"].items() if k in sensors}
    imu = read_imu(path)
    t0_ns = _grid_start_ns(streams, to_ns)
    assert imu.t_s[0] == 0.0 and np.allclose(np.diff(imu.t_s), 0.01)
    t0_sim = (t0_ns - to_ns(0.0)) / 1e9
    truth = motion["imu"]
    for sensor in sensors:
        got = getattr(imu, COLUMN[sensor])
        assert np.allclose(got, _expected(streams[sensor], to_ns, t0_ns, imu.t_s), rtol=0, atol=1e-9), sensor
        # Against the truth: re-interpolation moves a sample by at most the truth's own second difference.
        truth_values = getattr(truth, COLUMN[sensor])
        exact = np.column_stack([np.interp(t0_sim + imu.t_s, truth.t_s, truth_values[:, k]) for k in range(3)])
        bound = np.abs(np.diff(truth_values, 2, axis=0)).max(axis=0)
        assert np.all(np.abs(got - exact).max(axis=0) <= bound + 1e-9), sensor
    return t0_sim


def _check_gnss(path: Path, motion, to_ns, t0_sim: float, origin=ORIGIN) -> None:
    fixes = motion["fixes"]
    gnss, fix = read_gnss(path)
    with h5py.File(path, "r") as f:
        group = f[schema.GNSS]
        attrs = dict(group.attrs)
        up, accuracy = group["z_m"][()], group["accuracy_m"][()]
        lat, lon = group["lat_deg"][()], group["lon_deg"][()]
    assert tuple(attrs[name] for name in schema.ORIGIN_ATTRS) == pytest.approx(origin, abs=1e-12)
    e, n, u = pymap3d.geodetic2enu(fixes.lat_deg, fixes.lon_deg, fixes.height_m, *origin)
    assert np.abs(gnss.x_m - e).max() < 1e-3 and np.abs(gnss.y_m - n).max() < 1e-3 and np.abs(up - u).max() < 1e-3
    if origin == ORIGIN:  # the logged fixes came from the simulator's ENU about this origin
        assert np.abs(gnss.x_m - motion["gnss"].x_m).max() < 1e-3
        assert np.abs(gnss.y_m - motion["gnss"].y_m).max() < 1e-3
    assert np.array_equal(lat, fixes.lat_deg) and np.array_equal(lon, fixes.lon_deg)
    assert np.array_equal(accuracy, fixes.accuracy_m)
    assert np.allclose(gnss.t_s, fixes.t_s - t0_sim, atol=1e-9)
    # The start fix: every fix from the grid's start to the detected walk start, weighted by accuracy^-2 (a fix's
    # sigma the 68 % radius over 1.51), its sigma that of the mean of errors correlated as exp(-dt / tau).
    walk_start = attrs[schema.WALK_START_ATTR]
    true_start = motion["walk"].walk_start_t_s - t0_sim
    assert true_start - 1.0 <= walk_start <= true_start + 0.5
    i = np.flatnonzero((gnss.t_s >= 0.0) & (gnss.t_s <= walk_start))
    sigma = accuracy[i] / ACCURACY_RADIUS_SIGMAS
    w = sigma**-2 / np.sum(sigma**-2)
    assert fix.t_s == gnss.t_s[i[-1]]
    assert (fix.x_m, fix.y_m) == pytest.approx((w @ gnss.x_m[i], w @ gnss.y_m[i]), abs=1e-9)
    covariance = np.outer(sigma, sigma) * np.exp(-np.abs(np.subtract.outer(gnss.t_s[i], gnss.t_s[i])) / FIX_ERROR_TAU_S)
    assert fix.sigma_m == pytest.approx(np.sqrt(w @ covariance @ w), rel=1e-9)
    assert attrs["start_fix_fixes"] == len(i)


def test_the_accuracy_radius_holds_68_percent_of_a_circular_normal_error():
    """Android's stated accuracy is a 68 % radius: a circular normal error of unit sigma per axis (its distance
    from the truth Rayleigh-distributed) falls within ACCURACY_RADIUS_SIGMAS with that probability."""
    assert rayleigh.cdf(ACCURACY_RADIUS_SIGMAS) == pytest.approx(ACCURACY_CONFIDENCE, rel=1e-12)


def _check_timing_attrs(path: Path, sensors=tuple(RATES_HZ)) -> dict:
    with h5py.File(path, "r") as f:
        attrs = dict(f[schema.IMU].attrs)
    assert attrs["rate_hz"] == 100.0 and attrs["preset"] == "phone"
    for sensor in sensors:
        assert attrs[f"{sensor}_rate_hz"] == pytest.approx(RATES_HZ[sensor], rel=0.01)
        assert 0.005 < attrs[f"{sensor}_jitter"] < 0.015
    return attrs


def test_a_gnsslogger_log_imports_to_the_logged_samples(motion, tmp_path, capsys):
    log = _write_gnsslogger(tmp_path, motion)
    out = tmp_path / "sensors.h5"
    err = _import(capsys, str(log), "-o", str(out), "--origin", ",".join(map(str, ORIGIN)))
    t0_sim = _check_imu(out, motion, elapsed_ns)
    _check_gnss(out, motion, elapsed_ns, t0_sim)
    attrs = _check_timing_attrs(out)
    assert attrs[schema.HAS_MAGNETOMETER_ATTR] and attrs["gap_sensors"] == "" and attrs["gap_start_s"].size == 0
    assert attrs["frame"].startswith("phone") and attrs["source_format"] == "GnssLogger"
    t0_ns = _grid_start_ns(motion["streams"], elapsed_ns)
    # UTC from the rows' utcTimeMillis (rounded to the millisecond).
    assert abs(int(attrs[schema.START_UTC_NS_ATTR]) - (t0_ns + UTC_OFFSET_NS)) <= 1_000_000
    start = datetime.datetime.fromisoformat(attrs[schema.START_UTC_ATTR])
    assert start.utcoffset() == datetime.timedelta(0)
    assert abs(start.timestamp() * 1e9 - int(attrs[schema.START_UTC_NS_ATTR])) < 2e3
    with h5py.File(out, "r") as f:  # each fix's C/N0: the mean of its Status rows used in the fix
        np.testing.assert_allclose(f["gnss/cn0_dbhz"][()], motion["fixes"].cn0_dbhz, rtol=0, atol=1e-12)
        assert "provider GPS" in f[schema.GNSS].attrs["source"]
    assert "jitter" in err and "FLP left out" in err


def test_the_default_origin_is_the_first_fix(motion, tmp_path, capsys):
    log = _write_gnsslogger(tmp_path, motion)
    out = tmp_path / "sensors.h5"
    _import(capsys, "-q", str(log), "-o", str(out))
    fixes = motion["fixes"]
    first = (fixes.lat_deg[0], fixes.lon_deg[0], fixes.height_m[0])
    t0_sim = (_grid_start_ns(motion["streams"], elapsed_ns) - BOOT_NS) / 1e9
    _check_gnss(out, motion, elapsed_ns, t0_sim, origin=first)
    gnss, _ = read_gnss(out)
    assert gnss.x_m[0] == 0.0 and gnss.y_m[0] == 0.0


def test_an_origin_without_height_takes_the_first_fixs(motion, tmp_path, capsys):
    log = _write_gnsslogger(tmp_path, motion)
    out = tmp_path / "sensors.h5"
    # A start window of 0 s makes the start fix of the standstill's last fix alone, and says so.
    err = _import(capsys, str(log), "-o", str(out), "--origin", f"{ORIGIN[0]},{ORIGIN[1]}", "--start-window", "0")
    with h5py.File(out, "r") as f:
        assert f[schema.GNSS].attrs["origin_height_m"] == motion["fixes"].height_m[0]
        assert f[schema.GNSS].attrs["start_fix_fixes"] == 1 and "last 0 s" in f[schema.GNSS].attrs["start_fix_rule"]
    assert "start fix of 1 fix(es)" in err


@pytest.mark.parametrize("mag", [True, False], ids=["with-magnetometer", "without-magnetometer"])
def test_pdr_walks_the_imported_log(motion, tmp_path, capsys, mag):
    """Without a magnetometer the PDR takes its attitude from the gyro and accelerometer, and says so."""
    log = _write_gnsslogger(tmp_path, motion, mag=mag)
    sensors, pdr = tmp_path / "sensors.h5", tmp_path / "pdr.h5"
    _import(capsys, "-q", str(log), "-o", str(sensors))
    assert main(["pdr", str(sensors), "-o", str(pdr)]) == EXIT_OK
    err = capsys.readouterr().err
    assert ("gyro and accelerometer alone" in err) is not mag
    # A phone log has no calibrated Weinberg gain: the PDR says it takes the step-frequency model instead.
    assert "no calibrated Weinberg gain" in err
    assert main(["pdr", str(sensors), "-o", str(pdr), "--weinberg-k", "0.45"]) == EXIT_OK
    assert "Weinberg" not in capsys.readouterr().err
    with h5py.File(pdr, "r") as f:
        steps = len(f["pdr/t_s"])
        assert np.all(np.isfinite(f["pdr/x_m"][()])) and np.all(np.isfinite(f["pdr/heading_rad"][()]))
    true_steps = len(motion["walk"].step_t_s)
    assert abs(steps - true_steps) <= max(1, 0.1 * true_steps)


def _sensor_logger_ns(t_s: float) -> int:
    return SENSOR_LOGGER_T0_NS + round(t_s * 1e9)


@pytest.mark.parametrize("layout", ["folder", "zip", "csv-files", "gravity", "ios"])
def test_a_sensor_logger_export_imports_to_the_logged_samples(motion, tmp_path, capsys, layout):
    s = motion["streams"]
    folder = write_sensor_logger(tmp_path / "export", s["accelerometer"], s["gyroscope"], s["magnetometer"],
                                 motion["fixes"], gravity_split=layout in ("gravity", "ios"), ios=layout == "ios")
    if layout == "zip":
        logs = [str(tmp_path / "export.zip")]
        with zipfile.ZipFile(logs[0], "w") as archive:
            for path in folder.iterdir():
                archive.write(path, arcname=f"recording/{path.name}")
    elif layout == "csv-files":
        logs = [str(p) for p in sorted(folder.glob("*.csv"))]
    else:
        logs = [str(folder)]
    out = tmp_path / "sensors.h5"
    _import(capsys, "-q", *logs, "-o", str(out), "--origin", ",".join(map(str, ORIGIN)))
    t0_sim = _check_imu(out, motion, _sensor_logger_ns)
    _check_gnss(out, motion, _sensor_logger_ns, t0_sim)
    attrs = _check_timing_attrs(out)
    assert attrs["source_format"] == "Sensor Logger"
    if layout not in ("gravity", "ios"):
        assert attrs["accelerometer_source"].endswith("TotalAcceleration.csv")  # not the gravity-free decoy
    t0_ns = _grid_start_ns(s, _sensor_logger_ns)
    assert int(attrs[schema.START_UTC_NS_ATTR]) == t0_ns


def test_gaps_are_reported_and_stored(motion, tmp_path, capsys):
    gyro = motion["streams"]["gyroscope"]
    keep = (gyro.t_s < 5.0) | (gyro.t_s > 5.5)
    streams = {**motion["streams"], "gyroscope": Stream(gyro.t_s[keep], gyro.values[keep])}
    log = write_lines(tmp_path / "gnss_log.txt", gnsslogger_lines(
        streams["accelerometer"], streams["gyroscope"], streams["magnetometer"], motion["fixes"]))
    out = tmp_path / "sensors.h5"
    err = _import(capsys, str(log), "-o", str(out))
    with h5py.File(out, "r") as f:
        attrs = dict(f[schema.IMU].attrs)
    t0_sim = (_grid_start_ns(streams, elapsed_ns) - BOOT_NS) / 1e9
    assert attrs["gap_sensors"] == "gyroscope"
    assert attrs["gap_start_s"] == pytest.approx([gyro.t_s[~keep][0] - 1 / 200 - t0_sim], abs=2e-3)
    assert attrs["gap_end_s"] == pytest.approx([gyro.t_s[~keep][-1] + 1 / 200 - t0_sim], abs=2e-3)
    assert "gyroscope: no samples for" in err


def test_a_log_without_magnetometer_stores_zeros_and_says_so(motion, tmp_path, capsys):
    log = _write_gnsslogger(tmp_path, motion, mag=False)
    out = tmp_path / "sensors.h5"
    err = _import(capsys, str(log), "-o", str(out))
    imu = read_imu(out)
    assert np.all(imu.mag_ut == 0.0)
    with h5py.File(out, "r") as f:
        assert not f[schema.IMU].attrs[schema.HAS_MAGNETOMETER_ATTR]
    assert "no magnetometer" in err
    _check_imu(out, motion, elapsed_ns, sensors=("accelerometer", "gyroscope"))


def test_a_repeated_timestamp_is_dropped_with_a_warning(tmp_path, capsys):
    acc, gyro, mag, fixes = static_log()
    lines = gnsslogger_lines(acc, gyro, mag, fixes)
    first_gyro = next(i for i, line in enumerate(lines) if line.startswith("Gyro,"))
    lines.insert(first_gyro + 1, lines[first_gyro])
    log = write_lines(tmp_path / "gnss_log.txt", lines)
    err = _import(capsys, str(log), "-o", str(tmp_path / "sensors.h5"))
    assert "1 sample(s) with a repeated timestamp dropped" in err and f"line {first_gyro + 2})" in err


def test_a_fix_takes_the_c_n0_of_the_nearest_status_report_within_the_window(tmp_path):
    """Real logs seldom stamp a fix and its Status report with the same millisecond: a fix takes the mean C/N0 of
    the signals used (one not used does not count) of the Status report nearest its UTC time within
    CN0_JOIN_WINDOW_MS, NaN where none is that close (noted, with the count)."""
    acc, gyro, mag, fixes = static_log(seconds=6.0)
    lines = gnsslogger_lines(acc, gyro, mag, fixes, flp=False)
    time_field = 1 + GNSSLOGGER_HEADERS["Fix"].index("UnixTimeMillis")
    fix_ms = [line.split(",")[time_field] for line in lines if line.startswith("Fix,")]
    # Fix 1's report moved past the window (and nearer no other fix than that fix's own), fix 4's within it.
    shift = {fix_ms[1]: CN0_JOIN_WINDOW_MS + 200, fix_ms[4]: CN0_JOIN_WINDOW_MS - 200}
    for i, line in enumerate(lines):
        fields = line.split(",")
        if fields[0] == "Status" and fields[1] in shift:
            lines[i] = ",".join([fields[0], str(int(fields[1]) + shift[fields[1]]), *fields[2:]])
    log = read_gnsslogger(write_lines(tmp_path / "gnss_log.txt", lines))
    expected = fixes.cn0_dbhz.copy()
    expected[1] = np.nan
    np.testing.assert_allclose(log.fixes.cn0_dbhz, expected, rtol=0, atol=1e-12)
    assert any(f"1 of {len(expected)} fixes have no C/N0" in note for note in log.notes)


@pytest.mark.parametrize("platform", ["android", "ios"])
def test_a_device_name_with_a_comma_is_one_quoted_field(tmp_path, platform):
    """Sensor Logger quotes a Metadata.csv field holding a comma: read as one field, the platform after it is
    read too (iOS: the acceleration's sign reversed to Android's)."""
    acc, gyro, mag, fixes = static_log()
    folder = write_sensor_logger(tmp_path / "export", acc, gyro, mag, fixes, gravity_split=True,
                                 ios=platform == "ios", device_name="Pixel 7, work phone")
    assert ',"Pixel 7, work phone",' in (folder / METADATA).read_text()
    log = read_phone_log([folder])
    assert any("iOS acceleration frame" in note for note in log.notes) is (platform == "ios")
    np.testing.assert_allclose(log.accelerometer.values, acc.values, rtol=0, atol=1e-12)


def test_an_old_fix_header_without_elapsed_time_uses_utc(tmp_path):
    """Versions of the app before elapsedRealtimeNanos in Fix rows: the fix time comes from its UTC time."""
    acc, gyro, mag, fixes = static_log(seconds=3.0)
    lines = gnsslogger_lines(acc, gyro, mag, fixes, flp=False)
    old = []
    for line in lines:
        if line.startswith("# Fix,"):
            line = "# Fix,Provider,Latitude,Longitude,Altitude,Speed,Accuracy,(UTC)TimeInMs"
        elif line.startswith("Fix,"):
            f = line.split(",")
            line = ",".join([f[0], "gps", f[2], f[3], f[4], f[5], f[6], f[8]])
        old.append(line)
    log = read_gnsslogger(write_lines(tmp_path / "gnss_log.txt", old))
    assert np.abs(log.fixes.t_ns - elapsed_ns(fixes.t_s)).max() <= 1_000_000
    assert np.array_equal(log.fixes.lat_deg, fixes.lat_deg)


def _parsed(lines: list[str], newline: str) -> tuple:
    with tempfile.TemporaryDirectory() as folder:
        log = read_gnsslogger(write_lines(Path(folder) / "gnss_log.txt", lines, newline))
    series = [log.accelerometer, log.gyroscope, log.magnetometer]
    return (tuple((s.t_ns.tobytes(), s.values.tobytes()) for s in series),
            log.fixes.t_ns.tobytes(), log.fixes.lat_deg.tobytes(), log.fixes.cn0_dbhz.tobytes(), log.utc_offset_ns)


_SHORT = static_log(seconds=1.5, rate_hz=20.0)
_REFERENCE = _parsed(gnsslogger_lines(*_SHORT), "\n")


@settings(max_examples=25, deadline=None)
@given(order=st.permutations(ROW_TYPES), newline=st.sampled_from(["\n", "\r\n"]))
def test_header_order_and_line_endings_do_not_matter(order, newline):
    assert _parsed(gnsslogger_lines(*_SHORT, row_types=tuple(order)), newline) == _REFERENCE


SENSORS_ONLY = """
import json, sys
from dtmbnav.cli import main
code = main(["-q", "sensors", sys.argv[1], "-o", sys.argv[2]])
print(json.dumps({"code": code, "sim": sorted(m for m in sys.modules if m == "sim" or m.startswith("sim."))}))
"""


def test_the_sensors_command_never_imports_the_simulator(tmp_path):
    log = write_lines(tmp_path / "gnss_log.txt", gnsslogger_lines(*static_log()))
    result = subprocess.run([sys.executable, "-c", SENSORS_ONLY, str(log), str(tmp_path / "sensors.h5")],
                            capture_output=True, text=True, timeout=300, cwd=ROOT, check=False)
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout.strip().splitlines()[-1])
    assert outcome == {"code": 0, "sim": []}


def test_a_tower_by_latitude_and_longitude_lands_in_the_sensors_frame(motion, tmp_path, capsys, monkeypatch):
    log = _write_gnsslogger(tmp_path, motion)
    sensors = tmp_path / "sensors.h5"
    _import(capsys, "-q", str(log), "-o", str(sensors), "--origin", ",".join(map(str, ORIGIN)))
    tower = (30.54, 114.38, 150.0)
    e, n, u = pymap3d.geodetic2enu(*tower, *ORIGIN)
    assert tower_in_sensors_frame(sensors, GeodeticPoint(*tower)) == pytest.approx((e, n, u), abs=1e-6)
    assert tower_in_sensors_frame(sensors, GeodeticPoint(*tower[:2]))[2] == 0.0  # no height: as --tower X,Y
    seen = {}

    def fake_fuse(receiver, sensors_path, out, **kwargs):
        seen.update(kwargs)
        raise ValueError("stop here")

    monkeypatch.setattr("dtmbnav.chain.fuse.fuse_files", fake_fuse)
    rx = tmp_path / "rx.h5"
    rx.write_bytes(b"")
    code = main(["-q", "fuse", "--receiver", str(rx), "--sensors", str(sensors), "-o", str(tmp_path / "f.h5"),
                 "--tower-ll", ",".join(map(str, tower))])
    assert code == 3 and "stop here" in capsys.readouterr().err
    assert seen["tower_xy_m"] == pytest.approx((e, n), abs=1e-6) and seen["tower_height_m"] == pytest.approx(u)
    assert math.isfinite(seen["tower_height_m"])
