"""Real SDR front ends against an ideal one: the device presets, a leakage, imbalance and offset sweep, drops.

A front end is judged by the walk it spoils, not by its own estimates: the
park-loop-cw walk (C/N 15 dB, the end of its standstill for f_s, then
:data:`WALK_S` seconds of walking; :data:`WALKS` walks of the tuning range)
is received through the impaired front end and through an *ideal* twin,
the same scenario with every impairment key of
:data:`sim.frontend.IMPAIRMENT_DEFAULTS` at its default (same rate, sample
format, oscillator and tuner offset, same noise), and the figures are
averaged over the walks. A case passes (docs/devices.md, "Judging a front
end") when the receiver

- locks and names the SI word the tower sends,
- flags at most :data:`MAX_LOW_QUALITY` of its frames LOW_QUALITY, and
- keeps the range-change error's 95th percentile and the RMSE of 1 s mean
  radial velocities within :data:`TOLERANCE` times the ideal twin's, for the
  SI-carrier range and for the first path's.

A third case drops runs of samples (:data:`DROPS_PER_MINUTE` a minute, of
:data:`DROP_SAMPLES` samples): every drop counted exactly, ``t_s`` within
:data:`MAX_DROP_T_S_SAMPLES` of the truth after each, and no first-path range
jump over :data:`MAX_DROP_JUMP_M` across one.

Run ``python -m dtmbnav.evaluation.frontends`` to print the three (``--devices``,
``--sweep`` or ``--drops`` for one); ``dtmbnav results --sections frontends`` prints them
into docs/results.md.
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtmbnav.evaluation.accuracy import (
    CaptureRun,
    accuracy,
    direct_range_m,
    match_truth,
    path_accuracy,
    run_capture,
    segment_config,
)
from dtmbnav.evaluation.distributed import ClusterConfig, Task, run_tasks
from dtmbnav.evaluation.evaluate import seed_scenario
from dtmbnav.evaluation.seeds import TUNING_SEEDS
from dtmbnav_core.constants import CLOCK_PRESETS
from dtmbnav_core.records import FrameFlag
from sim.devices import DEVICES, get_device
from sim.frontend import IMPAIRMENT_DEFAULTS
from sim.scenario import Scenario, load_scenario

#: The walk every case receives.
SCENARIO = "park-loop-cw"
#: Seconds of the standstill received (for f_s) and of walking scored after it.
STILL_S = 4.0
WALK_S = 20.0
#: Largest share of frames flagged LOW_QUALITY a passing front end may cause.
MAX_LOW_QUALITY = 0.05
#: Largest ratio of an error figure to the ideal twin's.
TOLERANCE = 1.2
#: Walks each case and its twin are received on (their figures averaged): a first-path figure of one walk
#: moves by tens of per cent with which paths the tracker happens to follow, impairment or not.
WALKS = 3
#: Where the walks run by default: a local Dask cluster, a worker per core.
LOCAL = ClusterConfig()
#: Sweep axes: LO leakage (dBc; None: none), I/Q imbalance (gain dB, phase deg) and tuner offset (Hz) at the
#: sweep's rate and format.
SWEEP_LEAKAGE_DBC = (None, -40.0, -20.0, -12.0, -6.0)
SWEEP_IQ = ((0.0, 0.0), (1.0, 5.0), (2.0, 10.0))
SWEEP_OFFSET_HZ = (-60e3, 0.0, 60e3)
#: The sweep's rate and format: the scenario's own (a zero-IF capture at the symbol rate).
SWEEP_RATE_HZ = 7.56e6
SWEEP_FORMAT = "ci8"


@dataclass(frozen=True)
class FrontEndScore:
    """What one receiver run on a front end gave over the scored walk.

    Attributes
    ----------
    locked : bool
        At least one frame came out.
    si_word_ok : bool
        The SI word identified is the one the tower sends.
    low_quality_share : float
        Frames flagged LOW_QUALITY over frames received (scored window).
    si_range_p95_m, si_velocity_rmse_mps : float
        SI-carrier range-change error, 95th percentile, m; RMSE of 1 s mean radial velocities, m/s.
    first_path_range_p95_m, first_path_velocity_rmse_mps : float
        The same for the first path's range (the first tower's direct path as truth).
    drops : int
        Drops the receiver found.
    """

    locked: bool
    si_word_ok: bool
    low_quality_share: float
    si_range_p95_m: float
    si_velocity_rmse_mps: float
    first_path_range_p95_m: float
    first_path_velocity_rmse_mps: float
    drops: int

    #: The error figures judged against the ideal twin, with their table titles.
    ERRORS = (("si_range_p95_m", "SI range 95 %"), ("si_velocity_rmse_mps", "SI velocity RMSE"),
              ("first_path_range_p95_m", "first-path range 95 %"),
              ("first_path_velocity_rmse_mps", "first-path velocity RMSE"))


def first_path_velocity_rmse_mps(run: CaptureRun, t_from_s: float, t_to_s: float) -> float:
    """RMSE of the first path's 1 s mean radial velocities over ``[t_from_s, t_to_s)``, m/s.

    Each second's mean velocity is its range change between the second's
    first and last frame with a first-path range over their time apart,
    against the same of the first tower's direct-path range (a second with
    under half its frames scored counts as lost: infinite error).
    """
    f = run.frames
    assert run.paths is not None and f.first_path_range_change_m is not None
    truth = direct_range_m(run.paths, 0, f.t_s)
    errors = []
    for lo in np.arange(t_from_s, t_to_s - 1.0 + 1e-9, 1.0):
        sel = np.flatnonzero((f.t_s >= lo) & (f.t_s < lo + 1.0))
        ok = sel[np.isfinite(f.first_path_range_change_m[sel])]
        if len(sel) == 0 or len(ok) < 0.5 * len(sel):
            return float("inf")
        a, b = ok[0], ok[-1]
        span = f.t_s[b] - f.t_s[a]
        measured = (f.first_path_range_change_m[b] - f.first_path_range_change_m[a]) / span
        errors.append(measured - (truth[b] - truth[a]) / span)
    return float(np.sqrt(np.mean(np.square(errors))))


def score(run: CaptureRun, t_from_s: float, t_to_s: float) -> FrontEndScore:
    """Score a run over the capture-time window ``[t_from_s, t_to_s)``."""
    f = run.frames
    if len(f) == 0:
        nan = float("nan")
        return FrontEndScore(False, False, nan, nan, nan, nan, nan, 0)
    sel = (f.t_s >= t_from_s) & (f.t_s < t_to_s)
    low = float(np.mean((f.flags[sel] & FrameFlag.LOW_QUALITY) > 0)) if sel.any() else 1.0
    si = accuracy(run, t_from_s, t_to_s)
    # A narrowband capture has no path tracker, so no first-path range.
    tracked = run.receiver.config.track_paths
    first_p95 = path_accuracy(run, t_from_s, t_to_s).first_path_error_p95_m if tracked else float("nan")
    first_rmse = first_path_velocity_rmse_mps(run, t_from_s, t_to_s) if tracked else float("nan")
    return FrontEndScore(True, run.receiver.si_index == run.scenario.tower.si_index, low, si.range_error_p95_m,
                         si.velocity_rmse_1s_mps, first_p95, first_rmse, len(run.receiver.drops.samples))


def failures(case: FrontEndScore, ideal: FrontEndScore) -> list[str]:
    """The criteria (module docstring) a case misses against its ideal twin; empty when it passes."""
    out = []
    if not case.locked:
        return ["no lock"]
    if not case.si_word_ok:
        out.append("SI word")
    if not case.low_quality_share <= MAX_LOW_QUALITY:
        out.append(f"LOW_QUALITY {100 * case.low_quality_share:.1f} %")
    for name, title in FrontEndScore.ERRORS:
        reference = getattr(ideal, name)
        # A figure neither front end gives (the first path of a narrowband capture) is not judged.
        if np.isfinite(reference) and not getattr(case, name) <= TOLERANCE * reference:
            out.append(title)
    return out


def ideal_front_end(scenario: Scenario) -> Scenario:
    """``scenario`` with every impairment key at its default: the same rate, format, oscillator and tuner."""
    return scenario.replace(receiver=dict(IMPAIRMENT_DEFAULTS))


def receive_walk(scenario: Scenario, walk_s: float = WALK_S) -> FrontEndScore:
    """Receive the last :data:`STILL_S` s of the scenario's standstill and ``walk_s`` s of walking with the
    receiver's defaults; score the walking part."""
    start = scenario.walk.start_still_s - STILL_S
    run = run_capture(scenario, start_s=start, seconds=STILL_S + walk_s, config=segment_config(scenario, start))
    return score(run, STILL_S, STILL_S + walk_s)


def device_scenario(name: str) -> Scenario:
    """The reference walk recorded with device ``name``: its rate, format, impairments and crystal offset.

    The crystal's wander is left out (the GNSS-disciplined clock's Allan
    deviation): a free-running oscillator's drift is the same through any
    front end, and it would hide what the front end itself does (the
    receiver's table has a free-running row).
    """
    device = get_device(name).receiver_table()
    device["clock"] = {**device["clock"], "drift_adev": CLOCK_PRESETS["gnss-disciplined"][1]}
    return load_scenario(SCENARIO).replace(receiver=device)


@dataclass(frozen=True)
class FrontEndCase:
    """One row of a table: the case's label, its score and its ideal twin's."""

    label: str
    case: FrontEndScore
    ideal: FrontEndScore


def mean_score(scores: Sequence[FrontEndScore]) -> FrontEndScore:
    """One score for several walks: locked and the right SI word on every walk, the shares and error figures
    averaged (NaN where a walk has none), the drops added."""
    def mean(name: str) -> float:
        return float(np.mean([getattr(s, name) for s in scores]))

    return FrontEndScore(all(s.locked for s in scores), all(s.si_word_ok for s in scores), mean("low_quality_share"),
                         *(mean(name) for name, _ in FrontEndScore.ERRORS), sum(s.drops for s in scores))


def walk_scenario(scenario: Scenario, k: int) -> Scenario:
    """Walk ``k`` of a case: the scenario with Monte Carlo seed ``k`` of the tuning range, its layout kept."""
    return seed_scenario(scenario, k, first_seed=TUNING_SEEDS.start, vary_geometry=False)


def compare(cases: Sequence[tuple[str, Scenario, Scenario]], walks: int = WALKS, cluster: ClusterConfig = LOCAL,
            progress: bool = False) -> list[FrontEndCase]:
    """Receive every ``(label, scenario, ideal twin)`` on ``walks`` walks where ``cluster`` says (a twin shared by
    several cases is received once) and score each case against its twin, averaged over the walks."""
    scenarios: list[Scenario] = []
    for _, case, ideal in cases:
        scenarios.extend(s for s in (case, ideal) if s not in scenarios)
    tasks = [Task(f"{s.name} walk {k}", receive_walk, (walk_scenario(s, k),)) for s in scenarios
             for k in range(walks)]
    outcome = run_tasks(tasks, cluster, progress, "front ends")
    if outcome.failures:
        failed = "; ".join(f"{f.label}: {f.error}" for f in outcome.failures)
        raise RuntimeError(f"front ends: walks failed: {failed}")
    scores = [mean_score(outcome.results[i * walks: (i + 1) * walks]) for i in range(len(scenarios))]
    return [FrontEndCase(label, scores[scenarios.index(case)], scores[scenarios.index(ideal)])
            for label, case, ideal in cases]


def device_cases(names: Sequence[str] = tuple(DEVICES)) -> list[tuple[str, Scenario, Scenario]]:
    """Each device preset at its usual rate and format (:mod:`sim.devices`) with its ideal twin."""
    scenarios = {name: device_scenario(name) for name in names}
    return [(name, scenario, ideal_front_end(scenario)) for name, scenario in scenarios.items()]


def sweep_cases() -> list[tuple[str, Scenario, Scenario]]:
    """Every point of the LO-leakage, I/Q-imbalance and tuner-offset grid (the sweep axes) with its ideal twin."""
    base = load_scenario(SCENARIO).replace(receiver={"sample_rate_hz": SWEEP_RATE_HZ,
                                                     "sample_format": SWEEP_FORMAT})
    out = []
    for offset in SWEEP_OFFSET_HZ:
        tuned = base.replace(receiver={"bulk_cfo_hz": offset})
        for leakage, (gain_db, phase_deg) in itertools.product(SWEEP_LEAKAGE_DBC, SWEEP_IQ):
            if leakage is None and gain_db == 0.0 and phase_deg == 0.0:
                continue
            impaired = tuned.replace(receiver={"lo_leakage_dbc": leakage, "iq_gain_db": gain_db,
                                               "iq_phase_deg": phase_deg})
            label = (f"{offset / 1e3:+g} kHz, {'no leakage' if leakage is None else f'{leakage:g} dBc'}, "
                     f"{gain_db:g} dB / {phase_deg:g} deg")
            out.append((label, impaired, tuned))
    return out


#: The drop case: drops a minute, their length range (samples at the capture's rate) and seconds of walking.
DROPS_PER_MINUTE = 10.0
DROP_SAMPLES = (1, 100_000)
DROP_WALK_S = 60.0
#: Largest first-path range jump across a drop, m, and t_s error after one, samples.
MAX_DROP_JUMP_M = 0.05
MAX_DROP_T_S_SAMPLES = 1.0


@dataclass(frozen=True)
class DropScore:
    """How a run kept its ranges and time base across the samples its front end dropped.

    Attributes
    ----------
    true_samples, found_samples : list of int
        Samples lost in each drop between the first frame and the last: the simulator's truth and what the
        receiver counted (in order).
    t_s_error_samples : float
        Largest change, across any drop, of the receiver's ``t_s`` less the truth's for the same frame,
        samples at the capture's rate (0: the time base stays on the real clock).
    first_path_jump_m, si_jump_m : float
        Largest change of the first-path (SI-carrier) range-change error from the last frame before a
        drop to the first after it, m.
    """

    true_samples: list[int]
    found_samples: list[int]
    t_s_error_samples: float
    first_path_jump_m: float
    si_jump_m: float

    def failures(self) -> list[str]:
        """What misses the drop criteria (:data:`MAX_DROP_JUMP_M`, :data:`MAX_DROP_T_S_SAMPLES`, every drop
        counted exactly)."""
        out = []
        if self.found_samples != self.true_samples:
            out.append("drops counted")
        if not self.t_s_error_samples <= MAX_DROP_T_S_SAMPLES:
            out.append("t_s")
        if not self.first_path_jump_m <= MAX_DROP_JUMP_M:
            out.append("first-path jump")
        return out


def drop_score(run: CaptureRun) -> DropScore:
    """Score a run's drops against the simulator's (:class:`sim.rf.DropTruth`)."""
    f, tr = run.frames, run.truth
    assert run.drops is not None and run.paths is not None
    fs = run.scenario.receiver.sample_rate_hz
    j = match_truth(f, tr)
    t_error = (f.t_s - tr.t_s[j]) * fs
    first = direct_range_m(run.paths, 0, f.t_s)
    fp_error = f.first_path_range_change_m - (first - first[0])
    si_error = f.range_change_m - (tr.range_m[j] - tr.range_m[j[0]])
    t_jump = fp_jump = si_jump = 0.0
    # Only the drops between the first frame and the last can show in the frames.
    seen = (run.drops.receiver_sample / fs > f.t_s[0]) & (run.drops.receiver_sample / fs < f.t_s[-1])
    for at in run.drops.receiver_sample[seen] / fs:
        before, after = np.flatnonzero(f.t_s < at), np.flatnonzero(f.t_s > at)
        b, a = before[-1], after[0]
        t_jump = max(t_jump, abs(t_error[a] - t_error[b]))
        # The last finite first-path range before the drop and the first after it (a weak frame has none).
        fb = before[np.isfinite(fp_error[before])]
        fa = after[np.isfinite(fp_error[after])]
        fp_jump = max(fp_jump, abs(fp_error[fa[0]] - fp_error[fb[-1]]) if len(fa) and len(fb) else np.inf)
        si_jump = max(si_jump, abs(si_error[a] - si_error[b]))
    return DropScore([int(n) for n in run.drops.samples[seen]], list(run.receiver.drops.samples), float(t_jump),
                     float(fp_jump), float(si_jump))


def drop_case(drops_per_minute: float = DROPS_PER_MINUTE, walk_s: float = DROP_WALK_S) -> tuple[DropScore, float]:
    """The reference walk with ``drops_per_minute`` drops of :data:`DROP_SAMPLES` samples over ``walk_s`` s of
    walking: its score and the walk's first-path range error 95 %, m."""
    scenario = load_scenario(SCENARIO).replace(receiver={"drops_per_minute": drops_per_minute,
                                                         "drop_samples": list(DROP_SAMPLES)})
    start = scenario.walk.start_still_s - STILL_S
    run = run_capture(scenario, start_s=start, seconds=STILL_S + walk_s, config=segment_config(scenario, start))
    return drop_score(run), path_accuracy(run, STILL_S, STILL_S + walk_s).first_path_error_p95_m


def drop_table(score: DropScore, first_path_p95_m: float) -> str:
    """The drop case as Markdown: what was lost, what was counted, and the criteria."""
    missed = score.failures()
    return (f"{len(score.true_samples)} drops of {', '.join(map(str, score.true_samples))} samples "
            f"(receiver counted {', '.join(map(str, score.found_samples)) or 'none'}); largest change of t_s "
            f"against the truth across a drop {score.t_s_error_samples:.2f} samples (at most "
            f"{MAX_DROP_T_S_SAMPLES:g}); largest range jump across a drop {score.first_path_jump_m:.3f} m on the first "
            f"path (at most {MAX_DROP_JUMP_M:g}), {score.si_jump_m:.3f} m on the SI carriers; first-path range error "
            f"95 % over the walk {first_path_p95_m:.3f} m: "
            + ("pass." if not missed else "FAIL: " + ", ".join(missed) + "."))


def _ratio(case: float, ideal: float) -> str:
    if np.isnan(case) and np.isnan(ideal):
        return "-"
    return f"{case:.3f} ({case / ideal:.2f})"


def frontend_table(cases: Sequence[FrontEndCase]) -> tuple[str, int]:
    """A Markdown table of the cases and the number that fail."""
    head = ["case", "lock, SI word", "LOW_QUALITY", *(title + (", m" if name.endswith("_m") else ", m/s")
                                                      for name, title in FrontEndScore.ERRORS), "drops", "verdict"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    failed = 0
    for row in cases:
        missed = failures(row.case, row.ideal)
        failed += bool(missed)
        c = row.case
        lock = "no lock" if not c.locked else ("yes, right" if c.si_word_ok else "yes, WRONG")
        cells = [row.label, lock, "-" if not c.locked else f"{100 * c.low_quality_share:.1f} %",
                 *(_ratio(getattr(c, name), getattr(row.ideal, name)) for name, _ in FrontEndScore.ERRORS),
                 str(c.drops), "pass" if not missed else "FAIL: " + ", ".join(missed)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines), failed


def describe() -> str:
    """The paragraph above the tables: what is received and how it is judged."""
    first = TUNING_SEEDS.start
    return (f"The {SCENARIO} walk (its layout; Monte Carlo seeds {first}-{first + WALKS - 1} of the tuning range), "
            f"C/N 15 dB, the last {STILL_S:g} s of its standstill then {WALK_S:g} s of walking, received through each "
            "front end and through its ideal twin (every impairment key at its default; same rate, format, "
            "oscillator, tuner offset and noise). Each error column gives the mean over the walks and, in brackets, "
            f"its ratio to the twin's; a case passes with lock and the right SI word on every walk, at most "
            f"{100 * MAX_LOW_QUALITY:g} % of frames LOW_QUALITY and every ratio at most {TOLERANCE:g}.")


def main(argv: list[str] | None = None) -> int:
    """Print the device table, the sweep table and the drop case (module docstring); exit status 1 when a case
    fails."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", action="store_true", help="only the device presets")
    parser.add_argument("--sweep", action="store_true", help="only the leakage / imbalance / offset sweep")
    parser.add_argument("--drops", action="store_true", help="only the dropped-samples case")
    args = parser.parse_args(argv)
    both = not (args.devices or args.sweep or args.drops)
    print(describe())
    failed = 0
    if args.devices or both:
        table, n = frontend_table(compare(device_cases(), progress=True))
        print(f"\nDevice presets at their usual rate and format:\n\n{table}", flush=True)
        failed += n
    if args.sweep or both:
        table, n = frontend_table(compare(sweep_cases(), progress=True))
        print(f"\nSweep at {SWEEP_RATE_HZ / 1e6:g} Msps {SWEEP_FORMAT}:\n\n{table}", flush=True)
        failed += n
    if args.drops or both:
        score_, p95 = drop_case()
        print(f"\nDropped samples, {DROPS_PER_MINUTE:g} a minute of {DROP_SAMPLES[0]} to {DROP_SAMPLES[1]} samples: "
              f"{drop_table(score_, p95)}", flush=True)
        failed += bool(score_.failures())
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
