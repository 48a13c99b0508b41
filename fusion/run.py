"""Fuse one recording: PDR steps + receiver range -> initial heading -> every filter's track.

This is the function behind ``dtmbnav fuse``: it solves the initial heading
(eq. 14-15), builds the filter epochs (:mod:`fusion.observations`: with a
free-running clock also the standstill epochs) and runs the requested
filters on identical inputs.

Which filter takes which observation: every filter (``pf``, ``ukf``,
``wt-ukf``, ``adaptive-kf``, ``rank-kf``, ``rb-pf``) takes the SI-carrier range, the
first-path range of every tower and the tower differences (the range
channels of :class:`fusion.model.ObservationLayout`), the PDR heading and
speed, and with ``clock_model="free-running"`` (or ``clock_state``) carries
the clock's states (:class:`fusion.model.ClockModel`); all
of them vet the range channels with the same integrity monitor
(:mod:`fusion.integrity`). The WT-UKF re-estimates the SI-carrier range's
noise only, the adaptive EKF grades the SI-carrier range's by the link SNR;
the path channels keep the sigma of their aggregation rule.

Every track states its error (an east/north covariance per row,
:class:`dtmbnav_core.records.FusedTrack`), and with ``FusionConfig.smooth``
each filter also gives its smoothed track (:mod:`fusion.smoothing`): the
filtered track stays the real-time answer.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import partial
from typing import Callable

import numpy as np

from dtmbnav_core.records import FusedTrack, PdrSteps, RangeSeries
from fusion import (CLOCK_MODELS, DEFAULT_CLOCK_MODEL, DEFAULT_HEADING_RANGE, DEFAULT_PARTICLES, DEFAULT_SI_RANGE_USE,
                    DEFAULT_SMOOTHING_LAG, FILTER_NAMES, HEADING_RANGES, SI_RANGE_USES)
from fusion.adaptive_kf import AdaptiveEkf
from fusion.driver import FusionFilter, drive_filter, run_filter
from fusion.heading_init import HEADING_WINDOW_S, HeadingSolution, solve_initial_heading
from fusion.integrity import IntegrityConfig
from fusion.model import ClockModel, Geometry, ModelNoise
from fusion.observations import AggregationConfig, FilterEpochs, PathAggregationConfig, PathEpochs, RangeEpochs, StandstillConfig, aggregate_paths, aggregate_ranges, build_epochs, epoch_times, si_range_epochs
from dtmbnav_core.records import PathRanges
from fusion.particle_filter import start_particle_filter
from fusion.rank_kf import RangePdrRankKf
from fusion.rb_particle_filter import start_marginalised_filter
from fusion.transmit_delays import CodeOffsets, TransmitDelays, tie_code_differences
from fusion.ukf import RangePdrUkf
from fusion.wt_ukf import WaveletUkf


@dataclass(frozen=True)
class FusionConfig:
    """Settings shared by every filter of a fusion run.

    Attributes
    ----------
    noise : ModelNoise
    aggregation : AggregationConfig
    n_particles : int
        Particle-filter Np.
    seed : int
        Particle-filter seed.
    clock_model : {"disciplined", "free-running"}
        The receiver clock (:class:`fusion.model.ClockModel`): a free-running
        one gives every filter the clock state and the standstill epochs.
    clock_allan_deviation : float or None
        Allan deviation of the clock at ``clock_allan_tau_s``; None: the
        preset of its kind.
    clock_allan_tau_s : float
        Its averaging time, s.
    clock_state : bool
        Whether the filters carry a disciplined clock's states too (its
        holdover wander; :class:`fusion.model.ClockModel`). Off by default
        (the paper's model, no clock): it helps a walk whose clock drifts,
        but not on average over the tuning walks (docs/decisions.md, D23).
    integrity : IntegrityConfig
        The range integrity monitor every filter uses.
    paths : PathAggregationConfig
        The path channels' aggregation.
    standstills : StandstillConfig
        Where the standstill epochs go.
    heading_range : {"si", "first-path"}
        The range eq. 15 is solved on with a disciplined clock
        (:func:`initial_heading`).
    si_range : {"always", "without-first-path"}
        Where the filters take the SI-carrier range
        (:func:`fusion.observations.si_range_epochs`); eq. 15 sees all of it.
    heading_drift_radps : float
        The PDR heading's rate error that eq. 15's sigma counts
        (:func:`fusion.heading_init.heading_sigma`), rad/s: the drift that
        bends the PDR track over the solved window, far below the filters'
        initial heading-rate spread, which must also hold a bias the range
        has not yet shown (chosen on the tuning walks so that the sigma holds
        the heading errors; docs/decisions.md, D45).
    smooth : bool
        Whether every filter also smooths the recording (:mod:`fusion.smoothing`;
        ``FusionResult.smoothed``). Off unless asked for: a Monte Carlo evaluation
        scores the filtered tracks and the particle filter's smoother costs time;
        ``dtmbnav fuse`` always smooths (``dtmbnav.chain.fuse.fuse_files``).
    smoothing_lag : int
        The particle filter's smoothing lag, epochs (:mod:`fusion.particle_filter`).
    """

    noise: ModelNoise = field(default_factory=ModelNoise)
    aggregation: AggregationConfig = field(default_factory=AggregationConfig)
    n_particles: int = DEFAULT_PARTICLES
    seed: int = 0
    clock_model: str = DEFAULT_CLOCK_MODEL
    clock_allan_deviation: float | None = None
    clock_allan_tau_s: float = 1.0
    clock_state: bool = False
    integrity: IntegrityConfig = field(default_factory=IntegrityConfig)
    paths: PathAggregationConfig = field(default_factory=PathAggregationConfig)
    standstills: StandstillConfig = field(default_factory=StandstillConfig)
    heading_range: str = DEFAULT_HEADING_RANGE
    si_range: str = DEFAULT_SI_RANGE_USE
    heading_drift_radps: float = np.deg2rad(0.02)
    smooth: bool = False
    smoothing_lag: int = DEFAULT_SMOOTHING_LAG

    def __post_init__(self) -> None:
        if self.clock_model not in CLOCK_MODELS:
            raise ValueError(f"clock_model {self.clock_model!r}: expected one of {', '.join(CLOCK_MODELS)}")
        if self.heading_range not in HEADING_RANGES:
            raise ValueError(f"heading_range {self.heading_range!r}: expected one of {', '.join(HEADING_RANGES)}")
        if self.si_range not in SI_RANGE_USES:
            raise ValueError(f"si_range {self.si_range!r}: expected one of {', '.join(SI_RANGE_USES)}")
        self.clock()

    def clock(self) -> ClockModel:
        """The clock model the filters use."""
        return ClockModel(self.clock_model, self.clock_allan_deviation, self.clock_allan_tau_s,
                          state=self.clock_state)


def initial_heading(pdr: PdrSteps, range_epochs: RangeEpochs, path_epochs: PathEpochs | None, at_steps: np.ndarray,
                    geometry: Geometry, config: FusionConfig, window_s: float | None = HEADING_WINDOW_S
                    ) -> HeadingSolution:
    """Eq. 15 at the PDR steps: on the range to tower 0, or on a tower difference when the clock runs free.

    A free-running receiver clock drifts in a way a single tower's range
    cannot tell from motion, so the eq. 15 heading solved on it is off by tens
    of degrees; the difference of two towers' first paths (an SFN) is free of
    the clock, so with ``clock_model="free-running"`` eq. 15 is solved on the
    first tower difference that constrains the heading, and on the range to
    tower 0 otherwise. With a disciplined clock that range is the SI-carrier
    one (the paper's), or with ``heading_range="first-path"`` tower 0's
    first-path range where it constrains the heading (in a street whose
    direct path is blocked the SI carriers follow a reflection). A first-path
    epoch that starts from a new origin (a slip, a re-found path) is left
    out, so that eq. 15 gives the run after it a free offset. ``window_s``: eq. 15's first window
    (:func:`fusion.heading_init.solve_initial_heading`'s ``max_duration_s``).
    """
    # What eq. 15's sigma counts beyond the residuals: the fix's error and the PDR heading's drift.
    sigmas = dict(start_sigma_m=config.noise.initial_position_m,
                  heading_rate_sigma_radps=config.heading_drift_radps, max_duration_s=window_s)
    if config.clock().free_running and path_epochs is not None:
        for k in range(path_epochs.range_difference_m.shape[1]):
            try:
                return solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, path_epochs.range_difference_m[at_steps, k],
                                             geometry, difference_tower=k + 1,
                                             **sigmas)
            except ValueError:  # too few epochs of this difference: try the next, then the range
                continue
    if config.heading_range == "first-path" and path_epochs is not None:
        first = np.where(path_epochs.first_path_new_origin[:, 0], np.nan, path_epochs.first_path_range_m[:, 0])
        try:
            return solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, first[at_steps], geometry,
                                         **sigmas)
        except ValueError:  # too few first-path epochs: the SI-carrier range
            pass
    return solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, range_epochs.range_change_m[at_steps], geometry,
                                 **sigmas)


def with_heading_spread(config: FusionConfig, heading: HeadingSolution) -> FusionConfig:
    """``config`` with the filters' initial heading spread widened to eq. 15's sigma where that is wider.

    The filters start around the solved heading with
    ``ModelNoise.initial_heading_rad``; where the range leaves the heading
    less certain than that (a walk along the line of sight, a short window),
    a narrower start would hold the filters away from the truth.
    """
    if heading.sigma_rad <= config.noise.initial_heading_rad:
        return config
    return replace(config, noise=replace(config.noise, initial_heading_rad=heading.sigma_rad))


FilterBuilder = Callable[[FilterEpochs, Geometry, FusionConfig], FusionFilter]
FilterRunner = Callable[[FilterEpochs, Geometry, FusionConfig], FusedTrack]

#: Filter name -> the filter, started at P0 for the epochs. "pf" is the main paper's particle filter.
FILTER_BUILDERS: dict[str, FilterBuilder] = {
    "pf": lambda e, g, c: start_particle_filter(e, g, c.noise, c.n_particles, c.seed, clock=c.clock(),
                                                integrity=c.integrity, smoothing_lag=c.smoothing_lag),
    "ukf": lambda e, g, c: RangePdrUkf(g, c.noise, *e.initial_heading_speed(), c.clock(), c.integrity),
    "wt-ukf": lambda e, g, c: WaveletUkf(g, c.noise, e, clock=c.clock(), integrity=c.integrity),
    "adaptive-kf": lambda e, g, c: AdaptiveEkf(g, c.noise, e, clock=c.clock(), integrity=c.integrity),
    "rank-kf": lambda e, g, c: RangePdrRankKf(g, c.noise, *e.initial_heading_speed(), clock=c.clock(),
                                              integrity=c.integrity),
    "rb-pf": lambda e, g, c: start_marginalised_filter(e, g, c.noise, seed=c.seed, clock=c.clock(),
                                                       integrity=c.integrity, smoothing_lag=c.smoothing_lag),
}


def _run_built(build: FilterBuilder, epochs: FilterEpochs, geometry: Geometry, config: FusionConfig) -> FusedTrack:
    return run_filter(build(epochs, geometry, config), epochs)


#: Filter name -> runner: the filtered track of :data:`FILTER_BUILDERS`' filter (no smoothing).
FILTERS: dict[str, FilterRunner] = {name: partial(_run_built, build) for name, build in FILTER_BUILDERS.items()}
assert tuple(FILTERS) == FILTER_NAMES, "fusion.FILTER_NAMES and fusion.run.FILTERS must list the same filters"


@dataclass
class FusionResult:
    """What a fusion run produces.

    Attributes
    ----------
    tracks : dict of str -> FusedTrack
        Each filter's estimate with its stated error, one row per PDR step.
    heading : HeadingSolution
        The eq. 15 solution whose ``heading_rad`` every filter started from.
    epochs : FilterEpochs
        The inputs the filters consumed.
    start_xy_m : (float, float)
        The start fix P0 every filter started from, ENU m.
    code_offsets : CodeOffsets or None
        The transmit delay offsets taken out of the tower differences' codes
        (:func:`fusion.transmit_delays.tie_code_differences`); None without
        path observations.
    smoothed : dict of str -> FusedTrack
        Each filter's smoothed track with its error (empty unless ``FusionConfig.smooth``).
    """

    tracks: dict[str, FusedTrack]
    heading: HeadingSolution
    epochs: FilterEpochs
    start_xy_m: tuple[float, float]
    code_offsets: CodeOffsets | None = None
    smoothed: dict[str, FusedTrack] = field(default_factory=dict)


def fuse(pdr: PdrSteps, ranges: RangeSeries, start_xy_m: tuple[float, float], tower_xy_m: tuple[float, float],
         filters: tuple[str, ...] = tuple(FILTERS), *, tower_height_m: float = 0.0,
         other_towers: tuple[tuple[float, float, float], ...] = (), paths: PathRanges | None = None,
         transmit_delays: TransmitDelays | None = None, start_sigma_m: float | None = None,
         config: FusionConfig = FusionConfig()) -> FusionResult:
    """Run the requested filters on one recording's PDR and receiver output.

    Parameters
    ----------
    pdr : PdrSteps
        PDR steps (relative frame and heading).
    ranges : RangeSeries
        Receiver integrated range (relative to the capture start, spent at P0).
    start_xy_m : (float, float)
        Start fix P0, ENU m.
    tower_xy_m : (float, float)
        Tower position, ENU m.
    filters : tuple of str
        Names from :data:`FILTERS`.
    tower_height_m : float
        Tower antenna height above the walker, m.
    other_towers : tuple of (x_m, y_m, height_m)
        Further towers of a single-frequency network (:class:`fusion.model.Geometry`).
    paths : PathRanges, optional
        The receiver's first-path ranges and tower differences.
    transmit_delays : TransmitDelays, optional
        The towers' transmit delay offsets (a network plan's, with their
        sigmas); None: unknown, estimated at the start fix
        (:mod:`fusion.transmit_delays`).
    start_sigma_m : float, optional
        The start fix's stated standard deviation per axis, m: the filters'
        initial position spread, eq. 15's sigma and the code offsets' tie to
        the fix take it in place of ``config.noise.initial_position_m`` (a
        fix under a blocked sky states a wider one). None: that default.
    config : FusionConfig

    Returns
    -------
    FusionResult

    Raises
    ------
    ValueError
        For an unknown filter name.
    """
    unknown = [f for f in filters if f not in FILTERS]
    if unknown:
        raise ValueError(f"fuse: unknown filter(s) {unknown}; known: {', '.join(FILTERS)}")
    if start_sigma_m is not None:
        if not (np.isfinite(start_sigma_m) and start_sigma_m > 0):
            raise ValueError(f"fuse: the start fix's sigma must be positive and finite, got {start_sigma_m}")
        config = replace(config, noise=replace(config.noise, initial_position_m=float(start_sigma_m)))
    geometry = Geometry(start_xy_m[0], start_xy_m[1], tower_xy_m[0], tower_xy_m[1], tower_height_m, other_towers)
    standstills = config.standstills if config.clock().free_running else None
    t_s = epoch_times(pdr.t_s, float(ranges.t_s[0]), standstills)
    range_epochs = aggregate_ranges(ranges, t_s, config.aggregation)
    at_steps = np.searchsorted(t_s, pdr.t_s)
    path_epochs, code_offsets = None, None
    if paths is not None:
        path_epochs, code_offsets = tie_code_differences(
            aggregate_paths(paths, t_s, geometry.n_towers, config.paths), geometry, transmit_delays,
            float(pdr.t_s[0]), config.noise.initial_position_m)
    heading = initial_heading(pdr, range_epochs, path_epochs, at_steps, geometry, config)
    epochs = build_epochs(pdr, si_range_epochs(range_epochs, path_epochs, config.si_range), heading.heading_rad,
                          path_epochs)
    filter_config = with_heading_spread(config, heading)
    runs = {name: drive_filter(FILTER_BUILDERS[name](epochs, geometry, filter_config), epochs, config.smooth)
            for name in filters}
    return FusionResult(tracks={name: run.track for name, run in runs.items()}, heading=heading, epochs=epochs,
                        start_xy_m=(start_xy_m[0], start_xy_m[1]), code_offsets=code_offsets,
                        smoothed={name: run.smoothed for name, run in runs.items() if run.smoothed is not None})
