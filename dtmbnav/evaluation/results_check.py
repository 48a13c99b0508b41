"""``dtmbnav results --check``: re-run the first walks of printed sections and compare with the results data.

A walk depends only on its seed (docs/evaluation.md), so the first walks of
a printed section, run again on the commit that printed it, give its
figures again; after a change they move, and this module says whether they
moved further than the walks' spread. Every figure is read from the data
file (:mod:`dtmbnav.evaluation.results_data`), never from the Markdown
rendered from it; nothing is written.

What is compared
----------------
*Fusion sections* (any section with the table of
:func:`dtmbnav.evaluation.results.fusion_table`: ``fusion-iq``, ``fusion-obs``,
``fusion-exact``). The walks are the printed ones: the first index, the
count and the level come from the section's walks, the scenarios from its
table's rows; ``check_seeds`` walks of each scenario are run again (all of
them when the section printed fewer). For each scenario and each track of
the table (``PDR``, ``PDR@fix`` and every filter) the mean 95 % error of the
re-run walks is compared with a printed reference:

- where the section keeps the 95 % error of each walk (its ``per_walk``
  data: every track of a section printed with it; for ``fusion-iq`` printed
  before, the tracks of its per-walk table), the reference is the mean of
  the printed figures of the *same* walks, and each walk is also compared
  on its own;
- otherwise the reference is the printed row, the mean over all ``N``
  printed walks, of which the re-run walks are the first ``n``.

The *spread* is the half-width of the two-sided 95 % confidence interval of
a mean of ``n`` walks, ``t(0.975, nu) * s / sqrt(n)``, where ``s`` is the
standard deviation (``ddof=1``) of the single walks' 95 % errors of that
scenario and track: those of the ``N`` printed walks where the section
keeps them (``nu = N - 1``: the section's own scatter), else those of the
``n`` re-run walks (``nu = n - 1``, which misjudges the scatter when the
few re-run walks happen to lie close together: reprint such a section to
keep its walks); it is 0 with a single walk. A row is a ``REGRESSION``
when the re-run mean exceeds the reference by more than the spread plus
the printed rounding (half a unit of the figure's last printed digit),
``better`` when it is below by as much, and ``ok`` otherwise. A change
that moves the figures no further than the walks themselves scatter is not
told apart from the luck of the walks; a short check can only see a large
regression, and ``check_seeds`` buys a tighter one.

*Row sections* (``receiver``, ``paths``, ``pdr``): every row is one fixed
walk (the scenario file's own seed), so the whole section is run again and
every figure compared with its printed one. One walk has no spread: a figure
worse than the printed one beyond its rounding is a ``REGRESSION``. In
``receiver`` and ``paths`` the unit says which way is worse: a share (``%``)
is better higher, a count of seconds only says which stretch was scored (a
change is ``moved``), every other figure is an error whose magnitude is
better lower. ``pdr``'s figures describe the walk (step counts, a gain,
drifts) more than they score it, so any of them that changes is ``moved``.

Where the checkout's code is that which printed a section
(:func:`dtmbnav.evaluation.results_status.same_code`: the files of its
fingerprint unchanged, or for a section printed without one no tracked
file but the documents differs from its commit), a figure of the same walks
that differs beyond its rounding is ``NOT REPRODUCED``: the walks did not depend
on their seeds alone. Elsewhere a moved walk is ``moved``, which does not
fail the check. ``REGRESSION`` and ``NOT REPRODUCED`` fail it.

The other sections are not checked (:data:`UNCHECKED` says why). The report
also carries each section's status (up to date, out of date, unknown:
:mod:`dtmbnav.evaluation.results_status`), which the command prints first.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dtmbnav.evaluation import results, results_status
from dtmbnav.evaluation.results_data import Cell, Figure, ResultsData, Section
from dtmbnav.evaluation.results_status import SectionStatus
from dtmbnav.evaluation.seeds import CHECK_SEEDS

#: Sections of fixed walks, one per row, run again whole and compared figure by figure.
ROW_SECTIONS = ("receiver", "paths", "pdr")
#: Row sections whose figures have no better direction: a change is ``moved``.
UNDIRECTED_SECTIONS = ("pdr",)
#: Why the other sections are not checked.
UNCHECKED = {
    "frontends": "it is a check of its own (each row passes or fails against the ideal front end; "
                 "`python -m dtmbnav.evaluation.frontends` exits 1 on a failed row), and its walks take hours, not a "
                 "short campaign",
    "field": "it is a check of its own (each row passes or fails against the simulator's files; "
             "`python -m dtmbnav.evaluation.field_check` exits 1 on a failed row)",
    "weak-signal": "it is a check of its own (a row with a walk worse than its PDR@fix fails; "
                   "`python -m dtmbnav.evaluation.weak_signal` exits 1 on it)",
    "steps": "it needs the Oxford step counter data set, which is not part of this repository (rerun "
             "`dtmbnav results --sections steps --step-data DIR` on a checkout of it)",
    "live": "it is a check of its own (one replayed walk; `python -m dtmbnav.evaluation.live_check` exits 1 when a "
            "live process fails), and its CPU and timing figures are this machine's",
    "bench": "every figure is a timing of the machine that printed it, which varies from run to run",
}
#: Verdicts that fail the check.
FAILING = ("REGRESSION", "NOT REPRODUCED")
#: Confidence of the spread's interval (two-sided).
CONFIDENCE = 0.95


@dataclass(frozen=True)
class FusionFigures:
    """The figures of a printed fusion section.

    Attributes
    ----------
    level : str
        Where its ranges came from (:data:`dtmbnav.evaluation.seeds.LEVELS`).
    first_seed, walks : int
        First Monte Carlo index and walks per scenario.
    means : dict of (str, str) -> Figure
        Mean 95 % error, m, by (scenario, track); tracks the table marks ``-`` are absent.
    per_walk : dict of (str, int, str) -> Figure
        95 % error of each walk, m, by (scenario, Monte Carlo index, track), where the section keeps them.
    seeds : dict of (str, int) -> int
        Scenario seed of each kept walk, by (scenario, Monte Carlo index).
    """

    level: str
    first_seed: int
    walks: int
    means: dict[tuple[str, str], Figure]
    per_walk: dict[tuple[str, int, str], Figure]
    seeds: dict[tuple[str, int], int]

    @property
    def scenarios(self) -> list[str]:
        """The scenarios of the table, in its order."""
        return list(dict.fromkeys(scenario for scenario, _ in self.means))


#: Track names and their column titles in the fusion table, as :func:`dtmbnav.evaluation.results.fusion_table`
#: writes them.
FUSION_TRACKS = (*results.BASELINE_COLUMNS, ("pf", results.PF_COLUMN), *results.OTHER_FILTER_COLUMNS)


def fusion_figures(section: Section) -> FusionFigures | None:
    """The figures of a fusion section's data, or None when the section holds no fusion table.

    Raises
    ------
    ValueError
        A fusion table without the section's walks, or whose walk counts disagree with them.
    """
    table = section.table("fusion")
    if table is None:
        return None
    if section.walks is None:
        raise ValueError(f"results data: section {section.name} has a fusion table but no walks")
    walks = section.walks
    means: dict[tuple[str, str], Figure] = {}
    for scenario, row in zip(table.keys, table.rows):
        count = row[table.column("walks")].figures[0].value
        if count != walks.count:
            raise ValueError(f"results data: section {section.name}, {scenario}: {count} walks, but the section's "
                             f"walks are {walks.first}-{walks.indices[-1]}")
        for track, title in FUSION_TRACKS:
            if title not in table.header:   # a table printed before the filter was added
                continue
            figures = row[table.column(title)].figures
            if figures:
                means[(scenario, track)] = figures[0]
    per_walk: dict[tuple[str, int, str], Figure] = {}
    seeds: dict[tuple[str, int], int] = {}
    for walk in section.per_walk.walks if section.per_walk else ():
        seeds[(walk.scenario, walk.index)] = walk.seed
        per_walk.update({(walk.scenario, walk.index, track): Figure(value, section.per_walk.decimals, "m")
                         for track, value in walk.p95_m.items()})
    return FusionFigures(walks.level, walks.first, walks.count, means, per_walk, seeds)


@dataclass(frozen=True)
class Comparison:
    """One line of the check's table: a printed figure, the re-run's, the spread allowed and the verdict."""

    section: str
    row: str
    walks: str
    printed: str
    rerun: str
    spread: str
    verdict: str


def spread_m(values: Sequence[float], n: int) -> float:
    """The walks' spread: half-width of the two-sided :data:`CONFIDENCE` interval of a mean of ``n`` walks.

    Parameters
    ----------
    values : sequence of float
        95 % errors of single walks, m, whose scatter stands for the walks': ``nu = len(values) - 1``.
    n : int
        Walks in the mean.

    Returns
    -------
    float
        ``t(0.5 + CONFIDENCE / 2, nu) * std(values, ddof=1) / sqrt(n)``, m; 0 for a single value (no scatter
        to measure).
    """
    from scipy import stats

    values = np.asarray(values, dtype=np.float64)
    if values.size < 2:
        return 0.0
    return float(stats.t.ppf(0.5 + CONFIDENCE / 2.0, values.size - 1) * np.std(values, ddof=1) / np.sqrt(n))


def judge(printed: float, rerun: float, spread: float, rounding: float, reproducible: bool,
          direction: int = -1) -> str:
    """The verdict on a re-run figure against its printed one.

    Parameters
    ----------
    printed, rerun : float
        The printed reference and the re-run figure.
    spread : float
        How far the re-run may lie from the reference on either side (:func:`spread_m`), same unit.
    rounding : float
        Half a unit of the printed figure's last digit, same unit.
    reproducible : bool
        The re-run ran the same walks on the commit that printed them: any difference beyond the rounding
        is ``NOT REPRODUCED``.
    direction : {-1, 1, 0}
        Better lower (-1), better higher (1), or neither (0: a difference is ``moved``).

    Returns
    -------
    str
        ``ok``, ``better``, ``REGRESSION``, ``moved`` or ``NOT REPRODUCED``.
    """
    allowed = spread + rounding * (1.0 + 1e-9)  # the relative slack keeps a figure that prints the same "ok"
    if reproducible and abs(rerun - printed) > rounding * (1.0 + 1e-9):
        return "NOT REPRODUCED"
    if direction == 0:
        return "moved" if abs(rerun - printed) > allowed else "ok"
    worse = (printed - rerun) * direction
    if worse > allowed:
        return "REGRESSION"
    return "better" if worse < -allowed else "ok"


def _m(value: float) -> str:
    return f"{value:.2f} m"


def compare_fusion(name: str, figures: FusionFigures, walks: Sequence[dict[str, object]], same_code: bool
                   ) -> list[Comparison]:
    """Each scenario and track of a printed fusion section against the re-run walks (module docstring).

    Parameters
    ----------
    name : str
        The section.
    figures : FusionFigures
        Its printed figures.
    walks : sequence of dict
        The re-run walks' records (:func:`dtmbnav.evaluation.evaluate.walk_record`): the first walks of each scenario.
    same_code : bool
        The checkout runs the code that printed the section (:func:`dtmbnav.evaluation.results_status.same_code`).

    Raises
    ------
    ValueError
        A re-run walk whose scenario seed is not the one printed for it (the scenario changed: not the same walk).
    """
    out: list[Comparison] = []
    walk_rows: list[Comparison] = []
    for scenario in figures.scenarios:
        mine = sorted((w for w in walks if w["scenario"] == scenario), key=lambda w: w["k"])
        indices = [int(w["first_seed"]) + int(w["k"]) for w in mine]
        for w, index in zip(mine, indices):
            printed_seed = figures.seeds.get((scenario, index))
            if printed_seed is not None and printed_seed != w["seed"]:
                raise ValueError(f"results --check {name}: {scenario} index {index} ran seed {w['seed']}, the file "
                                 f"printed seed {printed_seed}; not the same walk, reprint the section")
        n = len(mine)
        span = f"{indices[0]}-{indices[-1]}"
        for track, _ in FUSION_TRACKS:
            printed = figures.means.get((scenario, track))
            if printed is None:
                continue
            rerun = [float(w["p95_m"][track]) for w in mine]
            printed_walks = [figures.per_walk.get((scenario, index, track)) for index in indices]
            if all(f is not None for f in printed_walks):
                everyone = [f.value for (s, _, t), f in figures.per_walk.items() if s == scenario and t == track]
                reference = float(np.mean([f.value for f in printed_walks]))
                spread, same_walks = spread_m(everyone, n), True
                walks_text = f"{span} (same walks)"
                # A single walk is not judged better or worse (the row is): it is reproduced or it moved.
                walk_rows += [Comparison(name, f"{scenario} walk {index} {track}", str(index), _m(figure.value),
                                         _m(value), "-", judge(figure.value, value, 0.0, figure.rounding, same_code,
                                                               direction=0))
                              for index, figure, value in zip(indices, printed_walks, rerun)]
            else:
                reference, spread, same_walks = printed.value, spread_m(rerun, n), n == figures.walks
                walks_text = f"{span} of {figures.first_seed}-{figures.first_seed + figures.walks - 1}"
            mean = float(np.mean(rerun))
            out.append(Comparison(name, f"{scenario} {track}", walks_text, _m(reference), _m(mean), _m(spread),
                                  judge(reference, mean, spread, printed.rounding, same_code and same_walks)))
    return out + walk_rows


def check_fusion(section: Section, figures: FusionFigures, check_seeds: int, config: results.ResultsConfig,
                 same_code: bool) -> list[Comparison]:
    """Run the first ``check_seeds`` printed walks of each scenario of a fusion section again and compare."""
    n = min(check_seeds, figures.walks)
    _, walks, _ = results.fusion_walks(section.name, figures.scenarios, figures.level, n,
                                       dataclasses.replace(config, first_seed=figures.first_seed))
    return compare_fusion(section.name, figures, walks, same_code)


#: Direction of a figure by its printed unit (:func:`judge`): a share is better higher, a count of seconds has none.
_DIRECTION = {"%": 1, "s": 0}
#: Verdicts from the mildest to the most severe (a cell with several figures takes its most severe).
_SEVERITY = ("ok", "better", "moved", "REGRESSION", "NOT REPRODUCED")


def _cell_verdict(printed: Cell, rerun: Cell, same_code: bool, directed: bool = True) -> str | None:
    """The verdict on a table cell of one walk (spread 0), None when it holds no figure on either side; without
    ``directed`` every figure is judged as one without a better direction."""
    ours, theirs = printed.figures, rerun.figures
    if not ours and not theirs:
        return None
    if len(ours) != len(theirs):  # a figure became "-" (not found, not finite) or appeared
        return "NOT REPRODUCED" if same_code else "REGRESSION" if len(theirs) < len(ours) else "better"
    verdicts = []
    for figure, again in zip(ours, theirs):
        direction = _DIRECTION.get(figure.unit, -1) if directed else 0
        printed_value, value = figure.value, again.value
        if direction == -1:  # an error: its magnitude (a signed offset is as bad either way)
            printed_value, value = abs(printed_value), abs(value)
        verdicts.append(judge(printed_value, value, 0.0, figure.rounding, same_code, direction))
    return max(verdicts, key=_SEVERITY.index)


def compare_tables(printed: Section, rerun: Section, same_code: bool) -> list[Comparison]:
    """Every figure of a printed row section against the same section run again (module docstring).

    Raises
    ------
    ValueError
        The tables or their rows differ (the section's layout changed since it was printed: reprint it).
    """
    name = printed.name
    ours, theirs = printed.tables(), rerun.tables()
    if [t.header for t in ours] != [t.header for t in theirs]:
        raise ValueError(f"results --check {name}: its tables changed since it was printed; reprint the section")
    out = []
    for mine, other in zip(ours, theirs):
        rows = {row[0].text: row for row in other.rows}
        for row in mine.rows:
            label = row[0].text
            if label not in rows:
                raise ValueError(f"results --check {name}: row {label!r} is no longer printed; reprint the section")
            for title, cell, again in zip(mine.header[1:], row[1:], rows[label][1:]):
                verdict = _cell_verdict(cell, again, same_code, name not in UNDIRECTED_SECTIONS)
                if verdict is not None:
                    out.append(Comparison(name, f"{label}: {title}", "the same walk", cell.text, again.text, "-",
                                          verdict))
    return out


@dataclass
class CheckReport:
    """What a check compared, the status of each section it was asked for, and the sections it did not check
    (with why)."""

    comparisons: list[Comparison] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    statuses: list[SectionStatus] = field(default_factory=list)

    @property
    def failed(self) -> list[Comparison]:
        """The comparisons whose verdict fails the check."""
        return [c for c in self.comparisons if c.verdict in FAILING]

    def table(self) -> str:
        """The comparisons as a Markdown table."""
        lines = ["| section | row | walks | printed | re-run | spread | verdict |", "|---" * 7 + "|"]
        lines += [f"| {c.section} | {c.row} | {c.walks} | {c.printed} | {c.rerun} | {c.spread} | {c.verdict} |"
                  for c in self.comparisons]
        return "\n".join(lines)

    def summary(self) -> str:
        """One line: how many figures were compared and which failed."""
        failed = self.failed
        if not failed:
            return f"results --check: {len(self.comparisons)} figures compared, none failed"
        return (f"results --check: {len(failed)} of {len(self.comparisons)} figures failed: "
                + "; ".join(f"{c.section} {c.row} {c.verdict}" for c in failed))


def check_results(data_file: Path, sections: Sequence[str], check_seeds: int = CHECK_SEEDS,
                  config: results.ResultsConfig = results.ResultsConfig()) -> CheckReport:
    """Check the printed ``sections`` of the results data against a short re-run (module docstring).

    Parameters
    ----------
    data_file : Path
        The results data (:mod:`dtmbnav.evaluation.results_data`); it is only read.
    sections : sequence of str
        Sections to check; those that cannot be checked, or that the data lacks, are named in the report's notes.
    check_seeds : int
        Walks of each scenario a fusion section runs again (its first ones).
    config : ResultsConfig
        Where the walks run and whether to show progress; the walks themselves are the printed ones.

    Raises
    ------
    ValueError
        None of ``sections`` could be checked, or a section's figures cannot be compared (the message says why).
    """
    data = ResultsData.load(data_file)
    report = CheckReport(statuses=results_status.statuses(data, sections))
    for name in sections:
        if name not in data:
            report.notes.append(f"{name}: not in {data_file}, nothing to check")
            continue
        section = data[name]
        same_code = results_status.same_code(section)
        figures = fusion_figures(section)
        if figures is not None:
            report.comparisons += check_fusion(section, figures, check_seeds, config, same_code)
        elif name in ROW_SECTIONS:
            report.comparisons += compare_tables(section, results.section_runners(config)[name](), same_code)
        else:
            report.notes.append(f"{name}: not checked: {UNCHECKED.get(name, 'no check is defined for it')}")
    if not report.comparisons:
        raise ValueError(f"results --check: nothing to check in {data_file} ({'; '.join(report.notes)})")
    return report
