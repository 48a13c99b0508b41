"""A Sensor Logger export's platform (its acceleration's sign) without Metadata.csv, and fixes without C/N0.

Issue 59: an export without ``Metadata.csv`` is told iOS or Android from the Earth's field's dip against
gravity where that is unambiguous (``dtmbnav.field.platform``), else refused naming ``--platform``; the
/imu it gives is the one the export with its Metadata.csv gives. Fixes without C/N0 are weighted by their
stated accuracy (``fusion.adaptive_kf.GnssFixes``), and the reader says how many there are, once.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import TINY_WALK
from phone_log_samples import Stream, fixes_of, write_sensor_logger

from dtmbnav.cli import EXIT_OK, main
from dtmbnav.field import platform
from dtmbnav.field.phone_logs import read_sensor_logger
from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS
from dtmbnav_core.sensors import read_imu
from fusion.adaptive_kf import GRADE_FACTORS, GnssFixes

WUHAN_LAT_DEG = 30.5


@pytest.fixture(scope="module")
def walk_streams():
    """The tiny walk's IMU as three 100 Hz streams, and a fix a second at Wuhan's latitude (the simulator's
    Earth field dips 45 deg down there)."""
    from sim.imu import simulate_imu
    from sim.scenario import load_scenario
    from sim.walk import simulate_walk

    scenario = load_scenario(TINY_WALK)
    imu = simulate_imu(scenario, simulate_walk(scenario))
    step = max(1, round(0.01 / float(np.median(np.diff(imu.t_s)))))
    t = imu.t_s[::step]
    streams = [Stream(t, values[::step]) for values in (imu.acc_mps2, imu.gyro_radps, imu.mag_ut)]
    fix_t = np.arange(0.0, float(t[-1]), 1.0)
    n = len(fix_t)
    fixes = fixes_of(fix_t, np.full(n, WUHAN_LAT_DEG), np.full(n, 114.3), np.full(n, 20.0), np.full(n, 3.5))
    return streams, fixes


def _import(capsys, folder, out, *extra: str) -> str:
    code = main(["sensors", str(folder), "-o", str(out), *extra])
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    return err


@pytest.mark.parametrize("ios", [True, False], ids=["ios", "android"])
def test_an_export_without_metadata_gives_the_imu_of_the_one_with_it(walk_streams, tmp_path, capsys, ios):
    """Gravity split (no TotalAcceleration.csv, which would say Android): the dip says the platform."""
    (acc, gyro, mag), fixes = walk_streams
    folder = write_sensor_logger(tmp_path / "export", acc, gyro, mag, fixes, gravity_split=True, ios=ios)
    _import(capsys, folder, tmp_path / "stated.h5")
    (folder / "Metadata.csv").unlink()
    err = _import(capsys, folder, tmp_path / "detected.h5")
    assert f"carries {'ios' if ios else 'android'}'s sign" in err
    stated, detected = read_imu(tmp_path / "stated.h5"), read_imu(tmp_path / "detected.h5")
    np.testing.assert_array_equal(detected.acc_mps2, stated.acc_mps2)
    # Android's sign, the simulated specific force's: the means agree (iOS's would be their opposite).
    np.testing.assert_allclose(detected.acc_mps2.mean(axis=0), acc.values.mean(axis=0), atol=0.05)


def test_given_platform_gives_the_same_imu_as_metadata(walk_streams, tmp_path, capsys):
    (acc, gyro, mag), fixes = walk_streams
    folder = write_sensor_logger(tmp_path / "export", acc, gyro, mag, fixes, gravity_split=True, ios=True)
    _import(capsys, folder, tmp_path / "stated.h5")
    (folder / "Metadata.csv").unlink()
    err = _import(capsys, folder, tmp_path / "given.h5", "--platform", "ios")
    assert "dip" not in err
    np.testing.assert_array_equal(read_imu(tmp_path / "given.h5").acc_mps2, read_imu(tmp_path / "stated.h5").acc_mps2)


def _still(field_ut: tuple[float, float, float], sign: float = 1.0, n: int = 200):
    """A still phone face up (Android's sign times ``sign``) in the field ``field_ut``: force, times, field."""
    t_ns = np.arange(n, dtype=np.int64) * 10_000_000
    return sign * np.tile([0.0, 0.0, 9.81], (n, 1)), t_ns, np.tile(field_ut, (n, 1)), t_ns


@pytest.mark.parametrize(("latitude", "field_z", "sign", "expected"), [
    (30.0, -40.0, 1.0, platform.ANDROID),   # north: the field dips down, against the force up
    (30.0, -40.0, -1.0, platform.IOS),
    (-35.0, 40.0, 1.0, platform.ANDROID),   # south: the field points up, with the force
    (-35.0, 40.0, -1.0, platform.IOS),
])
def test_the_dip_and_the_hemisphere_give_the_sign(latitude, field_z, sign, expected):
    force, t_ns, field, field_t = _still((20.0, 0.0, field_z), sign)
    assert platform.platform_from_data(force, t_ns, field, field_t, np.array([latitude]), "x") == expected


def test_a_field_too_flat_to_say_is_refused_naming_the_option():
    # Inclination asin(5 / 40.3) = 7 deg: below the 15 deg taken as evidence.
    force, t_ns, field, field_t = _still((40.0, 0.0, -5.0))
    with pytest.raises(ValueError, match=r"x: no platform .*dip against gravity \(7 deg.*--platform android"):
        platform.platform_from_data(force, t_ns, field, field_t, np.array([30.0]), "x")


def test_metadata_and_the_given_platform_must_agree():
    assert platform.check_given(None, platform.IOS, "x") == platform.IOS
    assert platform.check_given(platform.IOS, None, "x") == platform.IOS
    with pytest.raises(ValueError, match="x: --platform android, but Metadata.csv says .* ios's sign"):
        platform.check_given(platform.ANDROID, platform.IOS, "x")


# --- fixes without C/N0 ---------------------------------------------------------------------------------

def test_a_fix_without_cn0_is_weighted_by_its_stated_accuracy():
    """Known answer: sigma_m^2 times the grade where C/N0 is given; (accuracy / 1.51)^2 where not; sigma_m^2
    where neither is."""
    cn0 = np.array([40.0, np.nan, 40.0, np.nan])
    accuracy = np.array([9.0, 4.5, 9.0, np.nan])
    fixes = GnssFixes(np.arange(4.0), np.zeros(4), np.zeros(4), cn0, sigma_m=3.0, accuracy_m=accuracy)
    expected = [9.0 * GRADE_FACTORS[0], (4.5 / ACCURACY_RADIUS_SIGMAS) ** 2, 9.0 * GRADE_FACTORS[0], 9.0]
    np.testing.assert_allclose(fixes.variances_m2(), expected, rtol=1e-12)
    assert math.sqrt(fixes.variances_m2()[1]) == pytest.approx(2.981, abs=1e-3)
    # Without stated accuracies the fixes weigh as before: a NaN C/N0 is graded good.
    np.testing.assert_allclose(replace(fixes, accuracy_m=None).variances_m2(), [9.0] * 4)


def test_the_reader_says_once_how_many_fixes_have_no_cn0(walk_streams, tmp_path):
    (acc, gyro, mag), fixes = walk_streams
    folder = write_sensor_logger(tmp_path / "export", acc, gyro, mag, fixes)
    notes = [note for note in read_sensor_logger([folder]).notes if "C/N0" in note]
    n = len(fixes.t_s)
    expected = (f"{folder / 'Location.csv'}: {n} of {n} fixes have no C/N0 (Sensor Logger logs none): weighted by "
                f"their stated accuracy (per-axis sigma = accuracy / {ACCURACY_RADIUS_SIGMAS:.2f})")
    assert notes == [expected]
