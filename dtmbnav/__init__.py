"""dtmbnav: DTMB Doppler ranging receiver and PDR fusion, the application layer.

``receiver``, ``sim`` and ``fusion`` are the libraries; this package wires them
into the ``dtmbnav`` command line (simulate, receive, pdr, fuse, run, report,
evaluate, bench, demo).
"""
