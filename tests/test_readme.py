"""The README is a reference: short, undated, its figures the generated results file's.

The headline table between the README's markers must be exactly what
``dtmbnav results --readme README.md`` writes from the results data
(``docs/results.json``, which ``docs/results.md`` renders), so a figure
cannot be typed in or go stale; every section of the results must name the
command that printed it; the test command the README shows must be
the one CI runs; the links between the documents must resolve.
"""

from __future__ import annotations

import re
from pathlib import Path

from dtmbnav.evaluation import results
from dtmbnav.evaluation.results_data import ResultsData

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DATA = ROOT / "docs" / "results.json"
DATE = re.compile(r"(?<![\w-])20\d\d-\d\d-\d\d(?![\w-])")


def _headline_block(text: str) -> str:
    begin = text.index(results.HEADLINE_BEGIN) + len(results.HEADLINE_BEGIN) + 1
    return text[begin:text.index(results.HEADLINE_END)]


def test_the_readme_is_short_and_its_prose_undated():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    block = _headline_block(text)
    prose = text.replace(block, "")
    assert not DATE.findall(prose), "dates belong in CHANGELOG.md, docs/decisions.md and the results' headers"


def test_the_headline_table_is_the_results_files():
    block = _headline_block(README.read_text(encoding="utf-8"))
    assert block == results.headline_table(ResultsData.load(DATA)) + "\n"


def test_every_results_section_names_the_command_that_printed_it():
    # The Markdown is the data's rendering (tests/test_results_data.py): nothing is typed between the sections.
    sections = ResultsData.load(DATA).sections
    assert sections
    for section in sections:
        assert section.name in results.SECTIONS
        assert re.match(rf"dtmbnav results --sections {section.name}\b", section.command), section.name
        assert re.fullmatch(r"[0-9a-f]{10}", section.commit) and re.fullmatch(r"20\d\d-\d\d-\d\d", section.date)


def test_the_readme_shows_the_test_command_ci_runs():
    readme = README.read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = re.search(r"python -m pytest[^\n`]*", readme).group(0).strip()
    assert command in ci


def test_links_between_the_documents_resolve():
    for page in [README, ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" in target:
                continue
            assert (page.parent / target).exists(), f"{page.relative_to(ROOT)} links to a missing {target}"
