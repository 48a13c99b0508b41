"""Fuse one recording: PDR steps + receiver range -> initial heading -> every filter's track.

This is the function behind ``dtmbnav fuse``: it solves the initial heading
(eq. 14-15), builds the filter epochs (:mod:`fusion.observations`) and runs
the requested filters on identical inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from dtmbnav.core.records import PdrSteps, RangeSeries, Track
from fusion import DEFAULT_PARTICLES, FILTER_NAMES
from fusion.adaptive_kf import run_adaptive_kf
from fusion.heading_init import HeadingSolution, solve_initial_heading
from fusion.model import Geometry, ModelNoise
from fusion.observations import AggregationConfig, FilterEpochs, aggregate_ranges, build_epochs
from fusion.particle_filter import run_particle_filter
from fusion.rank_kf import run_rank_kf
from fusion.ukf import run_ukf
from fusion.wt_ukf import run_wt_ukf


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
    """

    noise: ModelNoise = field(default_factory=ModelNoise)
    aggregation: AggregationConfig = field(default_factory=AggregationConfig)
    n_particles: int = DEFAULT_PARTICLES
    seed: int = 0


FilterRunner = Callable[[FilterEpochs, Geometry, FusionConfig], Track]

#: Filter name -> runner. "pf" is the main paper's particle filter.
FILTERS: dict[str, FilterRunner] = {
    "pf": lambda e, g, c: run_particle_filter(e, g, c.noise, c.n_particles, c.seed),
    "ukf": lambda e, g, c: run_ukf(e, g, c.noise),
    "wt-ukf": lambda e, g, c: run_wt_ukf(e, g, c.noise),
    "adaptive-kf": lambda e, g, c: run_adaptive_kf(e, g, c.noise),
    "rank-kf": lambda e, g, c: run_rank_kf(e, g, c.noise),
}
assert tuple(FILTERS) == FILTER_NAMES, "fusion.FILTER_NAMES and fusion.run.FILTERS must list the same filters"


@dataclass
class FusionResult:
    """What a fusion run produces.

    Attributes
    ----------
    tracks : dict of str -> Track
        Each filter's estimate, one row per PDR step.
    heading : HeadingSolution
        The eq. 15 solution whose ``heading_rad`` every filter started from.
    epochs : FilterEpochs
        The inputs the filters consumed.
    """

    tracks: dict[str, Track]
    heading: HeadingSolution
    epochs: FilterEpochs


def fuse(pdr: PdrSteps, ranges: RangeSeries, start_xy_m: tuple[float, float], tower_xy_m: tuple[float, float],
         filters: tuple[str, ...] = tuple(FILTERS), *, tower_height_m: float = 0.0,
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
    geometry = Geometry(start_xy_m[0], start_xy_m[1], tower_xy_m[0], tower_xy_m[1], tower_height_m)
    range_epochs = aggregate_ranges(ranges, pdr.t_s, config.aggregation)
    heading = solve_initial_heading(pdr.t_s, pdr.x_m, pdr.y_m, range_epochs.range_change_m, geometry)
    epochs = build_epochs(pdr, range_epochs, heading.heading_rad)
    tracks = {name: FILTERS[name](epochs, geometry, config) for name in filters}
    return FusionResult(tracks=tracks, heading=heading, epochs=epochs)
