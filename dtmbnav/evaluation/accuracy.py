"""End-to-end accuracy of the receiver on simulated captures (tests, ``dtmbnav results`` and a script).

:func:`run_capture` simulates a scenario segment with :class:`sim.rf.CaptureGenerator`
(quantised to the requested format and decoded back, as a file would be),
runs the receiver on it in chunks and returns its rows with the simulator's
per-frame truth; :func:`accuracy` scores them over the walking part.

:func:`path_accuracy` scores the path tracker's outputs (``docs/paths.md``):
the first path's range change against the first tower's direct path, and the
clock-free range difference of two towers against theirs, from the per-path
truth (``/truth/paths``).

Run ``python -m dtmbnav.evaluation.accuracy`` to print the 60 s figures: park-loop with the GNSS-disciplined and the
free-running clock, and street, SI carriers and first path. ``--walk NAME``
scores a whole walk (or ``--start``/``--seconds`` a segment of it), simulated
in the process; ``--capture DIR`` scores a capture that ``dtmbnav simulate``
wrote into DIR (the capture and its ``truth.h5``), without simulating again.
``--mc-walk K`` with ``--walk`` takes the walk ``dtmbnav evaluate`` runs as
Monte Carlo index K instead of the scenario file's, ``--clock-path`` the path
on which the first path's f_s is measured. ``--narrowband`` prints the narrowband figures: park-loop, GNSS-disciplined clock,
40 s of walking recorded at 2.048, 2.4 and 3.2 Msps (an RTL-SDR's rates).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dtmbnav.evaluation.evaluate import seed_scenario
from dtmbnav_core import schema
from dtmbnav_core.h5io import read_columns
from dtmbnav_core.iqformat import decode
from dtmbnav_core.records import FrameBatch, FrameFlag
from receiver import CLOCK_PATHS, DEFAULT_CLOCK_PATH
from receiver.capture import open_capture
from receiver.delay_doppler import CHECK_FRAMES, DopplerConfig
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from sim.channel import DIRECT
from sim.path_truth import PathTruth, path_truth
from sim.rf import CaptureGenerator, DropTruth, FrameTruth
from sim.scenario import Scenario, load_scenario, scenario_from_dict
from sim.walk import simulate_walk


@dataclass
class CaptureRun:
    """A receiver run on a simulated segment."""

    frames: FrameBatch
    truth: FrameTruth
    receiver: Receiver
    scenario: Scenario
    start_s: float
    seconds_per_second: float
    paths: PathTruth | None = None
    drops: DropTruth | None = None


def run_capture(scenario: str | Scenario, *, start_s: float, seconds: float | None, config: ReceiverConfig,
                sample_rate_hz: float | None = None, sample_format: str | None = None, pn_mode: str | None = None,
                chunk_samples: int = 1 << 20, **receiver_overrides) -> CaptureRun:
    """Simulate a segment and receive it.

    ``receiver_overrides`` change fields of the scenario's ``[receiver]``
    section (e.g. ``bulk_cfo_hz=5000``, ``clock={"preset": "free-running"}``).
    """
    scn = load_scenario(scenario) if isinstance(scenario, str) else scenario
    if receiver_overrides:
        scn = scn.replace(receiver=receiver_overrides)
    walk = simulate_walk(scn)
    gen = CaptureGenerator(scn, walk.track, seconds=seconds, start_s=start_s, sample_rate_hz=sample_rate_hz,
                           sample_format=sample_format, pn_mode=pn_mode)
    fmt = gen.sample_format

    def chunks():
        for chunk in gen.chunks(chunk_samples):
            yield chunk if fmt == "cf32" else decode(gen.frontend.quantise(chunk), fmt)

    rx = Receiver(gen.sample_rate_hz, gen.carrier_hz, config)
    t0 = time.perf_counter()
    frames = FrameBatch.concatenate(list(receive_stream(chunks(), gen.sample_rate_hz, gen.carrier_hz, receiver=rx)))
    elapsed = time.perf_counter() - t0
    return CaptureRun(frames, gen.frame_truth(), rx, scn, start_s, elapsed / gen.num_samples * gen.sample_rate_hz,
                      path_truth(gen), gen.drops())


def load_simulated_capture(folder: str | Path) -> tuple[Path, FrameTruth, PathTruth, Scenario, float]:
    """The capture, frame truth, path truth, scenario and segment start of a ``dtmbnav simulate`` folder."""
    import tomllib

    import h5py

    folder = Path(folder)
    meta = sorted(folder.glob("*.sigmf-meta"))
    if not meta:
        raise ValueError(f"{folder}: no SigMF capture")
    truth_file = folder / "truth.h5"
    frames_truth = FrameTruth(**read_columns(truth_file, schema.TRUTH_FRAMES))
    paths = PathTruth(**read_columns(truth_file, schema.TRUTH_PATHS))
    with h5py.File(truth_file, "r") as f:
        scenario = scenario_from_dict(tomllib.loads(f[schema.TRUTH_FRAMES].attrs["scenario"]))
        start_s = float(f[schema.TRUTH_FRAMES].attrs[schema.CAPTURE_START_ATTR])
    return meta[0], frames_truth, paths, scenario, start_s


def run_simulated_capture(folder: str | Path) -> CaptureRun:
    """Receive a capture written by ``dtmbnav simulate`` into ``folder`` (with its ``truth.h5``)."""
    capture, frames_truth, paths, scenario, start_s = load_simulated_capture(folder)
    source = open_capture(capture)
    config = segment_config(scenario, start_s, frames_truth)
    rx = Receiver(source.sample_rate_hz, source.center_hz, config)
    t0 = time.perf_counter()
    frames = FrameBatch.concatenate(list(receive_stream(source.chunks(1 << 20), source.sample_rate_hz,
                                                        source.center_hz, receiver=rx)))
    elapsed = time.perf_counter() - t0
    return CaptureRun(frames, frames_truth, rx, scenario, start_s, elapsed / source.num_samples * source.sample_rate_hz,
                      paths)


def match_truth(frames: FrameBatch, truth: FrameTruth) -> np.ndarray:
    """Index of the truth frame nearest in time to each receiver frame."""
    j = np.clip(np.searchsorted(truth.t_s, frames.t_s), 1, len(truth.t_s) - 1)
    return np.where(np.abs(truth.t_s[j - 1] - frames.t_s) < np.abs(truth.t_s[j] - frames.t_s), j - 1, j)


@dataclass
class Accuracy:
    """Scores over a time window of a run."""

    velocity_rmse_1s_mps: float
    cfo_rmse_1s_hz: float
    range_error_p95_m: float
    range_error_max_m: float
    clock_offset_error_hz: float
    frames: int
    seconds: float

    def __str__(self) -> str:
        return (f"velocity RMSE (1 s means) {self.velocity_rmse_1s_mps:.4f} m/s, CFO RMSE against the true "
                f"Doppler + clock offset (1 s means) {self.cfo_rmse_1s_hz:.3f} Hz, range error p95 "
                f"{self.range_error_p95_m:.3f} m (max {self.range_error_max_m:.3f} m), f_s error "
                f"{self.clock_offset_error_hz:+.3f} Hz, {self.frames} frames over {self.seconds:.1f} s")


def true_clock_offset_hz(run: CaptureRun) -> float:
    """The f_s the receiver should measure: the true clock offset over its static window plus the tuner's, Hz.

    The truth's clock offset is the oscillator part only; the receiver's f_s
    also holds the bulk tuner offset. NaN without a static window.
    """
    f, tr = run.frames, run.truth
    calibration = (f.flags & FrameFlag.CALIBRATION) > 0
    if not calibration.any():
        return float("nan")
    return float(np.mean(tr.clock_offset_hz[match_truth(f, tr)][calibration])) + run.scenario.receiver.bulk_cfo_hz


def accuracy(run: CaptureRun, t_from_s: float, t_to_s: float) -> Accuracy:
    """Velocity RMSE of 1 s means and range-change error over ``[t_from_s, t_to_s)`` (capture time).

    The range change is compared with the true range change since the
    receiver's first frame.
    """
    f, tr = run.frames, run.truth
    j = match_truth(f, tr)
    true_range = tr.range_m[j] - tr.range_m[j[0]]
    sel = (f.t_s >= t_from_s) & (f.t_s < t_to_s)
    range_err = np.abs(f.range_change_m[sel] - true_range[sel])
    bins = np.floor(f.t_s[sel] - t_from_s).astype(int)
    ok = np.isfinite(f.velocity_mps[sel])
    counts = np.bincount(bins[ok])
    rx_mean = np.bincount(bins[ok], f.velocity_mps[sel][ok]) / np.maximum(counts, 1)
    true_mean = np.bincount(bins[ok], tr.radial_velocity_mps[j][sel][ok]) / np.maximum(counts, 1)
    full = counts > 0.9 * np.max(counts)
    rmse = float(np.sqrt(np.mean((rx_mean - true_mean)[full] ** 2)))
    # The CFO itself against the truth (separates receiver errors from the f_s model's: oscillator drift).
    true_cfo = tr.doppler_hz[j] + tr.clock_offset_hz[j] + run.scenario.receiver.bulk_cfo_hz
    rx_cfo = np.bincount(bins[ok], f.cfo_hz[sel][ok]) / np.maximum(counts, 1)
    true_cfo_mean = np.bincount(bins[ok], true_cfo[sel][ok]) / np.maximum(counts, 1)
    cfo_rmse = float(np.sqrt(np.mean((rx_cfo - true_cfo_mean)[full] ** 2)))
    fs_err = (run.receiver.ranging.clock_offset_hz or np.nan) - true_clock_offset_hz(run)
    return Accuracy(rmse, cfo_rmse, float(np.percentile(range_err, 95)), float(np.max(range_err)), fs_err, int(sel.sum()),
                    float(t_to_s - t_from_s))


#: Narrowband case: rates (an RTL-SDR's) and seconds of walking.
NARROWBAND_RATES_HZ = (2.048e6, 2.4e6, 3.2e6)
NARROWBAND_WALK_S = 40.0


@dataclass
class PathAccuracy:
    """Scores of the path tracker's outputs over a time window of a run (``docs/paths.md``)."""

    first_path_error_p95_m: float
    first_path_error_max_m: float
    si_error_p95_m: float
    difference_error_p95_m: float
    difference_error_max_m: float
    first_path_share: float
    frames: int
    seconds: float

    def __str__(self) -> str:
        text = (f"first-path range error p95 {self.first_path_error_p95_m:.3f} m (max {self.first_path_error_max_m:.3f} m; "
                f"SI carriers p95 {self.si_error_p95_m:.3f} m), first path found in {100 * self.first_path_share:.1f} % "
                f"of the frames")
        if np.isfinite(self.difference_error_p95_m):
            text += (f"; tower-differenced range error p95 {self.difference_error_p95_m:.3f} m "
                     f"(max {self.difference_error_max_m:.3f} m)")
        return text + f"; {self.frames} frames over {self.seconds:.1f} s"


def direct_range_m(paths: PathTruth, tower: int, t_s: np.ndarray) -> np.ndarray:
    """A tower's direct-path range at capture times ``t_s``, interpolated from the per-path truth, m."""
    rows = (paths.tower_id == tower) & (paths.kind == DIRECT)
    return np.interp(t_s, paths.t_s[rows], paths.range_m[rows])


def path_accuracy(run: CaptureRun, t_from_s: float, t_to_s: float) -> PathAccuracy:
    """First-path and tower-differenced range-change errors over ``[t_from_s, t_to_s)`` (capture time).

    The first path's range change is compared with the first tower's direct
    path since the receiver's first frame (as :func:`accuracy` does for the
    SI carriers); the range difference (tower 1 minus tower 0) with the
    truth's since the first frame where the receiver reports it.
    """
    f = run.frames
    assert run.paths is not None
    r0 = direct_range_m(run.paths, 0, f.t_s)
    sel = (f.t_s >= t_from_s) & (f.t_s < t_to_s)
    first_err = np.abs(f.first_path_range_change_m - (r0 - r0[0]))[sel]
    first_err = np.where(np.isfinite(first_err), first_err, np.inf)
    si_err = np.abs(f.range_change_m - (r0 - r0[0]))[sel]
    diff_p95 = diff_max = np.nan
    reported = np.flatnonzero(np.isfinite(f.range_difference_change_1_m))
    if len(reported) and np.any(run.paths.tower_id == 1):
        true_diff = direct_range_m(run.paths, 1, f.t_s) - r0
        ref = reported[0]
        err = np.abs(f.range_difference_change_1_m - (true_diff - true_diff[ref]))[sel & (np.arange(len(f)) >= ref)]
        err = np.where(np.isfinite(err), err, np.inf)
        diff_p95, diff_max = float(np.percentile(err, 95)), float(np.max(err))
    return PathAccuracy(float(np.percentile(first_err, 95)), float(np.max(first_err)),
                        float(np.percentile(si_err, 95)), diff_p95, diff_max,
                        float(np.mean(f.first_path_id[sel] >= 0)), int(sel.sum()), float(t_to_s - t_from_s))


def segment_config(scn: Scenario, start_s: float, truth: FrameTruth | None = None) -> ReceiverConfig:
    """Receiver settings for a segment from ``start_s``: the f_s window is the standstill but its last 0.5 s.

    A segment that starts after the standstill has no static window: it is
    given the true f_s (the clock offset of its first second, plus the
    tuner's offset), and says so.
    """
    still = scn.walk.start_still_s - start_s
    if still > 1.0:
        return ReceiverConfig(static_window_s=still - 0.5)
    if truth is None:
        raise ValueError("a segment after the standstill needs the truth for its f_s")
    first = truth.t_s < truth.t_s[0] + 1.0
    return ReceiverConfig(clock_offset_hz=float(np.mean(truth.clock_offset_hz[first])) + scn.receiver.bulk_cfo_hz)


def report(run: CaptureRun, label: str, t_from_s: float, t_to_s: float) -> None:
    """Print the SI-carrier and the path figures of a run."""
    print(f"{label}: {accuracy(run, t_from_s, t_to_s)}", flush=True)
    print(f"{label}: {path_accuracy(run, t_from_s, t_to_s)}; receiver at {1 / run.seconds_per_second:.1f}x real "
          "time incl. simulation wait", flush=True)


#: The 60 s cases of :func:`short_cases`: scenario, receiver overrides and label.
SHORT_CASES = (("park-loop-cw", {}, "park-loop, GNSS-disciplined clock"),
               ("park-loop-cw", {"clock": {"preset": "free-running"}}, "park-loop, free-running clock"),
               ("street-out", {}, "street (out), GNSS-disciplined clock"),
               ("sfn-park", {}, "sfn-park, free-running clock"))
#: Seconds of walking the 60 s cases score, after the scenario's standstill.
SHORT_WALK_S = 60.0
#: Whole walks of :func:`walk_cases` (the scenario files' own walk and seed).
WALK_CASES = ("park-loop-cw", "sfn-park", "street-out", "street-back")


def short_cases() -> Iterator[tuple[str, Accuracy, PathAccuracy]]:
    """Each 60 s case (:data:`SHORT_CASES`): its label, SI-carrier and path scores over the walking minute."""
    for name, overrides, label in SHORT_CASES:
        scn = load_scenario(name)
        still = scn.walk.start_still_s
        run = run_capture(scn, start_s=0.0, seconds=still + SHORT_WALK_S, config=segment_config(scn, 0.0),
                          **overrides)
        yield label, accuracy(run, still, still + SHORT_WALK_S), path_accuracy(run, still, still + SHORT_WALK_S)


def narrowband_cases() -> Iterator[tuple[float, Accuracy]]:
    """park-loop recorded at each narrowband rate (:data:`NARROWBAND_RATES_HZ`), Hz, and its scores."""
    for rate in NARROWBAND_RATES_HZ:
        scn = load_scenario("park-loop-cw")
        still = scn.walk.start_still_s
        run = run_capture(scn, start_s=0.0, seconds=still + NARROWBAND_WALK_S, config=segment_config(scn, 0.0),
                          sample_rate_hz=rate)
        yield rate, accuracy(run, still, still + NARROWBAND_WALK_S)


def walk_case(name: str) -> tuple[Scenario, PathAccuracy]:
    """A scenario file's whole walk through the receiver, path figures scored from the end of its standstill."""
    scn = load_scenario(name)
    run = run_capture(scn, start_s=0.0, seconds=None, config=segment_config(scn, 0.0))
    return scn, path_accuracy(run, scn.walk.start_still_s, float(run.frames.t_s[-1]) + 1e-9)


def main(argv: list[str] | None = None) -> None:
    """Print the brief's 60 s figures, or a whole walk's (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--walk", help="score this scenario's whole walk (name or .toml)")
    parser.add_argument("--start", type=float, default=0.0, help="segment start, s (with --walk)")
    parser.add_argument("--seconds", type=float, help="segment length, s (with --walk; default: to the end)")
    parser.add_argument("--capture", type=Path, help="score a capture written by dtmbnav simulate into this folder")
    parser.add_argument("--narrowband", action="store_true", help="park-loop recorded at the narrowband rates")
    parser.add_argument("--doppler-check", action="store_true",
                        help="with --walk: the path tracker's first-path Doppler check on (docs/paths.md)")
    parser.add_argument("--clock-path", choices=CLOCK_PATHS, default=DEFAULT_CLOCK_PATH,
                        help="with --walk: the path on which the first path's f_s is measured (docs/paths.md)")
    parser.add_argument("--mc-walk", type=int, metavar="K",
                        help="with --walk: the walk dtmbnav evaluate runs as Monte Carlo index K (its seed and layout)")
    args = parser.parse_args(argv)
    if args.narrowband:
        for rate, acc in narrowband_cases():
            print(f"park-loop at {rate / 1e6:g} Msps, GNSS-disciplined clock: {acc}", flush=True)
        return
    if args.capture is not None:
        run = run_simulated_capture(args.capture)
        still = run.scenario.walk.start_still_s - run.start_s
        f_s = "true f_s" if run.receiver.config.clock_offset_hz is not None else "f_s from the standstill"
        report(run, f"{run.scenario.name} capture from {run.start_s:g} s ({f_s})", max(still, 0.0),
               float(run.frames.t_s[-1]) + 1e-9)
        return
    if args.walk is not None:
        scn = load_scenario(args.walk)
        if args.mc_walk is not None:
            scn = seed_scenario(scn, args.mc_walk, first_seed=0)
        walk_truth = None
        if scn.walk.start_still_s - args.start <= 1.0:
            walk = simulate_walk(scn)
            walk_truth = CaptureGenerator(scn, walk.track, start_s=args.start, seconds=1.0).frame_truth()
        config = segment_config(scn, args.start, walk_truth)
        if args.doppler_check:
            config = replace(config, paths=replace(config.paths, doppler=DopplerConfig(frames=CHECK_FRAMES)))
        config = replace(config, paths=replace(config.paths, clock_path=args.clock_path))
        run = run_capture(scn, start_s=args.start, seconds=args.seconds, config=config)
        still = scn.walk.start_still_s - args.start
        walk = "" if args.mc_walk is None else f" (Monte Carlo walk {args.mc_walk})"
        report(run, f"{scn.name}{walk} from {args.start:g} s", max(still, 0.0), float(run.frames.t_s[-1]) + 1e-9)
        print(f"first-path f_s {run.receiver.first_path_ranging.clock_offset_hz:+.4f} Hz, measured on the "
              f"{args.clock_path} path (true {true_clock_offset_hz(run):+.4f} Hz)", flush=True)
        return
    for label, acc, paths in short_cases():
        print(f"{label}: {acc}", flush=True)
        print(f"{label}: {paths}", flush=True)

if __name__ == "__main__":
    main()
