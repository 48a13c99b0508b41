"""The distribution's version, defined once (``pyproject.toml`` reads :data:`__version__`)."""

from __future__ import annotations

#: The package version; ``dtmbnav --version`` and every file's attribute print the installed metadata's,
#: this when run from a source tree that is not installed.
__version__ = "0.1.0"


def package_version() -> str:
    """The installed distribution's version; :data:`__version__` when run from a tree that is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("dtmbnav")
    except PackageNotFoundError:
        return __version__
