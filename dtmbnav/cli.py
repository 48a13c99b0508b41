"""The ``dtmbnav`` command line: one entry point, one subcommand per job.

Exit codes
----------
0  success
1  the job ran but found nothing usable (e.g. no DTMB lock in a capture)
2  bad command-line usage (argparse)
3  bad input: a file that is missing, truncated, malformed or inconsistent

Diagnostics go to stderr; ``-`` means stdin/stdout where a stream makes sense.
Heavy imports (numba kernels) happen inside the handlers so that ``--help``
stays instant. This module is the only one that knows the command line's
option names: it turns them into the libraries' typed configs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.seeds import LEVELS, REPORTING_SEEDS, TUNING_SEEDS
from fusion import DEFAULT_PARTICLES, FILTER_NAMES, FOOT_INS
from receiver import DEFAULT_STATIC_WINDOW_S

EXIT_OK = 0
EXIT_NO_RESULT = 1
EXIT_USAGE = 2
EXIT_BAD_INPUT = 3

EXAMPLES = """\
examples:
  dtmbnav demo                                   # simulate park-loop, receive, fuse, report
  dtmbnav simulate park-loop --seconds 5 -o out/ # 5 s SigMF capture + truth.h5
  dtmbnav simulate street-back --no-iq -o out/   # IMU, GNSS and truth only
  dtmbnav receive out/park-loop-cw.sigmf-meta -o out/rx.h5
  dtmbnav receive cap.ci8 --format ci8 --rate 10e6 --center 666e6 -o rx.h5
  rtl_sdr ... | dtmbnav receive - --format cu8 --rate 2.4e6 --center 666e6 -o rx.h5
  dtmbnav pdr out/truth.h5 -o out/pdr.h5
  dtmbnav fuse --receiver out/rx.h5 --sensors out/truth.h5 -o out/fused.h5
  dtmbnav run captures/                          # the whole chain on the bundled capture set
  dtmbnav report out/results.h5 -o out/report
  dtmbnav evaluate park-loop --seeds 20 --json table.json
  dtmbnav evaluate all --level iq --seeds 10      # IQ-level Monte Carlo on a local Dask cluster
  dtmbnav bench --json bench.json
"""


def _xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    return x, y


def _filter_list(known: tuple[str, ...]):
    """An argparse type: comma-separated names, each one of ``known``."""
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(name for name in text.split(",") if name)
        unknown = [name for name in names if name not in known]
        if unknown or not names:
            raise argparse.ArgumentTypeError(f"unknown filter(s) {unknown or [text]}; choose from {','.join(known)}")
        return names
    return parse


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def _index(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be at least 0, got {text!r}")
    return value


def _rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


# --- handlers ---------------------------------------------------------------------------

def cmd_simulate(args: argparse.Namespace) -> int:
    from dtmbnav.simulation import simulate_capture_set
    from sim.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    result = simulate_capture_set(scenario, args.output, seconds=args.seconds, start_s=args.start,
                                  sample_rate_hz=args.rate, sample_format=args.format, pn_mode=args.pn_mode,
                                  seed=args.seed, container=args.container, with_iq=not args.no_iq,
                                  progress=not args.quiet)
    if result.capture_path is not None:
        print(f"capture: {result.capture_path}", file=sys.stderr)
    print(f"truth:   {result.truth_path}", file=sys.stderr)
    return EXIT_OK


def _receiver_config(args: argparse.Namespace):
    from receiver.pipeline import ReceiverConfig

    return ReceiverConfig(pn_mode=args.pn_mode, static_window_s=args.static_window,
                          clock_offset_hz=args.clock_offset, conjugate_iq=args.conjugate)


def _pdr_config(args: argparse.Namespace):
    from fusion.pdr import PdrConfig

    return PdrConfig(step_model=args.step_model, weinberg_k_m=args.weinberg_k)


def cmd_receive(args: argparse.Namespace) -> int:
    from dtmbnav.chain import receive_capture
    from receiver.capture import open_capture

    source = open_capture(args.capture, sample_format=args.format, sample_rate_hz=args.rate,
                          center_hz=args.center)
    summary = receive_capture(source, args.output, _receiver_config(args), csv_path=args.csv,
                              progress=not args.quiet)
    print(summary.describe(), file=sys.stderr)
    return EXIT_OK if summary.frames else EXIT_NO_RESULT


def cmd_pdr(args: argparse.Namespace) -> int:
    from dtmbnav.chain import run_pdr_file

    result = run_pdr_file(args.sensors, args.output, _pdr_config(args), csv_path=args.csv)
    print(f"pdr: {len(result.steps)} steps, {result.steps.step_length_m.sum():.1f} m walked -> {args.output}",
          file=sys.stderr)
    return EXIT_OK if len(result.steps) else EXIT_NO_RESULT


def cmd_fuse(args: argparse.Namespace) -> int:
    from dtmbnav.chain import fuse_files

    result = fuse_files(args.receiver, args.sensors, args.output, filters=args.filters,
                        pdr_config=_pdr_config(args), tower_xy_m=args.tower, start_xy_m=args.start,
                        n_particles=args.particles, seed=args.seed)
    print(f"initial heading {result.heading.describe()}", file=sys.stderr)
    print(f"fused {', '.join(result.tracks)} -> {args.output}", file=sys.stderr)
    return EXIT_OK


def cmd_run(args: argparse.Namespace) -> int:
    from dtmbnav.chain import run_directory
    from dtmbnav.distributed import Task, run_tasks

    folders = args.directory or [Path("captures")]
    if len(folders) == 1 and args.scheduler is None and args.workers is None:
        outcome = run_directory(folders[0], args.output, filters=args.filters, progress=not args.quiet)
        print(outcome.summary, file=sys.stderr if args.json else sys.stdout)
        return EXIT_OK
    outputs = [args.output / folder.resolve().name for folder in folders]
    if len(set(outputs)) < len(outputs):
        raise ValueError("run: capture-set folders must have different names (each gets OUTPUT/NAME)")
    cluster = _cluster(args)
    tasks = [Task(str(folder), run_directory, (folder, out, args.filters, False))
             for folder, out in zip(folders, outputs)]
    outcome = run_tasks(tasks, cluster, progress=not args.quiet, description="run")
    for result in outcome.results:
        if result is not None:
            print(result.summary, file=sys.stderr if args.json else sys.stdout)
    for f in outcome.failures:
        print(f"dtmbnav run: {f.label} failed: {f.error}\n  re-run it alone: dtmbnav run {f.label} -o "
              f"{outputs[f.index]}", file=sys.stderr)
    return EXIT_NO_RESULT if outcome.failures else EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from dtmbnav.report import write_report

    folder = write_report(args.results, args.output, truth_path=args.truth)
    print(f"report written to {folder}", file=sys.stderr)
    return EXIT_OK


def _cluster(args: argparse.Namespace):
    from dtmbnav.distributed import ClusterConfig

    return ClusterConfig(workers=args.workers, scheduler=args.scheduler)


def _rerun_walk(args: argparse.Namespace, failure) -> str:
    """The command that runs one failed Monte Carlo walk alone, in this process."""
    options = [f"--seeds 1 --first-seed {failure.first_seed + failure.k}", f"--level {args.level}",
               f"--filters {','.join(args.filters)}", "--workers 0"]
    if args.particles is not None:
        options.append(f"--particles {args.particles}")
    if not args.vary_geometry:
        options.append("--no-vary-geometry")
    return f"dtmbnav evaluate {failure.argument} {' '.join(options)}"


def cmd_evaluate(args: argparse.Namespace) -> int:
    from dtmbnav import evaluate
    from fusion.run import FusionConfig

    scenarios = evaluate.expand_scenarios(args.scenarios)
    if args.pdr:
        from dtmbnav.pdr_table import pdr_table

        print(pdr_table(scenarios))
        return EXIT_OK
    config = FusionConfig() if args.particles is None else FusionConfig(n_particles=args.particles)
    outcome = evaluate.evaluate_many(scenarios, args.seeds, args.filters, level=args.level, config=config,
                                     first_seed=args.first_seed, vary_geometry=args.vary_geometry,
                                     cluster=_cluster(args), progress=not args.quiet)
    for f in outcome.failures:
        print(f"dtmbnav evaluate: {f.scenario} walk k={f.k} (seed {f.seed}) failed: {f.error}\n"
              f"  re-run it alone: {_rerun_walk(args, f)}", file=sys.stderr)
    rows = outcome.rows
    table = evaluate.format_table(rows)
    if args.json == "-":
        print(evaluate.rows_to_json(rows))
        print(table, file=sys.stderr)
    else:
        print(table)
        if args.json:
            Path(args.json).write_text(evaluate.rows_to_json(rows))
    return EXIT_NO_RESULT if outcome.failures else EXIT_OK


def cmd_bench(args: argparse.Namespace) -> int:
    from dtmbnav.bench import run_benchmarks

    return run_benchmarks(json_path=args.json, quick=args.quick)


def cmd_demo(args: argparse.Namespace) -> int:
    from dtmbnav.demo import run_demo

    run_demo(args.output, scenario=args.scenario, seconds=args.seconds, progress=not args.quiet)
    return EXIT_OK


FILTERS_HELP = f"comma-separated filters (default: all, {','.join(FILTER_NAMES)})"


# --- parser -------------------------------------------------------------------------------

def _add_receiver_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("receiver")
    g.add_argument("--pn-mode", choices=["PN420", "PN595", "PN945"], help="header mode (default: detect)")
    g.add_argument("--static-window", type=float, default=DEFAULT_STATIC_WINDOW_S, metavar="S",
                   help="seconds at the start during which the receiver stands still; f_s is measured there "
                        f"(default {DEFAULT_STATIC_WINDOW_S:g})")
    g.add_argument("--clock-offset", type=float, metavar="HZ",
                   help="oscillator offset f_s in Hz, if known (skips the static window)")
    g.add_argument("--conjugate", action="store_true", help="the front end swaps I and Q")


def _add_pdr_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("PDR")
    g.add_argument("--step-model", choices=["weinberg", "frequency"], default="weinberg",
                   help="step-length model (default weinberg)")
    g.add_argument("--weinberg-k", type=float, metavar="K",
                   help="calibrated Weinberg gain; default: read from the sensors file's calibration "
                        "attribute, else the frequency model is used")


def _add_cluster_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("Dask")
    g.add_argument("--workers", type=_index, metavar="N",
                   help="local Dask worker processes (default: one per CPU core; 0: in this process, no Dask)")
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="use an existing Dask cluster")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dtmbnav", description="DTMB (GB 20600) Doppler-ranging receiver and PDR fusion for pedestrian "
                                    "navigation.", epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("simulate", help="scenario -> IQ capture + IMU + GNSS + truth.h5")
    p.add_argument("scenario", help="park-loop, park-loop-ccw, street, street-back, or a scenario .toml file")
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--seconds", type=float, help="segment length, s (default: the whole walk)")
    p.add_argument("--start", type=float, default=0.0, help="segment start, s (default 0)")
    p.add_argument("--rate", type=_rate, help="sample rate, Hz (default: the scenario's)")
    p.add_argument("--format", choices=["cu8", "ci8", "ci16", "cf32"], help="sample format")
    p.add_argument("--pn-mode", choices=["PN420", "PN595", "PN945"], help="header mode")
    p.add_argument("--seed", type=int, help="seed (default: the scenario's)")
    p.add_argument("--container", choices=["sigmf", "raw"], default="sigmf", help="raw = raw file + JSON sidecar")
    p.add_argument("--no-iq", action="store_true", help="write IMU, GNSS and truth only")
    p.set_defaults(handler=cmd_simulate)

    p = sub.add_parser("receive", help="IQ capture -> per-frame CFO, Doppler, range (HDF5)")
    p.add_argument("capture", help="SigMF .sigmf-meta/.sigmf-data, raw file (+ .json sidecar), or - for stdin")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file")
    p.add_argument("--format", choices=["cu8", "ci8", "ci16", "cf32"], help="sample format of a raw file/stdin")
    p.add_argument("--rate", type=_rate, help="sample rate of a raw file/stdin, Hz")
    p.add_argument("--center", type=_rate, help="RF centre frequency, Hz (needed for velocity and range)")
    p.add_argument("--csv", metavar="FILE", help="also write the frame table as CSV ('-' for stdout)")
    _add_receiver_options(p)
    p.set_defaults(handler=cmd_receive)

    p = sub.add_parser("pdr", help="IMU log (/imu of an HDF5 file) -> pedestrian dead reckoning")
    p.add_argument("sensors", help="HDF5 file with /imu (e.g. truth.h5 from simulate)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/pdr)")
    p.add_argument("--csv", metavar="FILE", help="also write the steps as CSV ('-' for stdout)")
    _add_pdr_options(p)
    p.set_defaults(handler=cmd_pdr)

    p = sub.add_parser("fuse", help="receiver range + PDR -> corrected trajectory")
    p.add_argument("--receiver", required=True, help="HDF5 file with /receiver/frames")
    p.add_argument("--sensors", required=True, help="HDF5 file with /imu and /gnss (start fix)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/pdr, /fusion/<filter>)")
    p.add_argument("--filters", type=_filter_list(FILTER_NAMES), default=FILTER_NAMES, help=FILTERS_HELP)
    p.add_argument("--tower", type=_xy, metavar="X,Y", help="tower position, ENU m (default: from the sensors file)")
    p.add_argument("--start", type=_xy, metavar="X,Y", help="start fix P0, ENU m (default: from /gnss)")
    p.add_argument("--particles", type=_positive_int, help=f"particle-filter Np (default {DEFAULT_PARTICLES})")
    p.add_argument("--seed", type=int, default=0, help="particle-filter seed")
    _add_pdr_options(p)
    p.set_defaults(handler=cmd_fuse)

    p = sub.add_parser("run", help="the whole chain (receive, PDR, fuse, report) on capture sets")
    p.add_argument("directory", nargs="*", type=Path,
                   help="folders, each with one capture and its sensors/truth file (default: captures/); "
                        "several run as Dask tasks")
    p.add_argument("-o", "--output", type=Path, default=Path("out/run"),
                   help="output folder (default out/run; OUTPUT/NAME per folder when several or on Dask)")
    p.add_argument("--filters", type=_filter_list(FILTER_NAMES), default=FILTER_NAMES, help=FILTERS_HELP)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    _add_cluster_options(p)
    p.set_defaults(handler=cmd_run)

    p = sub.add_parser("report", help="plots and a summary table from a results file")
    p.add_argument("results", help="HDF5 file from run/fuse")
    p.add_argument("-o", "--output", required=True, type=Path, help="report folder")
    p.add_argument("--truth", help="truth.h5 (default: the truth group inside the results file)")
    p.set_defaults(handler=cmd_report)

    p = sub.add_parser("evaluate", help="Monte Carlo accuracy table of every filter against truth")
    p.add_argument("scenarios", nargs="+", help="scenario names/files; 'all', 'park-loop', 'street' = groups")
    p.add_argument("--seeds", type=_positive_int, default=20, help="walks per scenario (default 20)")
    p.add_argument("--filters", type=_filter_list((*FILTER_NAMES, FOOT_INS)), default=FILTER_NAMES,
                   help=f"{FILTERS_HELP}; {FOOT_INS} adds the foot-mounted ZUPT INS")
    p.add_argument("--particles", type=_positive_int, help=f"particle-filter Np (default {DEFAULT_PARTICLES})")
    p.add_argument("--json", metavar="FILE", help="also write the table as JSON ('-' for stdout)")
    p.add_argument("--pdr", action="store_true", help="only the PDR figures (steps, step length, drift, error)")
    p.add_argument("--first-seed", type=_index, default=REPORTING_SEEDS.start, metavar="N",
                   help=f"first Monte Carlo index (default {REPORTING_SEEDS.start}: the reporting range "
                        f"{REPORTING_SEEDS.start}-{REPORTING_SEEDS[-1]}; tuning range "
                        f"{TUNING_SEEDS.start}-{TUNING_SEEDS[-1]})")
    p.add_argument("--level", choices=LEVELS, default="obs",
                   help="range from the observation-level model (obs, default) or the IQ transmitter, channel "
                        "and receiver (iq)")
    p.add_argument("--vary-geometry", action=argparse.BooleanOptionalAction, default=True,
                   help="each walk gets its own scene orientation and tower bearing and distance (default on)")
    _add_cluster_options(p)
    p.set_defaults(handler=cmd_evaluate)

    p = sub.add_parser("bench", help="throughput of every kernel next to its plain-numpy reference")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON ('-' for stdout)")
    p.add_argument("--quick", action="store_true", help="short runs (smoke test)")
    p.set_defaults(handler=cmd_bench)

    p = sub.add_parser("demo", help="simulate a walk at IQ level, receive, fuse and write a report")
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    p.add_argument("--scenario", default="park-loop", help="scenario (default park-loop)")
    p.add_argument("--seconds", type=float, help="simulate only this many seconds (default: the whole walk)")
    p.set_defaults(handler=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dtmbnav`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except (ValueError, OSError) as exc:
        print(f"dtmbnav {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"dtmbnav {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
