"""The field path against the simulator's own files: a phone's log and a capture with its start time.

Each walk is simulated once with its capture and the phone's own log in each
app's format (:data:`PHONE_LOG_FORMATS`), on a phone clock :data:`CLOCK`
off the capture's start time and drifting; then, as a user with a recording
would, the commands ``sensors`` -> ``receive`` -> ``fuse --tower-ll`` ->
``report`` run on those files alone. The same walk is fused from the
simulator's own files (``truth.h5``, the capture's recorded start) with the
same start fix (the one ``sensors`` chose, put into the scenario's frame),
so what differs is only what the field path adds: the phone's formats and
clock, the resampling, the geodetic frames and the time alignment. Scored:
each filter's 95 % horizontal error against the truth (the field run's
through its latitude and longitude) and the time offset ``fuse`` found
against the true one.

Run ``python -m dtmbnav.evaluation.field_check``; ``dtmbnav results --sections field``
prints it into docs/results.md.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from dtmbnav.evaluation.distributed import ClusterConfig, Task, run_tasks
from dtmbnav.evaluation.evaluate import seed_scenario
from dtmbnav.evaluation.seeds import TUNING_SEEDS
from dtmbnav.field.towers import read_towers
from dtmbnav.simulation.capture_set import receiver_clock_model
from dtmbnav_core import schema
from dtmbnav_core.geodetic import GeodeticPoint, read_origin, to_enu, to_geodetic
from dtmbnav_core.phone import PHONE_LOG_FORMATS, PhoneClock
from dtmbnav_core.records import Track
from dtmbnav_core.sensors import read_capture_start_s, read_gnss, read_walk_truth, read_weinberg_k_m
from fusion.metrics import error_stats, position_errors_m

#: The walks the field path is checked on (the issue's two: a park loop and a street).
SCENARIOS = ("park-loop-cw", "street-out")
#: Walks of each scenario, from the tuning range (their layouts kept).
WALKS = 2
#: The phone's clock against the capture's: offset, s, and drift, ppm.
CLOCK = PhoneClock(offset_s=0.7, drift_ppm=20.0)
#: Largest ratio of a field run's 95 % error to the same walk's from the simulator's files.
TOLERANCE = 1.05
#: Largest error of the time offset found, s.
MAX_OFFSET_ERROR_S = 0.02


@dataclass(frozen=True)
class FieldRun:
    """One walk through both paths.

    Attributes
    ----------
    label : str
        Scenario and walk.
    own_p95_m : dict of str -> float
        Each filter's 95 % error fused from the simulator's own files, m.
    field_p95_m : dict of str -> dict of str -> float
        The same from each phone format's log, m.
    offset_error_s : dict of str -> float
        Time offset found minus the true one, per phone format, s.
    offset_sigma_s : dict of str -> float
        Its stated 1-sigma uncertainty, s.
    """

    label: str
    own_p95_m: dict[str, float]
    field_p95_m: dict[str, dict[str, float]]
    offset_error_s: dict[str, float]
    offset_sigma_s: dict[str, float]


def _cli(*argv: str) -> None:
    """Run a ``dtmbnav`` command as a user does: a process of its own."""
    done = subprocess.run([sys.executable, "-m", "dtmbnav.cli", "-q", *argv], capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"dtmbnav {' '.join(argv)} exited {done.returncode}: {done.stderr.strip()}")


def p95_errors_m(results: Path, truth_path: Path, origin: GeodeticPoint | None) -> dict[str, float]:
    """Each filter's 95 % horizontal error against the truth track, m (:func:`fusion.metrics.error_stats`);
    with ``origin``, the track's latitude and longitude put into the scenario's frame about it (a field
    run's), else its own x, y.

    Raises
    ------
    ValueError
        A track with an epoch outside the truth's span (a field run's times are on the phone's clock, which
        runs fast: past the truth's end, it would be scored against a truth held still), naming the file
        and the filter.
    """
    truth = read_walk_truth(truth_path).track
    errors = {}
    with h5py.File(results, "r") as f:
        for name in f[schema.FUSION]:
            group = f[schema.fusion_group(name)]
            track = Track(**{column: group[column][:] for column in schema.TRACK_COLUMNS})
            if origin is not None:
                x, y, _ = to_enu(group["lat_deg"][:], group["lon_deg"][:], np.zeros(len(track)), origin)
                track = replace(track, x_m=x, y_m=y)
            try:
                errors_m = position_errors_m(track, truth)
            except ValueError as exc:
                raise ValueError(f"{results}: {name}: not scored: its epochs leave the span of the truth "
                                 f"{truth_path}, which is not extrapolated ({exc})") from None
            errors[name] = error_stats(errors_m).p95_m
    return errors


def _start_in_scenario_frame(sensors_path: Path, origin: GeodeticPoint) -> tuple[float, float]:
    """The start fix ``sensors`` chose, in the scenario's frame, m."""
    fix = read_gnss(sensors_path)[1]
    lat, lon = to_geodetic(np.array([fix.x_m]), np.array([fix.y_m]), 0.0, read_origin(sensors_path))
    east, north, _ = to_enu(lat, lon, np.zeros(1), origin)
    return float(east[0]), float(north[0])


def run_walk(name: str, k: int) -> FieldRun:
    """Walk ``k`` of scenario ``name`` through the field path (both phone formats) and the simulator's files."""
    from dtmbnav.simulation.capture_set import simulate_capture_set
    from sim.scenario import load_scenario

    scenario = seed_scenario(load_scenario(name), k, first_seed=TUNING_SEEDS.start, vary_geometry=False)
    origin = scenario.origin.point
    field, errors, sigmas = {}, {}, {}
    with tempfile.TemporaryDirectory(prefix="dtmbnav-field-") as tmp:
        folder = Path(tmp)
        logs = {}
        for i, app in enumerate(PHONE_LOG_FORMATS):
            out = folder / app
            result = simulate_capture_set(scenario, out, with_iq=i == 0, phone_log=app, phone_clock=CLOCK)
            logs[app] = result.phone_log_path
            if i == 0:
                capture, truth = result.capture_path, result.truth_path
        _cli("receive", str(capture), "-o", str(folder / "rx.h5"))
        tower = read_towers(folder / PHONE_LOG_FORMATS[0] / "towers.csv")[0]
        # What a user knows of their own walk: the tower, their SDR's clock and their calibrated step gain.
        known = ["--tower-ll", f"{tower.lat_deg!r},{tower.lon_deg!r},{tower.height_m!r}", "--clock-model",
                 receiver_clock_model(scenario), "--weinberg-k", repr(read_weinberg_k_m(truth))]
        true_offset_s = read_capture_start_s(truth) * (1.0 + CLOCK.drift_ppm * 1e-6)
        for app in PHONE_LOG_FORMATS:
            sensors, fused = folder / f"sensors-{app}.h5", folder / f"fused-{app}.h5"
            _cli("sensors", str(logs[app]), "-o", str(sensors))
            _cli("fuse", "--receiver", str(folder / "rx.h5"), "--sensors", str(sensors), *known, "-o", str(fused))
            _cli("report", str(fused), "-o", str(folder / f"report-{app}"))
            field[app] = p95_errors_m(fused, truth, origin)
            with h5py.File(fused, "r") as f:
                attrs = f[schema.FUSION].attrs
                errors[app] = float(attrs["time_offset_s"]) - true_offset_s
                sigmas[app] = float(attrs["time_offset_sigma_s"])
        start = _start_in_scenario_frame(folder / f"sensors-{PHONE_LOG_FORMATS[0]}.h5", origin)
        _cli("fuse", "--receiver", str(folder / "rx.h5"), "--sensors", str(truth), f"--start={start[0]},{start[1]}",
             "--clock-model", receiver_clock_model(scenario), "-o", str(folder / "own.h5"))
        own = p95_errors_m(folder / "own.h5", truth, None)
    return FieldRun(f"{name} walk {k}", own, field, errors, sigmas)


def check(walks: int = WALKS, cluster: ClusterConfig = ClusterConfig(), progress: bool = False) -> list[FieldRun]:
    """Every walk of :data:`SCENARIOS` through both paths, where ``cluster`` says."""
    tasks = [Task(f"{name} walk {k}", run_walk, (name, k)) for name in SCENARIOS for k in range(walks)]
    outcome = run_tasks(tasks, cluster, progress, "field path")
    if outcome.failures:
        raise RuntimeError("field path: walks failed: " + "; ".join(f"{f.label}: {f.error}" for f in outcome.failures))
    return list(outcome.results)


def field_table(runs: list[FieldRun]) -> tuple[str, int]:
    """The Markdown table of the runs, and how many rows fail (a ratio over :data:`TOLERANCE` or an offset
    error over :data:`MAX_OFFSET_ERROR_S`)."""
    lines = ["| walk | phone log | PF 95 %, m: field / own (ratio) | UKF 95 %, m: field / own (ratio) | "
             "time offset error, ms (stated 1-sigma) | verdict |", "|---" * 6 + "|"]
    failed = 0
    for run in runs:
        for app, errors in run.field_p95_m.items():
            ratios = {name: errors[name] / run.own_p95_m[name] for name in ("pf", "ukf")}
            bad = [f"{name.upper()} ratio" for name, ratio in ratios.items() if ratio > TOLERANCE]
            if abs(run.offset_error_s[app]) > MAX_OFFSET_ERROR_S:
                bad.append("time offset")
            failed += bool(bad)
            cells = " | ".join(f"{errors[name]:.2f} / {run.own_p95_m[name]:.2f} ({ratios[name]:.2f})"
                               for name in ("pf", "ukf"))
            lines.append(f"| {run.label} | {app} | {cells} | {1e3 * run.offset_error_s[app]:+.1f} "
                         f"({1e3 * run.offset_sigma_s[app]:.0f}) | {'FAIL: ' + ', '.join(bad) if bad else 'pass'} |")
    return "\n".join(lines), failed


def describe() -> str:
    """What the table shows, for docs/results.md."""
    return (f"{', '.join(SCENARIOS)}, {WALKS} walks each (tuning range, layouts kept), C/N as in the scenario; the "
            f"phone's clock {CLOCK.offset_s:g} s off the capture's start time and {CLOCK.drift_ppm:g} ppm fast. "
            "Field: `simulate --phone-log` -> `sensors` -> `receive` -> `fuse --tower-ll` -> `report` on those files "
            "alone; own: `fuse` on the simulator's `truth.h5` with the same start fix. A row passes with both "
            f"ratios at most {TOLERANCE:g} and the time offset within {1e3 * MAX_OFFSET_ERROR_S:g} ms of the truth.")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dtmbnav.evaluation.field_check",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--walks", type=int, default=WALKS, help=f"walks per scenario (default {WALKS})")
    args = parser.parse_args(argv)
    table, failed = field_table(check(args.walks, progress=True))
    print(describe() + "\n\n" + table)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
