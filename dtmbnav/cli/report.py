"""``dtmbnav report``: plots, a summary table and map files from a results file: its options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav report`` and its options."""
    p = options.command_parser(subparsers, common, "report", "plots and a summary table from a results file")
    p.add_argument("results", help="HDF5 file from run/fuse")
    p.add_argument("-o", "--output", required=True, type=Path, help="report folder")
    p.add_argument("--truth", help="truth.h5 (default: the truth group inside the results file)")
    p.add_argument("--origin", type=options.geodetic, metavar="LAT,LON[,H]",
                   help="place the results' ENU frame on WGS84 for the map files (tracks.geojson, tracks.gpx, "
                        "map.html): its origin, deg, and height above the ellipsoid, m (default 0); default: the "
                        "origin the results file holds (fused from a 'dtmbnav sensors' file), else no map files")
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav report``; its exit code."""
    from dtmbnav.chain.report import write_report_folder

    folder = write_report_folder(args.results, args.output, truth_path=args.truth, origin=args.origin)
    print(f"report written to {folder}", file=sys.stderr)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("RESULTS", args.results), ("--truth", args.truth)], folders=[("-o", args.output)])
