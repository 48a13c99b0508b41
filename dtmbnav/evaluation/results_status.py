"""Which printed sections of the results are out of date: the files each ran, against the checkout's.

When ``dtmbnav results`` prints a section it records the project's modules
that are imported once the section has run (``sys.modules``, restricted to
:data:`PACKAGES`) and the data files they read (:data:`DATA_FILES`), each
with a hash of its contents (:func:`fingerprint`). A section is *up to date*
while each of those files hashes as it did, and *out of date* when some
changed or were removed: its figures may have moved, and only a reprint
says how far. The list is what this process imported: walks run in worker
or child processes import the same modules, as each section imports the
modules they run here first (the fusion sections their level's range
source, the field section the commands its walks run), and a section run
after others in one process also lists theirs, which can call it out of
date for a change it does not depend on.

A section printed before fingerprints were kept has none. Where git knows
the commit that printed it, the library packages (:data:`LIBRARY`) of that
commit are compared with the checkout's files (``git diff``, local changes
included); the application's modules are not, as they have moved since.
Without git, or for a commit git does not know, its status is unknown.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from dtmbnav.evaluation.results_data import ResultsData, Section

#: The checkout: the folder holding the project's packages.
ROOT = Path(__file__).resolve().parents[2]
#: Packages whose modules a section's figures depend on: the library and the application's rooms that compute
#: (not the command line).
PACKAGES = ("dtmbnav_core", "receiver", "sim", "fusion", "dtmbnav.evaluation", "dtmbnav.simulation",
            "dtmbnav.chain", "dtmbnav.field")
#: The library packages, compared with git for a section printed without a fingerprint.
LIBRARY = ("dtmbnav_core", "receiver", "sim", "fusion")
#: Data files a module reads, by module: a section that imported it depends on them too (glob under the checkout).
DATA_FILES = {"sim.scenario": "sim/scenarios/*.toml"}
#: Hex digits of a file's SHA-256 kept in a fingerprint (enough to tell a changed file).
HASH_CHARS = 16
#: Files named on a status line; more are counted.
LISTED = 8
#: Status of a section printed before fingerprints where git cannot compare.
UNKNOWN = "unknown (printed before fingerprints; reprint to track)"


def file_hash(path: Path) -> str:
    """The first :data:`HASH_CHARS` hex digits of the SHA-256 of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()[:HASH_CHARS]


def _in_packages(name: str) -> bool:
    return any(name == package or name.startswith(package + ".") for package in PACKAGES)


def fingerprint(root: Path = ROOT, modules: Mapping[str, ModuleType] | None = None) -> dict[str, str]:
    """The project files a section ran, by path under ``root`` (POSIX), with their :func:`file_hash`.

    Parameters
    ----------
    root : Path
        The checkout.
    modules : mapping of str to module, optional
        The imported modules (default ``sys.modules``); those of :data:`PACKAGES` whose files lie under ``root``
        count, with the :data:`DATA_FILES` they read.
    """
    modules = sys.modules if modules is None else modules
    files: set[Path] = set()
    for name, module in list(modules.items()):
        if not _in_packages(name):
            continue
        if getattr(module, "__file__", None):
            files.add(Path(module.__file__).resolve())
        if name in DATA_FILES:
            files.update(p.resolve() for p in root.glob(DATA_FILES[name]))
    root = root.resolve()
    return {path.relative_to(root).as_posix(): file_hash(path) for path in sorted(files) if path.is_relative_to(root)}


@dataclass(frozen=True)
class SectionStatus:
    """Whether a printed section's figures come from the checkout's files.

    Attributes
    ----------
    name : str
        The section.
    state : str
        ``up to date``, ``out of date``, ``unknown`` or ``not printed``.
    changed, removed : tuple of str
        Files (paths under the checkout) that changed, or are gone, since it was printed.
    basis : str
        What was compared, as the status line says it.
    """

    name: str
    state: str
    changed: tuple[str, ...] = ()
    removed: tuple[str, ...] = ()
    basis: str = ""

    @property
    def up_to_date(self) -> bool:
        return self.state == "up to date"

    def line(self) -> str:
        """One line: ``NAME: up to date (basis)``, ``NAME: out of date, basis: files``, or the state alone."""
        if self.state == "unknown":
            return f"{self.name}: {UNKNOWN}"
        if self.state == "up to date":
            return f"{self.name}: up to date ({self.basis})"
        if self.state != "out of date":
            return f"{self.name}: {self.state}"
        named = [*self.changed, *(f"{path} (removed)" for path in self.removed)]
        more = f" and {len(named) - LISTED} more" if len(named) > LISTED else ""
        return f"{self.name}: out of date, {self.basis}: {', '.join(named[:LISTED])}{more}"


def run_git(root: Path, *args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess | None:
    """A git command in ``root``, its output captured as text; None where git is missing or times out."""
    try:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.SubprocessError):
        return None


def _known_commit(commit: str) -> bool:
    """Whether ``commit`` names a commit of its own (not ``unknown``, nor one printed from a modified checkout)."""
    return re.fullmatch(r"[0-9a-f]{7,40}", commit) is not None


def changes_since(commit: str, paths: Sequence[str], root: Path = ROOT) -> tuple[list[str], list[str]] | None:
    """Files under ``paths`` that differ between ``commit`` and the checkout (local changes included): those
    changed or added, and those removed; None where git cannot tell (no git, an unknown commit)."""
    if not _known_commit(commit):
        return None
    done = run_git(root, "diff", "--name-status", "--no-renames", commit, "--", *paths)
    if done is None or done.returncode != 0:
        return None
    changed, removed = [], []
    for line in done.stdout.splitlines():
        status, _, path = line.partition("\t")
        (removed if status == "D" else changed).append(path)
    return changed, removed


def code_unchanged_since(commit: str, root: Path = ROOT) -> bool:
    """Whether the checkout's code is that of ``commit``: no tracked file but the Markdown documents and the results
    data differs from it, local changes included. False for a commit git does not know, or outside a git
    checkout."""
    if not _known_commit(commit):
        return False
    done = run_git(root, "diff", "--quiet", commit, "--", ".", ":(exclude)*.md", ":(exclude)docs/results.json")
    return done is not None and done.returncode == 0


def section_status(section: Section, root: Path = ROOT) -> SectionStatus:
    """The status of a printed section (module docstring)."""
    if section.fingerprint is not None:
        changed = tuple(path for path, digest in section.fingerprint.items()
                        if (root / path).exists() and file_hash(root / path) != digest)
        removed = tuple(path for path in section.fingerprint if not (root / path).exists())
        if changed or removed:
            count = len(changed) + len(removed)
            return SectionStatus(section.name, "out of date", changed, removed,
                                 f"{count} of the {len(section.fingerprint)} files it ran changed")
        return SectionStatus(section.name, "up to date", basis=f"its {len(section.fingerprint)} files unchanged")
    diff = changes_since(section.commit, LIBRARY, root)
    if diff is None:
        return SectionStatus(section.name, "unknown")
    changed, removed = diff
    library = ", ".join(LIBRARY)
    if changed or removed:
        count = len(changed) + len(removed)
        return SectionStatus(section.name, "out of date", tuple(changed), tuple(removed),
                             f"{count} file{'s' if count > 1 else ''} of {library} changed since {section.commit} "
                             "(printed before fingerprints)")
    return SectionStatus(section.name, "up to date",
                         basis=f"{library} unchanged since {section.commit}; printed before fingerprints")


def statuses(data: ResultsData, names: Sequence[str], root: Path = ROOT) -> list[SectionStatus]:
    """The status of each of ``names``, in that order (``not printed`` for one the data lacks)."""
    return [section_status(data[name], root) if name in data else SectionStatus(name, "not printed")
            for name in names]


def same_code(section: Section, root: Path = ROOT) -> bool:
    """Whether the checkout runs the code that printed ``section``, so that its walks must give its figures again:
    its fingerprint's files unchanged, or, for a section without one, :func:`code_unchanged_since` its commit."""
    if section.fingerprint is not None:
        return section_status(section, root).up_to_date
    return code_unchanged_since(section.commit, root)
