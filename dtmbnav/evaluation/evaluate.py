"""Monte Carlo accuracy evaluation of every filter against truth, next to the paper's figures.

For each reference walk and each Monte Carlo walk k, the whole chain runs:
scenario (with the walk's seed, :mod:`dtmbnav.evaluation.seeds`, and by default its own
layout, :func:`sim.variation.vary_scenario`) -> walk -> phone IMU -> PDR, and
a range source -> :func:`fusion.run.fuse` -> error of every filter against
the truth at the PDR step times. The range comes from the observation-level
model (``level="obs"``, :mod:`sim.obs_range` and :mod:`sim.obs_paths`) or from the IQ transmitter,
channel and receiver (``level="iq"``, :mod:`dtmbnav.simulation.iq_range`), or is the
direct path's exact range change (``level="exact"``: what the filters and
the single-tower geometry allow with a perfect receiver). Each walk is
one task of :mod:`dtmbnav.evaluation.distributed` (in this process, or on a Dask
cluster); a walk depends only on its seed, so the table does not depend on
where it ran.

Figures, as the paper reports them (``docs/method.md`` §6):

- 68 % / 95 % / max position error of each filter and of the PDR, computed
  per walk and averaged over the seeds (the paper's table is one walk per
  row; averaging per-walk statistics keeps that meaning);
- the 95 % reduction against the PDR, ``1 - mean PF95 / mean PDR95``, and
  against ``pdr@fix`` (below);
- the median initial-heading error of eq. 15 over the seeds.

The PDR baseline (row ``pdr``, the reference of the reductions) is placed the
way the paper reports PDR error: its relative track rotated by the true
initial heading and started at the true start. The filters start from the
GNSS start fix and the solved heading, as a user would; row ``pdr@fix`` is
the PDR placed that same way, for a like-for-like comparison. It is also how
the paper's own PDR must have been placed (``docs/method.md`` §4: the PDR starts at
the last GNSS fix P0, and its initial heading is what eq. 15 solves), so
column ``red@fix`` is the closer match to the paper's reduction; column
``95%red`` measures against the stricter true-start, true-heading PDR.

``dtmbnav evaluate all --seeds 50`` prints the table for the four reference
walks on the reporting seeds (``--first-seed 100`` for the tuning seeds);
``--json FILE`` also writes it (``-`` for stdout). The protocol is
``docs/evaluation.md``.
"""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from dtmbnav.chain.paper import paper_figures
from dtmbnav.evaluation.distributed import IN_PROCESS, ClusterConfig, Task, run_tasks
from dtmbnav.evaluation.seeds import LEVELS, REPORTING_SEEDS, TUNING_SEEDS, monte_carlo_seed, seed_range_name
from dtmbnav.evaluation.survey import scenario_towers, survey_transmit_delays
from dtmbnav.simulation.capture_set import calibration_walk_k_m, receiver_clock_model
from dtmbnav_core.records import ImuLog, Observations, PathRanges, PdrSteps, RangeSeries, Track
from fusion import FILTER_NAMES, FOOT_INS
from fusion.foot_ins import ZuptInsRankKf
from fusion.metrics import (
    PDR_AT_FIX,
    PDR_BASELINE,
    StatedErrorStats,
    error_stats,
    heading_error_rad,
    interpolate_track,
    pdr_baselines,
    position_errors_m,
    stated_error_stats,
)
from fusion.pdr import PdrConfig, run_pdr
from fusion.run import FusionConfig, fuse
from fusion.transmit_delays import TransmitDelays, given_transmit_delays
from sim.gnss import simulate_gnss, simulate_start_fix
from sim.imu import simulate_imu
from sim.obs_paths import simulate_obs_paths
from sim.obs_range import exact_range, simulate_obs_range
from sim.scenario import Scenario, load_scenario
from sim.variation import vary_scenario
from sim.walk import simulate_walk

#: The four reference walks, and the names that stand for groups of them here.
REFERENCE_WALKS = ("park-loop-cw", "park-loop-ccw", "street-out", "street-back")
GROUPS = {"all": REFERENCE_WALKS, "park-loop": REFERENCE_WALKS[:2], "street": REFERENCE_WALKS[2:]}


@dataclass
class ChainOutput:
    """What the simulated walk gives the fusion and the evaluation.

    Attributes
    ----------
    truth : Track
        True trajectory.
    pdr : PdrSteps
        PDR output.
    start_fix_xy_m : (float, float)
        GNSS start fix P0.
    walk_start_t_s : float
        When the walker leaves P0 (end of the standing calibration), s.
    ranges : RangeSeries
        Receiver range for the walk.
    foot_imu : ImuLog or None
        A foot-mounted IMU on the same walk, when asked for (the ZUPT INS).
    paths : PathRanges or None
        The path tracker's first-path ranges and tower differences (IQ level), when the range source has them.
    start_fix_sigma_m : float or None
        The start fix's stated sigma per axis, m (None: the filters' default spread).
    """

    truth: Track
    pdr: PdrSteps
    start_fix_xy_m: tuple[float, float]
    walk_start_t_s: float
    ranges: RangeSeries
    foot_imu: ImuLog | None = None
    paths: PathRanges | None = None
    start_fix_sigma_m: float | None = None


RangeSource = Callable[[Scenario, Track], Observations]
Chain = Callable[[Scenario, RangeSource, bool], ChainOutput]


def obs_range_source(scenario: Scenario, truth: Track) -> Observations:
    """Observation-level receiver range (:func:`sim.obs_range.simulate_obs_range`) and path tracker
    (:func:`sim.obs_paths.simulate_obs_paths`): what the IQ level's receiver gives, from the truth."""
    paths = simulate_obs_paths(scenario, truth)
    return Observations(simulate_obs_range(scenario, truth),
                        PathRanges(first_path={0: paths.first_path}, differences=paths.differences))


def exact_range_source(scenario: Scenario, truth: Track) -> Observations:
    """The direct path's exact range change (:func:`sim.obs_range.exact_range`): the filters with a perfect receiver."""
    return Observations(exact_range(scenario, truth))


def level_range_source(level: str) -> RangeSource:
    """The range source of a level (:data:`LEVELS`); the IQ level's imports the receiver only when asked for."""
    if level == "obs":
        return obs_range_source
    if level == "exact":
        return exact_range_source
    if level == "iq":
        from dtmbnav.simulation.iq_range import iq_range_source

        return iq_range_source
    raise ValueError(f"evaluate: level must be one of {LEVELS}, got {level!r}")


def seed_scenario(scenario: Scenario, k: int, first_seed: int = REPORTING_SEEDS.start,
                  vary_geometry: bool = True) -> Scenario:
    """The scenario of Monte Carlo walk ``k``: its seed, and with ``vary_geometry`` its own layout.

    The layout (:func:`sim.variation.vary_scenario`) is drawn from the walk's
    seed, so a walk is the same whichever process runs it.
    """
    seed = monte_carlo_seed(scenario.seed, k, first_seed)
    seeded = scenario.replace(seed=seed)
    return vary_scenario(seeded, seed) if vary_geometry else seeded


def scenario_transmit_delays(scenario: Scenario, range_source: RangeSource = obs_range_source
                             ) -> TransmitDelays | None:
    """What the fusion is given of an SFN's transmit delay offsets (``[network] known``): None for unknown (and for
    one tower), the network plan's with its error as sigma, a survey's on another walk of the network through
    ``range_source`` (:mod:`dtmbnav.evaluation.survey`), or the walk's true offsets."""
    return given_transmit_delays(scenario.network.known, [site.transmit_delay_s for site in scenario.sites],
                                 scenario.network.plan_error_s, scenario.transmit_delays_s,
                                 lambda: survey_transmit_delays(scenario, range_source))


def with_transmit_delays(scenario: Scenario, known: str) -> Scenario:
    """The scenario with the fusion given ``known`` of its transmit delay offsets (``[network] known``), named
    ``"NAME (delays KNOWN)"`` where that differs from the scenario's own (:func:`load_evaluation_scenario` reads
    the name back)."""
    if known == scenario.network.known:
        return scenario
    return scenario.replace(network={"known": known}, name=f"{scenario.name} (delays {known})")


def load_evaluation_scenario(name: str) -> Scenario:
    """A scenario by name or file, or a variant :func:`with_transmit_delays` named, ``"NAME (delays KNOWN)"``."""
    variant = re.fullmatch(r"(?P<name>.+) \(delays (?P<known>\w+)\)", name)
    if variant is None:
        return load_scenario(name)
    return with_transmit_delays(load_scenario(variant["name"]), variant["known"])


def calibrated_pdr_config(scenario: Scenario) -> PdrConfig:
    """PDR settings with the Weinberg K from the walker's calibration walk."""
    return PdrConfig(weinberg_k_m=calibration_walk_k_m(scenario))


def simulated_chain(scenario: Scenario, range_source: RangeSource, foot_imu: bool = False) -> ChainOutput:
    """Walk -> phone IMU -> PDR and GNSS start fix, plus the range source, for one scenario.

    With ``foot_imu`` the same walk also gets a foot-mounted IMU (preset
    ``foot-mems``) for the ZUPT INS.
    """
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    pdr = run_pdr(imu, calibrated_pdr_config(scenario))
    start_fix = simulate_start_fix(scenario, walk, simulate_gnss(scenario, walk))
    foot = simulate_imu(scenario.replace(imu={"preset": "foot-mems"}), walk) if foot_imu else None
    observed = range_source(scenario, walk.track)
    return ChainOutput(truth=walk.track, pdr=pdr.steps, start_fix_xy_m=(start_fix.x_m, start_fix.y_m),
                       walk_start_t_s=walk.walk_start_t_s, ranges=observed.ranges, foot_imu=foot,
                       paths=observed.paths, start_fix_sigma_m=start_fix.sigma_m)


@dataclass
class SeedResult:
    """One walk (scenario + seed) through the chain and the filters.

    Attributes
    ----------
    truth : Track
        True trajectory.
    tracks : dict of str -> Track
        The PDR baseline (``"pdr"``) and each filter's estimate.
    errors_m : dict of str -> ndarray
        Position error at each PDR step, same keys (CDFs: fusion.metrics.error_cdf).
    heading_error_rad : float
        Error of the eq. 15 initial heading.
    heading_sigma_rad : float
        Its stated standard uncertainty (:attr:`fusion.heading_init.HeadingSolution.sigma_rad`).
    heading_uncertain : bool
        Whether the solution said it may be more than a few degrees off
        (:meth:`fusion.heading_init.HeadingSolution.uncertain`).
    stated : dict of str -> StatedErrorStats
        Each filter's stated error against the truth (:func:`fusion.metrics.stated_error_stats`): the share of its
        rows inside its stated 95 % ellipse and its mean NEES.
    """

    truth: Track
    tracks: dict[str, Track]
    errors_m: dict[str, np.ndarray]
    heading_error_rad: float
    heading_sigma_rad: float = float("nan")
    heading_uncertain: bool = False
    stated: dict[str, StatedErrorStats] = field(default_factory=dict)


def run_seed(scenario: Scenario, filters: tuple[str, ...], config: FusionConfig,
             range_source: RangeSource = obs_range_source, chain: Chain = simulated_chain) -> SeedResult:
    """Run one walk through the chain and the filters and measure the errors.

    ``filters`` may include :data:`FOOT_INS`: the foot-mounted ZUPT INS,
    which like the PDR baseline starts at the true start with the
    true heading (it has no absolute heading either), evaluated at the PDR
    step times.
    """
    out = chain(scenario, range_source, FOOT_INS in filters)
    # The further towers of an SFN, for the tower differences of the path tracker.
    tower_xy, tower_height, other_towers = scenario_towers(scenario)
    fused = tuple(f for f in filters if f != FOOT_INS)
    config = dataclasses.replace(config, clock_model=receiver_clock_model(scenario))
    result = fuse(out.pdr, out.ranges, out.start_fix_xy_m, tower_xy, fused, tower_height_m=tower_height,
                  other_towers=other_towers, paths=out.paths,
                  transmit_delays=scenario_transmit_delays(scenario, range_source),
                  start_sigma_m=out.start_fix_sigma_m, config=config)
    baselines, true_heading = pdr_baselines(out.pdr, out.truth, out.walk_start_t_s, out.start_fix_xy_m,
                                            result.heading.heading_rad)
    tracks = {**baselines, **result.tracks}
    if FOOT_INS in filters:
        if out.foot_imu is None:
            raise ValueError(f"run_seed: {FOOT_INS!r} asked for but the chain produced no foot IMU")
        foot = out.foot_imu
        start = (float(out.truth.x_m[0]), float(out.truth.y_m[0]))
        ins = ZuptInsRankKf().run(foot.t_s, foot.acc_mps2, foot.gyro_radps, start, true_heading)
        tracks[FOOT_INS] = interpolate_track(ins, out.pdr.t_s)
    return SeedResult(truth=out.truth, tracks=tracks,
                      errors_m={name: position_errors_m(track, out.truth) for name, track in tracks.items()},
                      heading_error_rad=float(heading_error_rad(result.heading.heading_rad, true_heading)),
                      heading_sigma_rad=float(result.heading.sigma_rad), heading_uncertain=result.heading.uncertain(),
                      stated={name: stated_error_stats(track, out.truth) for name, track in result.tracks.items()})


@dataclass(frozen=True)
class EvaluationRow:
    """One line of the table: a filter (or the PDR) on a scenario over the seeds.

    Errors in metres, averaged per-walk statistics; ``reduction_95`` against
    the PDR and ``reduction_95_vs_fix`` against ``pdr@fix`` (None for the PDR
    rows); ``worst_vs_fix``: the largest ratio, over the walks, of a walk's
    95 % error to that walk's ``pdr@fix`` 95 %, minus one (positive where the
    filter made some walk worse than the PDR it started from; None for the
    PDR rows); paper figures None where the paper has none for this filter.
    """

    scenario: str
    filter: str
    seeds: int
    p68_m: float
    p95_m: float
    max_m: float
    reduction_95: float | None
    reduction_95_vs_fix: float | None
    heading_error_median_deg: float
    worst_vs_fix: float | None = None
    paper_p68_m: float | None = None
    paper_p95_m: float | None = None
    paper_max_m: float | None = None
    paper_reduction_95: float | None = None
    first_seed: int = REPORTING_SEEDS.start
    level: str = "obs"
    geometry_varied: bool = True


@dataclass(frozen=True)
class RunSettings:
    """How a scenario's walks were drawn: first Monte Carlo index, range level, per-walk layout or not."""

    first_seed: int = REPORTING_SEEDS.start
    level: str = "obs"
    vary_geometry: bool = True


def summarise(scenario_name: str, results: list[SeedResult], settings: RunSettings = RunSettings()
              ) -> list[EvaluationRow]:
    """Table rows of one scenario from its per-seed results."""
    heading_median = float(np.rad2deg(np.median([r.heading_error_rad for r in results])))
    paper = paper_figures(scenario_name)
    names = list(results[0].errors_m)
    stats = {name: [error_stats(r.errors_m[name]) for r in results] for name in names}
    mean = {name: (float(np.mean([s.p68_m for s in st])), float(np.mean([s.p95_m for s in st])),
                   float(np.mean([s.max_m for s in st]))) for name, st in stats.items()}
    rows = []
    for name in names:
        p68, p95, pmax = mean[name]
        reference = {PDR_BASELINE: paper.pdr, "pf": paper.pf}.get(name) if paper else None
        baseline = name in (PDR_BASELINE, PDR_AT_FIX)  # the references themselves: no reductions
        rows.append(EvaluationRow(
            scenario=scenario_name, filter=name, seeds=len(results), p68_m=p68, p95_m=p95, max_m=pmax,
            reduction_95=None if baseline else 1.0 - p95 / mean[PDR_BASELINE][1],
            reduction_95_vs_fix=None if baseline else 1.0 - p95 / mean[PDR_AT_FIX][1],
            worst_vs_fix=None if baseline else
            max(s.p95_m / f.p95_m for s, f in zip(stats[name], stats[PDR_AT_FIX])) - 1.0,
            heading_error_median_deg=heading_median,
            paper_p68_m=reference[0] if reference else None, paper_p95_m=reference[1] if reference else None,
            paper_max_m=reference[2] if reference else None,
            paper_reduction_95=paper.reduction_95 if paper and name == "pf" else None,
            first_seed=settings.first_seed, level=settings.level, geometry_varied=settings.vary_geometry))
    return rows


def walk_record(scenario_name: str, k: int, seed: int, result: SeedResult, settings: RunSettings = RunSettings()
                ) -> dict[str, object]:
    """One walk's figures, JSON-ready: a line of ``dtmbnav evaluate --walks`` (the table averages them).

    Keys: ``scenario``, ``k`` (Monte Carlo index within the run), ``seed``,
    ``first_seed``, ``level``, ``geometry_varied``, ``heading_error_deg``,
    ``heading_sigma_deg`` and ``heading_uncertain`` (eq. 15), per filter ``in_ellipse_95`` and ``nees`` (its
    stated error against the truth), and per track (the PDR baselines and each filter) ``p68_m``,
    ``p95_m``, ``max_m``.
    """
    stats = {name: error_stats(errors) for name, errors in result.errors_m.items()}
    return {"scenario": scenario_name, "k": k, "seed": seed, "first_seed": settings.first_seed,
            "level": settings.level, "geometry_varied": settings.vary_geometry,
            "heading_error_deg": float(np.rad2deg(result.heading_error_rad)),
            "heading_sigma_deg": float(np.rad2deg(result.heading_sigma_rad)),
            "heading_uncertain": bool(result.heading_uncertain),
            "in_ellipse_95": {name: s.in_ellipse_95 for name, s in result.stated.items()},
            "nees": {name: s.mean_nees for name, s in result.stated.items()},
            **{key: {name: getattr(s, key) for name, s in stats.items()} for key in ("p68_m", "p95_m", "max_m")}}


def run_walk(scenario: Scenario, k: int, first_seed: int, vary_geometry: bool, filters: tuple[str, ...],
             config: FusionConfig, level: str, range_source: RangeSource | None, chain: Chain) -> SeedResult:
    """Monte Carlo walk ``k`` of a scenario (:func:`seed_scenario`) through :func:`run_seed`: one task.

    Everything it draws comes from the walk's seed, so it gives the same
    result in any process (:mod:`dtmbnav.evaluation.distributed`).
    """
    source = range_source or level_range_source(level)
    return run_seed(seed_scenario(scenario, k, first_seed, vary_geometry), filters, config, source, chain)


@dataclass(frozen=True)
class WalkFailure:
    """A Monte Carlo walk that raised.

    Attributes
    ----------
    scenario : str
        Scenario name.
    argument : str
        The scenario as it was given (name or file path), to run the walk again.
    k, first_seed, seed : int
        Monte Carlo index, first index of the run, scenario seed of the walk.
    error : str
        ``ExceptionType: message``.
    """

    scenario: str
    argument: str
    k: int
    first_seed: int
    seed: int
    error: str


@dataclass
class EvaluationOutcome:
    """The table rows of the scenarios whose walks all ran, and the walks that failed."""

    rows: list[EvaluationRow]
    failures: list[WalkFailure]


def _check(seeds: int, level: str, first_seed: int) -> None:
    if seeds < 1:
        raise ValueError(f"evaluate: seeds must be >= 1, got {seeds}")
    if level not in LEVELS:
        raise ValueError(f"evaluate: level must be one of {LEVELS}, got {level!r}")
    for k in (0, seeds - 1):
        monte_carlo_seed(0, k, first_seed)


def evaluate_many(scenarios: list[str | Scenario], seeds: int = 20, filters: tuple[str, ...] = FILTER_NAMES,
                  level: str = "obs", range_source: RangeSource | None = None, config: FusionConfig = FusionConfig(),
                  first_seed: int = REPORTING_SEEDS.start, chain: Chain = simulated_chain, vary_geometry: bool = True,
                  cluster: ClusterConfig = IN_PROCESS, progress: bool = False,
                  on_walk: Callable[[dict[str, object]], None] | None = None,
                  transmit_delays: str | None = None) -> EvaluationOutcome:
    """Monte Carlo evaluation of several scenarios, every walk a task (:mod:`dtmbnav.evaluation.distributed`).

    Parameters
    ----------
    scenarios : list of str or Scenario
        Scenario names, files or objects.
    seeds : int
        Monte Carlo walks per scenario; walk k runs seed
        :func:`dtmbnav.evaluation.seeds.monte_carlo_seed` ``(scenario.seed, k, first_seed)``.
    filters : tuple of str
        Filters to run (:data:`fusion.FILTER_NAMES`, and :data:`FOOT_INS`).
    level : {"obs", "iq", "exact"}
        Where the receiver range comes from (:data:`LEVELS`).
    range_source : callable, optional
        Replaces the level's range source (scenario, truth -> RangeSeries).
    config : FusionConfig
    first_seed : int
        First Monte Carlo index (:data:`REPORTING_SEEDS`, :data:`TUNING_SEEDS`).
    chain : callable
        Walk simulation (replaceable for tests).
    vary_geometry : bool
        Each walk gets its own layout (:func:`sim.variation.vary_scenario`).
    cluster : ClusterConfig
        Where the walks run (default: in this process).
    progress : bool
        Progress bar on stderr.
    on_walk : callable, optional
        Called with each walk's :func:`walk_record` as the walk finishes (in
        the order walks finish, in this process).
    transmit_delays : {"unknown", "plan", "surveyed", "exact"}, optional
        What the fusion is given of an SFN's transmit delay offsets, for
        every scenario (:func:`with_transmit_delays`); None: each scenario's
        own ``[network] known``.

    Returns
    -------
    EvaluationOutcome
        Rows in the order of ``scenarios`` (each: the PDR rows, then the
        filters), for the scenarios whose walks all ran; the failed walks.
    """
    _check(seeds, level, first_seed)
    loaded = [s if isinstance(s, Scenario) else load_evaluation_scenario(s) for s in scenarios]
    if transmit_delays is not None:
        loaded = [with_transmit_delays(scn, transmit_delays) for scn in loaded]
    tasks = [Task(f"{scn.name} k={k} (seed {monte_carlo_seed(scn.seed, k, first_seed)})", run_walk,
                  (scn, k, first_seed, vary_geometry, filters, config, level, range_source, chain))
             for scn in loaded for k in range(seeds)]
    settings = RunSettings(first_seed, level, vary_geometry)

    def finished(index: int, result: SeedResult) -> None:
        scn, k = loaded[index // seeds], index % seeds
        on_walk(walk_record(scn.name, k, monte_carlo_seed(scn.seed, k, first_seed), result, settings))

    outcome = run_tasks(tasks, cluster, progress=progress, description=f"evaluate ({level} level)",
                        on_result=None if on_walk is None else finished)
    failed = {f.index: f for f in outcome.failures}
    rows: list[EvaluationRow] = []
    failures: list[WalkFailure] = []
    for i, scn in enumerate(loaded):
        span = range(i * seeds, (i + 1) * seeds)
        for j in span:
            if j in failed:
                k = j - span.start
                argument = scenarios[i] if isinstance(scenarios[i], str) else scn.name
                failures.append(WalkFailure(scn.name, argument, k, first_seed,
                                            monte_carlo_seed(scn.seed, k, first_seed), failed[j].error))
        if not any(j in failed for j in span):
            rows.extend(summarise(scn.name, [outcome.results[j] for j in span], settings))
    return EvaluationOutcome(rows, failures)


def run_seeds(scenario: str | Scenario, seeds: int = 20, filters: tuple[str, ...] = FILTER_NAMES,
              level: str = "obs", range_source: RangeSource | None = None, config: FusionConfig = FusionConfig(),
              first_seed: int = REPORTING_SEEDS.start, chain: Chain = simulated_chain,
              vary_geometry: bool = True) -> tuple[str, list[SeedResult]]:
    """Monte Carlo walks of one scenario in this process; returns its name and the per-walk results.

    Arguments as :func:`evaluate_many`.
    """
    _check(seeds, level, first_seed)
    scn = scenario if isinstance(scenario, Scenario) else load_evaluation_scenario(scenario)
    return scn.name, [run_walk(scn, k, first_seed, vary_geometry, filters, config, level, range_source, chain)
                      for k in range(seeds)]


def evaluate(scenario: str | Scenario, seeds: int = 20, filters: tuple[str, ...] = FILTER_NAMES,
             level: str = "obs", range_source: RangeSource | None = None, config: FusionConfig = FusionConfig(),
             first_seed: int = REPORTING_SEEDS.start, chain: Chain = simulated_chain, vary_geometry: bool = True,
             cluster: ClusterConfig = IN_PROCESS) -> list[EvaluationRow]:
    """Monte Carlo evaluation of one scenario (arguments as :func:`evaluate_many`).

    Returns
    -------
    list of EvaluationRow
        The PDR rows first, then one row per filter.

    Raises
    ------
    RuntimeError
        When a walk fails (the message names its seed and the error).
    """
    outcome = evaluate_many([scenario], seeds, filters, level, range_source, config, first_seed, chain,
                            vary_geometry, cluster)
    if outcome.failures:
        f = outcome.failures[0]
        raise RuntimeError(f"evaluate {f.scenario}: walk k={f.k} (seed {f.seed}) failed: {f.error}")
    return outcome.rows


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def describe_seeds(first_seed: int, seeds: int, level: str, geometry_varied: bool) -> str:
    """One line saying which walks a table row averages: indices, named seed ranges, level, layouts."""
    layout = "a layout per walk" if geometry_varied else "the scenario file's layout"
    return (f"Monte Carlo indices {first_seed}-{first_seed + seeds - 1} ({seed_range_name(first_seed, seeds)}; "
            f"reporting range {REPORTING_SEEDS.start}-{REPORTING_SEEDS[-1]}, tuning range "
            f"{TUNING_SEEDS.start}-{TUNING_SEEDS[-1]}), {level} level, "
            f"{layout}")


def format_table(rows: list[EvaluationRow]) -> str:
    """A fixed-width text table, our figures next to the paper's, under a line naming the walks."""
    runs = dict.fromkeys((r.first_seed, r.seeds, r.level, r.geometry_varied) for r in rows)
    header = (f"{'scenario':<15} {'filter':<12} {'seeds':>5}  {'68%':>6} {'95%':>6} {'max':>6}  {'95%red':>6} "
              f"{'red@fix':>7} {'worst@fix':>9}  "
              f"{'hdg_err':>7}  | paper {'68%':>6} {'95%':>6} {'max':>6} {'red':>5}")
    lines = [describe_seeds(*run) for run in runs] + [header, "-" * len(header)]
    for r in rows:
        lines.append(
            f"{r.scenario:<15} {r.filter:<12} {r.seeds:>5}  {r.p68_m:6.2f} {r.p95_m:6.2f} {r.max_m:6.2f}  "
            f"{_fmt(None if r.reduction_95 is None else 100 * r.reduction_95, '5.1f'):>5}% "
            f"{_fmt(None if r.reduction_95_vs_fix is None else 100 * r.reduction_95_vs_fix, '6.1f'):>6}% "
            f"{_fmt(None if r.worst_vs_fix is None else 100 * r.worst_vs_fix, '+8.1f'):>8}%  "
            f"{r.heading_error_median_deg:6.2f}d  |       {_fmt(r.paper_p68_m, '6.2f'):>6} "
            f"{_fmt(r.paper_p95_m, '6.2f'):>6} {_fmt(r.paper_max_m, '6.2f'):>6} "
            f"{_fmt(None if r.paper_reduction_95 is None else 100 * r.paper_reduction_95, '4.0f'):>4}%")
    return "\n".join(lines)


def rows_to_json(rows: list[EvaluationRow]) -> str:
    """The rows as a JSON array of objects (units in the key names)."""
    return json.dumps([asdict(r) for r in rows], indent=2)


def expand_scenarios(names: list[str]) -> list[str]:
    """Scenario arguments with the group names (``all``, ``park-loop``, ``street``) expanded."""
    out: list[str] = []
    for name in names:
        out.extend(GROUPS.get(name, (name,)))
    return out

