"""Samples the front end dropped: found in the frame timing, counted, and kept out of the time base.

An SDR whose host falls behind (a USB overflow) loses a run of samples; the
capture file simply lacks them, so every later sample sits earlier in the
file than its true time. The frame grid shows it: frames arrive on a grid of
one frame period, so a frame timing that jumps by anything other than whole
periods is a drop, and the jump measures it.

- **Inside a lock** (a drop shorter than the channel window): the measured
  frame timing (window start plus the taps' centroid) of consecutive frames
  steps by ``period - n`` instead of ``period``. The frame-to-frame timing
  difference scatters by hundredths of a sample on a usable signal, so a step
  of more than :data:`MIN_STEP` samples (earlier, never later: samples are
  lost, never added) is a drop when the power profile of the frame's taps
  matches its predecessor's shifted by the same whole number of samples, and
  clearly better than unshifted (:func:`profile_shift`): a path appearing or
  fading moves the centroid but not the profile.
  A step of more than half :data:`MAX_IN_LOCK_STEP` whose profile shifts by
  more than it ends the lock at the frame (the loop would otherwise follow it
  and take the lost samples into its grid): a multipath tail leaving the
  window makes the centroid understate such a step, so the profile is
  searched over the whole window there.
- **Across a loss of lock** (a longer drop throws the header out of the
  window): the grid the lost lock was coasting on, carried over the gap,
  predicts where the frame the new lock starts with should be; the new lock
  finds it ``n`` samples earlier. With a rotating header the frame is known
  within the superframe, so drops up to half a superframe are counted in
  whole; with a constant header phase only the part below one frame is.

The lost input samples are ``round(n * fs_in / 7.56 MHz)``; the receiver adds
them to ``t_s`` from the drop on, so the time base stays on the real clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ

#: Smallest step of the frame timing, 7.56 Msps samples, taken as a drop: many times the frame-to-frame
#: scatter of the measured timing on a usable signal, and below one input sample up to 15 Msps.
MIN_STEP = 0.5
#: How much better the tap-power profile must match its predecessor's at the drop's shift than unshifted: a
#: real drop moves every path, while the paths of several towers (an SFN) that change their balance move
#: the centroid without shifting the profile.
MIN_PROFILE_GAIN = 2.0
#: Largest step followed inside a lock, 7.56 Msps samples; a longer drop is taken as a loss of lock at the
#: frame, and measured on the grid when the receiver locks again (the taps' centroid is biased once the
#: main path nears the edge of the channel window).
MAX_IN_LOCK_STEP = 24.0
#: A re-acquisition after a drop keeps the segment (the range bridges it with the last Doppler) when the
#: frames on either side are at most this far apart on the real clock, s; a longer silence is a gap.
MAX_BRIDGE_S = 0.25


def profile_shift(prev_taps: np.ndarray, taps: np.ndarray, max_lag: int, expected: int = 0) -> tuple[int, float]:
    """Whole-sample shift of a frame's tap-power profile against the previous frame's (negative: earlier).

    Parameters
    ----------
    prev_taps, taps : (L,) complex
        Channel taps of consecutive frames over the same window offsets.
    max_lag : int
        Largest shift searched, samples.
    expected : int
        The shift without a drop (the windows' own step beyond the period).

    Returns
    -------
    lag : int
        The lag ``k`` maximising ``sum |taps[i]|^2 |prev_taps[i - k]|^2``.
    gain : float
        That correlation over the one at ``expected`` (``inf`` when the latter is 0).
    """
    a = np.abs(np.asarray(prev_taps)) ** 2
    b = np.abs(np.asarray(taps)) ** 2
    full = np.correlate(b, a, mode="full")        # index i: lag i - (len(a) - 1)
    centre = len(a) - 1
    lo = min(max(centre - max_lag + min(expected, 0), 0), len(full) - 1)
    hi = max(min(centre + max_lag + max(expected, 0), len(full) - 1), lo)
    lag = int(np.argmax(full[lo: hi + 1])) + lo - centre
    base = full[min(max(centre + expected, 0), len(full) - 1)]
    return lag, float(full[centre + lag] / base) if base > 0 else float("inf")


def lost_input_samples(step_stream: float, input_rate_hz: float) -> int:
    """Input samples lost for a timing step of ``step_stream`` 7.56 Msps samples (positive: lost)."""
    return int(round(step_stream * input_rate_hz / SYMBOL_RATE_HZ))


def find_in_lock_drop(measured: np.ndarray, strong: np.ndarray, period: float, prev_measured: float | None,
                      taps: np.ndarray, prev_taps: np.ndarray | None, starts: np.ndarray,
                      prev_start: int) -> tuple[int, float] | None:
    """The first drop inside a batch of locked frames (module docstring), or None.

    Parameters
    ----------
    measured : (B,) float64
        Measured frame timings, 7.56 Msps samples.
    strong : (B,) bool
        Frames whose header correlation is trusted.
    period : float
        The timing loop's frame period, samples.
    prev_measured : float or None
        Measured timing of the frame before the batch (None: the lock's first batch).
    taps : (B, L) complex
        Each frame's channel taps.
    prev_taps : (L,) complex or None
        Taps of the frame before the batch.
    starts : (B,) int64
        Each frame's window start, samples.
    prev_start : int
        Window start of the frame before the batch.

    Returns
    -------
    (int, float) or None
        Position of the first frame after the drop, and the step in samples
        (positive: that many samples were lost).
    """
    if prev_measured is None:
        before = measured[:-1]
        pos0 = 1
    else:
        before = np.concatenate([[prev_measured], measured[:-1]])
        pos0 = 0
    step = period - (measured[pos0:] - before)      # positive when the frame arrives early
    candidates = np.flatnonzero((step > MIN_STEP) & strong[pos0:]) + pos0
    for b in candidates:
        if b > 0 and not strong[b - 1]:
            continue
        previous = taps[b - 1] if b > 0 else prev_taps
        if previous is None:
            continue
        size = float(step[b - pos0])
        # The windows' own step beyond the period shifts the taps too (the loop rounds its timing).
        window_shift = int(starts[b] - (starts[b - 1] if b > 0 else prev_start) - round(period))
        # A step near the window's edge moves the centroid less than the paths (a multipath tail leaves the
        # window): there the profile alone measures it, searched over the whole window.
        long_step = size > MAX_IN_LOCK_STEP / 2
        max_lag = len(taps[b]) // 2 if long_step else int(np.ceil(size)) + 2
        lag, gain = profile_shift(previous, taps[b], max_lag, -window_shift)
        shift = -lag - window_shift
        if shift < 1 or gain < MIN_PROFILE_GAIN:
            continue
        if abs(shift - size) <= 0.75:
            return int(b), size
        if long_step and shift > MAX_IN_LOCK_STEP:
            return int(b), float(shift)
    return None


@dataclass
class DropLog:
    """The drops found in one run: where (time on the real clock, input index), and how many samples.

    Attributes
    ----------
    t_s : list of float
        Real-clock time of the first frame after each drop, s.
    sample_index : list of int
        Input sample index of that frame.
    samples : list of int
        Input samples lost.
    """

    t_s: list[float] = field(default_factory=list)
    sample_index: list[int] = field(default_factory=list)
    samples: list[int] = field(default_factory=list)

    def add(self, t_s: float, sample_index: int, samples: int) -> None:
        """Record one drop."""
        self.t_s.append(float(t_s))
        self.sample_index.append(int(sample_index))
        self.samples.append(int(samples))

    @property
    def total(self) -> int:
        """Input samples lost in all."""
        return int(sum(self.samples))

    def attributes(self) -> dict[str, Any]:
        """The ``/receiver/frames`` attributes: count, total and one list per field."""
        return {"drops": len(self.samples), "dropped_samples": self.total,
                "drop_t_s": np.asarray(self.t_s, dtype=np.float64),
                "drop_sample_index": np.asarray(self.sample_index, dtype=np.int64),
                "drop_samples": np.asarray(self.samples, dtype=np.int64)}
