"""Step detection: peaks of the acceleration norm, one per step period (docs/method.md §3).

The norm of the specific force is orientation-free; its slowly varying part
(gravity, plus whatever bias and scale error the accelerometer has) is removed
with a long moving average, the rest is smoothed with a short moving average.
Candidate steps are its local peaks above an adaptive threshold: the threshold
follows the walker's own acceleration level, as in Zhao's pedometer (N. Zhao,
"Full-featured pedometer design realized with 3-axis digital accelerometer",
Analog Dialogue 44-06, 2010), because that level varies several-fold with the
carriage and the pace (Brajdic & Harle, "Walk detection and step counting on
unconstrained smartphones", UbiComp 2013); a low absolute floor keeps sensor
noise from counting while the walker stands still.

A threshold alone counts a slow step that gives two peaks twice, and the humps
a pocket or a swinging arm adds between steps. So the peaks are then held to
the walker's step period, measured from the signal itself
(:mod:`fusion.pdr.step_period`):

1. the highest candidates are taken first, and each takes out the candidates
   closer to it than a fraction of the local period (one step, one count);
2. a gap of two or three periods between regular steps is a step or two
   whose peak stayed under the threshold (the quieter leg in a back pocket):
   the missing steps are put in evenly;
3. a step counts only where the signal is periodic (``min_walk_strength``):
   a bag swaying after the walker stopped, or the phone being handled, is not;
   the slower step that ends a walk into a standstill is the exception;
4. and only as part of a bout of regular steps (intervals close to
   the period): handling the phone (taking it out, putting it in a pocket or a
   bag) gives a few irregular jolts, walking gives a run of them. Brajdic and
   Harle found such walk detection to be what keeps handling from counting.

Each step also gets its window (from the previous peak or, for the first step
after standing still, as long as the walker's next step) and the extremes of
the smoothed signal over that window, which feed Weinberg's step length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import percentile_filter, uniform_filter1d
from scipy.signal import find_peaks

from dtmbnav_core.resampling import UNIFORM_SPREAD, is_uniform
from fusion.pdr.step_period import StepPeriod, step_period


@dataclass(frozen=True)
class StepDetectorConfig:
    """Settings of the step detector.

    Attributes
    ----------
    smoothing_s : float
        Moving-average window that smooths the acceleration norm, s.
    gravity_window_s : float
        Moving-average window that estimates gravity (and sensor bias) in the norm, s.
    amplitude_window_s : float
        Centred window over which the walker's acceleration level is taken, s
        (a few steps even at a slow pace).
    amplitude_percentile : float
        Percentile of the dynamic acceleration over that window that measures the level (0-100).
    threshold_fraction : float
        Least peak height of a step as a fraction of the level.
    floor_mps2 : float
        Least peak height of a step whatever the level, m/s^2 (above sensor noise and tremor at rest).
    min_step_s : float
        Least time between two steps, s (a step takes 0.3-2 s).
    max_step_s : float
        A longer gap than this means the walker stood still in between, s.
    period_window_s : float
        Window over which the step period is measured, s (a few strides at a slow pace).
    period_hop_s : float
        Spacing of the period's windows, s.
    max_period_s : float
        Longest lag searched for the period, s (a stride at a normal pace; halved into a step).
    stride_ratio : float
        Part of the autocorrelation's highest peak that the autocorrelation half-way to
        it must exceed for that peak to be a stride rather than a step.
    spacing_fraction : float
        Least spacing of two steps as a fraction of the local step period.
    max_missed_steps : int
        Most steps put into one gap between two detected steps (0: none).
    min_fill_strength : float
        Least periodicity (autocorrelation at the period) at both ends of a gap for
        missed steps to be put in.
    min_walk_strength : float
        Least periodicity where a step counts.
    min_bout_steps : int
        Fewest regular steps in a row that make a walk; shorter runs are handling.
    bout_tolerance : float
        Longest interval, in local step periods, that still links two steps of a bout.
    last_step_tolerance : float
        Longest interval, in local step periods, from a bout's last step to the slower
        step that ends it into a standstill.
    """

    smoothing_s: float = 0.15
    gravity_window_s: float = 2.0
    amplitude_window_s: float = 4.0
    amplitude_percentile: float = 90.0
    threshold_fraction: float = 0.25
    floor_mps2: float = 0.2
    min_step_s: float = 0.3
    max_step_s: float = 2.0
    period_window_s: float = 4.0
    period_hop_s: float = 0.25
    max_period_s: float = 1.4
    stride_ratio: float = 0.1
    spacing_fraction: float = 0.6
    max_missed_steps: int = 2
    min_fill_strength: float = 0.3
    min_walk_strength: float = 0.25
    min_bout_steps: int = 8
    bout_tolerance: float = 1.6
    last_step_tolerance: float = 2.5


@dataclass(frozen=True)
class DetectedSteps:
    """Steps found in an acceleration record.

    Attributes
    ----------
    t_s : ndarray
        Time of each step's peak, s.
    start_t_s : ndarray
        Start of each step's window, s.
    acc_max_mps2, acc_min_mps2 : ndarray
        Extremes of the smoothed, gravity-free norm over the window, m/s^2.
    """

    t_s: np.ndarray
    start_t_s: np.ndarray
    acc_max_mps2: np.ndarray
    acc_min_mps2: np.ndarray

    @property
    def duration_s(self) -> np.ndarray:
        """Duration of each step, s."""
        return self.t_s - self.start_t_s


def dynamic_acceleration(t_s: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig) -> np.ndarray:
    """Smoothed acceleration norm with gravity removed, m/s^2 (one value per sample).

    Raises
    ------
    ValueError
        Samples not N x 3, fewer than two, or not on a uniform time grid (intervals
        within :data:`~dtmbnav_core.resampling.UNIFORM_SPREAD` of their mean:
        :func:`fusion.pdr.pipeline.run_pdr` resamples uneven ones).
    """
    acc_mps2 = np.asarray(acc_mps2, dtype=np.float64)
    if acc_mps2.ndim != 2 or acc_mps2.shape[1] != 3 or len(acc_mps2) != len(t_s) or len(t_s) < 2:
        raise ValueError(f"acc_mps2 must be N x 3 with N = len(t_s) >= 2, got {acc_mps2.shape} and {len(t_s)}")
    dt = np.diff(t_s)
    if np.any(dt <= 0) or not is_uniform(t_s):
        raise ValueError(f"t_s must increase at a uniform rate (interval spread at most {UNIFORM_SPREAD:g} of the "
                         f"mean interval, got {np.ptp(dt) / abs(dt.mean()):.3g}); resample uneven times first "
                         "(run_pdr does)")
    rate_hz = 1.0 / dt.mean()
    norm = np.linalg.norm(acc_mps2, axis=1)
    gravity = uniform_filter1d(norm, max(1, round(config.gravity_window_s * rate_hz)), mode="nearest")
    return uniform_filter1d(norm - gravity, max(1, round(config.smoothing_s * rate_hz)), mode="nearest")


def _window_extremes(signal: np.ndarray, start: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Max and min of ``signal[start[i]:stop[i]]`` for each i (non-empty windows, start ascending)."""
    # reduceat over the interleaved bounds [s0, e0, s1, e1, ...]: the even results are the windows.
    bounds = np.column_stack([start, stop]).ravel()
    padded = np.append(signal, signal[-1])  # a window may end at the last sample
    return np.maximum.reduceat(padded, bounds)[::2], np.minimum.reduceat(padded, bounds)[::2]


def step_threshold(dyn_mps2: np.ndarray, rate_hz: float, config: StepDetectorConfig) -> np.ndarray:
    """Least height of a step's peak at each sample: a fraction of the walker's own level, m/s^2.

    The level is a running percentile (``amplitude_percentile``) of the dynamic
    acceleration over a centred window of ``amplitude_window_s``: close to the
    height of the step peaks in it, whatever the carriage and the pace, and
    unmoved by a few outlying samples. The threshold is ``threshold_fraction`` of
    it, but never below ``floor_mps2``, which keeps sensor noise and a still
    hand's tremor from counting as steps.
    """
    width = max(1, round(config.amplitude_window_s * rate_hz))
    level = percentile_filter(dyn_mps2, config.amplitude_percentile, size=width, mode="nearest")
    return np.maximum(config.threshold_fraction * level, config.floor_mps2)


@dataclass(frozen=True)
class StepCandidates:
    """Peaks held to the step period, before the bouts are found (:func:`step_candidates`).

    Attributes
    ----------
    dyn_mps2 : ndarray
        Smoothed, gravity-free acceleration norm at every sample, m/s^2.
    rate_hz : float
        Sample rate, Hz.
    peaks : ndarray of int
        Sample index of each candidate step, ascending.
    period_samples : ndarray
        Local step period at each candidate, samples.
    periodic : ndarray of bool
        Whether the walk's autocorrelation at each candidate reaches ``min_walk_strength``.
    """

    dyn_mps2: np.ndarray
    rate_hz: float
    peaks: np.ndarray
    period_samples: np.ndarray
    periodic: np.ndarray


def step_candidates(t_s: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig) -> StepCandidates | None:
    """Peaks of the dynamic acceleration held to the step period (steps 1-2 of the module docstring).

    None where nothing is periodic anywhere (no walk). :func:`detect_steps` keeps
    those in bouts; a stream (:mod:`fusion.pdr.streaming`) decides which of them are final.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    dyn = dynamic_acceleration(t_s, acc_mps2, config)
    rate_hz = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    candidates, _ = find_peaks(dyn, height=step_threshold(dyn, rate_hz, config))
    period = step_period(t_s, dyn, config.period_window_s, config.period_hop_s, config.min_step_s,
                         config.max_period_s, config.stride_ratio)
    period_s, _ = period.at(t_s[candidates])
    if candidates.size == 0 or not np.all(np.isfinite(period_s)):  # nothing periodic anywhere: no walk
        return None
    peaks = _one_per_period(candidates, dyn[candidates], period_s * rate_hz, config.spacing_fraction)
    peaks = _put_in_missed(peaks, t_s, rate_hz, period, config)
    period_s, strength = period.at(t_s[peaks])
    return StepCandidates(dyn_mps2=dyn, rate_hz=rate_hz, peaks=peaks, period_samples=period_s * rate_hz,
                          periodic=strength >= config.min_walk_strength)


def detect_steps(t_s: np.ndarray, acc_mps2: np.ndarray, config: StepDetectorConfig) -> DetectedSteps:
    """Detect steps: peaks of the dynamic acceleration, one per step period, in bouts of walking (docs/method.md §3).

    Candidates are the local peaks of :func:`dynamic_acceleration` above
    :func:`step_threshold`; they are held to the local step period
    (:func:`fusion.pdr.step_period.step_period`) by :func:`_one_per_period`,
    :func:`_put_in_missed` and :func:`in_bouts`, with its periodicity floor (the module docstring says why).
    Each step gets its window from :func:`step_windows`.

    Parameters
    ----------
    t_s : ndarray
        Uniformly spaced sample times, s.
    acc_mps2 : ndarray, shape (N, 3)
        Accelerometer specific force, m/s^2, any sensor frame.
    config : StepDetectorConfig

    Returns
    -------
    DetectedSteps
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    candidates = step_candidates(t_s, acc_mps2, config)
    if candidates is None:
        return step_windows(t_s, np.zeros(len(t_s)), np.zeros(0, dtype=int), 1.0, config)
    peaks = in_bouts(candidates.peaks, candidates.period_samples, candidates.periodic, config)
    return step_windows(t_s, candidates.dyn_mps2, peaks, candidates.rate_hz, config)


def step_windows(t_s: np.ndarray, dyn_mps2: np.ndarray, peaks: np.ndarray, rate_hz: float,
                 config: StepDetectorConfig) -> DetectedSteps:
    """The steps at sample indices ``peaks`` (ascending), with their windows and extremes.

    A step's window runs from the previous step's peak; a step more than
    ``max_step_s`` after the previous one (the first after a standstill) has no
    previous peak, and gets the duration of the walker's next step, clipped to
    ``[min_step_s, max_step_s]`` (or the median step duration of the steps
    given when the next step is not part of the same walk), so that its speed
    and length are those of a real step.
    """
    if peaks.size == 0:
        empty = np.zeros(0)
        return DetectedSteps(t_s=empty, start_t_s=empty, acc_max_mps2=empty, acc_min_mps2=empty)
    gap = np.diff(peaks, prepend=-np.iinfo(np.int64).max // 2)
    after_standstill = gap > config.max_step_s * rate_hz
    start = peaks - np.where(after_standstill, _first_step_samples(gap, after_standstill, rate_hz, config), gap)
    start = np.maximum(start, 0)
    acc_max, acc_min = _window_extremes(dyn_mps2, start, peaks + 1)
    return DetectedSteps(t_s=t_s[peaks], start_t_s=t_s[start], acc_max_mps2=acc_max, acc_min_mps2=acc_min)


def _one_per_period(candidates: np.ndarray, height: np.ndarray, period_samples: np.ndarray,
                    fraction: float) -> np.ndarray:
    """The candidates left when, highest first, each removes those within ``fraction`` of its period.

    ``candidates`` are sample indices in ascending order; the result is too.
    """
    # A loop over the candidates by height: each removes a contiguous run of
    # neighbours (found by bisection), so the cost is n log n, not n^2.
    removed = np.zeros(len(candidates), dtype=bool)
    kept = np.zeros(len(candidates), dtype=bool)
    reach = fraction * period_samples
    low = np.searchsorted(candidates, candidates - reach, side="right")
    high = np.searchsorted(candidates, candidates + reach, side="left")
    for k in np.argsort(-height, kind="stable"):
        if not removed[k]:
            kept[k] = True
            removed[low[k]:high[k]] = True
    return candidates[kept]


def _put_in_missed(peaks: np.ndarray, t_s: np.ndarray, rate_hz: float, period: StepPeriod,
                   config: StepDetectorConfig) -> np.ndarray:
    """``peaks`` with evenly spaced steps put into gaps of 2 to ``max_missed_steps + 1`` periods.

    Only inside walking: the gap within a quarter of a period of a whole number of
    periods, both its ends periodic (``min_fill_strength``), and a regular step
    interval (half a period to ``bout_tolerance`` periods) on each side of it. The
    last keeps the long first step from a standstill, whose push-off can peak well
    before its heel strike, from being taken for a gap.
    """
    if config.max_missed_steps < 1 or len(peaks) < 4:
        return peaks
    period_s, strength = period.at(t_s[peaks])
    gap = np.diff(peaks)
    periods = gap / (0.5 * (period_s[1:] + period_s[:-1]) * rate_hz)
    whole = np.rint(periods).astype(int)
    regular = (periods > 0.5) & (periods < config.bout_tolerance)
    between_regular = np.concatenate([[False], regular[:-2] & regular[2:], [False]])
    missed = ((whole >= 2) & (whole <= config.max_missed_steps + 1) & (np.abs(periods - whole) < 0.25)
              & (np.minimum(strength[1:], strength[:-1]) >= config.min_fill_strength) & between_regular)
    added = [peaks[i] + (gap[i] * np.arange(1, whole[i])) // whole[i] for i in np.flatnonzero(missed)]
    return np.sort(np.concatenate([peaks, *added])) if added else peaks


def in_bouts(peaks: np.ndarray, period_samples: np.ndarray, periodic: np.ndarray,
              config: StepDetectorConfig) -> np.ndarray:
    """The steps that belong to a bout of at least ``min_bout_steps`` regular, periodic steps.

    Bouts are made of the ``periodic`` steps (where the walk's autocorrelation
    reaches ``min_walk_strength``); two are linked when their interval lies
    between half a period and ``bout_tolerance`` periods. The step that ends a
    bout into a standstill is slower (the walker brings the feet together) and
    half its window is the standstill, which weakens the autocorrelation there:
    the next step up to ``last_step_tolerance`` periods after a bout's last
    belongs to the bout, periodic or not.
    """
    strong, bout = bouts(peaks, period_samples, periodic, config)
    if strong.size == 0:
        return peaks[:0]
    kept = np.zeros(len(peaks), dtype=bool)
    kept[strong] = np.bincount(bout)[bout] >= config.min_bout_steps
    # The step after each kept bout's last one.
    last = strong[kept[strong] & np.append(bout[1:] != bout[:-1], True)]
    last = last[last + 1 < len(peaks)]
    closing_gap = peaks[last + 1] - peaks[last]
    closes = ((closing_gap > 0.5 * period_samples[last + 1])
              & (closing_gap < config.last_step_tolerance * period_samples[last + 1]))
    kept[last[closes] + 1] = True
    return peaks[kept]


def bouts(peaks: np.ndarray, period_samples: np.ndarray, periodic: np.ndarray,
          config: StepDetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """The periodic steps (indices into ``peaks``) and the bout each belongs to (0, 1, ... in time order).

    Two periodic steps in a row are in one bout when their interval lies between
    half a period and ``bout_tolerance`` periods (the period at the later one).
    """
    strong = np.flatnonzero(periodic)
    gap = np.diff(peaks[strong])
    linked = (gap > 0.5 * period_samples[strong[1:]]) & (gap < config.bout_tolerance * period_samples[strong[1:]])
    return strong, np.concatenate([[0], np.cumsum(~linked)])[:strong.size]


def _first_step_samples(gap: np.ndarray, after_standstill: np.ndarray, rate_hz: float,
                        config: StepDetectorConfig) -> np.ndarray:
    """Window length, in samples, of every step if it were the first after a standstill.

    A step from a standstill lasts about as long as the next one (the cadence
    settles within a step or two); where the next step is itself after a
    standstill (or there is none) the median duration of the steps that do
    follow another stands in, or ``max_step_s`` when there are none.
    """
    lo, hi = round(config.min_step_s * rate_hz), round(config.max_step_s * rate_hz)
    walking = gap[~after_standstill]
    fallback = int(np.median(walking)) if walking.size else hi
    next_gap = np.append(gap[1:], 0)
    next_walking = np.append(~after_standstill[1:], False)
    return np.clip(np.where(next_walking, next_gap, fallback), lo, hi)
