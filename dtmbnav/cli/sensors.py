"""``dtmbnav sensors``: a phone's own log -> sensors file: its options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths
from dtmbnav.field.platform import PLATFORMS


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav sensors`` and its options."""
    p = options.command_parser(subparsers, common, "sensors",
                               "a phone's own log (GnssLogger, Sensor Logger) -> sensors file "
                               "(/imu, /gnss)")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="a GnssLogger text log, or a Sensor Logger export (its folder, zip, or CSV files)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/imu, /gnss)")
    p.add_argument("--rate", type=options.positive, default=100.0, help="rate of the resampled /imu, Hz (default 100)")
    p.add_argument("--origin", type=options.geodetic, metavar="LAT,LON[,H]",
                   help="origin of the ENU frame, WGS84 deg and m above the ellipsoid (default: the first fix; "
                        "without H, the first fix's height)")
    p.add_argument("--platform", choices=PLATFORMS,
                   help="the phone a Sensor Logger export comes from, for the acceleration's sign (iOS logs the "
                        "opposite of Android's unless \"Standardise Units & Frames\" is on: then give android); "
                        "default: Metadata.csv's, else TotalAcceleration.csv means android, else told from the "
                        "Earth's field's dip against gravity where that is unambiguous. Must agree with Metadata.csv")
    p.add_argument("--start-window", type=options.non_negative, metavar="S",
                   help="make the start fix of the fixes of the standstill's last S seconds only (up to its last fix "
                        "before the walk; 0: that fix alone); default: every fix of the standstill, from the motion "
                        "sensors' first sample to the walk's start")
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav sensors``; its exit code."""
    from dtmbnav.field.sensors_import import describe, gap_warnings, import_phone_log

    result = import_phone_log(args.logs, args.output, rate_hz=args.rate, origin=args.origin,
                              platform=args.platform, start_window_s=args.start_window)
    for line in describe(result):
        print(f"sensors: {line}", file=sys.stderr)
    for message in [*gap_warnings(result), *result.notes]:
        options.warn(args, message)
    print(f"sensors: -> {args.output}", file=sys.stderr)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("LOG", log) for log in args.logs], [("-o", args.output)])
