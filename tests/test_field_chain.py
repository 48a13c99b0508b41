"""The field path end to end: a phone's own log and a capture with its start time, nothing of the simulator's.

``simulate --phone-log`` writes the tiny walk as a phone app logs it, on a phone clock 0.7 s off the
capture's ``core:datetime`` and 20 ppm fast; then ``sensors`` -> ``receive`` -> ``fuse --towers`` ->
``report`` run in a child process that must not import any ``sim`` module. The fused tracks must be
as good as the same walk fused from the simulator's own files, and the time alignment must find
that the capture and the log start together although their UTC stamps say 0.7 s apart.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from dtmbnav.cli import EXIT_OK, main
from dtmbnav.evaluation.field_check import p95_errors_m
from dtmbnav_core import schema
from sim.scenario import load_scenario

TINY_WALK = Path(__file__).parent / "data" / "tiny-walk.toml"
CLOCK_OFFSET_S, CLOCK_DRIFT_PPM = 0.7, 20.0
#: The field commands' child: runs ``dtmbnav`` and fails if any simulator module was imported.
CHILD = ("import sys; from dtmbnav.cli import main; code = main(sys.argv[1:]); "
         "bad = sorted(m for m in sys.modules if m == 'sim' or m.startswith('sim.')); "
         "print('imported ' + ', '.join(bad), file=sys.stderr) if bad else None; sys.exit(code or (9 if bad else 0))")


def _field_command(*args: str) -> None:
    done = subprocess.run([sys.executable, "-c", CHILD, "-q", *args], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    """The tiny walk simulated with its capture and both phone logs, received once."""
    out = tmp_path_factory.mktemp("field")
    clock = ["--phone-clock-offset", str(CLOCK_OFFSET_S), "--phone-clock-drift", str(CLOCK_DRIFT_PPM)]
    assert main(["-q", "simulate", str(TINY_WALK), "-o", str(out / "gnsslogger"), "--phone-log", "gnsslogger",
                 *clock]) == EXIT_OK
    assert main(["-q", "simulate", str(TINY_WALK), "--no-iq", "-o", str(out / "sensorlogger"), "--phone-log",
                 "sensorlogger", *clock]) == EXIT_OK
    _field_command("receive", str(out / "gnsslogger" / "tiny-walk.sigmf-meta"), "-o", str(out / "rx.h5"))
    assert main(["-q", "fuse", "--receiver", str(out / "rx.h5"), "--sensors", str(out / "gnsslogger" / "truth.h5"),
                 "-o", str(out / "own.h5"), "--step-model", "frequency"]) == EXIT_OK
    return out


@pytest.mark.slow
@pytest.mark.parametrize("app", ["gnsslogger", "sensorlogger"])
def test_a_phone_log_fuses_as_well_as_the_simulators_own_files(walk, app, tmp_path):
    # GnssLogger's text log, or Sensor Logger's export folder.
    logs = sorted(p for p in (walk / app).iterdir() if p.name.startswith("gnss_log") or p.is_dir())
    _field_command("sensors", *map(str, logs), "-o", str(tmp_path / "sensors.h5"))
    _field_command("fuse", "--receiver", str(walk / "rx.h5"), "--sensors", str(tmp_path / "sensors.h5"),
                   "--towers", str(walk / app / "towers.csv"), "-o", str(tmp_path / "fused.h5"))
    _field_command("report", str(tmp_path / "fused.h5"), "-o", str(tmp_path / "report"))
    with h5py.File(tmp_path / "fused.h5", "r") as f:
        alignment = dict(f[schema.FUSION].attrs)
    # The phone's UTC stamps put its log 0.7 s after the capture's start; both truly start together.
    assert alignment["time_offset_coarse_offset_s"] == pytest.approx(-CLOCK_OFFSET_S, abs=2e-3)
    assert alignment["time_offset_source"] == "fine"
    assert abs(alignment["time_offset_s"]) < 3 * alignment["time_offset_sigma_s"]
    truth = walk / "gnsslogger" / "truth.h5"
    field = p95_errors_m(tmp_path / "fused.h5", truth, load_scenario(TINY_WALK).origin.point)
    own = p95_errors_m(walk / "own.h5", truth, None)
    for name, error in own.items():
        assert field[name] <= 1.05 * error, (name, field[name], error)
    assert (tmp_path / "report" / "map.html").is_file() and (tmp_path / "report" / "tracks.gpx").is_file()
