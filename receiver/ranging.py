"""Clock-offset calibration and Doppler ranging (docs/method.md §2, eq. 9-11).

``df_m = f_s + f_d,m + noise`` (eq. 9): f_s, the constant part of the carrier
offset (oscillator mismatch plus the tuner's bulk offset), is measured while
the receiver stands still at the start (``static_window_s``, default :data:`receiver.DEFAULT_STATIC_WINDOW_S`) or
given by the user. Then per frame

- ``doppler_hz = cfo_hz - f_s``,
- ``velocity_mps = doppler_hz * c / fc`` (eq. 10; positive when closing),
- ``range_change_m = -(c / fc) * sum (cfo_hz - f_s) * dt`` (eq. 11 with the
  sign of docs/conventions.md: range shrinks when closing), with dt the time
  between the frame and the one before it.

The f_s of the static window is the time-weighted mean of the CFO over it,
i.e. the total SI phase advance over the window divided by its duration (the
per-frame phase differences telescope). The sum is kept in float64 and is
continuous across batches. The first frame of a lock has no CFO pair and
adds nothing, so across a gap (a loss of lock and a re-acquisition) the range
is held flat: nothing is known of the motion during the gap, and inventing
some (the last velocity times the gap) would put a jump in the range. After a
gap ``range_change_m`` is therefore the range change since the first frame of
the new segment (``segment_id``) plus the last value of the segment before
it; the receiver flags that frame GAP, and the fusion takes the new segment as
a new range origin.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dtmbnav.core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav.core.records import FrameBatch, FrameFlag
from receiver import DEFAULT_STATIC_WINDOW_S


class RangeIntegrator:
    """Turns CFO rows into Doppler, velocity and integrated range.

    Parameters
    ----------
    carrier_hz : float
        RF carrier of the tower, Hz.
    clock_offset_hz : float or None
        f_s given by the user; None to measure it over the static window.
    static_window_s : float
        Length of the static window at the start of the first lock, s.
    """

    def __init__(self, carrier_hz: float, clock_offset_hz: float | None = None,
                 static_window_s: float = DEFAULT_STATIC_WINDOW_S) -> None:
        if not np.isfinite(carrier_hz) or carrier_hz <= 0:
            raise ValueError(f"carrier_hz must be a positive frequency, got {carrier_hz!r}")
        if clock_offset_hz is None and static_window_s <= 0:
            raise ValueError("static_window_s must be positive when no clock_offset_hz is given")
        self.carrier_hz = carrier_hz
        self.wavelength_m = SPEED_OF_LIGHT_MPS / carrier_hz
        self.clock_offset_hz = clock_offset_hz
        self.static_window_s = static_window_s
        self._pending: list[FrameBatch] = []
        self._t_first: float | None = None
        self._range_m = 0.0
        self._last_t_s: float | None = None

    def push(self, batch: FrameBatch) -> list[FrameBatch]:
        """Add receiver rows; return the rows whose range is now known."""
        if len(batch) == 0:
            return []
        if self._t_first is None:
            self._t_first = float(batch.t_s[0])
        if self.clock_offset_hz is not None:
            return [self._integrate(batch)]
        self._pending.append(batch)
        if float(batch.t_s[-1]) < self._t_first + self.static_window_s:
            return []
        return self._calibrate()

    def flush(self) -> list[FrameBatch]:
        """End of stream: calibrate on what arrived if the window never filled."""
        return self._calibrate() if self._pending else []

    def _calibrate(self) -> list[FrameBatch]:
        rows = FrameBatch.concatenate(self._pending)
        self._pending = []
        in_window = rows.t_s < self._t_first + self.static_window_s
        dt = np.diff(rows.t_s, prepend=np.nan)
        usable = in_window & np.isfinite(rows.cfo_hz) & ((rows.flags & FrameFlag.LOW_QUALITY) == 0)
        if not np.any(usable):
            raise ValueError("no valid frame in the static window: cannot estimate the clock offset f_s "
                             "(give clock_offset_hz or a longer static_window_s)")
        self.clock_offset_hz = float(np.sum(rows.cfo_hz[usable] * dt[usable]) / np.sum(dt[usable]))
        rows.flags[in_window] |= np.uint8(FrameFlag.CALIBRATION)
        return [self._integrate(rows)]

    def _integrate(self, batch: FrameBatch) -> FrameBatch:
        assert self.clock_offset_hz is not None
        doppler = batch.cfo_hz - self.clock_offset_hz
        t_prev = np.concatenate([[self._last_t_s if self._last_t_s is not None else batch.t_s[0]], batch.t_s[:-1]])
        # A frame without a CFO pair (a lock's first) adds nothing: the range is held across a gap.
        cycles = np.cumsum(np.where(np.isfinite(doppler), doppler * (batch.t_s - t_prev), 0.0))
        range_m = self._range_m - self.wavelength_m * cycles
        self._range_m = float(range_m[-1])
        self._last_t_s = float(batch.t_s[-1])
        return replace(batch, doppler_hz=doppler, velocity_mps=doppler * self.wavelength_m, range_change_m=range_m)
