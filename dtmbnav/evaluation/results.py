"""``dtmbnav results``: the project's result tables, kept as data and rendered into one Markdown file.

Every table of ``docs/results.md`` is printed by this module, never typed:
each section runs its campaign (:func:`dtmbnav.evaluation.evaluate.evaluate_many` and
friends) and keeps its content as data (:mod:`dtmbnav.evaluation.results_data`) in
``docs/results.json``, with the command that reprints it, the commit, the
date, the machine, the Monte Carlo walks and the files it ran
(:mod:`dtmbnav.evaluation.results_status`); the Markdown file is rendered from the whole data
file. Running the same command again reproduces both byte for byte except
the timing and date fields (the walks depend only on their seeds,
docs/evaluation.md).

A run of some sections (``--sections``) replaces only those in the data and
keeps the others as they were printed, each under its own header. The
README's headline table sits between ``<!-- results:headline -->`` markers
and is rewritten from the fusion sections' data when ``--readme`` names it.
"""

from __future__ import annotations

import datetime as dt
import importlib
import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from dtmbnav.evaluation.distributed import IN_PROCESS, ClusterConfig
from dtmbnav.evaluation.results_data import (
    Cell,
    Code,
    PerWalk,
    Prose,
    ResultsData,
    Section,
    Table,
    WalkErrors,
    Walks,
    data_path,
    join,
    number,
    percent,
)
from dtmbnav.evaluation.results_status import ROOT, fingerprint, run_git
from dtmbnav.evaluation.seeds import IQ_SEEDS, OBS_SEEDS, REPORTING_SEEDS, RESULT_SECTIONS, TUNING_SEEDS

#: Scenarios of the fusion tables, in the order they are printed.
FUSION_SCENARIOS = ("park-loop-cw", "park-loop-ccw", "sfn-park", "sfn3-park", "street-out", "street-back",
                    "street-out-sfn")
#: Further rows of the observation-level table: the SFN walks with the network plan's transmit delay offsets, with
#: those surveyed on another walk of the network (dtmbnav.evaluation.survey), and with the walks' true ones (the
#: fusion's bound; the rows above know nothing of them).
SFN_DELAY_ROWS = ("sfn-park (delays plan)", "sfn-park (delays surveyed)", "sfn-park (delays exact)",
                  "sfn3-park (delays plan)", "sfn3-park (delays surveyed)", "sfn3-park (delays exact)")
#: Scenarios of the exact-range table (the filters' bound with a perfect single-tower receiver).
EXACT_SCENARIOS = ("park-loop-cw", "park-loop-ccw")
#: The filters after the PF in the order of the table's columns (with their column titles).
OTHER_FILTER_COLUMNS = (("ukf", "UKF"), ("wt-ukf", "WT-UKF"), ("adaptive-kf", "adaptive KF"), ("rank-kf", "rank KF"),
                        ("rb-pf", "RB-PF"))
#: The PDR baselines (track names and column titles), the first figures of the fusion and the per-walk tables.
BASELINE_COLUMNS = (("pdr", "PDR"), ("pdr@fix", "PDR@fix"))
#: Title of the fusion table's PF column: its mean 95 % error, then its reductions in brackets.
PF_COLUMN = "PF (vs PDR / vs PDR@fix)"
#: Filters of the per-walk table, after the PDR baselines (each titled by its name in capitals).
PER_WALK_FILTERS = ("pf", "ukf")
#: What the field section's walks run in child processes (``dtmbnav receive``, ``sensors``, ``fuse``, ``report``),
#: imported in the printing process too so that the section's fingerprint names it.
FIELD_COMMAND_MODULES = ("dtmbnav.chain.receive", "dtmbnav.chain.fuse", "dtmbnav.chain.report",
                         "dtmbnav.field.sensors_import", "receiver.mixer")
#: Decimals of each walk's 95 % errors kept in a fusion section's data (those of the per-walk table).
WALK_DECIMALS = 2
HEADLINE_BEGIN, HEADLINE_END = "<!-- results:headline -->", "<!-- /results:headline -->"


@dataclass(frozen=True)
class ResultsConfig:
    """What a ``dtmbnav results`` run computes.

    Attributes
    ----------
    iq_seeds, obs_seeds : int
        Monte Carlo walks per scenario at the IQ level and at the observation
        (and exact) level.
    first_seed : int
        First Monte Carlo index (docs/evaluation.md, "Tuning and reporting seeds").
    cluster : ClusterConfig
        Where the walks run (:mod:`dtmbnav.evaluation.distributed`).
    progress : bool
        Progress bars on stderr.
    step_data : Path or None
        A checkout of the Oxford step counter data set (the ``steps`` section needs it).
    """

    iq_seeds: int = IQ_SEEDS
    obs_seeds: int = OBS_SEEDS
    first_seed: int = REPORTING_SEEDS.start
    cluster: ClusterConfig = IN_PROCESS
    progress: bool = False
    step_data: Path | None = None



#: The command every section's command line starts with.
COMMAND = "dtmbnav results"
#: Every section, in the file's order.
SECTIONS = RESULT_SECTIONS


def commit_id(root: Path = ROOT) -> str:
    """The checkout's commit (short hash, ``+modified`` where tracked files differ from it); ``unknown``
    outside a git checkout."""
    head = run_git(root, "rev-parse", "--short=10", "HEAD", timeout_s=30.0)
    dirty = run_git(root, "status", "--porcelain", "--untracked-files=no", timeout_s=30.0)
    if head is None or dirty is None or head.returncode or dirty.returncode:
        return "unknown"
    return head.stdout.strip() + ("+modified" if dirty.stdout.strip() else "")


def machine_description() -> str:
    """The machine in a few words: processor, cores, Python."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores, Python {platform.python_version()}"


def _clock_of(scenario_name: str) -> str:
    from dtmbnav.evaluation.evaluate import load_evaluation_scenario
    from dtmbnav.simulation.capture_set import receiver_clock_model

    return receiver_clock_model(load_evaluation_scenario(scenario_name))


def _separated(cells: Sequence[Cell], separator: str = " / ") -> Cell:
    """One cell of ``cells`` with ``separator`` between them."""
    parts: list[str | Cell] = []
    for cell in cells:
        parts += [separator, cell] if parts else [cell]
    return join(*parts)


def fusion_table(rows: Sequence, walks: Sequence[dict[str, object]]) -> tuple[Table, list[dict[str, object]]]:
    """The fusion table of evaluation rows (one line per scenario, keyed by it), and the headline figures of each
    scenario (rounded to 4 decimals).

    Parameters
    ----------
    rows : sequence of dtmbnav.evaluation.evaluate.EvaluationRow
    walks : sequence of dict
        The per-walk records (:func:`dtmbnav.evaluation.evaluate.walk_record`) of the same run.
    """
    by_scenario: dict[str, dict[str, object]] = {}
    for r in rows:
        by_scenario.setdefault(r.scenario, {})[r.filter] = r
    other_titles = [title for name, title in OTHER_FILTER_COLUMNS]
    header = ("walk (clock)", "walks", *(title for _, title in BASELINE_COLUMNS), PF_COLUMN, *other_titles,
              "PF worst@fix",
              "walks > 5 % worse than PDR@fix (PF, " + ", ".join(other_titles) + ")",
              "truth in the stated 95 % ellipse, PF / UKF (mean NEES)", "heading error (median)", "paper PF reduction")
    cells, headline = [], []
    for scenario, named in by_scenario.items():
        pdr, at_fix, pf = named["pdr"], named["pdr@fix"], named.get("pf")
        mine = [w for w in walks if w["scenario"] == scenario]
        worse = {name: sum(w["p95_m"][name] > 1.05 * w["p95_m"]["pdr@fix"] for w in mine)
                 for name in ("pf", *(name for name, _ in OTHER_FILTER_COLUMNS)) if name in named}
        no_pf = Cell.plain("-")
        cells.append((Cell.plain(f"{scenario} ({_clock_of(scenario)})"), number(pdr.seeds, 0),
                      number(pdr.p95_m, 2, "m"), number(at_fix.p95_m, 2, "m"),
                      join(number(pf.p95_m, 2, "m"), " (", percent(pf.reduction_95), " / ",
                           percent(pf.reduction_95_vs_fix), ")") if pf else no_pf,
                      *(number(named[n].p95_m, 2, "m") if n in named else no_pf for n, _ in OTHER_FILTER_COLUMNS),
                      percent(pf.worst_vs_fix, 1, signed=True) if pf else no_pf,
                      _separated([number(n, 0) for n in worse.values()]),
                      join(percent(_walk_mean(mine, "in_ellipse_95", "pf"), 0), " / ",
                           percent(_walk_mean(mine, "in_ellipse_95", "ukf"), 0), " (",
                           number(_walk_mean(mine, "nees", "pf"), 1), " / ", number(_walk_mean(mine, "nees", "ukf"), 1),
                           ")"),
                      number(pdr.heading_error_median_deg, 2, "deg"),
                      percent(pf.paper_reduction_95, 0) if pf else no_pf))
        figures = {"scenario": scenario, "level": pdr.level, "walks": pdr.seeds, "pdr": pdr.p95_m,
                   "pdr_at_fix": at_fix.p95_m, "pf": pf.p95_m if pf else None,
                   "reduction": pf.reduction_95 if pf else None,
                   "reduction_at_fix": pf.reduction_95_vs_fix if pf else None,
                   "worst": pf.worst_vs_fix if pf else None, "walks_worse": worse.get("pf", 0),
                   "paper": pf.paper_reduction_95 if pf else None}
        headline.append({key: round(value, 4) if isinstance(value, float) else value for key, value in figures.items()})
    return Table(header, tuple(cells), tuple(by_scenario), "fusion"), headline


def _walk_mean(walks: Sequence[dict[str, object]], key: str, track: str) -> float | None:
    """Mean over the walks of one track's per-walk figure ``key`` (``in_ellipse_95``, ``nees``); None where no
    walk has it (walks printed before the tracks stated their error)."""
    values = [w[key][track] for w in walks if track in w.get(key, {})]
    return math.fsum(values) / len(values) if values else None


def _walk_order(walks: Sequence[dict[str, object]]) -> list[dict[str, object]]:
    """The walks by scenario (in :data:`FUSION_SCENARIOS` order, others after them by name), then index."""
    return sorted(walks, key=lambda w: (FUSION_SCENARIOS.index(w["scenario"]) if w["scenario"] in FUSION_SCENARIOS
                                        else len(FUSION_SCENARIOS), w["scenario"], w["k"]))


def per_walk_table(walks: Sequence[dict[str, object]], filters: Sequence[str] = PER_WALK_FILTERS) -> Table:
    """Each walk's 95 % error, m: the PDR baselines and ``filters``, and eq. 15's heading error."""
    header = ("walk", "index", "seed", *(title for _, title in BASELINE_COLUMNS), *(f.upper() for f in filters),
              "heading error")
    rows = tuple((Cell.plain(w["scenario"]), number(w["first_seed"] + w["k"], 0), number(w["seed"], 0),
                  *(number(w["p95_m"].get(track), 2) for track in (*(t for t, _ in BASELINE_COLUMNS), *filters)),
                  number(abs(w["heading_error_deg"]), 2, "deg")) for w in _walk_order(walks))
    return Table(header, rows)


def per_walk_errors(walks: Sequence[dict[str, object]]) -> PerWalk:
    """Every walk's 95 % error of every track, rounded to :data:`WALK_DECIMALS`: the section's data, printed or not."""
    return PerWalk(WALK_DECIMALS, tuple(
        WalkErrors(w["scenario"], w["first_seed"] + w["k"], w["seed"],
                   {track: round(float(value), WALK_DECIMALS) for track, value in w["p95_m"].items()})
        for w in _walk_order(walks)))


def _walks_line(first_seed: int, seeds: int, level: str) -> str:
    from dtmbnav.evaluation.evaluate import describe_seeds

    return describe_seeds(first_seed, seeds, level, True)


def fusion_walks(name: str, scenarios: Sequence[str], level: str, seeds: int, config: ResultsConfig
                 ) -> tuple[list, list[dict[str, object]], float]:
    """The walks of fusion section ``name``: ``seeds`` walks of each scenario at ``level`` from ``config.first_seed``.

    Returns
    -------
    rows : list of dtmbnav.evaluation.evaluate.EvaluationRow
        The table's rows.
    walks : list of dict
        Each walk's record (:func:`dtmbnav.evaluation.evaluate.walk_record`), in the order the walks finished.
    wall_s : float
        Wall time of the walks, s.

    Raises
    ------
    RuntimeError
        When a walk fails (the message names each failed walk).
    """
    from dtmbnav.evaluation.evaluate import evaluate_many, level_range_source

    # The level's range source imported here too, so that the section's fingerprint names its modules when the
    # walks run in worker processes.
    level_range_source(level)
    walks: list[dict[str, object]] = []
    start = time.perf_counter()
    outcome = evaluate_many(list(scenarios), seeds, level=level, first_seed=config.first_seed,
                            cluster=config.cluster, progress=config.progress, on_walk=walks.append)
    wall_s = time.perf_counter() - start
    if outcome.failures:
        failed = "; ".join(f"{f.scenario} k={f.k} (seed {f.seed}): {f.error}" for f in outcome.failures)
        raise RuntimeError(f"results {name}: walks failed: {failed}")
    return outcome.rows, walks, wall_s


def fusion_section(name: str, title: str, scenarios: Sequence[str], level: str, seeds: int,
                   config: ResultsConfig, per_walk: bool) -> Section:
    """A fusion table: every filter on ``scenarios`` at ``level`` over ``seeds`` walks (and, with ``per_walk``, a
    table of each walk); every walk's 95 % errors are kept in the data either way."""
    rows, walks, _ = fusion_walks(name, scenarios, level, seeds, config)
    table, headline = fusion_table(rows, walks)
    blocks = (Prose(f"Walks: {_walks_line(config.first_seed, seeds, level)}."), table)
    if per_walk:
        blocks += (Prose("Per walk, 95 % error, m:"), per_walk_table(walks))
    seeds_option = "--iq-seeds" if level == "iq" else "--obs-seeds"
    return Section(name, title, f"{COMMAND} --sections {name} {seeds_option} {seeds} --first-seed {config.first_seed}",
                   blocks, Walks(config.first_seed, seeds, level), tuple(headline), per_walk_errors(walks))


def pdr_section(config: ResultsConfig) -> Section:
    """The PDR's own figures on the reference walks (:mod:`dtmbnav.evaluation.pdr_table`)."""
    from dtmbnav.evaluation.evaluate import REFERENCE_WALKS
    from dtmbnav.evaluation.pdr_table import pdr_figures

    rows = []
    for name in REFERENCE_WALKS:
        f = pdr_figures(name)
        paper = (Cell.plain("-") if f.paper_m is None else
                 join(number(f.paper_m[0], 2), " / ", number(f.paper_m[1], 2), " / ", number(f.paper_m[2], 2, "m")))
        rows.append((Cell.plain(f.scenario), join(number(f.steps_detected, 0), " / ", number(f.steps_true, 0)),
                     percent(f.step_length_error, signed=True), number(f.k_m, 3, "m"),
                     join(number(f.drift_dpm, 2, signed=True), " / ", number(f.gyro_only_drift_dpm, 2, signed=True),
                          " / ", number(f.predicted_drift_dpm, 2, signed=True)),
                     join(number(f.p68_m, 2), " / ", number(f.p95_m, 2), " / ", number(f.max_m, 2, "m")), paper))
    table = Table(("walk", "steps found / true", "step length error", "Weinberg K",
                   "heading drift, deg/min: with magnetometer / gyro only / gyro bias predicts",
                   "PDR 68 / 95 / max", "paper's PDR 68 / 95 / max"), tuple(rows))
    return Section("pdr", "PDR on the reference walks", f"{COMMAND} --sections pdr",
                   (Prose("Each scenario file's own walk and seed (`dtmbnav evaluate all --pdr` prints the same "
                          "figures); the step length after the K calibration walk."), table))


def steps_section(config: ResultsConfig) -> Section:
    """Step counts on real phones' traces, beside the data set's own counters (:mod:`dtmbnav.evaluation.step_count`).

    Raises
    ------
    FileNotFoundError
        ``config.step_data`` not given, or not a checkout of the data set.
    """
    from dtmbnav.evaluation.step_count import FETCH_HINT, step_count_blocks

    if config.step_data is None:
        raise FileNotFoundError(f"results --sections steps needs --step-data DIR, a checkout of the Oxford step "
                                f"counter data set ({FETCH_HINT})")
    head = run_git(config.step_data, "rev-parse", "--short", "HEAD")
    data_commit = head.stdout.strip() if head is not None and head.returncode == 0 else "unknown"
    return Section("steps", "Step counts on real phones (Oxford step counter data set)",
                   f"{COMMAND} --sections steps --step-data DataSet", step_count_blocks(config.step_data, data_commit))


def _metres_pair(p95_m: float, max_m: float) -> Cell:
    """``"0.133 m / 0.165 m"``: a 95 % and a largest error, m."""
    return join(number(p95_m, 3, "m"), " / ", number(max_m, 3, "m"))


def _difference(p95_m: float, max_m: float) -> Cell:
    """The tower difference's errors, where the walk has a second tower."""
    return _metres_pair(p95_m, max_m) if math.isfinite(p95_m) else Cell.plain("(one tower)")


def receiver_section(config: ResultsConfig) -> Section:
    """The receiver against the simulator's truth: 60 s of walking after each scenario's standstill, C/N 15 dB,
    and the narrowband rates (:mod:`dtmbnav.evaluation.accuracy`)."""
    from dtmbnav.evaluation.accuracy import NARROWBAND_WALK_S, SHORT_WALK_S, narrowband_cases, short_cases

    common = ("radial velocity RMSE, 1 s means", "SI-carrier range error 95 % / max", "f_s error")

    def figures(acc) -> tuple[Cell, ...]:
        return (number(acc.velocity_rmse_1s_mps, 3, "m/s"), _metres_pair(acc.range_error_p95_m, acc.range_error_max_m),
                number(acc.clock_offset_error_hz, 3, "Hz", signed=True))

    short = Table(("case", *common, "first path 95 % / max", "tower difference 95 % / max"), tuple(
        (Cell.plain(label), *figures(acc), _metres_pair(paths.first_path_error_p95_m, paths.first_path_error_max_m),
         _difference(paths.difference_error_p95_m, paths.difference_error_max_m))
        for label, acc, paths in short_cases()))
    narrow = Table(("rate", *common), tuple((Cell.plain(f"{rate / 1e6:g} Msps"), *figures(acc))
                                            for rate, acc in narrowband_cases()))
    return Section("receiver", "Receiver against truth", f"{COMMAND} --sections receiver", (
        Prose(f"Each scenario file's walk and seed, C/N 15 dB, {SHORT_WALK_S:g} s of walking after its standstill; "
              "range errors of the change since the first frame, the first path against the first tower's direct "
              "path (`python -m dtmbnav.evaluation.accuracy` prints the same cases)."), short,
        Prose(f"Narrowband (an RTL-SDR's rates): park-loop-cw, GNSS-disciplined clock, {NARROWBAND_WALK_S:g} s of "
              "walking (`python -m dtmbnav.evaluation.accuracy --narrowband`)."), narrow))


def paths_section(config: ResultsConfig) -> Section:
    """The path tracker over whole walks (:func:`dtmbnav.evaluation.accuracy.walk_case`)."""
    from dtmbnav.evaluation.accuracy import WALK_CASES, walk_case
    from dtmbnav.simulation.capture_set import receiver_clock_model

    rows = []
    for name in WALK_CASES:
        scn, acc = walk_case(name)
        rows.append((Cell.plain(f"{name} ({receiver_clock_model(scn)})"), number(acc.seconds, 0, "s"),
                     _metres_pair(acc.first_path_error_p95_m, acc.first_path_error_max_m),
                     number(acc.si_error_p95_m, 3, "m"), percent(acc.first_path_share),
                     _difference(acc.difference_error_p95_m, acc.difference_error_max_m)))
    table = Table(("walk (clock)", "seconds scored", "first path 95 % / max", "SI carriers 95 %", "first path found",
                   "tower difference 95 % / max (clock-free)"), tuple(rows))
    return Section("paths", "Path tracker over whole walks", f"{COMMAND} --sections paths", (
        Prose("Each scenario file's whole walk and seed, C/N 15 dB, ci8 at 7.56 Msps; range changes scored from the "
              "end of the standstill against the first tower's direct path "
              "(`python -m dtmbnav.evaluation.accuracy --walk NAME` prints one walk)."), table))


def frontends_section(config: ResultsConfig) -> Section:
    """The SDR front ends against an ideal one (:mod:`dtmbnav.evaluation.frontends`): device presets, sweep and
    drops."""
    from dtmbnav.evaluation.frontends import (
        DROP_SAMPLES,
        DROPS_PER_MINUTE,
        SWEEP_FORMAT,
        SWEEP_RATE_HZ,
        WALKS,
        compare,
        describe,
        device_cases,
        drop_case,
        drop_table,
        frontend_table,
        sweep_cases,
    )

    devices, _ = frontend_table(compare(device_cases(), cluster=config.cluster, progress=config.progress))
    sweep, _ = frontend_table(compare(sweep_cases(), cluster=config.cluster, progress=config.progress))
    command = "python -m dtmbnav.evaluation.frontends"
    return Section("frontends", "SDR front ends", f"{COMMAND} --sections frontends", (
        Prose(describe()), Prose(f"Device presets at their usual rate and format (`{command} --devices`):"),
        Table.parse(devices),
        Prose(f"LO leakage, I/Q imbalance and tuner offset at {SWEEP_RATE_HZ / 1e6:g} Msps {SWEEP_FORMAT} "
              f"(`{command} --sweep`):"), Table.parse(sweep),
        Prose(f"Dropped samples, {DROPS_PER_MINUTE:g} a minute of {DROP_SAMPLES[0]} to {DROP_SAMPLES[1]} samples "
              f"(`{command} --drops`): {drop_table(*drop_case())}")), Walks(TUNING_SEEDS.start, WALKS, "iq"))


def field_section(config: ResultsConfig) -> Section:
    """A phone's own log and a capture with its start time, against the simulator's files
    (:mod:`dtmbnav.evaluation.field_check`)."""
    from dtmbnav.evaluation.field_check import WALKS, check, describe, field_table

    for module in FIELD_COMMAND_MODULES:
        importlib.import_module(module)
    table, _ = field_table(check(cluster=config.cluster, progress=config.progress))
    return Section("field", "The field path: a phone's log and a capture's start time", f"{COMMAND} --sections field",
                   (Prose(f"{describe()} (`python -m dtmbnav.evaluation.field_check`)"), Table.parse(table)),
                   Walks(TUNING_SEEDS.start, WALKS, "iq"))


def weak_signal_section(config: ResultsConfig) -> Section:
    """Lock, ranges and fusion as the C/N falls, at IQ level (:mod:`dtmbnav.evaluation.weak_signal`)."""
    from dtmbnav.evaluation.weak_signal import (
        WALKS,
        cases,
        check,
        describe,
        per_walk_table,
        summarise,
        weak_signal_table,
    )

    first = config.first_seed
    walks = check(cases(), first, cluster=config.cluster, progress=config.progress)
    table, _ = weak_signal_table(summarise(walks))
    return Section("weak-signal", "Weak signals: lock, ranges and fusion against C/N",
                   f"{COMMAND} --sections weak-signal --first-seed {first}",
                   (Prose(f"{describe(first, WALKS)} "
                          f"(`python -m dtmbnav.evaluation.weak_signal --first-seed {first}`)"),
                    Table.parse(table), Prose("Per walk:"), Table.parse(per_walk_table(walks))),
                   Walks(first, WALKS, "iq"))


def bench_section(config: ResultsConfig) -> Section:
    """Throughput of every kernel next to its numpy reference (``dtmbnav bench``); every figure is a timing."""
    import contextlib
    import io

    from dtmbnav.evaluation.bench import run_benchmarks

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        run_benchmarks()
    return Section("bench", "Throughput (`dtmbnav bench`)", f"{COMMAND} --sections bench",
                   (Prose("Every figure here is a timing of this machine (they vary by tens of per cent from run to "
                          "run)."), Code(out.getvalue().rstrip())))


def section_runners(config: ResultsConfig) -> dict[str, Callable[[], Section]]:
    """What runs each section (its content; the writer adds where and when it was printed)."""
    return {
        "fusion-iq": lambda: fusion_section("fusion-iq", "Fusion at IQ level", FUSION_SCENARIOS, "iq",
                                            config.iq_seeds, config, per_walk=True),
        "fusion-obs": lambda: fusion_section("fusion-obs", "Fusion at the observation level",
                                             FUSION_SCENARIOS + SFN_DELAY_ROWS,
                                             "obs", config.obs_seeds, config, per_walk=False),
        "fusion-exact": lambda: fusion_section("fusion-exact", "Fusion with the exact range (the filters' bound)",
                                               EXACT_SCENARIOS, "exact", config.obs_seeds, config, per_walk=False),
        "pdr": lambda: pdr_section(config),
        "steps": lambda: steps_section(config),
        "receiver": lambda: receiver_section(config),
        "paths": lambda: paths_section(config),
        "frontends": lambda: frontends_section(config),
        "field": lambda: field_section(config),
        "weak-signal": lambda: weak_signal_section(config),
        "live": lambda: importlib.import_module("dtmbnav.evaluation.live_check").live_section(config),
        "bench": lambda: bench_section(config),
    }


def headline_table(data: ResultsData) -> str:
    """The README's headline table from the fusion sections' headline figures.

    Rows of the IQ and the observation level (the exact level is a bound, not
    a result), under a line per section naming its command, commit and date;
    a section printed on another seed range than :data:`REPORTING_SEEDS` (a
    burned one) is named as left out, not shown.
    """
    rows: dict[tuple[str, str], dict[str, object]] = {}
    sources, left_out = [], []
    for section in data.sections:
        if section.name not in ("fusion-iq", "fusion-obs") or not section.headline:
            continue
        if section.walks is None or section.walks.first not in REPORTING_SEEDS:
            left_out.append(f"`{section.name}`")   # printed on a former reporting range: not a figure of now
            continue
        sources.append(f"`{section.command}` at commit `{section.commit}` on {section.date}")
        for row in section.headline:
            rows[(row["scenario"], row["level"])] = row
    omitted = (f" Not here until printed again on the reporting range {REPORTING_SEEDS.start}-{REPORTING_SEEDS[-1]}: "
               f"{', '.join(left_out)}." if left_out else "")
    printed = ("Printed by " + "; ".join(sources) + " (docs/results.md has every filter, walk and table)." if sources
               else "No fusion section is printed on the reporting range yet.")
    lines = [printed + omitted, "",
             "| walk | level | walks | PDR | PDR@fix | PF | PF vs PDR / vs PDR@fix | walks > 5 % worse than PDR@fix "
             "| paper PF reduction |", "|---" * 9 + "|"]
    for level in ("iq", "obs"):
        for scenario in FUSION_SCENARIOS + SFN_DELAY_ROWS:
            row = rows.get((scenario, level))
            if row is None or row["pf"] is None:
                continue
            lines.append(f"| {scenario} | {level} | {row['walks']} | {row['pdr']:.2f} m | {row['pdr_at_fix']:.2f} m "
                         f"| {row['pf']:.2f} m | {percent(row['reduction']).text} / "
                         f"{percent(row['reduction_at_fix']).text} | {row['walks_worse']} of {row['walks']} "
                         f"| {percent(row['paper'], 0).text} |")
    return "\n".join(lines)


def _headline_span(readme: Path) -> tuple[str, int, int]:
    """The README's text and where its headline block begins and ends (ValueError without one)."""
    text = readme.read_text(encoding="utf-8")
    begin, end = text.find(HEADLINE_BEGIN), text.find(HEADLINE_END)
    if begin < 0 or end < begin:
        raise ValueError(f"{readme}: no {HEADLINE_BEGIN} ... {HEADLINE_END} block to fill")
    return text, begin, end


def update_readme(readme: Path, data: ResultsData) -> None:
    """Rewrite the block between the README's headline markers with :func:`headline_table`."""
    text, begin, end = _headline_span(readme)
    block = f"{HEADLINE_BEGIN}\n{headline_table(data)}\n"
    readme.write_text(text[:begin] + block + text[end:], encoding="utf-8")


def save(data: ResultsData, path: Path, data_file: Path) -> None:
    """Write the data file and the Markdown file rendered from it (each replaced whole, never half written)."""
    from dtmbnav_core.h5io import atomic_path

    for target, text in ((data_file, data.to_json()), (path, data.markdown())):
        with atomic_path(target) as tmp:
            tmp.write_text(text, encoding="utf-8")


def write_results(path: Path, sections: Sequence[str], config: ResultsConfig, readme: Path | None = None,
                  date: str | None = None, data_file: Path | None = None) -> ResultsData:
    """Run ``sections`` and write each into the data file, and the results file rendered from it (other sections
    kept).

    Parameters
    ----------
    path : Path
        The Markdown results file (created when missing).
    sections : sequence of str
        Names from :data:`SECTIONS`, run in this order; the files are written after each.
    config : ResultsConfig
    readme : Path, optional
        A README whose headline block is rewritten from the results.
    date : str, optional
        The date printed in the headers (default today, ISO).
    data_file : Path, optional
        The data file (default :func:`dtmbnav.evaluation.results_data.data_path` of ``path``).

    Returns
    -------
    ResultsData
        The data written.

    Raises
    ------
    ValueError
        An unknown section, a README without the headline markers, or a results file without its data file
        (its sections would be lost); before any walk runs.
    """
    unknown = [name for name in sections if name not in SECTIONS]
    if unknown:
        raise ValueError(f"results: unknown section(s) {unknown}; known: {', '.join(SECTIONS)}")
    if readme is not None:
        _headline_span(readme)  # a README without the block fails before the campaign, not after it
    data_file = data_file or data_path(path)
    if path.exists() and not data_file.exists():
        raise ValueError(f"results: {path} exists but its data file {data_file} does not; the Markdown is rendered "
                         "from the data, so its sections would be lost")
    data = ResultsData.load(data_file) if data_file.exists() else ResultsData()
    runners = section_runners(config)
    commit, machine = commit_id(), machine_description()
    date = date or dt.date.today().isoformat()
    for name in sections:
        start = time.perf_counter()
        section = runners[name]()
        printed = replace(section, commit=commit, date=date, machine=machine,
                          wall_s=round(time.perf_counter() - start, 1), fingerprint=fingerprint())
        data = data.with_sections([printed], SECTIONS)
        save(data, path, data_file)  # after each section: a later one that fails loses none of the campaign before it
    if readme is not None:
        update_readme(readme, data)
    return data
