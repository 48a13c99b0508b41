"""From the receiver's 1800 frames/s range and the PDR's steps to filter epochs.

The receiver integrates the Doppler every signal frame (1800 frames/s for
PN420) while the PDR produces one row per step (about 2 per second). The
filters run once per step, so each step needs one range observation and its
noise. The rule, applied per step time ``t_n``:

1. Take the receiver frames with ``|t - t_n| <= window_s / 2``.
2. Keep the frames the receiver marks valid (no gap, lock, quality flags).
3. If fewer than ``min_valid_fraction`` of the frames expected in the window
   (from the median frame interval) are valid, the epoch has no range
   observation (``range_change_m`` is NaN): a gap or a fade is skipped, not
   interpolated across.
4. Otherwise the observation is the mean range change of the valid frames.
   Averaging is not there to beat down per-frame noise (the integrated range
   telescopes and its frame noise is millimetres, docs/method.md §2): it makes the
   observation insensitive to which frame is nearest the step peak and to the
   odd flagged frame.
5. Its standard deviation is ``base_sigma_m`` (the drift/multipath error the
   integrated range accumulates over a walk, which is what limits it), inflated
   where the link is weak: the phase-noise variance grows as 1/SNR, and low
   SNR is where the direct path is blocked and a reflection sets the phase, so
   ``sigma = base_sigma_m * sqrt(max(1, 10^((good_snr_db - snr)/10)))`` with
   ``snr`` the mean SNR of the valid frames in dB, and a further factor
   ``1 / sqrt(valid fraction)`` for partly flagged windows.
6. **Multipath.** A reflection whose Doppler differs from the direct path's
   (a wall ahead while the tower is behind) bends the integrated range by up
   to a metre per second, at a healthy SNR. What gives it away is fading:
   two comparable paths with different Dopplers beat, so the SI-carrier
   power swings, where a line-of-sight link (direct path plus weak diffuse
   scattering, Rician K ~ 10 dB) stays steady. The Rician K-factor is
   estimated from the moments of the linear SNR over ``fading_window_s``
   around the step (Greenstein et al. 1999:
   ``gamma = Var(P) / E(P)^2``, ``K = sqrt(1 - gamma) / (1 - sqrt(1 - gamma))``)
   and an epoch with ``K < min_rician_k_db`` has no range observation. A
   reflection with the direct path's Doppler (walking along a wall) does not
   fade and does not bend the range, so it is rightly kept.

7. **Segments.** The receiver restarts its range at each re-acquisition
   (``segment_id``; the range is held flat across the gap, docs/schema.md):
   how far the walker moved during the gap is unknown. An epoch whose window
   reaches into a new segment, or which follows a change of segment since the
   previous epoch, has no range observation, and the range returns after
   rule 5's ``settle_s``: what follows is a range from a new origin.

Where an epoch has no range observation, the integrated range may have
jumped or drifted (a gap, a fade, a multipath stretch, a new segment): the
particle filter lets its range offset wander there
(:mod:`fusion.particle_filter`) and the Kalman-type filters re-anchor their
range origin (:func:`fusion.model.run_filter`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav.core.records import ColumnRecord, PdrSteps, RangeSeries
from fusion.model import StepControl, wrap_angle


@dataclass(frozen=True)
class AggregationConfig:
    """Parameters of the range-to-epoch rule (module docstring).

    Attributes
    ----------
    window_s : float
        Width of the window centred on each step time, s.
    min_valid_fraction : float
        Fraction of the window's expected frames that must be valid.
    base_sigma_m : float
        Range observation standard deviation on a good link, m. The
        receiver's integrated range stays within 0.1 m (95 %) of the truth
        over a minute of line-of-sight walking; 0.25 m leaves room for weak
        multipath the rules let through (on the tuning seeds 0.5 m gave
        0-6 points less reduction of the 95 % error, 0.15 m lost 2-4 points
        on the streets).
    good_snr_db : float
        SNR at and above which no inflation applies, dB.
    fading_window_s : float
        Width of the window for the Rician K-factor, s (several beat periods
        of paths whose Dopplers differ by a few Hz).
    min_rician_k_db : float or None
        Epochs whose K-factor is below this have no range observation, dB;
        None keeps them all.
    max_snr_deficit_db : float or None
        Epochs whose SNR is this far below the recording's line-of-sight
        level (its ``los_snr_percentile`` percentile epoch SNR) have no range
        observation, dB; None keeps them all.
    los_snr_percentile : float
        Percentile of the epoch SNRs taken as the line-of-sight level.
    settle_s : float
        After an epoch without a range observation, the range comes back
        only once this long has passed with every epoch passing rules 3-6, s.
        A link that recovers for a moment inside a blocked stretch (a lucky
        beat of two reflections) still carries the stretch's range error.
    """

    window_s: float = 0.2
    min_valid_fraction: float = 0.5
    base_sigma_m: float = 0.25
    good_snr_db: float = 10.0
    fading_window_s: float = 2.0
    min_rician_k_db: float | None = 6.0
    max_snr_deficit_db: float | None = 5.0
    los_snr_percentile: float = 90.0
    settle_s: float = 3.0


@dataclass
class RangeEpochs(ColumnRecord):
    """Range observations at the filter epochs.

    Attributes
    ----------
    t_s : ndarray
        Epoch time, s.
    range_change_m : ndarray
        Range change since the capture start, m; NaN where dropped.
    sigma_m : ndarray
        Observation standard deviation, m; NaN where dropped.
    snr_db : ndarray
        Mean SNR of the valid frames, dB; NaN where none.
    rician_k_db : ndarray
        Rician K-factor of the link around the epoch, dB (module rule 6);
        NaN where too few valid frames.
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    sigma_m: np.ndarray
    snr_db: np.ndarray
    rician_k_db: np.ndarray


@dataclass
class FilterEpochs(ColumnRecord):
    """Everything a filter consumes per epoch (one PDR step).

    Attributes
    ----------
    t_s : ndarray
        Step time, s.
    dt_s : ndarray
        Step duration as the PDR measured it (step length / speed), s; the
        process model moves by ``speed * dt_s``, so a pause between steps
        does not move the walker.
    range_change_m, range_sigma_m : ndarray
        Range observation and its standard deviation, m (NaN: none).
    snr_db : ndarray
        Link SNR of the epoch, dB (NaN: none).
    pdr_heading_rad : ndarray
        PDR heading made absolute with the solved initial heading, rad.
    pdr_heading_increment_rad : ndarray
        PDR heading change since the previous step (0 for the first), rad.
    pdr_speed_mps : ndarray
        PDR speed, m/s.
    pdr_speed_ratio : ndarray
        PDR speed over the previous step's (1 for the first).
    """

    t_s: np.ndarray
    dt_s: np.ndarray
    range_change_m: np.ndarray
    range_sigma_m: np.ndarray
    snr_db: np.ndarray
    pdr_heading_rad: np.ndarray
    pdr_heading_increment_rad: np.ndarray
    pdr_speed_mps: np.ndarray
    pdr_speed_ratio: np.ndarray

    def control(self, n: int) -> StepControl:
        """The process-model control input of epoch ``n``."""
        return StepControl(float(self.dt_s[n]), float(self.pdr_heading_increment_rad[n]),
                           float(self.pdr_speed_ratio[n]))


def _check_ranges(ranges: RangeSeries) -> None:
    if len(ranges) < 2:
        raise ValueError(f"ranges: need at least 2 receiver frames, got {len(ranges)}")
    if np.any(np.diff(ranges.t_s) <= 0):
        raise ValueError("ranges.t_s: frame times must increase strictly")


def _window_sums(t_s: np.ndarray, values: np.ndarray, centres: np.ndarray, width_s: float
                 ) -> tuple[np.ndarray, ...]:
    """Sums of each column of ``values`` over ``|t - centre| <= width_s / 2``, by prefix sums (no Python loop)."""
    lo = np.searchsorted(t_s, centres - width_s / 2.0, side="left")
    hi = np.searchsorted(t_s, centres + width_s / 2.0, side="right")
    cum = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    return tuple(cum[hi, j] - cum[lo, j] for j in range(values.shape[1]))


def rician_k_db(t_s: np.ndarray, snr_db: np.ndarray, valid: np.ndarray, centres: np.ndarray,
                width_s: float) -> np.ndarray:
    """Moment estimate of the Rician K-factor of the link around each centre time (module rule 6), dB.

    Parameters
    ----------
    t_s, snr_db, valid : ndarray
        Per-frame time (s), SNR (dB) and validity; invalid frames are left out.
    centres : ndarray
        Window centres, s.
    width_s : float
        Window width, s.

    Returns
    -------
    ndarray
        K in dB: ``+inf`` for a steady link, ``-inf`` for Rayleigh fading or
        worse (``gamma >= 1``), NaN where the window holds fewer than 2 valid frames.
    """
    power = np.where(valid, 10.0 ** (np.asarray(snr_db, dtype=np.float64) / 10.0), 0.0)
    n, s1, s2 = _window_sums(t_s, np.stack([valid.astype(np.float64), power, power**2], axis=1), centres, width_s)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        gamma = np.maximum(s2 / n - mean**2, 0.0) / mean**2
        root = np.sqrt(np.clip(1.0 - gamma, 0.0, 1.0))
        k_db = 10.0 * np.log10(root / (1.0 - root))
    return np.where(n >= 2, k_db, np.nan)


def settled(t_s: np.ndarray, passing: np.ndarray, settle_s: float) -> np.ndarray:
    """``passing`` epochs that follow at least ``settle_s`` of passing epochs (the first run counts from the start).

    An epoch in a run of passing epochs is kept when the run began at least
    ``settle_s`` before it, where a run begins at the time of the failing epoch
    before it, or at the first epoch for a run that opens the record.
    """
    passing = np.asarray(passing, dtype=bool)
    if settle_s <= 0.0 or not len(passing):
        return passing
    failed_at = np.where(~passing, t_s, -np.inf)
    last_fail = np.maximum.accumulate(failed_at)
    since = np.where(np.isfinite(last_fail), t_s - last_fail, np.inf)
    return passing & (since >= settle_s)


def segment_changes(ranges: RangeSeries, epoch_t_s: np.ndarray, window_s: float) -> np.ndarray:
    """Epochs whose window reaches into a new segment, or that follow a change of segment (module rule 7).

    The segment at the end of each epoch's window (of the last frame at or
    before it) is compared with the one at its start and with the previous
    epoch's.
    """
    segment = np.asarray(ranges.segment_id, dtype=np.int64)
    last = len(segment) - 1
    at_start = segment[np.clip(np.searchsorted(ranges.t_s, epoch_t_s - window_s / 2.0, side="left"), 0, last)]
    at_end = segment[np.clip(np.searchsorted(ranges.t_s, epoch_t_s + window_s / 2.0, side="right") - 1, 0, last)]
    return (at_start != at_end) | (at_end != np.concatenate([at_end[:1], at_end[:-1]]))


def aggregate_ranges(ranges: RangeSeries, epoch_t_s: np.ndarray,
                     config: AggregationConfig = AggregationConfig()) -> RangeEpochs:
    """Apply the module's aggregation rule at each epoch time.

    Parameters
    ----------
    ranges : RangeSeries
        Receiver output, one row per frame.
    epoch_t_s : ndarray
        Epoch (step) times, s.
    config : AggregationConfig

    Returns
    -------
    RangeEpochs
    """
    _check_ranges(ranges)
    epoch_t_s = np.asarray(epoch_t_s, dtype=np.float64)
    valid = np.asarray(ranges.valid, dtype=bool) & np.isfinite(ranges.range_change_m)
    n_valid, range_sum, snr_lin_sum = _window_sums(
        ranges.t_s, np.stack([valid.astype(np.float64), np.where(valid, ranges.range_change_m, 0.0),
                              np.where(valid, 10.0 ** (ranges.snr_db / 10.0), 0.0)], axis=1),
        epoch_t_s, config.window_s)
    expected = config.window_s / np.median(np.diff(ranges.t_s))
    fraction = np.minimum(n_valid / expected, 1.0)
    k_db = rician_k_db(ranges.t_s, ranges.snr_db, valid, epoch_t_s, config.fading_window_s)
    keep = (fraction >= config.min_valid_fraction) & (n_valid > 0) & ~segment_changes(ranges, epoch_t_s, config.window_s)
    if config.min_rician_k_db is not None:
        keep &= ~(k_db < config.min_rician_k_db)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_range = range_sum / n_valid
        snr_db = 10.0 * np.log10(snr_lin_sum / n_valid)
        inflation = np.maximum(1.0, 10.0 ** ((config.good_snr_db - snr_db) / 10.0))
        sigma = config.base_sigma_m * np.sqrt(inflation / fraction)
    if config.max_snr_deficit_db is not None and np.any(np.isfinite(snr_db)):
        los_snr_db = np.nanpercentile(snr_db, config.los_snr_percentile)
        keep &= ~(snr_db < los_snr_db - config.max_snr_deficit_db)
    keep = settled(epoch_t_s, keep, config.settle_s)
    nan = np.full(len(epoch_t_s), np.nan)
    return RangeEpochs(
        t_s=epoch_t_s,
        range_change_m=np.where(keep, mean_range, nan),
        sigma_m=np.where(keep, sigma, nan),
        snr_db=np.where(n_valid > 0, snr_db, nan),
        rician_k_db=k_db,
    )


def step_durations_s(pdr: PdrSteps) -> np.ndarray:
    """Duration of each step as the PDR measured it: length / speed, s."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = pdr.step_length_m / pdr.speed_mps
    bad = ~np.isfinite(dt) | (dt <= 0)
    if np.any(bad):
        # A zero-speed step carries no displacement; fall back on the time gap.
        gaps = np.diff(pdr.t_s, prepend=pdr.t_s[0] - np.median(np.diff(pdr.t_s)))
        dt = np.where(bad, gaps, dt)
    return dt


def build_epochs(pdr: PdrSteps, range_epochs: RangeEpochs, initial_heading_rad: float) -> FilterEpochs:
    """Filter epochs at the PDR step times.

    Parameters
    ----------
    pdr : PdrSteps
        PDR output (relative heading).
    range_epochs : RangeEpochs
        :func:`aggregate_ranges` at ``pdr.t_s``.
    initial_heading_rad : float
        Solved initial heading (fusion.heading_init), added to the PDR's
        relative heading.

    Returns
    -------
    FilterEpochs
    """
    if len(pdr) < 2:
        raise ValueError(f"pdr: need at least 2 steps, got {len(pdr)}")
    if len(range_epochs) != len(pdr) or not np.array_equal(range_epochs.t_s, pdr.t_s):
        raise ValueError("range_epochs: not aggregated at the PDR step times")
    heading = np.asarray(pdr.heading_rad, dtype=np.float64)
    speed = np.asarray(pdr.speed_mps, dtype=np.float64)
    if np.any(~np.isfinite(speed) | (speed <= 0)):
        raise ValueError("pdr.speed_mps: every step needs a finite positive speed")
    return FilterEpochs(
        t_s=np.asarray(pdr.t_s, dtype=np.float64),
        dt_s=step_durations_s(pdr),
        range_change_m=range_epochs.range_change_m,
        range_sigma_m=range_epochs.sigma_m,
        snr_db=range_epochs.snr_db,
        pdr_heading_rad=heading + initial_heading_rad,
        pdr_heading_increment_rad=np.asarray(wrap_angle(np.diff(heading, prepend=heading[0]))),
        pdr_speed_mps=speed,
        pdr_speed_ratio=np.concatenate([[1.0], speed[1:] / speed[:-1]]),
    )
