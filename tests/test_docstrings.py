"""Docstrings and comments say what the code does and why, not the evidence that chose it.

Tuning evidence, measured before/after figures, dates and commit ids belong
in ``docs/decisions.md`` and the history, where they can be dated and
re-measured; in a docstring they go stale the day a default moves. This test
reads every docstring (and every other bare string statement) with
:mod:`ast` and every comment with :mod:`tokenize`, in every module of the
five packages, and fails, naming file and line, on text that cites a Monte
Carlo walk by index, a before/after figure, a signed percentage change, a
date or a commit.

Constants of physics or of GB 20600 (3780 carriers, PN420, 7.56 Msps),
equation numbers, parameter defaults, chip ranges and arrows between names
are facts of the code and must not be flagged; the self-test below pins both
sides of each pattern.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dtmbnav_core", "receiver", "sim", "fusion", "dtmbnav")

#: The unit of a reported figure (an error in metres, a percentage, a level), with the space before it; not a
#: rate (Msps, Hz) or a duration, which a docstring may well convert between.
_FIGURE_UNIT = r"(?:\s*(?:%|(?:[ck]?m|m/s|dB|deg)\b))"
_ARROW = r"\s*(?:->|-->|=>|→)\s*"

#: What a docstring or comment may not cite, by name (the name is in the failure message).
PATTERNS: dict[str, re.Pattern[str]] = {
    # "walk 105", "walks 100-119", "walks 200, 203", "tuning walk 107", "reporting walks 200-203";
    # not "walks 10 m" (a distance) or "walks 2 s" (a duration); the figures are matched atomically, so that a
    # range of distances cannot match by giving back its end.
    "Monte Carlo walk index": re.compile(
        r"\bwalks?\s+(?:#\s*|no\.\s*|index\s+)?(?>\d+(?:\s*(?:-|–|\.\.|,|and|or|to)\s*\d+)*)\b"
        r"(?!\s*(?:m|km|s|min|steps?|%|x)\b)(?!\.\d)",
        re.IGNORECASE),
    # "street-out tuning 100-111", "reporting segments 200-209", "seeds 100-119": walks named by their range
    # without the word walk; not "the tuning seeds", "``--seeds 50``" or "chip indices 0-419".
    "Monte Carlo index range": re.compile(
        r"\b(?:tuning|reporting)\s+(?:(?:seeds?|segments?|runs?|indices)\s+)?\d+"
        r"|(?<![\w-])(?:seeds?|segments?)\s+\d+\s*(?:-|–|\.\.|,|and|to)\s*\d+",
        re.IGNORECASE),
    # "street-out 203", "sfn-park 106": a scenario's name and a walk's three-digit index; not a command-line
    # option ("--first-seed 100") or a figure with a unit.
    "scenario walk index": re.compile(
        r"(?<![\w-])[a-z][a-z0-9]*(?:-[a-z0-9]+)+\s+\d{3}\b(?!\.\d)"
        r"(?!\s*(?:%|[mk]?m|[mun]?s|[kMG]?Hz|dB|chips?|samples?|symbols?|frames?|carriers?|bits?)\b)"),
    # "6.42 -> 5.21", "2.09 -> 1.41 m", "+234 % -> +15 %": an arrow between figures; not "x_m -> y_m" or a
    # shape "(n, 3) -> (n,)".
    "before/after arrow": re.compile(
        r"(?<![\w.])[-+]?(?:\d+\.\d+" + _FIGURE_UNIT + r"?|\d+" + _FIGURE_UNIT + r")" + _ARROW + r"[-+]?\d"
        r"|(?<![\w.])[-+]?\d+" + _ARROW + r"[-+]?\d+\.\d"),
    # "36 m before the change, 12.25 m after"; "before: 6.42 m, after: 5.21 m".
    "before/after figures": re.compile(
        r"\d" + _FIGURE_UNIT + r"\s+before\b(?:[^.;]|\.\d){0,80}?\d" + _FIGURE_UNIT + r"\s+after\b"
        r"|\bbefore\s*[:=(]\s*[-+]?\d(?:[^.;]|\.\d){0,80}?\bafter\s*[:=(]\s*[-+]?\d",
        re.IGNORECASE),
    # "before the change", "since the fix": a history of the code rather than what it does.
    "change history": re.compile(
        r"\b(?:before|after|since|until)\s+(?:the|this|that)\s+(?:change|fix|rewrite|refactor(?:ing)?)\b",
        re.IGNORECASE),
    # "PF 95 % 36 m", "particle-filter 95 % errors of 4.66 and 4.34 m": a filter's reported error on some walk;
    # not "the 68 % / 95 % / max position error, m".
    "reported error figure": re.compile(
        r"(?:\b(?:PF|UKF|EKF|PDR@fix)\s+(?:(?:68|95)\s*%\s*)?"
        r"|\b(?:KF|PDR|particle[- ]filter|filter)(?:'s)?\s+(?:68|95)\s*%\s*)"
        r"(?:errors?\s+)?(?:of\s+|was\s+|were\s+|is\s+|at\s+|[:=]\s*)?"
        r"\d+(?:\.\d+)?(?:\s*(?:and|or|to|,|/)\s*\d+(?:\.\d+)?)*\s*m\b",
        re.IGNORECASE),
    # "+234 %", "-4.9 %" (a change measured against a baseline); not "+-5 %" or "10-20 %".
    "signed percentage": re.compile(r"(?<![\w.+\-/±])[+\-−]\d+(?:\.\d+)?\s*%"),
    # "2026-12-02".
    "date": re.compile(r"(?<![\w-])(?:19|20)\d\d-(?:0[1-9]|1[0-2])-(?:0[1-9]|[12]\d|3[01])(?![\w-])"),
    # "commit 3421eb0", "3421eb0 (commit)".
    "commit id": re.compile(
        r"\bcommit(?:s|ted)?\b[^\n]{0,24}?\b(?=[0-9a-f]*\d)[0-9a-f]{7,40}\b"
        r"|\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b\W{0,3}commit",
        re.IGNORECASE),
}

#: Text each pattern must flag.
MUST_MATCH = [
    "on walk 105 the street",
    "the tuning walks 100-119 at the observation level",
    "reporting walks 200, 203",
    "chosen on tuning walk 107",
    "reporting walks 200-203 show",
    "sfn-park tuning walk 100 has a scatter",
    "a first path on street-out 203 turned",
    "bit-identical on sfn-park 106 and street-out 105",
    "PF 95 % went 6.42 -> 5.21",
    "from 2.09 -> 1.41 m",
    "1.87 m -> 1.17 m",
    "36 m -> 12 m",
    "RMS 2 -> 1.4",
    "+234 % -> +15 %",
    "PF 95 % 36 m before the change, 12.25 m after",
    "before: 6.42 m, after: 5.21 m",
    "since the change the filter",
    "particle-filter 95 % errors of 4.66 and 4.34 m",
    "UKF 95 % 2.09 m on the park",
    "PF 11.1 m with it, 5.6 m without",
    "street-out tuning 100-111 (chosen on)",
    "on reporting segments 200-209",
    "obs neutral on seeds 100-119",
    "went from +234 % / +801 % (never) to +15 %",
    "a change of -4.9 % in the error",
    "measured 2026-12-02 on the street",
    "introduced in commit 3421eb0",
    "(3421eb0 commit) reverted",
]

#: Facts of the code no pattern may flag.
MUST_NOT_MATCH = [
    "the heading solution (eq. 15)",
    "the PN420 frame head",
    "a 3780-point FFT",
    "lags -83..82 chips",
    "searched over +-60 kHz",
    "searched over +/-5 %",
    "0.02 m/s by default",
    "(x_m, y_m) -> (east, north)",
    "x_m -> y_m",
    "shape (..., n) -> (..., n, n)",
    "chip indices 0-419 of the header",
    "a step-length gain error of 10-20 %",
    "the walker walks 10 m along the wall",
    "walks 10-20 m along the wall",
    "Monte Carlo walk ``k`` of a scenario",
    "chosen on the tuning walks; docs/decisions.md",
    "``--first-seed 100`` for the tuning seeds",
    "the particle-filter 95 % error",
    "68 % / 95 % / max position error of each filter, m",
    "the filter's 95 % error to that walk's PDR 95 %",
    "``dtmbnav evaluate all --seeds 50``",
    "the PF 95 % column of the table",
    "chosen on the tuning seeds (``--first-seed 100``)",
    "Monte Carlo indices ``first_seed .. first_seed + seeds - 1``",
    "7.56 Msps, 555.6 us frame, 29.6 kHz",
    "GB 20600-2006 section 4",
    "the 0.5 s before the frame",
    "uses the commit-free path of 4096 samples",
    "1e-3 of the frames",
    "a range change of -0.5 m",
    "streaming resampler, 20 Msps -> 7.56 Msps input",
    "eases 0 -> 1 with zero slope at both ends",
    "the lags of their mean CIR, from 4 before to 8 after",
    "1 ms before the peak and 2 ms after it",
]


def test_patterns_flag_evidence() -> None:
    missed = [text for text in MUST_MATCH if not any(p.search(text) for p in PATTERNS.values())]
    assert not missed, f"no pattern flags: {missed}"


def test_patterns_spare_code_facts() -> None:
    flagged = [(text, name) for text in MUST_NOT_MATCH for name, p in PATTERNS.items() if p.search(text)]
    assert not flagged, f"flagged facts of the code: {flagged}"


def source_files() -> list[Path]:
    """Every Python module of the five packages, sorted."""
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py") if "__pycache__" not in p.parts)


def texts(source: str) -> list[tuple[int, str]]:
    """(first line, text) of every bare string statement (docstrings included) and every comment block of a module.

    Comments on consecutive lines are joined into one block, so that a
    citation wrapped across two comment lines is still seen whole.
    """
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str)):
            out.append((node.lineno, node.value.value))
    block: list[str] = []
    start = last = 0
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type != tokenize.COMMENT:
            continue
        line = token.start[0]
        if block and line != last + 1:
            out.append((start, "\n".join(block)))
            block = []
        if not block:
            start = line
        block.append(token.string.lstrip("#:").strip())
        last = line
    if block:
        out.append((start, "\n".join(block)))
    return out


def violations(path: Path) -> list[str]:
    """``path:line: [pattern] text`` for each cited piece of evidence in a module's docstrings and comments."""
    found = []
    for first_line, text in texts(path.read_text(encoding="utf-8")):
        for name, pattern in PATTERNS.items():
            for match in pattern.finditer(text):
                line = first_line + text.count("\n", 0, match.start())
                excerpt = " ".join(text[max(0, match.start() - 30):match.end() + 30].split())
                found.append(f"{path.relative_to(ROOT)}:{line}: [{name}] ...{excerpt}...")
    return found


@pytest.mark.parametrize("path", source_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_cited_evidence(path: Path) -> None:
    found = violations(path)
    assert not found, "docstrings/comments cite tuning evidence or history (docs/decisions.md holds it):\n" + \
        "\n".join(found)
