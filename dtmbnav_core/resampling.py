"""Uneven sample times: their timing statistics and linear resampling onto a uniform grid.

A phone delivers its motion-sensor samples at uneven times (each carries the
time it was taken, but the intervals scatter around the nominal one, and the
operating system drops a run of samples now and then). The signal chains here
(filters, moving averages, the attitude filter) assume a uniform rate, so the
samples are linearly interpolated onto a uniform grid, and the unevenness is
measured on the way so that it can be reported: the jitter (standard deviation
of the sample interval over its mean) and the gaps (intervals longer than
:data:`GAP_INTERVALS` median intervals, across which the interpolation bridges
a stretch without data). Both the phone-log importer (``dtmbnav sensors``) and
the PDR (:func:`fusion.pdr.pipeline.run_pdr`) use this module, so it sits in the
bottom layer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A sample interval longer than this many median intervals is a gap (a run of dropped samples).
GAP_INTERVALS = 5.0
#: Largest spread (longest minus shortest interval) over the mean interval that still counts as a
#: uniform grid; beyond it the samples are resampled.
UNIFORM_SPREAD = 1e-3


@dataclass(frozen=True)
class SampleTiming:
    """How regularly a series was sampled.

    Attributes
    ----------
    rate_hz : float
        Mean sample rate over the intervals that are no gap, Hz.
    jitter : float
        Standard deviation of those intervals over their mean (0 for a uniform grid).
    gaps_s : tuple of (float, float)
        Start and end of each gap: the times of the samples on either side of it, s.
    """

    rate_hz: float
    jitter: float
    gaps_s: tuple[tuple[float, float], ...]

    def describe(self) -> str:
        """One line for the user: rate, jitter and the gaps."""
        text = f"{self.rate_hz:.2f} Hz, jitter {self.jitter:.2%}"
        if self.gaps_s:
            longest = max(end - start for start, end in self.gaps_s)
            text += f", {len(self.gaps_s)} gap(s) (longest {longest:.3f} s)"
        return text


def check_increasing(t_s: np.ndarray, where: str) -> None:
    """Raise ValueError naming ``where`` and the first offending sample unless ``t_s`` strictly increases.

    Raises
    ------
    ValueError
        Fewer than two samples, a non-finite time, or a time not later than the one before
        (a repeated or decreasing time stamp: every interval must exceed 0 s).
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    if t_s.ndim != 1 or len(t_s) < 2:
        raise ValueError(f"{where}: need at least two sample times, got shape {t_s.shape}")
    if not np.all(np.isfinite(t_s)):
        raise ValueError(f"{where}: sample times contain NaN or inf")
    bad = np.flatnonzero(np.diff(t_s) <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "repeats" if t_s[i] == t_s[i - 1] else "goes back from"
        raise ValueError(f"{where}: sample times must strictly increase (every interval > 0 s), but sample {i} "
                         f"({t_s[i]!r} s) {kind} the one before ({t_s[i - 1]!r} s); {bad.size} such interval(s)")


def sample_timing(t_s: np.ndarray) -> SampleTiming:
    """Rate, jitter and gaps of strictly increasing sample times ``t_s`` (s)."""
    t_s = np.asarray(t_s, dtype=np.float64)
    interval = np.diff(t_s)
    gap = interval > GAP_INTERVALS * float(np.median(interval))
    regular = interval[~gap]  # never empty: the median interval itself is no gap
    mean = float(regular.mean())
    gaps = tuple((float(t_s[i]), float(t_s[i + 1])) for i in np.flatnonzero(gap))
    return SampleTiming(rate_hz=1.0 / mean, jitter=float(regular.std() / mean), gaps_s=gaps)


def is_uniform(t_s: np.ndarray) -> bool:
    """Whether strictly increasing times ``t_s`` lie on a uniform grid (within :data:`UNIFORM_SPREAD`)."""
    interval = np.diff(np.asarray(t_s, dtype=np.float64))
    return bool(np.ptp(interval) <= UNIFORM_SPREAD * interval.mean())


def uniform_grid(start_s: float, end_s: float, rate_hz: float) -> np.ndarray:
    """Times ``start_s + k / rate_hz`` for k = 0, 1, ... up to ``end_s`` (s)."""
    n = int(np.floor((end_s - start_s) * rate_hz)) + 1
    return start_s + np.arange(n) / rate_hz


def interpolate(t_s: np.ndarray, values: np.ndarray, at_s: np.ndarray) -> np.ndarray:
    """Columns of ``values`` (N x k, sampled at ``t_s``) linearly interpolated at the times ``at_s``.

    Times outside ``t_s`` take the first or last sample (no extrapolation).
    """
    values = np.asarray(values, dtype=np.float64)
    return np.column_stack([np.interp(at_s, t_s, values[:, k]) for k in range(values.shape[1])])
