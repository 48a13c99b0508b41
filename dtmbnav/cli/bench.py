"""``dtmbnav bench``: throughput of every kernel next to its plain-numpy reference: its options and its handler."""

from __future__ import annotations

import argparse

from dtmbnav.cli import options
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav bench`` and its options."""
    p = options.command_parser(subparsers, common, "bench",
                               "throughput of every kernel next to its plain-numpy reference")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON ('-' for stdout)")
    p.add_argument("--quick", action="store_true", help="short runs (smoke test)")
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav bench``; its exit code."""
    from dtmbnav.evaluation.bench import run_benchmarks
    from dtmbnav_core.h5io import atomic_path

    if args.json in (None, "-"):
        return run_benchmarks(json_path=args.json, quick=args.quick)
    with atomic_path(args.json) as tmp:
        return run_benchmarks(json_path=str(tmp), quick=args.quick)


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths(files=[("--json", args.json)])
