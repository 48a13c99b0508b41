"""Accuracy metrics as the paper reports them (docs/method.md §6).

Position error is the horizontal distance between an estimate and the truth
interpolated at the estimate's own times; the statistics are the 68th and 95th
percentiles (numpy's linear interpolation between order statistics) and the
maximum, plus the empirical CDF for plotting. The PDR baseline is placed the
way the paper does when it reports PDR error: its relative track rotated by
the true initial heading and shifted to the true start.

Whether a track's stated error holds (:class:`dtmbnav_core.records.FusedTrack`):
each row's squared Mahalanobis distance of the true position,
``d^2 = e^T C^-1 e`` with ``e`` the east/north error and ``C`` the stated
covariance, is the normalised estimation error squared (NEES). For an error
that is Gaussian with the stated covariance it follows chi-square with two
degrees of freedom: mean 2, and ``d^2 <= 5.991`` (the stated 95 % ellipse)
on 95 % of the rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.records import ELLIPSE_95_CHI2, FusedTrack, PdrSteps, Track
from fusion.heading_init import rotate_pdr
from fusion.model import wrap_angle


@dataclass(frozen=True)
class ErrorStats:
    """Position error summary, m.

    Attributes
    ----------
    p68_m, p95_m, max_m : float
        68th / 95th percentile and maximum of the error, m.
    n : int
        Number of epochs.
    """

    p68_m: float
    p95_m: float
    max_m: float
    n: int


def interpolate_track(track: Track, t_s: np.ndarray) -> Track:
    """``track`` linearly interpolated at times ``t_s`` (headings through their unit vectors).

    Raises
    ------
    ValueError
        If ``t_s`` leaves the track's time span.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    if t_s.min() < track.t_s[0] - 1e-9 or t_s.max() > track.t_s[-1] + 1e-9:
        raise ValueError(f"interpolate_track: times {t_s.min():.3f}..{t_s.max():.3f} s leave the track's span "
                         f"{track.t_s[0]:.3f}..{track.t_s[-1]:.3f} s")
    sin_h = np.interp(t_s, track.t_s, np.sin(track.heading_rad))
    cos_h = np.interp(t_s, track.t_s, np.cos(track.heading_rad))
    return Track(t_s=t_s, x_m=np.interp(t_s, track.t_s, track.x_m), y_m=np.interp(t_s, track.t_s, track.y_m),
                 heading_rad=np.arctan2(sin_h, cos_h) % (2.0 * np.pi),
                 speed_mps=np.interp(t_s, track.t_s, track.speed_mps))


def position_errors_m(estimate: Track, truth: Track) -> np.ndarray:
    """Horizontal error of ``estimate`` against ``truth`` at the estimate's times, m."""
    ref = interpolate_track(truth, estimate.t_s)
    return np.hypot(estimate.x_m - ref.x_m, estimate.y_m - ref.y_m)


def error_stats(errors_m: np.ndarray) -> ErrorStats:
    """68 % / 95 % / max of a set of errors."""
    errors_m = np.asarray(errors_m, dtype=np.float64)
    if errors_m.size == 0:
        raise ValueError("error_stats: no errors given")
    p68, p95 = np.percentile(errors_m, [68.0, 95.0])
    return ErrorStats(p68_m=float(p68), p95_m=float(p95), max_m=float(errors_m.max()), n=int(errors_m.size))


@dataclass(frozen=True)
class StatedErrorStats:
    """How well a track's stated error holds the truth (module docstring).

    Attributes
    ----------
    in_ellipse_95 : float
        Share of the rows whose true position lies inside the stated 95 % ellipse (``d^2 <= 5.991``).
    mean_nees : float
        Mean of ``d^2`` over the rows (2 where the stated covariance is right).
    n : int
        Number of rows.
    """

    in_ellipse_95: float
    mean_nees: float
    n: int


def position_nees(estimate: FusedTrack, truth: Track) -> np.ndarray:
    """Each row's NEES ``e^T C^-1 e`` of the true position against the stated covariance (NaN where none)."""
    ref = interpolate_track(truth, estimate.t_s)
    error = np.stack([ref.x_m - estimate.x_m, ref.y_m - estimate.y_m], axis=-1)
    cov = estimate.position_covariance_m2()
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        # The 2x2 inverse written out: C^-1 = [[c11, -c01], [-c01, c00]] / det.
        return (cov[:, 1, 1] * error[:, 0] ** 2 - 2.0 * cov[:, 0, 1] * error[:, 0] * error[:, 1]
                + cov[:, 0, 0] * error[:, 1] ** 2) / det


def stated_error_stats(estimate: FusedTrack, truth: Track) -> StatedErrorStats:
    """Share of rows inside the stated 95 % ellipse and mean NEES; NaN for a track without stated error."""
    nees = position_nees(estimate, truth)
    if nees.size == 0:
        raise ValueError("stated_error_stats: no rows given")
    if not estimate.has_stated_error():
        return StatedErrorStats(float("nan"), float("nan"), int(nees.size))
    return StatedErrorStats(float(np.mean(nees <= ELLIPSE_95_CHI2)), float(np.mean(nees)), int(nees.size))


def error_cdf(errors_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Empirical CDF: sorted errors (m) and the fraction of epochs at or below each."""
    sorted_m = np.sort(np.asarray(errors_m, dtype=np.float64))
    return sorted_m, np.arange(1, sorted_m.size + 1) / sorted_m.size


def heading_error_rad(estimate_rad: float | np.ndarray, truth_rad: float | np.ndarray) -> np.ndarray:
    """Absolute heading difference on the circle, rad in [0, pi]."""
    return np.abs(wrap_angle(np.asarray(estimate_rad) - np.asarray(truth_rad)))


def place_pdr(pdr: PdrSteps, start_x_m: float, start_y_m: float, initial_heading_rad: float) -> Track:
    """The PDR's relative track rotated by ``initial_heading_rad`` and shifted to a start point.

    With the true start and true initial heading this is the paper's PDR
    baseline; with the GNSS fix and the solved heading it is what a user would
    get from PDR alone after eq. 15.
    """
    dx, dy = rotate_pdr(pdr.x_m, pdr.y_m, initial_heading_rad)
    return Track(t_s=np.asarray(pdr.t_s, dtype=np.float64), x_m=start_x_m + dx, y_m=start_y_m + dy,
                 heading_rad=(pdr.heading_rad + initial_heading_rad) % (2.0 * np.pi),
                 speed_mps=np.asarray(pdr.speed_mps, dtype=np.float64))


def true_initial_heading_rad(truth: Track, walk_start_t_s: float, distance_m: float = 3.0) -> float:
    """Direction of the truth's first ``distance_m`` metres walked after ``walk_start_t_s``, rad.

    The start-still period has no heading, so the initial heading is the
    bearing from the start to the point where the walker is first
    ``distance_m`` away from it.
    """
    i0 = int(np.searchsorted(truth.t_s, walk_start_t_s))
    away = np.hypot(truth.x_m[i0:] - truth.x_m[i0], truth.y_m[i0:] - truth.y_m[i0])
    far = np.nonzero(away >= distance_m)[0]
    if far.size == 0:
        raise ValueError(f"true_initial_heading_rad: truth never gets {distance_m} m from its start")
    j = i0 + far[0]
    return float(np.arctan2(truth.x_m[j] - truth.x_m[i0], truth.y_m[j] - truth.y_m[i0]) % (2.0 * np.pi))


#: Name of the PDR baseline placed as the paper reports PDR error (true start, true initial heading).
PDR_BASELINE = "pdr"
#: Name of the PDR placed as a user without truth would place it (GNSS start fix, eq. 15 heading).
PDR_AT_FIX = "pdr@fix"


def pdr_baselines(pdr: PdrSteps, truth: Track, walk_start_t_s: float, start_fix_xy_m: tuple[float, float],
                  solved_heading_rad: float) -> tuple[dict[str, Track], float]:
    """The two PDR baselines a fused track is compared with.

    Returns
    -------
    baselines : dict of str -> Track
        :data:`PDR_BASELINE`: the relative track rotated by the true initial
        heading and started at the true start (the paper's PDR row, the
        reference of the reductions); :data:`PDR_AT_FIX`: started at the GNSS
        fix with the solved (eq. 15) heading, like the filters.
    true_heading_rad : float
        The true initial heading, rad.
    """
    true_heading = true_initial_heading_rad(truth, walk_start_t_s)
    start = (float(truth.x_m[0]), float(truth.y_m[0]))
    return {PDR_BASELINE: place_pdr(pdr, *start, true_heading),
            PDR_AT_FIX: place_pdr(pdr, *start_fix_xy_m, solved_heading_rad)}, true_heading
