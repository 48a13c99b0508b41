"""Monte Carlo accuracy evaluation of every filter against truth, next to the paper's figures.

For each reference walk and each Monte Carlo seed, the whole chain runs:
scenario (with the seed) -> walk -> phone IMU -> PDR, and a range source
(observation level by default, :mod:`sim.obs_range`; the IQ-level pipeline
plugs in through ``range_source``) -> :func:`fusion.run.fuse` -> error of
every filter against the truth at the PDR step times.

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

``dtmbnav evaluate all --seeds 20`` prints the table for the four reference
walks; ``--json FILE`` also writes it (``-`` for stdout). The protocol is
``docs/evaluation.md``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from dtmbnav.core.records import ImuLog, PdrSteps, RangeSeries, Track
from dtmbnav.paper import paper_figures
from dtmbnav.simulation import calibration_walk_k_m
from fusion import FILTER_NAMES, FOOT_INS
from fusion.foot_ins import ZuptInsRankKf
from fusion.metrics import (PDR_AT_FIX, PDR_BASELINE, error_stats, heading_error_rad, interpolate_track, pdr_baselines,
                            position_errors_m)
from fusion.pdr import PdrConfig, run_pdr
from fusion.run import FusionConfig, fuse
from sim.gnss import simulate_start_fix
from sim.imu import simulate_imu
from sim.obs_range import simulate_obs_range
from sim.scenario import Scenario, load_scenario
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
    """

    truth: Track
    pdr: PdrSteps
    start_fix_xy_m: tuple[float, float]
    walk_start_t_s: float
    ranges: RangeSeries
    foot_imu: ImuLog | None = None


RangeSource = Callable[[Scenario, Track], RangeSeries]
Chain = Callable[[Scenario, RangeSource, bool], ChainOutput]



def obs_range_source(scenario: Scenario, truth: Track) -> RangeSeries:
    """Observation-level receiver range (:func:`sim.obs_range.simulate_obs_range`)."""
    return simulate_obs_range(scenario, truth)


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
    start_fix = simulate_start_fix(scenario, walk)
    foot = simulate_imu(scenario.replace(imu={"preset": "foot-mems"}), walk) if foot_imu else None
    return ChainOutput(truth=walk.track, pdr=pdr.steps, start_fix_xy_m=(start_fix.x_m, start_fix.y_m),
                       walk_start_t_s=walk.walk_start_t_s, ranges=range_source(scenario, walk.track),
                       foot_imu=foot)


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
    """

    truth: Track
    tracks: dict[str, Track]
    errors_m: dict[str, np.ndarray]
    heading_error_rad: float


def run_seed(scenario: Scenario, filters: tuple[str, ...], config: FusionConfig,
             range_source: RangeSource = obs_range_source, chain: Chain = simulated_chain) -> SeedResult:
    """Run one walk through the chain and the filters and measure the errors.

    ``filters`` may include :data:`FOOT_INS`: the foot-mounted ZUPT INS,
    which like the PDR baseline starts at the true start with the
    true heading (it has no absolute heading either), evaluated at the PDR
    step times.
    """
    out = chain(scenario, range_source, FOOT_INS in filters)
    tower = scenario.tower
    fused = tuple(f for f in filters if f != FOOT_INS)
    result = fuse(out.pdr, out.ranges, out.start_fix_xy_m, (tower.x_m, tower.y_m), fused,
                  tower_height_m=tower.height_m - scenario.channel.antenna_height_m, config=config)
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
                      heading_error_rad=float(heading_error_rad(result.heading.heading_rad, true_heading)))


@dataclass(frozen=True)
class EvaluationRow:
    """One line of the table: a filter (or the PDR) on a scenario over the seeds.

    Errors in metres, averaged per-walk statistics; ``reduction_95`` against
    the PDR and ``reduction_95_vs_fix`` against ``pdr@fix`` (None for the PDR
    rows); paper figures None where the paper has none for this filter.
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
    paper_p68_m: float | None = None
    paper_p95_m: float | None = None
    paper_max_m: float | None = None
    paper_reduction_95: float | None = None


def summarise(scenario_name: str, results: list[SeedResult]) -> list[EvaluationRow]:
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
        rows.append(EvaluationRow(
            scenario=scenario_name, filter=name, seeds=len(results), p68_m=p68, p95_m=p95, max_m=pmax,
            reduction_95=None if name in (PDR_BASELINE, PDR_AT_FIX) else 1.0 - p95 / mean[PDR_BASELINE][1],
            reduction_95_vs_fix=None if name in (PDR_BASELINE, PDR_AT_FIX) else 1.0 - p95 / mean[PDR_AT_FIX][1],
            heading_error_median_deg=heading_median,
            paper_p68_m=reference[0] if reference else None, paper_p95_m=reference[1] if reference else None,
            paper_max_m=reference[2] if reference else None,
            paper_reduction_95=paper.reduction_95 if paper and name == "pf" else None))
    return rows


def run_seeds(scenario: str | Scenario, seeds: int = 20, filters: tuple[str, ...] = FILTER_NAMES,
              level: str = "obs", range_source: RangeSource | None = None, config: FusionConfig = FusionConfig(),
              first_seed: int = 0, chain: Chain = simulated_chain) -> tuple[str, list[SeedResult]]:
    """Monte Carlo walks of one scenario; returns its name and the per-walk results.

    Parameters
    ----------
    scenario : str or Scenario
        Scenario name, file path or object.
    seeds : int
        Number of Monte Carlo walks; walk k uses scenario seed
        ``1000 * scenario.seed + first_seed + k``.
    filters : tuple of str
        Filters to run (:data:`fusion.FILTER_NAMES`, and :data:`FOOT_INS`).
    level : {"obs", "iq"}
        Where the receiver range comes from: the observation-level model, or
        ``range_source`` (the IQ pipeline: scenario, truth -> RangeSeries).
    range_source : callable, optional
        Required for ``level="iq"``; overrides the observation model otherwise.
    config : FusionConfig
    first_seed : int
    chain : callable
        Walk simulation (replaceable for tests).
    """
    if seeds < 1:
        raise ValueError(f"evaluate: seeds must be >= 1, got {seeds}")
    if level not in ("obs", "iq"):
        raise ValueError(f"evaluate: level must be 'obs' or 'iq', got {level!r}")
    if level == "iq" and range_source is None:
        raise ValueError("evaluate: level='iq' needs a range_source (the IQ receiver pipeline)")
    scn = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    source = range_source or obs_range_source
    return scn.name, [run_seed(scn.replace(seed=1000 * scn.seed + first_seed + k), filters, config, source, chain)
                      for k in range(seeds)]


def evaluate(scenario: str | Scenario, seeds: int = 20, filters: tuple[str, ...] = FILTER_NAMES,
             level: str = "obs", range_source: RangeSource | None = None, config: FusionConfig = FusionConfig(),
             first_seed: int = 0, chain: Chain = simulated_chain) -> list[EvaluationRow]:
    """Monte Carlo evaluation of one scenario (arguments as :func:`run_seeds`).

    Returns
    -------
    list of EvaluationRow
        The PDR row first, then one row per filter.
    """
    return summarise(*run_seeds(scenario, seeds, filters, level, range_source, config, first_seed, chain))


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_table(rows: list[EvaluationRow]) -> str:
    """A fixed-width text table, our figures next to the paper's."""
    header = (f"{'scenario':<15} {'filter':<12} {'seeds':>5}  {'68%':>6} {'95%':>6} {'max':>6}  {'95%red':>6} "
              f"{'red@fix':>7}  "
              f"{'hdg_err':>7}  | paper {'68%':>6} {'95%':>6} {'max':>6} {'red':>5}")
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(
            f"{r.scenario:<15} {r.filter:<12} {r.seeds:>5}  {r.p68_m:6.2f} {r.p95_m:6.2f} {r.max_m:6.2f}  "
            f"{_fmt(None if r.reduction_95 is None else 100 * r.reduction_95, '5.1f'):>5}% "
            f"{_fmt(None if r.reduction_95_vs_fix is None else 100 * r.reduction_95_vs_fix, '6.1f'):>6}%  "
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

