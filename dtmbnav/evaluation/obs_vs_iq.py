"""The observation-level range model against the IQ receiver, on the same walks.

For each case (a scenario, optionally changed) and each Monte Carlo seed, the
same walk goes through both range sources: the observation-level model
(:func:`sim.obs_range.simulate_obs_range`) and the IQ level (the capture
generated and received, :func:`dtmbnav.simulation.iq_range.iq_ranges`). Both see the
same channel and clock (same seed); the receiver's processing and its noise
differ. With ``e(t) = range_change_m(t) - (d(t) - d(t_0))`` the error of a
level's range against the true 3-D distance ``d`` to the tower (``t_0`` its
first sample), two error distributions are compared, each over the samples
while the walker walks (after ``walk.start_still_s``) and before the
segment's end:

- **integrated**: ``|e(t)|``, what the range has accumulated since the start
  (f_s calibration, multipath, and the jumps of deep fades);
- **change**: ``|e(t) - e(t - CHANGE_WINDOW_S)|``, the error of the range
  change over :data:`CHANGE_WINDOW_S`: the receiver's per-frame estimation
  in fades and multipath, with every fade seen in many windows, so a few
  walks give a stable median and 95 %.

Both are taken of the SI-carrier range and of tower 0's first-path range
(``first_integrated``, ``first_change``), and a third of the first path's
code range (``first_code``): ``|u(t) - median(u)|`` with ``u = code_range_m -
d``, the median over the walk's samples: the code range is an absolute range
up to a constant (``receiver.observables.first_path_code_range_m``), and what the
integrity monitor's late-path test (``fusion/integrity.py``) sees is how far
it strays from its constant.

The errors of all seeds of a case are pooled (the observation level's over
``obs_draws`` draws of the receiver noise per walk, which only narrows its
own spread), and each distribution is summarised by its median and 95th
percentile.

``python -m dtmbnav.evaluation.obs_vs_iq`` prints the comparison (``--help``: segment
length, seeds, cases, Dask workers); ``tests/test_obs_vs_iq.py`` runs short
segments and holds the change statistics within :data:`AGREEMENT` of each
other.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from dtmbnav.evaluation.distributed import IN_PROCESS, ClusterConfig, Task, run_tasks
from dtmbnav.evaluation.seeds import TUNING_SEEDS, monte_carlo_seed
from dtmbnav.simulation.iq_range import iq_observations
from dtmbnav_core.records import PathRangeSeries, RangeSeries, Track
from fusion.metrics import interpolate_track
from sim.obs_paths import ObsPathConfig, simulate_obs_paths
from sim.obs_range import ObsRangeConfig, simulate_obs_range
from sim.scenario import Scenario, load_scenario
from sim.walk import simulate_walk

#: Largest relative difference of a statistic between the levels that counts as agreement.
AGREEMENT = 0.25
#: Span of the range changes whose error is compared, s.
CHANGE_WINDOW_S = 0.1
#: Truth kept past the segment's end for the observation level, s (the track's spline needs no edge there).
TRACK_MARGIN_S = 2.0
#: Draws of the receiver noise per walk at the observation level.
OBS_DRAWS = 4


@dataclass(frozen=True)
class Case:
    """A walk to compare on: a reference scenario and what is changed in it.

    Attributes
    ----------
    label : str
        Name in the table.
    scenario : str
        Scenario name or file.
    change : callable
        Scenario -> Scenario (e.g. the buildings removed).
    """

    label: str
    scenario: str
    change: Callable[[Scenario], Scenario]

    def build(self, still_s: float | None = None) -> Scenario:
        """The case's scenario; ``still_s`` replaces the standstill before the walk (shorter calibration)."""
        scn = self.change(load_scenario(self.scenario))
        return scn if still_s is None else scn.replace(walk={"start_still_s": still_s})


def _unchanged(scn: Scenario) -> Scenario:
    return scn


def _no_buildings(scn: Scenario) -> Scenario:
    return scn.replace(channel={"buildings": []})


#: The cases: the street walk as it is (its first half in the buildings' shadow), the same street with the
#: buildings taken away (line of sight, the walls' reflections kept), and the open park loop.
CASES = (Case("street-out blocked", "street-out", _unchanged),
         Case("street-out LOS", "street-out", _no_buildings),
         Case("park-loop-cw", "park-loop-cw", _unchanged))


@dataclass(frozen=True)
class ErrorStats:
    """Median and 95th percentile of pooled absolute range errors, m, and how many samples they pool."""

    median_m: float
    p95_m: float
    samples: int

    @classmethod
    def of(cls, errors_m: np.ndarray) -> ErrorStats:
        return cls(float(np.median(errors_m)), float(np.percentile(errors_m, 95)), len(errors_m))


@dataclass(frozen=True)
class LevelErrors:
    """One walk's errors at one level: integrated and change over :data:`CHANGE_WINDOW_S` (module docstring),
    of the SI-carrier range and of tower 0's first path, and the first path's code-range error."""

    integrated_m: np.ndarray
    change_m: np.ndarray
    first_integrated_m: np.ndarray
    first_change_m: np.ndarray
    first_code_m: np.ndarray

    @classmethod
    def pool(cls, parts: Sequence[LevelErrors]) -> LevelErrors:
        return cls(*(np.concatenate([getattr(p, f"{metric}_m") for p in parts]) for metric in METRICS))


#: The compared metrics: the SI-carrier range's and the first path's, each integrated and over a change window,
#: and the first path's code range about its constant.
METRICS = ("integrated", "change", "first_integrated", "first_change", "first_code")


@dataclass(frozen=True)
class Comparison:
    """Both levels' range errors on one case (statistics of the pooled errors, :data:`METRICS`)."""

    label: str
    seeds: tuple[int, ...]
    seconds: float
    obs_integrated: ErrorStats
    iq_integrated: ErrorStats
    obs_change: ErrorStats
    iq_change: ErrorStats
    obs_first_integrated: ErrorStats
    iq_first_integrated: ErrorStats
    obs_first_change: ErrorStats
    iq_first_change: ErrorStats
    obs_first_code: ErrorStats
    iq_first_code: ErrorStats

    def ratios(self, metric: str = "change") -> tuple[float, float]:
        """Observation level over IQ level of ``metric`` (one of :data:`METRICS`): (median, 95 %)."""
        obs, iq = getattr(self, f"obs_{metric}"), getattr(self, f"iq_{metric}")
        return obs.median_m / iq.median_m, obs.p95_m / iq.p95_m

    def agrees(self, metric: str = "change", tolerance: float = AGREEMENT) -> bool:
        """Whether both statistics of ``metric`` are within ``tolerance`` (relative to the IQ level's)."""
        return all(abs(r - 1.0) <= tolerance for r in self.ratios(metric))


def true_range_m(scenario: Scenario, truth: Track, t_s: np.ndarray) -> np.ndarray:
    """The true 3-D distance from the walker's antenna to tower 0 at times ``t_s``, m."""
    at = interpolate_track(truth, t_s)
    tower = scenario.tower
    return np.hypot(np.hypot(at.x_m - tower.x_m, at.y_m - tower.y_m),
                    tower.height_m - scenario.channel.antenna_height_m)


def walking(scenario: Scenario, truth: Track, t_s: np.ndarray, end_s: float) -> np.ndarray:
    """Whether each time of ``t_s`` lies after the standstill and before ``end_s``."""
    walk_start = truth.t_s[0] + scenario.walk.start_still_s
    return (t_s >= walk_start) & (t_s < end_s)


def code_errors(scenario: Scenario, truth: Track, first_path: PathRangeSeries, end_s: float) -> np.ndarray:
    """The first path's code-range error about its constant while walking, before ``end_s`` (module docstring), m.

    Counts the valid samples that have a code range; empty when the series has none.
    """
    if first_path.code_range_m is None:
        return np.zeros(0)
    error = first_path.code_range_m - true_range_m(scenario, truth, first_path.t_s)
    error = error[walking(scenario, truth, first_path.t_s, end_s) & first_path.valid & np.isfinite(error)]
    return np.abs(error - np.median(error)) if len(error) else error


def range_errors(scenario: Scenario, truth: Track, ranges: RangeSeries | PathRangeSeries,
                 end_s: float) -> tuple[np.ndarray, np.ndarray]:
    """A level's integrated and change errors while walking, before ``end_s`` (module docstring).

    A first-path series counts over its valid samples only, each run from
    its origin (its first sample, and every origin break: the range after one
    starts from an unknown value, as the fusion takes it); a change window
    that straddles an origin break is left out.
    """
    true_m = true_range_m(scenario, truth, ranges.t_s)
    error = ranges.range_change_m - (true_m - true_m[0])
    if isinstance(ranges, PathRangeSeries):
        usable = ranges.valid
        run = np.cumsum(ranges.slip)
        run_start = np.maximum.accumulate(np.where(ranges.slip, np.arange(len(error)), 0))
        error = error - error[run_start]
    else:
        usable = np.ones(len(error), dtype=bool)
        run = np.zeros(len(error), dtype=np.int64)
    counted = walking(scenario, truth, ranges.t_s, end_s) & usable
    earlier = np.searchsorted(ranges.t_s, ranges.t_s - CHANGE_WINDOW_S)
    changing = (counted & walking(scenario, truth, ranges.t_s - CHANGE_WINDOW_S, end_s) & usable[earlier]
                & (run[earlier] == run))
    return np.abs(error[counted]), np.abs(error - error[earlier])[changing]


def level_errors(scenario: Scenario, truth: Track, ranges: RangeSeries, first_path: PathRangeSeries,
                 end_s: float) -> LevelErrors:
    """:func:`range_errors` of a level's SI-carrier range and of its (tower 0's) first path, and
    :func:`code_errors` of the first path."""
    return LevelErrors(*range_errors(scenario, truth, ranges, end_s),
                       *range_errors(scenario, truth, first_path, end_s),
                       code_errors(scenario, truth, first_path, end_s))


def walk_errors(scenario: Scenario, seconds: float, obs_draws: int = OBS_DRAWS
                ) -> tuple[list[LevelErrors], LevelErrors]:
    """The observation level's errors (one per noise draw) and the IQ level's on the scenario's first ``seconds``."""
    truth = simulate_walk(scenario).track
    end_s = float(truth.t_s[0]) + seconds
    short = truth.select(truth.t_s <= end_s + TRACK_MARGIN_S)
    obs = [level_errors(scenario, short, simulate_obs_range(scenario, short, ObsRangeConfig(noise_draw=draw)),
                        simulate_obs_paths(scenario, short, ObsPathConfig(noise_draw=draw)).first_path, end_s)
           for draw in range(obs_draws)]
    iq = iq_observations(scenario, truth, seconds=seconds)
    return obs, level_errors(scenario, truth, iq.ranges, iq.paths.first_path[0], end_s)


def compare(cases: Sequence[Case], seeds: Sequence[int], seconds: float, still_s: float | None = None,
            first_seed: int = TUNING_SEEDS.start, obs_draws: int = OBS_DRAWS,
            cluster: ClusterConfig = IN_PROCESS, progress: bool = False) -> list[Comparison]:
    """Both levels on Monte Carlo walks ``seeds`` of each case, every walk a task
    (:mod:`dtmbnav.evaluation.distributed`).

    Parameters
    ----------
    cases : sequence of Case
    seeds : sequence of int
        Monte Carlo indices k (walk k runs :func:`dtmbnav.evaluation.seeds.monte_carlo_seed` ``(scenario.seed, k,
        first_seed)``).
    seconds : float
        Segment length from the start of the capture, s (standstill included).
    still_s : float, optional
        Standstill before the walk, s (default: the scenario's).
    first_seed : int
    obs_draws : int
        Receiver-noise draws per walk at the observation level.
    cluster : ClusterConfig
        Where the walks run (default: in this process).
    progress : bool

    Raises
    ------
    RuntimeError
        When a walk fails (its case, seed and the error are named).
    """
    tasks = []
    for case in cases:
        base = case.build(still_s)
        for k in seeds:
            walk = base.replace(seed=monte_carlo_seed(base.seed, k, first_seed))
            tasks.append(Task(f"{case.label} k={k} (seed {walk.seed})", walk_errors, (walk, seconds, obs_draws)))
    outcome = run_tasks(tasks, cluster, progress=progress, description="obs vs iq")
    if outcome.failures:
        f = outcome.failures[0]
        raise RuntimeError(f"obs_vs_iq: {f.label} failed: {f.error}")
    rows = []
    for i, case in enumerate(cases):
        results = outcome.results[i * len(seeds):(i + 1) * len(seeds)]
        obs = LevelErrors.pool([e for draws, _ in results for e in draws])
        iq = LevelErrors.pool([e for _, e in results])
        rows.append(Comparison(case.label, tuple(seeds), seconds,
                               *(ErrorStats.of(getattr(level, f"{metric}_m")) for metric in METRICS
                                 for level in (obs, iq))))
    return rows


def format_comparisons(rows: Sequence[Comparison]) -> str:
    """A fixed-width table: each level's median and 95 % error (to 0.1 mm) and their ratios, for every metric."""
    header = (f"{'case':<20} {'metric':<16} {'seeds':>5} {'seconds':>7}  {'obs med':>8} {'iq med':>8} {'ratio':>5}  "
              f"{'obs 95%':>8} {'iq 95%':>8} {'ratio':>5}  agree")
    lines = [f"range error, m (change: over {CHANGE_WINDOW_S:g} s)", header, "-" * len(header)]
    for r in rows:
        for metric in METRICS:
            obs, iq = getattr(r, f"obs_{metric}"), getattr(r, f"iq_{metric}")
            med, p95 = r.ratios(metric)
            lines.append(f"{r.label:<20} {metric:<16} {len(r.seeds):>5} {r.seconds:>7.0f}  {obs.median_m:8.4f} "
                         f"{iq.median_m:8.4f} {med:5.2f}  {obs.p95_m:8.4f} {iq.p95_m:8.4f} {p95:5.2f}  "
                         f"{'yes' if r.agrees(metric) else 'no'}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the comparison table (``python -m dtmbnav.evaluation.obs_vs_iq --help``)."""
    parser = argparse.ArgumentParser(prog="python -m dtmbnav.evaluation.obs_vs_iq",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=70.0,
                        help="segment from the capture start, s, standstill included (default 70)")
    parser.add_argument("--still", type=float, help="standstill before the walk, s (default: the scenario's)")
    parser.add_argument("--seeds", type=int, default=3, help="Monte Carlo walks per case (default 3)")
    parser.add_argument("--first-seed", type=int, default=TUNING_SEEDS.start,
                        help=f"first Monte Carlo index (default {TUNING_SEEDS.start}, the tuning range: the calibration is chosen on it)")
    parser.add_argument("--cases", default=",".join(c.label for c in CASES),
                        help="comma-separated case labels (default: all)")
    parser.add_argument("--workers", type=int, help="local Dask workers (default: one per core; 0: this process)")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://HOST:PORT)")
    args = parser.parse_args(argv)
    by_label = {c.label: c for c in CASES}
    unknown = [label for label in args.cases.split(",") if label not in by_label]
    if unknown:
        parser.error(f"--cases: unknown {unknown}; choose from {', '.join(by_label)}")
    cluster = ClusterConfig(workers=args.workers, scheduler=args.scheduler)
    rows = compare([by_label[label] for label in args.cases.split(",")], range(args.seeds), args.seconds,
                   still_s=args.still, first_seed=args.first_seed, cluster=cluster, progress=True)
    print(format_comparisons(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
