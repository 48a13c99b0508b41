"""``dtmbnav simulate --phone-log``: the walk as a phone app logs it, read back by ``dtmbnav sensors``.

The tiny walk is simulated with the phone's clock 0.7 s ahead of the capture's and running 20 ppm fast,
in both formats, and imported with ``dtmbnav sensors`` about the scenario's origin: the imported ``/imu``
must be the simulator's own IMU (``truth.h5``) seen through that clock, the fixes its GNSS fixes, the
recorded start UTC the phone's at the log's start (so the offset shows against the capture's
``core:datetime``); ``towers.csv`` must put every tower back at its ENU position.
"""

from __future__ import annotations

import csv
import datetime
import json

import h5py
import numpy as np
import pytest
from conftest import TINY_WALK

from dtmbnav.cli import EXIT_OK, EXIT_USAGE, main
from dtmbnav.field.phone_logs import read_phone_log
from dtmbnav_core import schema
from dtmbnav_core.geodetic import to_enu
from dtmbnav_core.phone import PHONE_LOG_FORMATS, PhoneClock
from dtmbnav_core.records import ImuLog
from dtmbnav_core.sensors import read_gnss, read_imu

OFFSET_S, DRIFT_PPM = 0.7, 20.0
CLOCK = PhoneClock(OFFSET_S, DRIFT_PPM)
#: Where the capture starts on the scenario's clock, and its length, s.
CAPTURE_START_S, CAPTURE_SECONDS = 1.0, 0.1
COLUMNS = ("acc_mps2", "gyro_radps", "mag_ut")


def _scenario():
    from sim.scenario import load_scenario

    return load_scenario(TINY_WALK)


def _log_path(out, phone_log):
    """The GnssLogger file, or the Sensor Logger export's folder, that simulate wrote into ``out``."""
    found = sorted(out.glob("gnss_log_*.txt")) if phone_log == "gnsslogger" else [p for p in out.iterdir() if p.is_dir()]
    assert len(found) == 1, sorted(p.name for p in out.iterdir())
    return found[0]


@pytest.fixture(scope="module", params=PHONE_LOG_FORMATS)
def walk(request, tmp_path_factory):
    """The tiny walk simulated with a phone log of one format, and that log imported by ``dtmbnav sensors``."""
    phone_log = request.param
    out = tmp_path_factory.mktemp(phone_log)
    assert main(["-q", "simulate", str(TINY_WALK), "-o", str(out), "--start", str(CAPTURE_START_S), "--seconds",
                 str(CAPTURE_SECONDS), "--phone-log", phone_log, "--phone-clock-offset", str(OFFSET_S),
                 "--phone-clock-drift", str(DRIFT_PPM)]) == EXIT_OK
    origin = _scenario().origin
    sensors = out / "sensors.h5"
    assert main(["-q", "sensors", str(_log_path(out, phone_log)), "-o", str(sensors), "--origin",
                 f"{origin.lat_deg!r},{origin.lon_deg!r},{origin.height_m!r}"]) == EXIT_OK
    return {"format": phone_log, "out": out, "sensors": sensors, "truth": out / "truth.h5"}


def test_the_imported_imu_is_the_simulated_one_through_the_phone_clock(walk):
    imported, truth = read_imu(walk["sensors"]), read_imu(walk["truth"])
    # The log starts at the scenario's time 0; the grid's t_s runs on the phone's clock.
    t_true = CLOCK.reference_s(imported.t_s)
    assert imported.t_s[-1] == pytest.approx(truth.t_s[-1] * CLOCK.rate, abs=0.01)
    for column in COLUMNS:
        expected = np.column_stack([np.interp(t_true, truth.t_s, getattr(truth, column)[:, k]) for k in range(3)])
        np.testing.assert_allclose(getattr(imported, column), expected, rtol=0, atol=1e-6, err_msg=column)
    with h5py.File(walk["sensors"]) as f:
        assert f[schema.IMU].attrs[schema.HAS_MAGNETOMETER_ATTR]


def test_the_imported_fixes_are_the_simulated_ones(walk):
    imported, _ = read_gnss(walk["sensors"])
    truth, _ = read_gnss(walk["truth"])
    np.testing.assert_allclose(CLOCK.reference_s(imported.t_s), truth.t_s, rtol=0, atol=1e-8)
    np.testing.assert_allclose(imported.x_m, truth.x_m, rtol=0, atol=1e-3)
    np.testing.assert_allclose(imported.y_m, truth.y_m, rtol=0, atol=1e-3)
    with h5py.File(walk["sensors"]) as f:
        up = f[schema.GNSS]["z_m"][()]
    np.testing.assert_allclose(up, _scenario().channel.antenna_height_m, rtol=0, atol=1e-3)
    if walk["format"] == "gnsslogger":  # the mean C/N0 of its Status rows
        np.testing.assert_allclose(imported.cn0_dbhz, truth.cn0_dbhz, rtol=0, atol=1e-9)
    else:  # Sensor Logger's Location.csv has no C/N0
        assert np.isnan(imported.cn0_dbhz).all()


def test_the_start_utc_is_the_phone_clock_against_the_capture_datetime(walk):
    from sim.simulate import SIM_START_UTC_NS

    with h5py.File(walk["sensors"]) as f:
        start_utc_ns = int(f[schema.IMU].attrs[schema.START_UTC_NS_ATTR])
    # GnssLogger's UTC stamps are whole ms: the reader's offset is good to half of one.
    tolerance_ns = 600_000 if walk["format"] == "gnsslogger" else 0
    assert abs(start_utc_ns - (SIM_START_UTC_NS + round(OFFSET_S * 1e9))) <= tolerance_ns
    meta = json.loads(next(walk["out"].glob("*.sigmf-meta")).read_text())
    capture = datetime.datetime.fromisoformat(meta["captures"][0]["core:datetime"])
    capture_ns = int(capture.replace(microsecond=0).timestamp()) * 1_000_000_000 + capture.microsecond * 1000
    assert abs(start_utc_ns - capture_ns - round((OFFSET_S - CAPTURE_START_S) * 1e9)) <= tolerance_ns


def test_the_towers_file_round_trips_to_the_scenario_enu(walk, tmp_path):
    from sim.scenario import load_scenario
    from sim.towers_csv import write_towers_csv

    for scenario, path in ((_scenario(), walk["out"] / "towers.csv"),
                           (load_scenario("sfn3-park"), write_towers_csv(tmp_path, load_scenario("sfn3-park")))):
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        assert tuple(rows[0]) == schema.TOWERS_CSV_COLUMNS
        sites = scenario.sites
        assert [row["name"] for row in rows] == [f"tower{i}" for i in range(len(sites))]
        east, north, up = to_enu(*(np.array([float(row[key]) for row in rows]) for key in
                                   ("lat_deg", "lon_deg", "height_m")), scenario.origin.point)
        np.testing.assert_allclose(east, [s.x_m for s in sites], rtol=0, atol=1e-3)
        np.testing.assert_allclose(north, [s.y_m for s in sites], rtol=0, atol=1e-3)
        np.testing.assert_allclose(up, [s.height_m for s in sites], rtol=0, atol=1e-3)
        assert [float(row["channel_hz"]) for row in rows] == [scenario.tower.carrier_hz] * len(sites)
        assert [float(row["transmit_delay_s"]) for row in rows] == [s.transmit_delay_s for s in sites]
        assert [float(row["transmit_delay_sigma_s"]) for row in rows] == [scenario.network.plan_error_s] * len(sites)


@pytest.mark.parametrize("phone_log", PHONE_LOG_FORMATS)
@pytest.mark.parametrize("no_field", [np.nan, 0.0])
def test_an_imu_without_a_magnetometer_writes_no_magnetometer(phone_log, no_field, tmp_path):
    from sim.gnss import simulate_gnss
    from sim.imu import simulate_imu
    from sim.phone_log_writer import write_phone_log
    from sim.walk import simulate_walk

    scenario = _scenario()
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    imu = ImuLog(t_s=imu.t_s, acc_mps2=imu.acc_mps2, gyro_radps=imu.gyro_radps,
                 mag_ut=np.full_like(imu.mag_ut, no_field))
    path = write_phone_log(phone_log, tmp_path, scenario, imu, simulate_gnss(scenario, walk), CLOCK, 0)
    log = read_phone_log([path])
    assert log.magnetometer is None
    assert len(log.accelerometer.t_ns) == len(imu.t_s)


def test_an_unknown_phone_log_format_is_a_usage_error(tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["-q", "simulate", str(TINY_WALK), "--no-iq", "-o", str(out), "--phone-log", "gpslogger"])
    assert exc.value.code == EXIT_USAGE
    assert "--phone-log" in capsys.readouterr().err
    assert main(["-q", "simulate", str(TINY_WALK), "--no-iq", "-o", str(out), "--phone-clock-offset", "0.7"]) \
        == EXIT_USAGE
    assert "need --phone-log" in capsys.readouterr().err
    assert not out.exists()
