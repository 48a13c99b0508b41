"""dtmbnav: DTMB Doppler ranging receiver and PDR fusion, the application layer.

``receiver``, ``sim`` and ``fusion`` are the libraries; this package wires them
into the ``dtmbnav`` command line (simulate, receive, pdr, fuse, run, report,
evaluate, bench, demo).
"""

#: The package version, defined here once (``pyproject.toml`` reads it; ``dtmbnav --version`` prints the
#: installed metadata's, this when run from a source tree that is not installed).
__version__ = "0.1.0"


def package_version() -> str:
    """The installed distribution's version; :data:`__version__` when run from a tree that is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("dtmbnav")
    except PackageNotFoundError:
        return __version__
