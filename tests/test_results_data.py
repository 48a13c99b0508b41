"""The results as data: ``docs/results.json`` is the source, ``docs/results.md`` its rendering.

The committed Markdown must be exactly what the committed data renders to,
every number of a table must be a number in the data (with the digits and
unit it prints with), and the README's headline must come from the data
even where the Markdown is broken. Each section's status says whether the
files it ran changed since it was printed (its fingerprint), or, for a
section printed before fingerprints, whether git sees the library change
since its commit.
"""

from __future__ import annotations

import shutil
import subprocess
import types
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dtmbnav.cli import EXIT_OK, main
from dtmbnav.evaluation import results
from dtmbnav.evaluation.results_data import Cell, Code, Prose, ResultsData, Section, Table, join, number, percent
from dtmbnav.evaluation.results_status import UNKNOWN, file_hash, fingerprint, section_status, statuses

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results.md"
DATA = ROOT / "docs" / "results.json"


def test_the_results_file_is_the_rendering_of_its_data():
    assert ResultsData.load(DATA).markdown() == RESULTS.read_text(encoding="utf-8")


def test_the_data_file_is_as_the_writer_writes_it():
    text = DATA.read_text(encoding="utf-8")
    assert ResultsData.from_json(text).to_json() == text


def test_every_number_of_a_table_is_a_number_in_the_data():
    for section in ResultsData.load(DATA).sections:
        for table in section.tables():
            for row in table.rows:
                # The first cell names the row; every other cell holds each number it prints as a figure.
                for cell in row[1:]:
                    parsed = Cell.parse(cell.text)
                    assert (cell.template, [(f.value, f.decimals, f.unit) for f in cell.figures]) == \
                        (parsed.template, [(f.value, f.decimals, f.unit) for f in parsed.figures]), section.name


def test_the_fusion_rows_are_keyed_by_scenario_and_their_figures_are_numbers():
    table = ResultsData.load(DATA)["fusion-obs"].table("fusion")
    row = table.rows[table.keys.index("park-loop-cw")]
    pf = row[table.column(results.PF_COLUMN)]
    assert pf.text == "2.66 m (36.8 % / 41.8 %)" and [f.value for f in pf.figures] == [2.66, 36.8, 41.8]
    assert row[table.column("walks")].figures[0].value == 50


metres = st.floats(-1e4, 1e4, allow_nan=False)
cells = st.one_of(
    st.builds(number, metres, st.integers(0, 4), st.sampled_from(["", "m", "m/s", "Hz", "deg", "s"]), st.booleans()),
    st.builds(percent, st.floats(-5.0, 5.0), st.integers(0, 2), st.booleans()),
    st.builds(lambda a, b: join(a, " (", b, ")"), st.builds(number, metres, st.integers(0, 3), st.just("m")),
              st.builds(percent, st.floats(-5.0, 5.0))),
    st.sampled_from([Cell.plain("-"), Cell.plain("(one tower)"), Cell.plain("yes, right")]))


@given(st.lists(st.lists(cells, min_size=3, max_size=3), min_size=1, max_size=4))
def test_a_table_prints_back_as_the_numbers_it_keeps(rows):
    table = Table(("case", "a", "b", "c"), tuple((Cell.plain(f"row {i}"), *row) for i, row in enumerate(rows)))
    text = table.markdown()
    again = Table.parse(text)
    assert again.markdown() == text
    for mine, theirs in zip(table.rows, again.rows):
        for cell, parsed in zip(mine[1:], theirs[1:]):
            assert [(f.value, f.decimals, f.unit) for f in cell.figures] == \
                [(f.value, f.decimals, f.unit) for f in parsed.figures]
    section = Section("receiver", "t", "dtmbnav results --sections receiver", (Prose("p"), table, Code("x\ny")))
    assert ResultsData.from_json(ResultsData((section,)).to_json()) == ResultsData((section,))


def test_a_table_that_would_not_print_back_is_refused():
    with pytest.raises(ValueError, match="prints back"):
        Table.parse("|a|b|\n|:--|--|\n|x|1 m|")


def _module(name: str, path: Path) -> types.ModuleType:
    module = types.ModuleType(name)
    module.__file__ = str(path)
    return module


def _tree(root: Path) -> dict[str, types.ModuleType]:
    """A checkout with a library module, a scenario file, a command-line module and one outside; its modules."""
    for path in ("sim/scenario.py", "sim/scenarios/walk.toml", "dtmbnav/cli/results.py"):
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        (root / path).write_text(f"# {path}\n")
    return {"sim.scenario": _module("sim.scenario", root / "sim" / "scenario.py"),
            "dtmbnav.cli.results": _module("dtmbnav.cli.results", root / "dtmbnav" / "cli" / "results.py"),
            "numpy": _module("numpy", Path(__file__)), "sim.elsewhere": _module("sim.elsewhere", Path(__file__))}


def test_a_section_is_out_of_date_when_a_file_it_ran_changes(tmp_path):
    root = tmp_path / "checkout"
    printed = fingerprint(root, _tree(root))
    # The library's modules and the data they read, not the command line nor anything outside the checkout.
    assert printed == {"sim/scenario.py": file_hash(root / "sim" / "scenario.py"),
                       "sim/scenarios/walk.toml": file_hash(root / "sim" / "scenarios" / "walk.toml")}
    section = Section("pdr", "PDR", "dtmbnav results --sections pdr", (), commit="unknown", fingerprint=printed)
    assert section_status(section, root).line() == "pdr: up to date (its 2 files unchanged)"
    (root / "sim" / "scenarios" / "walk.toml").write_text("seed = 2\n")
    (root / "sim" / "scenario.py").unlink()
    assert section_status(section, root).line() == ("pdr: out of date, 2 of the 2 files it ran changed: "
                                                    "sim/scenarios/walk.toml, sim/scenario.py (removed)")


def _git(root: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True).stdout.strip()


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_section_printed_before_fingerprints_is_compared_with_git(tmp_path):
    _tree(tmp_path)
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "printed")
    section = Section("paths", "Paths", "dtmbnav results --sections paths", (),
                      commit=_git(tmp_path, "rev-parse", "--short=10", "HEAD"))
    assert section_status(section, tmp_path).line() == (
        f"paths: up to date (dtmbnav_core, receiver, sim, fusion unchanged since {section.commit}; printed before "
        "fingerprints)")
    # The application's modules are not compared (they moved between rooms); the library's are.
    (tmp_path / "dtmbnav" / "cli" / "results.py").write_text("# changed\n")
    assert section_status(section, tmp_path).up_to_date
    (tmp_path / "sim" / "scenario.py").write_text("# changed\n")
    assert section_status(section, tmp_path).line() == (
        f"paths: out of date, 1 file of dtmbnav_core, receiver, sim, fusion changed since {section.commit} (printed "
        "before fingerprints): sim/scenario.py")
    # A commit git does not know (or none): nothing to compare.
    for commit in ("unknown", "0123456789", f"{section.commit}+modified"):
        assert section_status(replace(section, commit=commit), tmp_path).line() == f"paths: {UNKNOWN}"


def test_status_prints_a_line_per_section_and_writes_nothing(tmp_path, capsys):
    shutil.copy(DATA, tmp_path / "results.json")
    assert main(["-q", "results", "--status", "-o", str(tmp_path / "results.md"), "--sections", "pdr,bench"]) == EXIT_OK
    out = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in out] == ["pdr", "bench"]
    assert all(": up to date (" in line or ": out of date, " in line or UNKNOWN in line for line in out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json"]
    assert [s.line() for s in statuses(ResultsData(), ["pdr"])] == ["pdr: not printed"]


def test_the_readme_headline_comes_from_the_data_whatever_the_markdown_holds(tmp_path, monkeypatch):
    shutil.copy(DATA, tmp_path / "results.json")
    (tmp_path / "results.md").write_text("garbage | 1.00 m |\n")
    readme = tmp_path / "README.md"
    shutil.copy(ROOT / "README.md", readme)
    text = readme.read_text(encoding="utf-8")
    readme.write_text(text.replace(text[text.index(results.HEADLINE_BEGIN):text.index(results.HEADLINE_END)],
                                   f"{results.HEADLINE_BEGIN}\nstale figures\n"), encoding="utf-8")
    # A quick section reprinted (a stand-in for the PDR's) with --readme: the headline is written from the fusion
    # sections' data, as the README has it, and the Markdown rendered again from the data.
    data = ResultsData.load(DATA)
    monkeypatch.setattr(results, "section_runners", lambda config: {"pdr": lambda: data["pdr"]})
    assert main(["-q", "results", "-o", str(tmp_path / "results.md"), "--sections", "pdr", "--readme",
                 str(readme)]) == EXIT_OK
    assert readme.read_text(encoding="utf-8") == (ROOT / "README.md").read_text(encoding="utf-8")
    written = ResultsData.load(tmp_path / "results.json")
    assert (tmp_path / "results.md").read_text(encoding="utf-8") == written.markdown()
    assert written["fusion-obs"] == data["fusion-obs"] and written["pdr"].fingerprint
