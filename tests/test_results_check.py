"""``dtmbnav results --check``: the printed figures read back from the data, a short re-run compared with them.

The check must read exactly what :mod:`dtmbnav.evaluation.results` keeps (a
round trip through the writer and the data file), and never the Markdown
rendered from it; it must pass where the re-run walks give the printed
figures again and fail, naming the row, where the data claims better
figures than the walks give by more than their spread; it must never write
the results. CI runs the check of the quick sections against the committed
data, so that a change that moves their figures beyond the walks' spread
cannot land without a reprint.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_NO_RESULT, EXIT_OK, EXIT_USAGE, main
from dtmbnav.evaluation import results, results_check
from dtmbnav.evaluation.distributed import ClusterConfig
from dtmbnav.evaluation.evaluate import RunSettings, SeedResult, summarise, walk_record
from dtmbnav.evaluation.results_data import Prose, ResultsData, Section, Table
from dtmbnav.evaluation.seeds import TUNING_SEEDS, monte_carlo_seed
from fusion import FILTER_NAMES

ROOT = Path(__file__).resolve().parents[1]
#: The campaign the tests print and check: a few exact-range walks of one scenario on the tuning range.
CONFIG = results.ResultsConfig(first_seed=TUNING_SEEDS.start)
SCENARIO = "park-loop-cw"
WALKS = 3
PRINTED_COMMIT = "0123456789"
#: What the Markdown file holds in the tests that show the check never reads it.
GARBAGE = "# not the results\n\n| a | b |\n|---|---|\n| 9.99 m | 0.01 m |\n"


@pytest.fixture(scope="module")
def campaign() -> tuple[list, list[dict[str, object]]]:
    """The rows and walk records of the campaign (run once)."""
    rows, walks, _ = results.fusion_walks("fusion-exact", (SCENARIO,), "exact", WALKS, CONFIG)
    return rows, walks


def _printed(rows: list, walks: list[dict[str, object]], per_walk: bool = True,
             scenarios: tuple[str, ...] = (SCENARIO,), level: str = "exact", first_seed: int = CONFIG.first_seed
             ) -> Section:
    """The ``fusion-exact`` section :mod:`dtmbnav.evaluation.results` keeps for these rows and walks, through the
    data file and back."""
    seeds = len(walks) // len(scenarios)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(results, "fusion_walks", lambda *args: (rows, walks, 60.0))
        section = results.fusion_section("fusion-exact", "Fusion with the exact range", scenarios, level, seeds,
                                         dataclasses.replace(CONFIG, first_seed=first_seed), per_walk)
    printed = dataclasses.replace(section, commit=PRINTED_COMMIT, date="2000-01-01", machine="a machine")
    return ResultsData.from_json(ResultsData((printed,)).to_json())["fusion-exact"]


def _write(tmp_path: Path, *sections: Section) -> Path:
    """The data file of ``sections`` beside a Markdown file of garbage; the Markdown's path."""
    (tmp_path / "results.json").write_text(ResultsData(sections).to_json())
    path = tmp_path / "results.md"
    path.write_text(GARBAGE)
    return path


def _with_track(rows: list, walks: list[dict[str, object]], track: str, values: list[float]
                ) -> tuple[list, list[dict[str, object]]]:
    """The campaign as if ``track``'s 95 % error had been ``values[k]`` on walk k."""
    walks = [{**w, "p95_m": {**w["p95_m"], track: float(values[w["k"]])}} for w in walks]
    rows = [dataclasses.replace(r, p95_m=float(np.mean(values))) if r.filter == track else r for r in rows]
    return rows, walks


def _verdicts(comparisons: list[results_check.Comparison]) -> dict[str, str]:
    return {c.row: c.verdict for c in comparisons}


def _printed_verdicts(out: str) -> dict[str, str]:
    """Row -> verdict of the table the check printed (columns: section, row, ..., verdict), after its status
    lines."""
    table = out[out.index("| section |"):]
    cells = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in table.splitlines()[2:]]
    return {row[1]: row[-1] for row in cells}


@st.composite
def campaigns(draw) -> tuple[list, list[dict[str, object]], int]:
    """Rows and walk records of a drawn campaign (:func:`dtmbnav.evaluation.evaluate.summarise` and ``walk_record``
    of drawn errors), and its first Monte Carlo index."""
    scenarios = draw(st.lists(st.sampled_from(results.FUSION_SCENARIOS), min_size=1, max_size=2, unique=True))
    filters = draw(st.lists(st.sampled_from(FILTER_NAMES), max_size=len(FILTER_NAMES), unique=True))
    seeds = draw(st.integers(1, 4))
    first_seed = draw(st.integers(TUNING_SEEDS.start, TUNING_SEEDS.stop - seeds))
    errors = st.lists(st.floats(0.01, 60.0), min_size=1, max_size=4).map(np.array)
    settings_ = RunSettings(first_seed, "exact")
    rows, walks = [], []
    for scenario in scenarios:
        results_ = [SeedResult(truth=None, tracks={}, heading_error_rad=draw(st.floats(-0.5, 0.5)),
                               errors_m={track: draw(errors) for track in ("pdr", "pdr@fix", *filters)})
                    for _ in range(seeds)]
        rows += summarise(scenario, results_, settings_)
        walks += [walk_record(scenario, k, monte_carlo_seed(7, k, first_seed), r, settings_)
                  for k, r in enumerate(results_)]
    return rows, walks, first_seed


@settings(max_examples=25, deadline=None)
@given(campaigns(), st.booleans())
def test_the_check_reads_every_figure_the_writer_keeps(campaign_, per_walk):
    rows, walks, first_seed = campaign_
    scenarios = tuple(dict.fromkeys(r.scenario for r in rows))
    section = _printed(rows, walks, per_walk, scenarios, first_seed=first_seed)
    assert section.commit == PRINTED_COMMIT and "--first-seed" in section.command
    figures = results_check.fusion_figures(section)
    assert (figures.level, figures.first_seed, figures.walks) == ("exact", first_seed, len(walks) // len(scenarios))
    assert figures.scenarios == list(scenarios)
    # Every mean the table prints, to its printed rounding, and nothing it does not print.
    assert {key: (f.value, f.rounding) for key, f in figures.means.items()} == {
        (r.scenario, r.filter): (float(f"{r.p95_m:.2f}"), 0.005) for r in rows}
    # Every walk's 95 % error of every track is kept, whether the section prints the per-walk table or not.
    assert {key: f.value for key, f in figures.per_walk.items()} == {
        (w["scenario"], w["first_seed"] + w["k"], track): round(value, 2) for w in walks
        for track, value in w["p95_m"].items()}
    assert figures.seeds == {(w["scenario"], w["first_seed"] + w["k"]): w["seed"] for w in walks}


def test_a_check_of_the_printed_walks_passes_and_writes_nothing(campaign, tmp_path, monkeypatch, capsys):
    path = _write(tmp_path, _printed(*campaign))
    before = {p: p.read_bytes() for p in tmp_path.iterdir()}
    # As if this checkout's code were the printing commit's: the same walks must then give the same figures.
    monkeypatch.setattr(results_check.results_status, "same_code", lambda section: section.commit == PRINTED_COMMIT)
    assert main(["-q", "results", "--check", "-o", str(path), "--sections", "fusion-exact,bench",
                 "--workers", "0"]) == EXIT_OK
    out, err = capsys.readouterr()
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == before
    # The sections' status first (this one names a commit git does not know), then the comparisons.
    assert out.splitlines()[:2] == ["fusion-exact: unknown (printed before fingerprints; reprint to track)",
                                    "bench: not printed"]
    verdicts = _printed_verdicts(out)
    # Every track of the table, and each walk of every track (the data keeps them all).
    assert len(verdicts) == len(campaign[0]) * (1 + WALKS)
    assert set(verdicts.values()) == {"ok"}
    assert "bench: not in" in err and "none failed" in err


def test_a_printed_figure_better_than_the_walks_give_is_a_regression(campaign, tmp_path, monkeypatch, capsys):
    rows, walks = campaign
    # The data claims a PF of 0.50 m on every walk (no spread among the printed walks), far below what they give;
    # the Markdown beside it is garbage, and the check reads the data alone.
    path = _write(tmp_path, _printed(*_with_track(rows, walks, "pf", [0.5] * WALKS)))
    monkeypatch.setattr(results, "fusion_walks", lambda *args: (rows, walks, 0.0))  # the re-run: the real walks
    assert main(["-q", "results", "--check", "-o", str(path), "--sections", "fusion-exact"]) == EXIT_NO_RESULT
    out, err = capsys.readouterr()
    assert path.read_text() == GARBAGE
    verdicts = _printed_verdicts(out)
    assert verdicts[f"{SCENARIO} pf"] == "REGRESSION" and verdicts[f"{SCENARIO} ukf"] == "ok"
    # Against the printed figures of the same walks, whose spread is that of the printed walks (none here).
    rerun = np.mean([w["p95_m"]["pf"] for w in walks])
    last = CONFIG.first_seed + WALKS - 1
    assert (f"| fusion-exact | {SCENARIO} pf | {CONFIG.first_seed}-{last} (same walks) | 0.50 m | {rerun:.2f} m "
            "| 0.00 m | REGRESSION |") in out
    # Another commit printed it: its walks moved, which alone fails nothing.
    assert {verdicts[f"{SCENARIO} walk {CONFIG.first_seed + k} pf"] for k in range(WALKS)} == {"moved"}
    assert f"fusion-exact {SCENARIO} pf REGRESSION" in err
    # Without the Markdown at all the verdict is the same.
    path.unlink()
    assert main(["-q", "results", "--check", "-o", str(path), "--sections", "fusion-exact"]) == EXIT_NO_RESULT


def test_the_section_s_own_walks_set_the_spread(campaign):
    rows, walks = campaign
    # A check of the first two walks is judged with the scatter of all the walks the section kept (here spread
    # wide by the third), not with that of the two re-run walks alone, which may lie close together by luck.
    printed_walks = [w["p95_m"]["pf"] + 5.0 * w["k"] for w in sorted(walks, key=lambda w: w["k"])]
    figures = results_check.fusion_figures(_printed(*_with_track(rows, walks, "pf", printed_walks)))
    first_two = [w for w in walks if w["k"] < 2]
    row = {c.row: c for c in results_check.compare_fusion("fusion-exact", figures, first_two, False)}[f"{SCENARIO} pf"]
    kept = results_check.spread_m([round(v, 2) for v in printed_walks], 2)
    assert row.walks.endswith("(same walks)") and row.spread == f"{kept:.2f} m"
    assert row.spread != f"{results_check.spread_m([w['p95_m']['pf'] for w in first_two], 2):.2f} m"


@pytest.mark.parametrize("side, margin, verdict", [(-1, 0.02, "REGRESSION"), (-1, -0.02, "ok"), (0, 0.0, "ok"),
                                                   (1, -0.02, "ok"), (1, 0.02, "better")])
def test_the_spread_of_the_rerun_walks_decides_where_no_walk_is_kept(campaign, side, margin, verdict):
    rows, walks = campaign
    pf = np.array([w["p95_m"]["pf"] for w in sorted(walks, key=lambda w: w["k"])])
    # The documented spread: a 95 % interval of the mean of the re-run walks, from their own scatter; the printed
    # figure's rounding is allowed on top. The data claims a PF mean just beyond (margin > 0) or just inside it.
    spread = stats.t.ppf(0.975, WALKS - 1) * np.std(pf, ddof=1) / np.sqrt(WALKS)
    claim = pf.mean() + side * (spread + 0.005 + margin)
    assert claim > 0.1
    doctored = [claim + (value - pf.mean()) for value in pf]  # the printed mean is the claim
    # A section printed before each walk was kept (migrated from the Markdown) has the table's means alone.
    section = dataclasses.replace(_printed(*_with_track(rows, walks, "pf", doctored), per_walk=False), per_walk=None)
    figures = results_check.fusion_figures(section)
    assert figures.per_walk == {} and figures.means[(SCENARIO, "pf")].value == pytest.approx(claim, abs=0.005)
    comparisons = results_check.compare_fusion("fusion-exact", figures, walks, same_code=False)
    assert _verdicts(comparisons)[f"{SCENARIO} pf"] == verdict


def test_the_same_walks_on_the_printing_code_must_give_the_printed_figures(campaign):
    rows, walks = campaign
    figures = results_check.fusion_figures(_printed(*_with_track(rows, walks, "ukf", [
        w["p95_m"]["ukf"] + 0.02 for w in sorted(walks, key=lambda w: w["k"])])))
    verdicts = _verdicts(results_check.compare_fusion("fusion-exact", figures, walks, same_code=True))
    # A walk 2 cm off its printed figure is not a regression beyond the spread, but the same code must reproduce it.
    assert verdicts[f"{SCENARIO} ukf"] == "NOT REPRODUCED"
    assert {verdicts[f"{SCENARIO} walk {CONFIG.first_seed + k} ukf"] for k in range(WALKS)} == {"NOT REPRODUCED"}
    assert verdicts[f"{SCENARIO} pf"] == "ok"
    verdicts = _verdicts(results_check.compare_fusion("fusion-exact", figures, walks, same_code=False))
    assert verdicts[f"{SCENARIO} ukf"] == "ok"
    # A walk that ran another seed is not the printed walk: refused rather than compared.
    other = [{**w, "seed": w["seed"] + 1} for w in walks]
    with pytest.raises(ValueError, match="not the same walk"):
        results_check.compare_fusion("fusion-exact", figures, other, same_code=False)


RECEIVER_TABLE = """| case | velocity RMSE | range error 95 % / max | f_s error | found | seconds |
|---|---|---|---|---|---|
| park-loop | 0.025 m/s | 0.069 m / 0.125 m | +0.005 Hz | 100.0 % | 93 s |
| sfn-park | 2.997 m/s | (one tower) | -0.006 Hz | 99.0 % | 93 s |"""


def _receiver(table: str) -> Section:
    return Section("receiver", "Receiver against truth", "dtmbnav results --sections receiver",
                   (Prose("Each scenario file's walk."), Table.parse(table)), commit=PRINTED_COMMIT,
                   date="2000-01-01", machine="a machine", wall_s=60.0)


def test_a_row_section_is_compared_figure_by_figure(tmp_path, monkeypatch):
    rerun = _receiver(RECEIVER_TABLE.replace("0.125 m", "0.131 m").replace("+0.005 Hz", "-0.005 Hz")
                      .replace("99.0 %", "98.0 %").replace("2.997", "2.990").replace("93 s |\n", "94 s |\n", 1))
    verdicts = _verdicts(results_check.compare_tables(_receiver(RECEIVER_TABLE), rerun, same_code=False))
    # An error grew: regression; the same magnitude of a signed offset: ok; a share fell: regression; an error
    # shrank: better; the scored stretch changed: moved; a cell without figures: not compared.
    assert verdicts == {"park-loop: velocity RMSE": "ok", "park-loop: range error 95 % / max": "REGRESSION",
                        "park-loop: f_s error": "ok", "park-loop: found": "ok", "park-loop: seconds": "moved",
                        "sfn-park: velocity RMSE": "better", "sfn-park: f_s error": "ok",
                        "sfn-park: found": "REGRESSION", "sfn-park: seconds": "ok"}
    printed = _receiver(RECEIVER_TABLE)
    assert set(_verdicts(results_check.compare_tables(printed, printed, True)).values()) == {"ok"}
    with pytest.raises(ValueError, match="tables changed"):
        results_check.compare_tables(printed, _receiver(RECEIVER_TABLE.replace("| seconds |", "| s |")), False)
    # Through check_results: the section is run again whole (here a stand-in for the receiver cases).
    _write(tmp_path, printed)
    monkeypatch.setattr(results, "receiver_section", lambda config: rerun)
    report = results_check.check_results(tmp_path / "results.json", ["receiver", "pdr"])
    assert [c.row for c in report.failed] == ["park-loop: range error 95 % / max", "sfn-park: found"]
    assert report.notes == [f"pdr: not in {tmp_path / 'results.json'}, nothing to check"]


def test_nothing_to_check_and_a_readme_are_refused(tmp_path):
    bench = Section("bench", "Throughput", "dtmbnav results --sections bench", (Prose("1 s"),),
                    commit=PRINTED_COMMIT, date="2000-01-01", machine="a machine", wall_s=1.0)
    path = _write(tmp_path, bench)
    assert main(["-q", "results", "--check", "-o", str(path), "--sections", "bench"]) == EXIT_BAD_INPUT
    for mode in ("--check", "--status"):
        assert main(["-q", "results", mode, "-o", str(path), "--readme", str(tmp_path / "README.md")]) == EXIT_USAGE
        assert main(["-q", "results", mode, "-o", str(tmp_path / "missing.md")]) == EXIT_BAD_INPUT
    with pytest.raises(SystemExit) as usage:  # argparse's: the two modes exclude each other
        main(["-q", "results", "--check", "--status", "-o", str(path)])
    assert usage.value.code == EXIT_USAGE


def test_the_quick_sections_check_against_the_committed_results():
    """The PDR and the exact-range fusion (the filters' bound) on their first printed walks, in this process.

    Both sections are deterministic walk for walk, so any figure that moves beyond its printed rounding, for
    better or worse, fails here until the sections are reprinted (``dtmbnav results --sections pdr,fusion-exact``):
    a change cannot land with the results file saying what it no longer does.
    """
    config = results.ResultsConfig(cluster=ClusterConfig(workers=0), progress=False)
    report = results_check.check_results(ROOT / "docs" / "results.json", ("pdr", "fusion-exact"), 2, config)
    assert {c.section for c in report.comparisons} == {"pdr", "fusion-exact"}
    moved = [f"{c.section} {c.row}: printed {c.printed}, now {c.rerun} ({c.verdict})" for c in report.comparisons
             if c.verdict != "ok"]
    assert moved == []
