"""``dtmbnav towers``: a network's towers file; ``towers calibrate`` surveys its transmit delay offsets on a walk."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav towers`` and its action ``calibrate``."""
    p = options.command_parser(subparsers, common, "towers",
                               "a network's towers file: survey its transmit delay offsets on a walk with GNSS")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    c = actions.add_parser(
        "calibrate", parents=[common],
        help="measure each tower's transmit delay offset (against the first) on a walk with GNSS fixes, for "
             "'fuse --towers' on later walks",
        description="Measure a single-frequency network's transmit delay offsets on a walk where GNSS works: at "
                    "each fix that states its accuracy, each tower difference's code minus the geometric "
                    "difference at the fix, weighted by the fix's accuracy; the sigma counts the fixes' errors "
                    "as correlated over tens of seconds. Writes the towers file again with transmit_delay_s and "
                    "transmit_delay_sigma_s (docs/cli.md).")
    c.set_defaults(parser=c)
    c.add_argument("receiver", help="the survey walk's receiver file (/receiver/frames and /receiver/paths)")
    c.add_argument("sensors", help="the survey walk's sensors file from 'dtmbnav sensors' (/imu, /gnss with each "
                                   "fix's accuracy)")
    c.add_argument("--towers", required=True, metavar="FILE",
                   help="the network's towers file, TOML or CSV (as 'fuse --towers' reads it)")
    c.add_argument("-o", "--output", required=True, type=Path,
                   help="the surveyed towers file to write (.csv): the input's towers, with the surveyed offsets")
    c.add_argument("--tower-name", type=options.tower_names, metavar="NAME[,NAME...]",
                   help="the towers to survey, the reference tower first (default: all of the file's on the "
                        "capture's channel, its first the reference)")
    c.add_argument("--time-offset", type=options.number, metavar="S",
                   help="where the capture starts on the IMU log's clock, s (default as 'fuse')")
    c.set_defaults(handler=run_calibrate, io_paths=io_paths, usage_problem=usage_problem)


def run_calibrate(args: argparse.Namespace) -> int:
    """Run ``dtmbnav towers calibrate``; its exit code."""
    from dtmbnav.chain.survey import survey_towers
    from dtmbnav.field.towers import write_towers_csv

    result = survey_towers(args.receiver, args.sensors, args.towers, args.tower_name, args.time_offset)
    for note in result.notes:
        options.warn(args, note)
    print(f"time alignment: {result.alignment.describe()}", file=sys.stderr)
    print(f"transmit delay offsets, against {result.names[0]}:\n{result.describe()}", file=sys.stderr)
    write_towers_csv(args.output, result.towers)
    print(f"surveyed {', '.join(result.names)} -> {args.output}", file=sys.stderr)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("RECEIVER", args.receiver), ("SENSORS", args.sensors), ("--towers", args.towers)],
                       [("-o", args.output)])


def usage_problem(args: argparse.Namespace) -> str | None:
    """Option combinations argparse cannot see; None when fine."""
    if args.output.suffix.lower() != ".csv":
        return f"-o {args.output}: the surveyed towers file is written as CSV; give a .csv path"
    return None
