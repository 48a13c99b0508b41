"""``dtmbnav demo``: the whole method on a simulated walk, end to end: its options and its handler."""

from __future__ import annotations

import argparse
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav demo`` and its options."""
    p = options.command_parser(subparsers, common, "demo",
                               "simulate a walk at IQ level, receive, fuse and write a report")
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    p.add_argument("--scenario", type=options.scenario, default="park-loop", help="scenario (default park-loop)")
    p.add_argument("--seconds", type=options.positive, help="simulate only this many seconds (default: the whole walk)")
    p.add_argument("--jobs", type=options.positive_int, metavar="N",
                   help="threads generating the IQ while the receiver runs (default: one per CPU core)")
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav demo``; its exit code."""
    from dtmbnav.simulation.demo import run_demo

    run_demo(args.output, scenario=args.scenario, seconds=args.seconds, progress=not args.quiet, jobs=args.jobs)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths(folders=[("-o", args.output)])
