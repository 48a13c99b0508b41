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
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/pdr)")
    p.add_argument("--csv", metavar="FILE", help="also write the steps as CSV ('-' for stdout)")
    options.add_pdr_options(p)
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav pdr``; its exit code."""
    from dtmbnav.chain.pdr import run_pdr_file

    options.say_pdr_choices(args)
    result = run_pdr_file(args.sensors, args.output, options.pdr_config(args), csv_path=args.csv)
    for note in result.notes:
        options.warn(args, f"{args.sensors}: {note}")
    print(f"pdr: {len(result.steps)} steps, {result.steps.step_length_m.sum():.1f} m walked -> {args.output}",
          file=sys.stderr)
    return EXIT_OK if len(result.steps) else EXIT_NO_RESULT


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("SENSORS", args.sensors)], [("-o", args.output), ("--csv", args.csv)])
