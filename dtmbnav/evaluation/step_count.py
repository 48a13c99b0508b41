"""Step counts on real phones: the Oxford step counter data set (the results' ``steps`` section).

The data set (Oxford-step-counter/DataSet on GitHub, CC BY 4.0; docs/evaluation.md
says how to fetch it) holds accelerometer traces of walks of a few hundred steps
with the phone in the hand, an armband, a front or back trouser pocket, a neck
pouch, a bag or purse, or a swinging arm, and the true steps from foot switches:

- ``optimisation/data/<walk>/``: ``accelerometer.csv`` (time since boot, ns; a
  sensor type; x, y, z in m/s^2) and ``stepcounter.csv`` (time, ns; one 0/1 column
  per foot switch). These are the tuning traces.
- ``validation/<user>_<carriage>_<start>.csv``: time (ns), x, y, z (m/s^2), then
  three running step counts: the data set's own app algorithm, the foot switches
  (the truth), and the phone's hardware step counter. These stay sealed for the
  table, like a reporting range.

A step of the truth is a foot switch closing. A switch that closes twice within
:data:`SWITCH_BOUNCE_S` is one step that bounced (one foot cannot step twice in
less than a stride): the tuning traces hold such bounces, which would otherwise
count a few per cent of steps that never were.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dtmbnav.evaluation.results_data import Prose, Table
from dtmbnav_core.resampling import interpolate, sample_timing, uniform_grid
from fusion.pdr.steps import StepDetectorConfig, detect_steps

#: Two closings of one foot switch closer than this are one step, s.
SWITCH_BOUNCE_S = 0.5
#: True steps of each short walk cut from a tuning walk's start and stop (:func:`start_and_stop`).
SHORT_WALK_STEPS = 25
#: How to get the data set (its validation traces are not in this repository).
FETCH_HINT = "git clone https://github.com/Oxford-step-counter/DataSet"


@dataclass(frozen=True)
class CountedWalk:
    """One walk's step counts.

    Attributes
    ----------
    name : str
        The walk (file or folder name).
    true_steps : int
        Steps of the foot switches.
    ours : int
        Steps :func:`fusion.pdr.steps.detect_steps` counts.
    app, hardware : int or None
        Steps the data set's app algorithm and the phone's hardware counter counted (validation traces
        only; None where that count never moved: not logged).
    """

    name: str
    true_steps: int
    ours: int
    app: int | None = None
    hardware: int | None = None


def _numeric_rows(path: Path) -> np.ndarray:
    """The rows of a CSV file that are all numbers (a header or a torn last line left out)."""
    rows = []
    with open(path, newline="") as f:
        for row in csv.reader(f):
            try:
                rows.append([float(cell) for cell in row])
            except ValueError:
                continue
    widths = {len(row) for row in rows}
    if not rows or len(widths) != 1:
        raise ValueError(f"{path}: expected rows of numbers of one width, found widths {sorted(widths)}")
    return np.array(rows)


def count_steps(t_ns: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig | None = None) -> int:
    """Steps detected in an accelerometer trace at uneven times (resampled to its mean rate first)."""
    t_s = (t_ns - t_ns[0]) / 1e9
    keep = np.concatenate([[True], np.diff(t_s) > 0])  # a repeated time stamp is one sample
    t_s, acc_mps2 = t_s[keep], acc_mps2[keep]
    grid = uniform_grid(float(t_s[0]), float(t_s[-1]), sample_timing(t_s).rate_hz)
    return len(detect_steps(grid, interpolate(t_s, acc_mps2, grid), config or StepDetectorConfig()).t_s)


def switch_steps(t_ns: np.ndarray, closed: np.ndarray) -> np.ndarray:
    """Times (ns) of one foot switch's closings, a bounce within :data:`SWITCH_BOUNCE_S` left out."""
    closings = t_ns[1:][np.diff(closed) == 1]
    steps: list[float] = []
    for t in closings:
        if not steps or t - steps[-1] >= SWITCH_BOUNCE_S * 1e9:
            steps.append(t)
    return np.array(steps)


def _tuning_recordings(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """A tuning walk's accelerometer rows and its true step times (ns), both over the time both recordings cover."""
    acc = _numeric_rows(folder / "accelerometer.csv")
    switches = _numeric_rows(folder / "stepcounter.csv")
    start, end = max(acc[0, 0], switches[0, 0]), min(acc[-1, 0], switches[-1, 0])
    truth = np.sort(np.concatenate([switch_steps(switches[:, 0], switches[:, k])
                                    for k in range(1, switches.shape[1])]))
    return acc[(acc[:, 0] >= start) & (acc[:, 0] <= end)], truth[(truth >= start) & (truth <= end)]


def tuning_walk(folder: Path, config: StepDetectorConfig | None = None) -> CountedWalk:
    """Counts of one ``optimisation/data/<walk>`` folder, over the time both recordings cover."""
    acc, truth = _tuning_recordings(folder)
    return CountedWalk(folder.name, len(truth), count_steps(acc[:, 0], acc[:, -3:], config))


def start_and_stop(folder: Path, steps: int = SHORT_WALK_STEPS,
                   config: StepDetectorConfig | None = None) -> tuple[CountedWalk, CountedWalk]:
    """Counts of a tuning walk's start and its stop: short walks of ``steps`` true steps.

    The start runs from the recording's first sample to a quarter of a second
    after the ``steps``-th true step, the stop from a quarter of a second before
    the ``steps``-th last to the recording's end: each holds the phone being put
    away or taken out, the walker setting off or stopping, and a cut in a walk.
    """
    acc, truth = _tuning_recordings(folder)
    halves = ((acc[0, 0], truth[steps - 1] + 0.25e9, "start"), (truth[-steps] - 0.25e9, acc[-1, 0], "stop"))
    counted = []
    for start, end, part in halves:
        inside = acc[(acc[:, 0] >= start) & (acc[:, 0] <= end)]
        true_steps = int(np.count_nonzero((truth >= start) & (truth <= end)))
        counted.append(CountedWalk(f"{folder.name} {part}", true_steps,
                                   count_steps(inside[:, 0], inside[:, -3:], config)))
    return counted[0], counted[1]


def short_walk_summary(walks: list[CountedWalk], within_steps: int = 2) -> str:
    """Markdown table: how many short walks are counted within ``within_steps`` steps, and the spread of the errors."""
    errors = np.array([w.ours - w.true_steps for w in walks])
    return "\n".join([
        "| short walks | true steps each | within 2 steps | error, steps: median / 5th / 95th percentile | worst |",
        "|---|---|---|---|---|",
        (f"| {len(walks)} | {walks[0].true_steps} | {int(np.sum(np.abs(errors) <= within_steps))} | "
         f"{np.median(errors):+.0f} / {np.percentile(errors, 5):+.0f} / {np.percentile(errors, 95):+.0f} | "
         f"{errors[np.argmax(np.abs(errors))]:+d} |")])


def validation_walk(path: Path, config: StepDetectorConfig | None = None) -> CountedWalk:
    """Counts of one ``validation/*.csv`` trace: ours, and the three running counts' increase over it."""
    rows = _numeric_rows(path)
    if rows.shape[1] != 7:
        raise ValueError(f"{path}: expected 7 columns (time, x, y, z, app, truth, hardware), found {rows.shape[1]}")
    app, truth, hardware = (int(rows[-1, k] - rows[0, k]) for k in (4, 5, 6))
    # A running count that never moves over a walk of hundreds of steps was not logged (None), not a count of 0.
    return CountedWalk(path.stem, truth, count_steps(rows[:, 0], rows[:, 1:4], config), app or None,
                       hardware or None)


def data_set_walks(root: Path, part: str) -> list[Path]:
    """The walks of ``part`` (``optimisation`` or ``validation``) under a checkout of the data set.

    Raises
    ------
    FileNotFoundError
        No such part there (with how to fetch the data set).
    """
    if part == "optimisation":
        walks = sorted(p for p in (root / part / "data").glob("*") if p.is_dir() and not p.name.startswith("_")
                       and (p / "accelerometer.csv").exists())
    else:
        walks = sorted((root / part).glob("*.csv"))
    if not walks:
        raise FileNotFoundError(f"{root}: no {part} walks of the Oxford step counter data set ({FETCH_HINT})")
    return walks


def error_percent(count: int | None, truth: int) -> str:
    """A count's error against the truth, per cent with a sign, or an em dash where there is no count."""
    return "—" if count is None else f"{100.0 * (count - truth) / truth:+.1f} %"


def step_count_table(walks: list[CountedWalk]) -> str:
    """Markdown table: one row per walk, then the median and largest absolute error of each counter.

    A summary covers the walks that have the count, and says how many they are.
    """
    lines = ["| walk | true steps | ours | ours error | app algorithm | hardware counter |",
             "|---|---|---|---|---|---|"]
    for walk in walks:
        lines.append(f"| {walk.name} | {walk.true_steps} | {walk.ours} | {error_percent(walk.ours, walk.true_steps)} "
                     f"| {error_percent(walk.app, walk.true_steps)} | "
                     f"{error_percent(walk.hardware, walk.true_steps)} |")
    for label, reduce in (("median abs error", np.median), ("largest abs error", np.max)):
        cells = []
        for counts in ([w.ours for w in walks], [w.app for w in walks], [w.hardware for w in walks]):
            errors = [abs(c - w.true_steps) / w.true_steps for c, w in zip(counts, walks) if c is not None]
            cells.append(f"{100.0 * reduce(errors):.1f} % ({len(errors)})" if errors else "—")
        lines.append(f"| **{label}** | - | - | {cells[0]} | {cells[1]} | {cells[2]} |")
    return "\n".join(lines)


def step_count_blocks(root: Path, data_commit: str) -> tuple[Prose | Table, ...]:
    """The results' ``steps`` section: the validation table, the tuning table and the short walks' summary.

    Parameters
    ----------
    root : Path
        A checkout of the data set.
    data_commit : str
        Its commit, as the section names it.
    """
    validation = [validation_walk(path) for path in data_set_walks(root, "validation")]
    tuning_folders = data_set_walks(root, "optimisation")
    tuning = [tuning_walk(path) for path in tuning_folders]
    short = [walk for path in tuning_folders for walk in start_and_stop(path)]
    return (Prose(f"Oxford-step-counter/DataSet at commit `{data_commit}` (CC BY 4.0). Its validation traces (a "
                  "Samsung S6, two walkers, six carriages; sealed: never used to tune) against the foot switches, "
                  "beside the data set's own app algorithm and the phone's hardware step counter:"),
            Table.parse(step_count_table(validation)),
            Prose("The tuning traces (`optimisation/`: the detector's settings were chosen on these), foot-switch "
                  "bounces within 0.5 s left out of the truth (docs/evaluation.md):"),
            Table.parse(step_count_table(tuning)),
            Prose(f"Starts and stops: the first and the last {SHORT_WALK_STEPS} steps of each tuning walk, each a "
                  "short walk with the phone put away or taken out, the walker setting off or stopping "
                  "(`dtmbnav.evaluation.step_count.start_and_stop`):"),
            Table.parse(short_walk_summary(short)))
