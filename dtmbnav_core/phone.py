"""What a phone's own log means: its clock against another's, and the accuracy it states for a fix.

The simulator writes a walk as a phone app would (``sim/phone_log_writer.py``) and ``dtmbnav sensors``
reads such logs back (``dtmbnav/field/sensors_import.py``); both take these definitions from here.

Clock model. A phone stamps its samples on its own oscillator. Against a reference clock (the capture's,
whose first sample has a known UTC time) it is off by a constant offset at the log's start and runs
fast by a drift: a moment ``t_s`` seconds after the log's start (reference clock) reads

- ``elapsed_s(t_s) = t_s (1 + drift_ppm 1e-6)`` on the phone's monotonic clock since the log's start
  (Android's ``elapsedRealtimeNanos`` less its value then);
- ``true UTC + offset_s + drift_ppm 1e-6 t_s`` on the phone's UTC clock.

Nothing here imports numpy (the methods take numpy arrays and use their own operators and methods), so
that the command line can take the defaults and the format names without slowing ``--help``.

Stated accuracy. Android states a fix's horizontal accuracy as the radius of
:data:`ACCURACY_CONFIDENCE` confidence; for a circular normal error that radius is
:data:`ACCURACY_RADIUS_SIGMAS` per-axis standard deviations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

#: The phone apps whose logs ``dtmbnav sensors`` reads and ``dtmbnav simulate --phone-log`` writes: Google's
#: GnssLogger (a text log) and the Sensor Logger app (a CSV export).
PHONE_LOG_FORMATS = ("gnsslogger", "sensorlogger")
#: Default phone clock offset against the capture's clock, s, and drift, ppm (the phone agrees with the capture).
DEFAULT_CLOCK_OFFSET_S = 0.0
DEFAULT_CLOCK_DRIFT_PPM = 0.0
#: Confidence of Android's stated horizontal accuracy radius.
ACCURACY_CONFIDENCE = 0.68
#: Radius of :data:`ACCURACY_CONFIDENCE` of a circular normal error, in per-axis sigmas.
ACCURACY_RADIUS_SIGMAS = math.sqrt(-2.0 * math.log(1.0 - ACCURACY_CONFIDENCE))


@dataclass(frozen=True)
class PhoneClock:
    """A phone's clock against the reference clock (module docstring).

    Attributes
    ----------
    offset_s : float
        Phone UTC minus true UTC at the log's start, s.
    drift_ppm : float
        How much faster the phone's oscillator runs, ppm (1e-6): positive, the phone's seconds are short.
    """

    offset_s: float = DEFAULT_CLOCK_OFFSET_S
    drift_ppm: float = DEFAULT_CLOCK_DRIFT_PPM

    def __post_init__(self) -> None:
        if not (math.isfinite(self.offset_s) and math.isfinite(self.drift_ppm)):
            raise ValueError(f"phone clock offset and drift must be finite, got {self.offset_s}, {self.drift_ppm}")
        if abs(self.drift_ppm) >= 1e6:
            raise ValueError(f"phone clock drift {self.drift_ppm} ppm: the clock would stand still or run back")

    @property
    def rate(self) -> float:
        """Phone seconds per reference second."""
        return 1.0 + self.drift_ppm * 1e-6

    def elapsed_s(self, t_s: np.ndarray) -> np.ndarray:
        """The phone's monotonic clock since the log's start at ``t_s`` s after it (reference clock), s."""
        return t_s * self.rate

    def reference_s(self, elapsed_s: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`elapsed_s`: the reference clock's seconds since the log's start, s."""
        return elapsed_s / self.rate

    def elapsed_ns(self, t_s: np.ndarray) -> np.ndarray:
        """:meth:`elapsed_s` in whole ns (int64 array)."""
        return (self.elapsed_s(t_s) * 1e9).round().astype("int64")

    def utc_ns(self, t_s: np.ndarray, start_utc_ns: int) -> np.ndarray:
        """The phone's UTC stamps (int64 ns since the Unix epoch) at ``t_s`` s after the log's start (an array),
        whose true UTC is ``start_utc_ns``."""
        return int(start_utc_ns) + ((self.elapsed_s(t_s) + self.offset_s) * 1e9).round().astype("int64")
