"""The towers' transmit delay offsets of a single-frequency network, and the tower differences' codes made absolute.

A tower difference's code (docs/paths.md, "Tower differences from the
code") measures ``c (tau_k - tau_0) = (r_k - r_0) + c (tx_k - tx_0)``: the
difference of the two towers' distances plus that of their transmit delay
offsets ``tx``, which a network plan sets and a user seldom knows to the
nanosecond. Once ``c (tx_k - tx_0)`` is taken out, the code says on which
hyperbola of the two towers the walker stands, and a filter re-anchoring the
difference takes its origin from there (:meth:`fusion.model.EpochObservation.anchor_channels`).
What is left of the offsets' uncertainty is a constant of the walk, carried
as the standard deviation of every such origin
(:meth:`fusion.model.EpochObservation.anchor_sigmas`); an anchor replaces the
origin rather than adding to it, so the constant is never averaged down.

Where ``c (tx_k - tx_0)`` comes from (:func:`tie_code_differences`):

- ``"plan"`` / ``"exact"``: given (:class:`TransmitDelays`, e.g. a towers
  file's ``transmit_delay_s`` and ``transmit_delay_sigma_s``, or a
  simulation's truth), with its stated standard deviation.
- ``"start fix"``: not given; estimated where the walk starts. While the
  walker still stands at the start fix P0 (before the PDR's first step) the
  difference's code minus the geometric difference at P0 is the offset. The
  code is averaged over the whole first run of the difference's carrier
  (no origin break), each epoch's code moved back to the run's first epoch by
  the carrier's change since, so walking does not blur it. Its error is the
  fix's, projected on the gradient of ``r_k - r_0`` at P0 (at most twice the
  fix's), with the code's averaged scatter.
- ``"unknown"``: neither: the difference is not tracked before the first
  step, so nothing ties its code to P0; its code is not used.
- ``"surveyed"``: given, measured once on another walk of the network while
  GNSS worked (:func:`survey_code_offsets`): the code's difference minus the
  geometric difference at each GNSS fix, weighted by the fix's stated
  accuracy. The fixes' errors are correlated in time, so the survey's sigma
  shrinks with the number of independent stretches of fixes, not with the
  number of fixes. Unlike the start fix's estimate, its error is not this
  walk's start fix error: the network's difference then places the walker
  along its gradient on its own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import PathRanges
from dtmbnav_core.start_fix import FIX_ERROR_TAU_S, correlated_weighted_mean
from fusion.model import Geometry
from fusion.observations import PathAggregationConfig, PathEpochs, aggregate_paths

#: Standard deviation of a network plan's transmit delay offset given without one, s: a plan is taken to
#: hold each tower's offset to about a tenth of a microsecond unless its file says better or worse.
DEFAULT_PLAN_SIGMA_S = 100e-9
#: A survey residual further than this many of its standard deviations (its fix's, or the residuals' robust spread
#: where larger) from the residuals' median is an outlier (a wrong first path, a fix far off) and left out.
SURVEY_OUTLIER_SIGMAS = 5.0


@dataclass(frozen=True)
class TransmitDelays:
    """The towers' transmit delay offsets as given to the fusion.

    Attributes
    ----------
    delays_s : tuple of float
        Each tower's transmit delay offset, in the geometry's tower order, s.
    sigmas_s : tuple of float
        Each one's standard deviation, s (0: exact).
    source : str
        What they are, for the record: ``"plan"`` (a network plan),
        ``"surveyed"`` (:func:`survey_code_offsets`) or ``"exact"`` (a
        simulation's truth).
    """

    delays_s: tuple[float, ...]
    sigmas_s: tuple[float, ...]
    source: str = "plan"

    def __post_init__(self) -> None:
        if len(self.delays_s) != len(self.sigmas_s):
            raise ValueError(f"TransmitDelays: {len(self.delays_s)} delays but {len(self.sigmas_s)} sigmas")
        values = np.array([*self.delays_s, *self.sigmas_s], dtype=np.float64)
        if not np.all(np.isfinite(values)) or min(self.sigmas_s, default=0.0) < 0.0:
            raise ValueError(f"TransmitDelays: delays and sigmas must be finite, sigmas >= 0; got {self}")


def given_transmit_delays(known: str, plan_s: Sequence[float], plan_error_s: float,
                          true_s: Callable[[], Sequence[float]],
                          surveyed: Callable[[], TransmitDelays | None] | None = None) -> TransmitDelays | None:
    """What the fusion is given of a network's transmit delay offsets, by what its user knows (``known``, one of
    :data:`dtmbnav_core.constants.TRANSMIT_DELAY_KNOWLEDGE`): None for ``"unknown"`` and for a single tower
    (estimated at the start fix); the plan's ``plan_s`` (s) with ``plan_error_s`` (s) as each one's sigma;
    a survey's, ``surveyed()`` (asked for only then; ValueError without it); or the true ones, ``true_s()``
    (s, asked for only then), exact."""
    if len(plan_s) < 2 or known == "unknown":
        return None
    if known == "plan":
        return TransmitDelays(tuple(float(d) for d in plan_s), (float(plan_error_s),) * len(plan_s), "plan")
    if known == "exact":
        return TransmitDelays(tuple(float(d) for d in true_s()), (0.0,) * len(plan_s), "exact")
    if known == "surveyed":
        if surveyed is None:
            raise ValueError("transmit delays: known = \"surveyed\" but no survey was given: survey the network on a "
                             "walk with GNSS ('dtmbnav towers calibrate') and give its towers file (fuse --towers)")
        return surveyed()
    raise ValueError(f"transmit delays: known must be one of unknown, plan, surveyed, exact; got {known!r}")


@dataclass(frozen=True)
class CodeOffsets:
    """What was taken out of each tower difference's code (difference k - 1 for tower k).

    Attributes
    ----------
    offset_m : ndarray
        ``c (tx_k - tx_0)``, m (NaN: unknown).
    sigma_m : ndarray
        Its standard deviation, m (``inf``: unknown).
    source : tuple of str
        ``"plan"``, ``"exact"``, ``"start fix"`` or ``"unknown"`` (module docstring).
    """

    offset_m: np.ndarray
    sigma_m: np.ndarray
    source: tuple[str, ...]

    def describe(self) -> str:
        """One line per difference, e.g. ``tower 1 - tower 0: +150.3 +- 2.1 m (start fix)``, joined by ``; ``."""
        def one(k: int) -> str:
            if not np.isfinite(self.offset_m[k]):
                return f"tower {k + 1} - tower 0: unknown (not tracked at the start fix; its code is not used)"
            return (f"tower {k + 1} - tower 0: {self.offset_m[k]:+.1f} +- {self.sigma_m[k]:.1f} m "
                    f"({self.source[k]})")

        return "; ".join(one(k) for k in range(len(self.source)))

    def attrs(self) -> dict[str, np.ndarray]:
        """``/fusion`` attributes: ``code_offset_m``, ``code_offset_sigma_m``, ``code_offset_source``."""
        return {"code_offset_m": np.asarray(self.offset_m, dtype=np.float64),
                "code_offset_sigma_m": np.asarray(self.sigma_m, dtype=np.float64),
                "code_offset_source": ",".join(self.source)}


def difference_gradient(geometry: Geometry, x_m: np.ndarray, y_m: np.ndarray, tower: int) -> np.ndarray:
    """Norm of the horizontal gradient of ``r_tower - r_0`` at the points ``x_m``, ``y_m`` (m; dimensionless,
    0..2): how much of a horizontal position error there a range difference sees."""
    x_m, y_m = np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)
    towers = geometry.towers()

    def unit(k: int) -> tuple[np.ndarray, np.ndarray]:
        r = geometry.range_m(x_m, y_m, k)
        return (x_m - towers[k, 0]) / r, (y_m - towers[k, 1]) / r

    (ex_k, ey_k), (ex_0, ey_0) = unit(tower), unit(0)
    return np.hypot(ex_k - ex_0, ey_k - ey_0)


def start_difference_gradient_m(geometry: Geometry, tower: int) -> float:
    """Norm of the horizontal gradient of ``r_tower - r_0`` at P0 (dimensionless, 0..2): how much of a
    horizontal error of P0 a range difference sees."""
    return float(difference_gradient(geometry, np.float64(geometry.start_x_m), np.float64(geometry.start_y_m),
                                     tower))


def start_fix_offset_m(paths: PathEpochs, column: int, geometry: Geometry, first_step_t_s: float,
                       fix_sigma_m: float) -> tuple[float, float]:
    """``c (tx_k - tx_0)`` of difference ``column`` (tower ``column + 1``) from its code while the walker is at P0.

    Returns
    -------
    offset_m, sigma_m : float
        The offset and its standard deviation, m; NaN and ``inf`` where the
        difference has no code and carrier together before ``first_step_t_s``.
    """
    code = paths.range_difference_code_m[:, column]
    carrier = paths.range_difference_m[:, column]
    valid = np.isfinite(code) & np.isfinite(carrier)
    if not valid.any():
        return np.nan, np.inf
    first = int(np.argmax(valid))
    if paths.t_s[first] > first_step_t_s:
        return np.nan, np.inf
    # The first run: up to the next new origin of the difference's carrier.
    later_origins = np.flatnonzero(paths.range_difference_new_origin[first + 1:, column])
    end = first + 1 + int(later_origins[0]) if len(later_origins) else len(code)
    run = np.flatnonzero(valid[first:end]) + first
    # Each epoch's code, moved back to the run's first epoch along the carrier's change since.
    at_first = code[run] - (carrier[run] - carrier[first])
    tower = column + 1
    geometric = geometry.start_range_m(tower) - geometry.start_range_m(0)
    offset = float(np.median(at_first)) - geometric
    scatter = 1.4826 * float(np.median(np.abs(at_first - np.median(at_first)))) / np.sqrt(len(run))
    return offset, float(np.hypot(fix_sigma_m * start_difference_gradient_m(geometry, tower), scatter))


def tie_code_differences(paths: PathEpochs, geometry: Geometry, known: TransmitDelays | None,
                         first_step_t_s: float, fix_sigma_m: float) -> tuple[PathEpochs, CodeOffsets]:
    """Take the towers' transmit delay offsets out of every tower difference's code (module docstring).

    Parameters
    ----------
    paths : PathEpochs
        :func:`fusion.observations.aggregate_paths`'s epochs, whose
        difference codes still hold the offsets.
    geometry : Geometry
        The towers and P0.
    known : TransmitDelays or None
        The offsets as given (one per tower of ``geometry``); None: estimated
        at the start fix.
    first_step_t_s : float
        Time of the PDR's first step: until then the walker stands at P0, s.
    fix_sigma_m : float
        The start fix's 1-sigma error per axis, m.

    Returns
    -------
    paths : PathEpochs
        With ``range_difference_code_m`` less the offsets and
        ``range_difference_code_sigma_m`` their standard deviations.
    offsets : CodeOffsets
    """
    n_differences = geometry.n_towers - 1
    if known is not None and len(known.delays_s) != geometry.n_towers:
        raise ValueError(f"transmit delays: one per tower ({geometry.n_towers}), got {len(known.delays_s)}")
    offset = np.full(n_differences, np.nan)
    sigma = np.full(n_differences, np.inf)
    source = []
    for column in range(n_differences):
        tower = column + 1
        if known is not None:
            offset[column] = SPEED_OF_LIGHT_MPS * (known.delays_s[tower] - known.delays_s[0])
            sigma[column] = SPEED_OF_LIGHT_MPS * float(np.hypot(known.sigmas_s[tower], known.sigmas_s[0]))
            source.append(known.source)
        else:
            offset[column], sigma[column] = start_fix_offset_m(paths, column, geometry, first_step_t_s, fix_sigma_m)
            source.append("start fix" if np.isfinite(offset[column]) else "unknown")
    code = paths.range_difference_code_m - offset[None, :]   # NaN throughout where the offset is unknown
    tied = replace(paths, range_difference_code_m=code,
                   range_difference_code_sigma_m=np.broadcast_to(sigma, code.shape).copy())
    return tied, CodeOffsets(offset, sigma, tuple(source))


@dataclass(frozen=True)
class SurveyFixes:
    """The GNSS fixes of a survey walk, on the receiver's paths' time base.

    Attributes
    ----------
    t_s : ndarray
        Fix times, increasing, s.
    x_m, y_m : ndarray
        Fixed east and north, m (the towers' frame).
    sigma_m : ndarray
        Each fix's stated 1-sigma error per axis, m (> 0; NaN or inf: no
        stated accuracy, the fix is not used).
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    sigma_m: np.ndarray

    def __post_init__(self) -> None:
        arrays = [np.asarray(a, dtype=np.float64) for a in (self.t_s, self.x_m, self.y_m, self.sigma_m)]
        if any(a.ndim != 1 or len(a) != len(arrays[0]) for a in arrays):
            raise ValueError("SurveyFixes: t_s, x_m, y_m and sigma_m must be 1-D and of one length")
        if not np.all(np.isfinite(arrays[0])) or np.any(np.diff(arrays[0]) <= 0):
            raise ValueError("SurveyFixes: fix times must be finite and increasing")
        if np.any(arrays[3] <= 0):
            raise ValueError("SurveyFixes: a fix's sigma must be > 0 (NaN: not stated)")


@dataclass(frozen=True)
class CodeOffsetSurvey:
    """Each tower difference's ``c (tx_k - tx_0)`` as a survey measured it (difference k - 1 for tower k).

    Attributes
    ----------
    offset_m : ndarray
        The offset, m (NaN: never measured, no code at a usable fix).
    sigma_m : ndarray
        Its standard deviation, m (``inf``: never measured).
    fixes : ndarray of int
        Fixes used.
    effective_fixes : ndarray
        How many independent fixes of their mean inverse variance they are worth
        (:mod:`dtmbnav_core.start_fix`).
    """

    offset_m: np.ndarray
    sigma_m: np.ndarray
    fixes: np.ndarray
    effective_fixes: np.ndarray

    def transmit_delays(self, tower_0_delay_s: float = 0.0) -> TransmitDelays:
        """The offsets as :class:`TransmitDelays` (source ``"surveyed"``): tower 0 at ``tower_0_delay_s`` (s) and
        exact, as the differences are relative to it; each other tower at it plus ``offset / c`` with ``sigma / c``.

        Raises
        ------
        ValueError
            Some difference was never measured.
        """
        missing = [k + 1 for k in range(len(self.offset_m)) if not np.isfinite(self.offset_m[k])]
        if missing:
            raise ValueError(f"transmit delay survey: tower(s) {missing} were never measured against tower 0 at a "
                             "usable GNSS fix")
        delays = (tower_0_delay_s, *(tower_0_delay_s + self.offset_m / SPEED_OF_LIGHT_MPS))
        return TransmitDelays(tuple(float(d) for d in delays),
                              (0.0, *(float(s) for s in self.sigma_m / SPEED_OF_LIGHT_MPS)), "surveyed")


def survey_code_offsets(paths: PathRanges, geometry: Geometry, fixes: SurveyFixes,
                        config: PathAggregationConfig = PathAggregationConfig(),
                        tau_s: float = FIX_ERROR_TAU_S) -> CodeOffsetSurvey:
    """Each tower difference's ``c (tx_k - tx_0)`` from a walk with GNSS fixes (module docstring, ``"surveyed"``).

    At each fix with a code for the difference (the code aggregated over the
    fix's epoch, :func:`fusion.observations.aggregate_paths`) the residual
    ``code - (r_k - r_0)(fix)`` is the offset plus the fix's error seen along
    the difference's gradient ``g`` (:func:`difference_gradient`) plus the
    code's error. Residuals further than :data:`SURVEY_OUTLIER_SIGMAS` from
    their median are left out; the rest are averaged with weights
    ``1 / (g sigma_fix)^2``. The sigma is that mean's under the fixes'
    first-order Gauss-Markov correlation in time
    (:func:`dtmbnav_core.start_fix.correlated_weighted_mean`, ``tau_s``), plus
    the residuals' scatter beyond the fixes' stated errors (the code's own,
    taken as independent from fix to fix).

    Parameters
    ----------
    paths : PathRanges
        The survey walk's tower differences, their codes holding the offsets.
    geometry : Geometry
        The towers (P0 is not used).
    fixes : SurveyFixes
        The survey walk's fixes, on the paths' time base.
    config : PathAggregationConfig
        How the code is aggregated at each fix.
    tau_s : float
        Correlation time of the fixes' errors, s.
    """
    n_differences = geometry.n_towers - 1
    offset, sigma = np.full(n_differences, np.nan), np.full(n_differences, np.inf)
    used, effective = np.zeros(n_differences, dtype=int), np.zeros(n_differences)
    stated = np.isfinite(fixes.sigma_m)
    t, x, y, fix_sigma = (np.asarray(a, dtype=np.float64)[stated]
                          for a in (fixes.t_s, fixes.x_m, fixes.y_m, fixes.sigma_m))
    if len(t) == 0:
        return CodeOffsetSurvey(offset, sigma, used, effective)
    code = aggregate_paths(paths, t, geometry.n_towers, config).range_difference_code_m
    for column in range(n_differences):
        tower = column + 1
        residual = code[:, column] - (geometry.range_m(x, y, tower) - geometry.range_m(x, y, 0))
        seen = fix_sigma * difference_gradient(geometry, x, y, tower)
        have = np.flatnonzero(np.isfinite(residual))
        if len(have) == 0:
            continue
        centre = float(np.median(residual[have]))
        spread = 1.4826 * float(np.median(np.abs(residual[have] - centre)))
        keep = have[np.abs(residual[have] - centre) <= SURVEY_OUTLIER_SIGMAS * np.maximum(seen[have], spread)]
        mean, fix_variance, effective[column] = correlated_weighted_mean(t[keep], residual[keep], seen[keep], tau_s)
        # What the residuals scatter beyond their fixes' stated errors is the code's own, independent per fix.
        weights = seen[keep] ** -2.0
        excess = float(np.sum(weights * ((residual[keep] - mean) ** 2 - seen[keep] ** 2)) / np.sum(weights))
        offset[column] = mean
        sigma[column] = float(np.sqrt(fix_variance + max(excess, 0.0) / len(keep)))
        used[column] = len(keep)
    return CodeOffsetSurvey(offset, sigma, used, effective)
