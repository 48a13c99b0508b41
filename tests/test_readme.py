"""The README is a reference: short, undated, its figures the generated results file's.

The headline table between the README's markers must be exactly what
``dtmbnav results --readme README.md`` writes from ``docs/results.md``, so a
figure cannot be typed in or go stale; every table of the results file must
name the command that printed it; the test command the README shows must be
the one CI runs; the links between the documents must resolve.
"""

from __future__ import annotations

import re
from pathlib import Path

from dtmbnav.evaluation import results

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
RESULTS = ROOT / "docs" / "results.md"
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
    assert block == results.headline_table(RESULTS.read_text(encoding="utf-8")) + "\n"


def test_every_results_section_names_the_command_that_printed_it():
    text = RESULTS.read_text(encoding="utf-8")
    assert text.startswith(results.PREAMBLE)
    sections = list(results.SECTION_RE.finditer(text))
    # Nothing typed between the sections: every line after the preamble belongs to one.
    assert sections and results.SECTION_RE.sub("", text[len(results.PREAMBLE):]).strip() == ""
    for match in sections:
        name = match.group("name")
        assert name in results.SECTIONS
        assert re.search(rf"Printed by `dtmbnav results --sections {name}\b[^`]*` at commit `[0-9a-f]{{10}}` on "
                         r"20\d\d-\d\d-\d\d;", match.group(0)), name


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
