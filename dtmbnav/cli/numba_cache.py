"""A writable place for numba's compiled kernels, chosen before numba is imported.

Every kernel is compiled with ``@njit(cache=True)``. numba writes the compiled
code to ``NUMBA_CACHE_DIR`` when it is set and writable, else next to the
source (each package's ``__pycache__``), else to the user's cache folder; when
it can write to none of them it refuses to define the kernels ("cannot cache
function ...: no locator available"), so every command would end in a
traceback (a package installed read-only by another user, a read-only home).
:func:`configure_numba_cache` checks those places first and, when none is
writable, points ``NUMBA_CACHE_DIR`` at one that is, or, as a last resort,
turns caching off (the kernels are then compiled on every run).

numba reads ``NUMBA_CACHE_DIR`` once, when it is imported: this must run
before, which the command line does before any handler imports a kernel.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import tempfile
from collections.abc import Iterable, MutableMapping
from pathlib import Path

#: The packages whose modules define cached numba kernels.
KERNEL_PACKAGES = ("receiver", "fusion", "sim", "dtmbnav")
CACHE_ENV = "NUMBA_CACHE_DIR"


def writable_folder(folder: Path) -> bool:
    """Whether ``folder`` exists or can be made, and a file can be created in it (numba's own test)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def source_cache_folders(packages: Iterable[str] = KERNEL_PACKAGES) -> list[Path]:
    """The ``__pycache__`` folder numba uses next to each package folder's modules."""
    folders = []
    for name in packages:
        spec = importlib.util.find_spec(name)
        for root in (spec.submodule_search_locations or []) if spec else []:
            for dirpath, dirnames, filenames in os.walk(root):
                dirnames[:] = [d for d in dirnames if d != "__pycache__" and not d.startswith(".")]
                if "__init__.py" in filenames:
                    folders.append(Path(dirpath) / "__pycache__")
    return folders


def fallback_cache_folders(environ: MutableMapping[str, str]) -> list[Path]:
    """Where the cache goes when numba's places are not writable: the user's cache folder, then the temp folder."""
    candidates = []
    xdg = environ.get("XDG_CACHE_HOME")
    try:
        candidates.append((Path(xdg) if xdg else Path.home() / ".cache") / "dtmbnav" / "numba")
    except RuntimeError:  # no home folder to be found
        pass
    candidates.append(Path(tempfile.gettempdir()) / f"dtmbnav-numba-{os.getuid() if hasattr(os, 'getuid') else 0}")
    return candidates


def choose_cache_folder(environ: MutableMapping[str, str], source_folders: Iterable[Path],
                        fallbacks: Iterable[Path]) -> tuple[Path | None, str | None]:
    """Decide where numba caches.

    Returns
    -------
    folder : Path or None
        A folder to set as ``NUMBA_CACHE_DIR``; None when numba's own choice
        works (``note`` is None) or when nothing is writable (``note`` says so).
    note : str or None
        Why the cache moved (for a warning), None when it did not.
    """
    given = environ.get(CACHE_ENV)
    if given:
        if writable_folder(Path(given)):
            return None, None
        note = f"{CACHE_ENV}={given} is not a writable folder"
    else:
        unwritable = [f for f in source_folders if not writable_folder(f)]
        if not unwritable:
            return None, None
        note = f"{unwritable[0]} is not writable"
    for folder in fallbacks:
        if writable_folder(folder):
            return folder, f"{note}; numba caches the compiled kernels in {folder}"
    return None, f"{note}, nor is any other cache folder; the kernels are compiled on every run (no cache)"


def _disable_caching() -> None:
    """Make ``@njit(cache=True)`` compile without a cache (numba has no setting for it)."""
    from numba.core.dispatcher import Dispatcher

    Dispatcher.enable_caching = lambda self: None


def configure_numba_cache(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Give numba a writable cache before it is imported; returns a warning line when it had to act.

    Does nothing once numba is imported (it has read its settings by then).
    """
    if "numba" in sys.modules:
        return None
    folder, note = choose_cache_folder(environ, source_cache_folders(), fallback_cache_folders(environ))
    if folder is not None:
        environ[CACHE_ENV] = str(folder)
    elif note is not None:
        environ.pop(CACHE_ENV, None)
        _disable_caching()
    return note
