"""Weak signals: how lock, the two ranges and the fusion degrade as the C/N falls.

Indoors and deep in a street canyon a C/N of 0-5 dB is common. Each case is
a reference walk (:data:`SCENARIOS`) at a C/N of :data:`CN_DB` (the
scenario's ``receiver.cn_db``: carrier power of the unobstructed direct path
over the noise in the 7.56 MHz band) and a Monte Carlo walk of it, run the
way ``dtmbnav evaluate --level iq`` runs it (:func:`dtmbnav.evaluation.evaluate.run_walk`
with :func:`dtmbnav.simulation.iq_range.iq_range_source`: the walk's own layout, the
capture generated and received, the PDR and the particle filter on what the
receiver gave). Per walk:

- **lock rate**: frames the receiver delivered usable (no flag of
  :data:`receiver.observables.UNUSABLE_FLAGS`, a finite range) over the
  frames the tower sent during the capture; and the share it delivered at
  all. A walk on which the receiver finds no signal is *no lock*: no frame,
  no range and nothing to fuse (the PDR is all a user has);
- **SI-carrier and first-path range 95 %**: the 95th percentile of the range
  change's error against the first tower's direct path, both since the
  receiver's first frame (as :func:`dtmbnav.evaluation.accuracy.path_accuracy` scores
  them), over the usable frames of the walking part; and the share of those
  frames with a first path;
- **fusion**: the particle filter's, the PDR's and the PDR@fix's 95 %
  position errors (:mod:`dtmbnav.evaluation.evaluate`).

A row (scenario and C/N) averages its walks; the PF's reductions are taken
from the mean 95 % errors, as ``dtmbnav evaluate`` takes them, and a row
fails where some walk's PF 95 % exceeds :data:`MAX_PF_OVER_FIX` times that
walk's PDR@fix (the fusion made a walk worse than the PDR it started from).

Run ``python -m dtmbnav.evaluation.weak_signal`` (``--first-seed 100`` for the tuning
range); ``dtmbnav results --sections weak-signal`` prints the table into
docs/results.md.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtmbnav.evaluation.distributed import ClusterConfig, Task, run_tasks
from dtmbnav.evaluation.evaluate import describe_seeds, run_walk, simulated_chain
from dtmbnav.evaluation.seeds import REPORTING_SEEDS, monte_carlo_seed
from dtmbnav.simulation.iq_range import NoSignal, iq_range_source
from dtmbnav_core import gb20600
from dtmbnav_core.records import Observations, Track
from fusion.metrics import PDR_AT_FIX, PDR_BASELINE, error_stats
from fusion.run import FusionConfig
from sim.obs_range import exact_range
from sim.scenario import Scenario, load_scenario

#: The walks of the table: a park loop in the open and a street whose buildings block the tower.
SCENARIOS = ("park-loop-cw", "street-out")
#: C/N of each row, dB (the reference walks' own is 15 dB).
CN_DB = (15.0, 10.0, 5.0, 0.0, -5.0)
#: Monte Carlo walks per scenario and C/N.
WALKS = 2
#: The filter the table scores.
FILTER = "pf"
#: Largest ratio of a walk's PF 95 % error to its PDR@fix 95 % before the walk counts as made worse.
MAX_PF_OVER_FIX = 1.05


@dataclass(frozen=True)
class WeakSignalWalk:
    """One walk at one C/N through the receiver and the fusion.

    Attributes
    ----------
    scenario : str
        Scenario name.
    cn_db : float
        C/N, dB.
    k, seed : int
        Monte Carlo index within the run and the walk's scenario seed.
    frames_sent : int
        Frames the tower sent during the capture.
    frames_received, frames_usable : int
        Frames the receiver delivered, and those of them usable for ranging (0 and 0: no lock).
    si_range_p95_m, first_path_range_p95_m : float
        95th percentile of the SI-carrier and first-path range-change errors over the walking part's usable
        frames, m (NaN: no such frame).
    first_path_share : float
        Share of the walking part's usable frames with a first-path range (NaN: no usable frame).
    p95_m : dict of str -> float or None
        95 % position error of the PDR, the PDR@fix and the PF, m; None: no lock, nothing fused.
    """

    scenario: str
    cn_db: float
    k: int
    seed: int
    frames_sent: int
    frames_received: int
    frames_usable: int
    si_range_p95_m: float
    first_path_range_p95_m: float
    first_path_share: float
    p95_m: dict[str, float] | None

    @property
    def locked(self) -> bool:
        """The receiver delivered frames."""
        return self.frames_received > 0

    @property
    def lock_rate(self) -> float:
        """Usable frames over the frames sent."""
        return self.frames_usable / self.frames_sent

    @property
    def pf_over_fix(self) -> float | None:
        """The PF's 95 % error over the PDR@fix's (None: nothing fused)."""
        return None if self.p95_m is None else self.p95_m[FILTER] / self.p95_m[PDR_AT_FIX]


class _RecordingSource:
    """The IQ-level range source (:func:`dtmbnav.simulation.iq_range.iq_range_source`), keeping what it was given
    and gave."""

    def __init__(self) -> None:
        self.scenario: Scenario | None = None
        self.truth: Track | None = None
        self.observed: Observations | None = None

    def __call__(self, scenario: Scenario, truth: Track) -> Observations:
        self.scenario, self.truth = scenario, truth
        self.observed = iq_range_source(scenario, truth)
        return self.observed


def frames_sent(scenario: Scenario, truth: Track) -> int:
    """Frames the tower sends over a whole-walk capture (from 0 to the end of the track)."""
    period_s = gb20600.PnMode.parse(scenario.tower.pn_mode).value.frame_duration_s
    return int(np.floor(float(truth.t_s[-1]) / period_s))


def range_errors_m(scenario: Scenario, truth: Track, observed: Observations) -> tuple[float, float, float]:
    """The SI-carrier and first-path range 95 % errors, m, and the first path's share (module docstring).

    Both ranges are changes since the receiver's first frame; the truth is the
    first tower's direct-path range (:func:`sim.obs_range.exact_range`) at the
    same times. Scored over the usable frames from the end of the standstill.
    """
    ranges = observed.ranges
    direct = exact_range(scenario, truth)
    true_m = np.interp(ranges.t_s, direct.t_s, direct.range_change_m)
    true_m = true_m - true_m[0]
    scored = ranges.valid & (ranges.t_s >= scenario.walk.start_still_s)
    if not scored.any():
        return float("nan"), float("nan"), float("nan")
    si_p95 = float(np.percentile(np.abs(ranges.range_change_m - true_m)[scored], 95))
    first = None if observed.paths is None else observed.paths.first_path.get(0)
    if first is None:
        return si_p95, float("nan"), float("nan")
    # The path series has a row per frame, as the SI carriers' range.
    held = scored & first.valid
    first_p95 = float(np.percentile(np.abs(first.range_change_m - true_m)[held], 95)) if held.any() else float("nan")
    return si_p95, first_p95, float(held.sum() / scored.sum())


def run_case(scenario: Scenario, cn_db: float, k: int, first_seed: int,
             config: FusionConfig = FusionConfig()) -> WeakSignalWalk:
    """Monte Carlo walk ``k`` of ``scenario`` at ``cn_db`` through the IQ level and the PF: one task."""
    source = _RecordingSource()
    scn = scenario.replace(receiver={"cn_db": cn_db})
    seed = monte_carlo_seed(scn.seed, k, first_seed)
    try:
        result = run_walk(scn, k, first_seed, True, (FILTER,), config, "iq", source, simulated_chain)
    except NoSignal:
        result = None
    assert source.scenario is not None and source.truth is not None
    sent = frames_sent(source.scenario, source.truth)
    if result is None or source.observed is None:
        nan = float("nan")
        return WeakSignalWalk(scn.name, cn_db, k, seed, sent, 0, 0, nan, nan, nan, None)
    ranges = source.observed.ranges
    si_p95, first_p95, share = range_errors_m(source.scenario, source.truth, source.observed)
    p95 = {name: error_stats(result.errors_m[name]).p95_m for name in (PDR_BASELINE, PDR_AT_FIX, FILTER)}
    return WeakSignalWalk(scn.name, cn_db, k, seed, sent, len(ranges), int(np.sum(ranges.valid)), si_p95,
                          first_p95, share, p95)


def cases(scenarios: Sequence[str] = SCENARIOS, cn_db: Sequence[float] = CN_DB, walks: int = WALKS
          ) -> list[tuple[Scenario, float, int]]:
    """Every (scenario, C/N, Monte Carlo index) of the table, scenario by scenario, C/N by C/N."""
    loaded = [load_scenario(name) for name in scenarios]
    return [(scn, cn, k) for scn in loaded for cn in cn_db for k in range(walks)]


def check(case_list: Sequence[tuple[Scenario, float, int]], first_seed: int = REPORTING_SEEDS.start,
          cluster: ClusterConfig = ClusterConfig(), progress: bool = False) -> list[WeakSignalWalk]:
    """Every case through :func:`run_case` where ``cluster`` says, in the order given.

    Raises
    ------
    RuntimeError
        When a walk fails (anything but finding no signal, which is a result).
    """
    tasks = [Task(f"{scn.name} C/N {cn:g} dB walk {k}", run_case, (scn, cn, k, first_seed))
             for scn, cn, k in case_list]
    outcome = run_tasks(tasks, cluster, progress, "weak signals")
    if outcome.failures:
        raise RuntimeError("weak signals: walks failed: " + "; ".join(f"{f.label}: {f.error}"
                                                                     for f in outcome.failures))
    return list(outcome.results)


@dataclass(frozen=True)
class WeakSignalRow:
    """One line of the table: a scenario at one C/N over its walks (module docstring).

    Attributes
    ----------
    scenario : str
    cn_db : float
    walks, locked : int
        Walks, and those on which the receiver locked.
    lock_rate, received_share : float
        Mean over the walks of the usable and of the delivered frames over the frames sent.
    si_range_p95_m, first_path_range_p95_m, first_path_share : float
        Means over the locked walks (NaN: none).
    pdr_p95_m, pdr_at_fix_p95_m, pf_p95_m : float
        Mean 95 % position errors over the locked walks, m (NaN: none).
    reduction, reduction_at_fix : float
        ``1 - PF / PDR`` and ``1 - PF / PDR@fix`` of those means (NaN: none).
    worst_at_fix : float
        The largest walk's PF 95 % over its PDR@fix 95 %, minus one (NaN: none fused).
    walks_worse : int
        Walks whose PF 95 % exceeds :data:`MAX_PF_OVER_FIX` times their PDR@fix's.
    """

    scenario: str
    cn_db: float
    walks: int
    locked: int
    lock_rate: float
    received_share: float
    si_range_p95_m: float
    first_path_range_p95_m: float
    first_path_share: float
    pdr_p95_m: float
    pdr_at_fix_p95_m: float
    pf_p95_m: float
    reduction: float
    reduction_at_fix: float
    worst_at_fix: float
    walks_worse: int


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


def summarise(walks: Sequence[WeakSignalWalk]) -> list[WeakSignalRow]:
    """One row per scenario and C/N, in the order the walks came."""
    groups: dict[tuple[str, float], list[WeakSignalWalk]] = {}
    for walk in walks:
        groups.setdefault((walk.scenario, walk.cn_db), []).append(walk)
    rows = []
    for (scenario, cn_db), group in groups.items():
        fused = [w for w in group if w.p95_m is not None]
        pdr, at_fix, pf = (_mean([w.p95_m[name] for w in fused]) for name in (PDR_BASELINE, PDR_AT_FIX, FILTER))
        ratios = [w.pf_over_fix for w in fused]
        rows.append(WeakSignalRow(
            scenario=scenario, cn_db=cn_db, walks=len(group), locked=sum(w.locked for w in group),
            lock_rate=_mean([w.lock_rate for w in group]),
            received_share=_mean([w.frames_received / w.frames_sent for w in group]),
            si_range_p95_m=_mean([w.si_range_p95_m for w in group if w.locked]),
            first_path_range_p95_m=_mean([w.first_path_range_p95_m for w in group if w.locked]),
            first_path_share=_mean([w.first_path_share for w in group if w.locked]),
            pdr_p95_m=pdr, pdr_at_fix_p95_m=at_fix, pf_p95_m=pf, reduction=1.0 - pf / pdr,
            reduction_at_fix=1.0 - pf / at_fix, worst_at_fix=max(ratios) - 1.0 if ratios else float("nan"),
            walks_worse=sum(r > MAX_PF_OVER_FIX for r in ratios)))
    return rows


def _m(value: float, spec: str = ".2f") -> str:
    return "-" if not np.isfinite(value) else f"{format(value, spec)} m"


def _pct(value: float, spec: str = ".1f") -> str:
    return "-" if not np.isfinite(value) else f"{format(100.0 * value, spec)} %"


def weak_signal_table(rows: Sequence[WeakSignalRow]) -> tuple[str, int]:
    """The Markdown table of the rows, and how many rows fail (a walk made worse than its PDR@fix)."""
    head = ["walk", "C/N", "walks locked", "lock rate (frames delivered)", "SI-carrier range 95 %",
            "first-path range 95 % (frames with one)", "PDR", "PDR@fix", "PF (vs PDR / vs PDR@fix)",
            "PF worst@fix", f"walks PF > {MAX_PF_OVER_FIX:g} x PDR@fix"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    failed = 0
    for r in rows:
        failed += r.walks_worse > 0
        if r.locked == 0:
            cells = [f"0 of {r.walks}", "no lock", "-", "-", "-", "-", "no lock: nothing fused", "-", "-"]
        else:
            fused = (f"{_m(r.pf_p95_m)} ({_pct(r.reduction)} / {_pct(r.reduction_at_fix)})")
            cells = [f"{r.locked} of {r.walks}", f"{_pct(r.lock_rate)} ({_pct(r.received_share)})",
                     _m(r.si_range_p95_m, ".3f"),
                     f"{_m(r.first_path_range_p95_m, '.3f')} ({_pct(r.first_path_share)})",
                     _m(r.pdr_p95_m), _m(r.pdr_at_fix_p95_m), fused, _pct(r.worst_at_fix, "+.1f"),
                     f"{r.walks_worse} of {r.locked}"]
        lines.append(f"| {r.scenario} | {r.cn_db:g} dB | " + " | ".join(cells) + " |")
    return "\n".join(lines), failed


def per_walk_table(walks: Sequence[WeakSignalWalk]) -> str:
    """Each walk's figures as Markdown: lock rate, the two range 95 %, and the 95 % errors, m."""
    lines = ["| walk | C/N | k | seed | lock rate | SI-carrier range 95 % | first-path range 95 % | PDR | PDR@fix "
             "| PF |", "|---" * 10 + "|"]
    for w in walks:
        p95 = w.p95_m or {}
        fused = " | ".join(_m(p95[name]) if name in p95 else "-" for name in (PDR_BASELINE, PDR_AT_FIX, FILTER))
        lock = _pct(w.lock_rate) if w.locked else "no lock"
        lines.append(f"| {w.scenario} | {w.cn_db:g} dB | {w.k} | {w.seed} | {lock} | {_m(w.si_range_p95_m, '.3f')} | "
                     f"{_m(w.first_path_range_p95_m, '.3f')} | {fused} |")
    return "\n".join(lines)


def describe(first_seed: int = REPORTING_SEEDS.start, walks: int = WALKS,
             scenarios: Sequence[str] = SCENARIOS, cn_db: Sequence[float] = CN_DB) -> str:
    """The paragraph above the table: the walks and how each column is computed."""
    return (f"{', '.join(scenarios)} at C/N {', '.join(f'{c:g}' for c in cn_db)} dB, {walks} walks each: "
            f"{describe_seeds(first_seed, walks, 'iq', True)}; the particle filter only. Lock rate: frames the "
            "receiver delivered usable over the frames the tower sent (in brackets, those it delivered at all); "
            "range 95 %: error of the range change since the receiver's first frame against the first tower's "
            "direct path, over the walking part's usable frames (in brackets, the share of them with a first "
            "path); position errors 95 %, means over the walks that locked. A row fails where some walk's PF "
            f"95 % exceeds {MAX_PF_OVER_FIX:g} times its PDR@fix 95 %.")


def main(argv: list[str] | None = None) -> int:
    """Print the weak-signal table and its walks; exit status 1 when a row fails."""
    parser = argparse.ArgumentParser(prog="python -m dtmbnav.evaluation.weak_signal",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--first-seed", type=int, default=REPORTING_SEEDS.start,
                        help=f"first Monte Carlo index (default {REPORTING_SEEDS.start}; 100 for the tuning range)")
    parser.add_argument("--seeds", type=int, default=WALKS, help=f"walks per scenario and C/N (default {WALKS})")
    parser.add_argument("--workers", type=int, default=None,
                        help="local Dask workers (default: one per core; 0: in this process)")
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), help="the walks (default: both)")
    parser.add_argument("--cn-db", type=float, nargs="+", default=list(CN_DB), help="the C/N of the rows, dB")
    args = parser.parse_args(argv)
    walks = check(cases(args.scenarios, args.cn_db, args.seeds), args.first_seed, ClusterConfig(workers=args.workers),
                  progress=True)
    table, failed = weak_signal_table(summarise(walks))
    print(f"{describe(args.first_seed, args.seeds, args.scenarios, args.cn_db)}\n\n{table}\n\nPer walk:\n\n"
          f"{per_walk_table(walks)}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
