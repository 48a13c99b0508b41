"""dtmbnav: DTMB Doppler ranging receiver and PDR fusion, the application layer.

``receiver``, ``sim`` and ``fusion`` are the libraries, standing on the
foundation ``dtmbnav_core``; this package wires them into the ``dtmbnav``
command line (simulate, receive, pdr, fuse, run, report, evaluate, results,
bench, demo).
"""

from dtmbnav_core.version import __version__, package_version

__all__ = ["__version__", "package_version"]
