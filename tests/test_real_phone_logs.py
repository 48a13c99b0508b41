"""Real GnssLogger logs (gnss_lib_py's test data, ``tests/data/real_logs/README.md``) through ``dtmbnav sensors``.

Each log is either read, and what comes out checked against physics (gravity's magnitude at rest, fixes of a
phone standing still close together, rates as logged), or refused with one line naming the file and why.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_OK, main
from dtmbnav.field.phone_logs import read_phone_log
from dtmbnav_core import schema
from dtmbnav_core.constants import GRAVITY_MPS2
from dtmbnav_core.geodetic import GeodeticPoint, to_enu

LOGS = Path(__file__).parent / "data" / "real_logs"


@pytest.mark.parametrize(("name", "code", "words"), [
    # One row of each sensor and no Fix row: no fixes is only a warning now, one sample is refused.
    ("all_sensors.txt", EXIT_BAD_INPUT, ["(Accel rows)", "1 sample(s)", "at least two"]),
    # Ten UncalAccel rows over 508 s: refused with its rate, never interpolated into 50 862 samples.
    ("pixel6.txt", EXIT_BAD_INPUT, ["(UncalAccel rows)", "accelerometer sampled at 0.0177 Hz", "10 samples",
                                    "508.7 s", "below the 20 Hz"]),
    # Raw measurements (and a Mag row) alone.
    ("filter_test.txt", EXIT_BAD_INPUT, ["no accelerometer rows"]),
    ("google_decimeter_2023_pixel7pro_gnss_log.txt", EXIT_BAD_INPUT, ["no accelerometer rows"]),
    # GnssLogger v2: Fix rows without elapsedRealtimeNanos; Status reports a minute after the fixes.
    ("google_decimeter_2021_Pixel4_GnssLog.txt", EXIT_OK, ["2 of 2 fixes have no C/N0", "provider GPS"]),
])
def test_a_real_log_is_read_or_refused_with_its_reason(tmp_path, capsys, name, code, words):
    log = LOGS / name
    out = tmp_path / "sensors.h5"
    assert main(["sensors", str(log), "-o", str(out)]) == code
    err = capsys.readouterr().err
    assert str(log) in err and "Traceback" not in err
    for word in words:
        assert word in err
    assert out.exists() == (code == EXIT_OK)
    if code != EXIT_OK:
        assert len([line for line in err.splitlines() if "error" in line]) == 1


def test_an_older_gnsslogger_log_is_physically_right(tmp_path):
    """Pixel 4, GnssLogger v2.0.4.2, lying still: the specific force is gravity (9.8 m/s^2), the sensors at their
    logged ~400 Hz (magnetometer ~100 Hz), the two GPS fixes a centimetre apart, and their times, which the v2
    Fix header gives on the UTC clock alone, placed on the sensors' clock by the UTC offset of the Accel rows."""
    log = read_phone_log([LOGS / "google_decimeter_2021_Pixel4_GnssLog.txt"])
    acc = log.accelerometer
    assert np.linalg.norm(acc.values, axis=1).mean() == pytest.approx(GRAVITY_MPS2, abs=0.1)
    for series, rate_hz in ((acc, 409.4), (log.gyroscope, 409.4), (log.magnetometer, 100.6)):
        assert 1e9 / np.median(np.diff(series.t_ns)) == pytest.approx(rate_hz, rel=0.01)
    fixes = log.fixes
    np.testing.assert_array_equal(fixes.t_ns, np.array([1589494247000, 1589494248000]) * 1_000_000
                                  - log.utc_offset_ns)
    east, north, _ = to_enu(fixes.lat_deg, fixes.lon_deg, fixes.height_m,
                            GeodeticPoint(fixes.lat_deg[0], fixes.lon_deg[0], fixes.height_m[0]))
    assert np.hypot(east, north).max() < 0.05
    assert np.isnan(fixes.cn0_dbhz).all()

    out = tmp_path / "sensors.h5"
    assert main(["-q", "sensors", str(LOGS / "google_decimeter_2021_Pixel4_GnssLog.txt"), "-o", str(out)]) == EXIT_OK
    with h5py.File(out) as f:
        # 51 ms of Accel rows: five grid samples, each with the sensor's noise (+-0.7 m/s^2 here).
        assert np.linalg.norm(f[schema.IMU]["acc_mps2"][()], axis=1).mean() == pytest.approx(GRAVITY_MPS2, abs=0.2)
        assert len(f[schema.GNSS]["t_s"]) == 2


def test_fixes_of_a_real_log_whose_sensors_are_refused_are_a_walk():
    """pixel6.txt (refused for its sensors' rate, not its fixes): 94 GPS fixes 6 s apart trace a walk of some
    200 m that comes back to its start, never faster than a walker, their stated accuracy a few metres."""
    fixes = read_phone_log([LOGS / "pixel6.txt"]).fixes
    east, north, _ = to_enu(fixes.lat_deg, fixes.lon_deg, fixes.height_m,
                            GeodeticPoint(fixes.lat_deg[0], fixes.lon_deg[0], float(fixes.height_m[0])))
    assert len(fixes.t_ns) == 94 and np.median(np.diff(fixes.t_ns)) == pytest.approx(6e9, rel=0.01)
    speed_mps = np.hypot(np.diff(east), np.diff(north)) / (np.diff(fixes.t_ns) / 1e9)
    assert speed_mps.max() < 3.0 and np.hypot(east[-1], north[-1]) < 10.0 < np.hypot(east, north).max()
    assert np.nanmedian(fixes.accuracy_m) < 10.0
