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
   telescopes and its frame noise is millimetres, method.md §2): it makes the
   observation insensitive to which frame is nearest the step peak and to the
   odd flagged frame.
5. Its standard deviation is ``base_sigma_m`` (the drift/multipath error the
   integrated range accumulates over a walk, which is what limits it), inflated
   where the link is weak: the phase-noise variance grows as 1/SNR, and low
   SNR is where the direct path is blocked and a reflection sets the phase, so
   ``sigma = base_sigma_m * sqrt(max(1, 10^((good_snr_db - snr)/10)))`` with
   ``snr`` the mean SNR of the valid frames in dB, and a further factor
   ``1 / sqrt(valid fraction)`` for partly flagged windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fusion.model import StepControl, wrap_angle
from fusion.records import ColumnRecord, PdrSteps, RangeSeries


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
        Range observation standard deviation on a good link, m.
    good_snr_db : float
        SNR at and above which no inflation applies, dB.
    """

    window_s: float = 0.2
    min_valid_fraction: float = 0.5
    base_sigma_m: float = 0.5
    good_snr_db: float = 10.0


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
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    sigma_m: np.ndarray
    snr_db: np.ndarray


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
    half = config.window_s / 2.0
    lo = np.searchsorted(ranges.t_s, epoch_t_s - half, side="left")
    hi = np.searchsorted(ranges.t_s, epoch_t_s + half, side="right")
    # Prefix sums give every window's count and sums without a Python loop.
    zero = np.zeros(1)
    n_valid_cum = np.concatenate([zero, np.cumsum(valid)])
    range_cum = np.concatenate([zero, np.cumsum(np.where(valid, ranges.range_change_m, 0.0))])
    snr_lin_cum = np.concatenate([zero, np.cumsum(np.where(valid, 10.0 ** (ranges.snr_db / 10.0), 0.0))])
    n_valid = n_valid_cum[hi] - n_valid_cum[lo]
    expected = config.window_s / np.median(np.diff(ranges.t_s))
    fraction = np.minimum(n_valid / expected, 1.0)
    keep = (fraction >= config.min_valid_fraction) & (n_valid > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_range = (range_cum[hi] - range_cum[lo]) / n_valid
        snr_db = 10.0 * np.log10((snr_lin_cum[hi] - snr_lin_cum[lo]) / n_valid)
        inflation = np.maximum(1.0, 10.0 ** ((config.good_snr_db - snr_db) / 10.0))
        sigma = config.base_sigma_m * np.sqrt(inflation / fraction)
    nan = np.full(len(epoch_t_s), np.nan)
    return RangeEpochs(
        t_s=epoch_t_s,
        range_change_m=np.where(keep, mean_range, nan),
        sigma_m=np.where(keep, sigma, nan),
        snr_db=np.where(n_valid > 0, snr_db, nan),
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
