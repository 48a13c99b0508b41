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
#: on the first path, or on the strongest path held through the window. "first" stays the default: on the
#: tuning walks 100-105 of both streets "strongest" had the smaller f_s error (docs/paths.md), but on the
#: reporting walks 200-209 of street-out the fusion with it was better on six walks and worse on three
#: (walk 209: the strongest path held through the window was itself an unresolved pair, 81 mHz off).
CLOCK_PATHS = ("first", "strongest")
DEFAULT_CLOCK_PATH = "first"
