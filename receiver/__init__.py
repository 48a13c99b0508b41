"""DTMB receiver: capture -> resampler -> acquisition -> tracking -> channel estimate -> body -> FFT -> CFO -> range.

One stage per module (``receiver.pipeline`` wires them). This module holds only
the defaults that callers need without importing the numba kernels (the
command line's parser uses them).
"""

#: Seconds at the start of a capture during which the receiver stands still; the oscillator
#: offset f_s is measured there (eq. 9-10) unless the user gives it.
DEFAULT_STATIC_WINDOW_S = 10.0

#: Half-width of the acquisition's carrier-offset search, Hz: cheap SDR crystals are off by +-20-25 ppm,
#: up to about 20 kHz at UHF (docs/paths.md, "Oscillators of common SDRs"), with margin.
DEFAULT_CFO_SEARCH_HZ = 60e3

#: Where the path ranges' f_s is measured over the static window (``receiver.paths.PathConfig.clock_path``):
#: on the first path, or on the path whose phase is steadiest there. The steadiest by default: where the
#: direct path is blocked during the standstill the first path merges with diffuse scatter and its mean
#: frequency there is off, while a wall reflection may hold its phase; with the direct path in sight both
#: agree (:mod:`receiver.ranging`; docs/paths.md, "Which path measures f_s"; docs/decisions.md, D5).
CLOCK_PATHS = ("first", "steadiest")
DEFAULT_CLOCK_PATH = "steadiest"

#: Whether the path tracker follows paths up to the guard interval either side of the frame timing
#: (``receiver.paths.PathConfig.guard_span``; with a rotating header phase): the towers of a
#: single-frequency network may arrive up to the guard interval apart, beyond the header's cyclic
#: extension (docs/paths.md, "The guard-interval span").
DEFAULT_GUARD_SPAN = True
