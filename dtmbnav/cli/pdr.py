"""``dtmbnav pdr``: IMU log -> pedestrian dead reckoning: its options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_NO_RESULT, EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav pdr`` and its options."""
    p = options.command_parser(subparsers, common, "pdr", "IMU log (/imu of an HDF5 file) -> pedestrian dead reckoning")
    p.add_argument("sensors", help="HDF5 file with /imu (e.g. truth.h5 from simulate)")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output HDF5 file (/pdr); with --calibrate, the walker profile (.toml) to write")
    p.add_argument("--csv", metavar="FILE", help="also write the steps as CSV ('-' for stdout)")
    p.add_argument("--calibrate", action="store_true",
                   help="fit the walker's Weinberg gain to a walk of a measured length (--distance) and write it "
                        "as a walker profile for --walker; every step of the log counts")
    p.add_argument("--distance", type=options.positive, metavar="M",
                   help="with --calibrate: the length of the walk in the log, m (e.g. measured along a corridor)")
    options.add_pdr_options(p)
    p.set_defaults(handler=run, io_paths=io_paths, usage_problem=usage_problem)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav pdr``; its exit code."""
    from dtmbnav.chain.pdr import calibrate_walker, run_pdr_file

    if args.calibrate:
        profile, result = calibrate_walker(args.sensors, args.distance, args.output, options.pdr_config(args))
        print(f"pdr: {profile.steps} steps over {profile.distance_m:g} m: Weinberg gain K = "
              f"{profile.weinberg_k_m:.4f} m (steps add up to {result.steps.step_length_m.sum():.2f} m) -> "
              f"{args.output}", file=sys.stderr)
        return EXIT_OK
    options.say_pdr_choices(args)
    result = run_pdr_file(args.sensors, args.output, options.pdr_config(args), csv_path=args.csv)
    for note in result.notes:
        options.warn(args, f"{args.sensors}: {note}")
    print(f"pdr: {len(result.steps)} steps, {result.steps.step_length_m.sum():.1f} m walked -> {args.output}",
          file=sys.stderr)
    if len(result.steps):
        from fusion.pdr.pipeline import CARRIAGE_CLASSES

        changes = f"; {result.carriage_changes} change(s) of carriage" if result.carriage_changes else ""
        print(f"pdr: the phone was {CARRIAGE_CLASSES[result.carriage]}{changes}", file=sys.stderr)
    return EXIT_OK if len(result.steps) else EXIT_NO_RESULT


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("SENSORS", args.sensors), ("--walker", args.walker)],
                       [("-o", args.output), ("--csv", args.csv)])


def usage_problem(args: argparse.Namespace) -> str | None:
    """Option combinations argparse cannot see; None when fine."""
    if not args.calibrate:
        return "--distance goes with --calibrate" if args.distance is not None else None
    if args.distance is None:
        return "--calibrate needs --distance M, the walk's measured length"
    given = [option for option, value in (("--csv", args.csv), ("--weinberg-k", args.weinberg_k),
                                          ("--walker", args.walker)) if value is not None]
    if given or args.step_model != "weinberg":
        return f"--calibrate fits the Weinberg gain: drop {' and '.join(given) or '--step-model'}"
    if args.output.suffix.lower() != ".toml":
        return f"-o {args.output}: --calibrate writes a walker profile: name it *.toml"
    return None
