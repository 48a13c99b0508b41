"""``dtmbnav run``: the whole chain on capture sets: its options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_NO_RESULT, EXIT_OK, UsageError
from dtmbnav.cli.paths import IoPaths, given_paths
from fusion import FILTER_NAMES


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav run`` and its options."""
    p = options.command_parser(subparsers, common, "run",
                               "the whole chain (receive, PDR, fuse, report) on capture sets")
    p.add_argument("directory", nargs="*", type=Path,
                   help="folders, each with one capture and its sensors/truth file (default: captures/); "
                        "several run as Dask tasks")
    p.add_argument("-o", "--output", type=Path, default=Path("out/run"),
                   help="output folder (default out/run; OUTPUT/NAME per folder when several or on Dask)")
    p.add_argument("--filters", type=options.filter_list(FILTER_NAMES), default=FILTER_NAMES, help=options.FILTERS_HELP)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    options.add_cluster_options(p)
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav run``; its exit code."""
    from dtmbnav.chain.run import run_directory
    from dtmbnav.evaluation.distributed import Task, run_tasks

    folders = args.directory or [Path("captures")]
    if len(folders) == 1 and args.scheduler is None and args.workers is None:
        outcome = run_directory(folders[0], args.output, filters=args.filters, progress=not args.quiet)
        print(outcome.summary, file=sys.stderr if args.json else sys.stdout)
        return EXIT_OK if outcome.found else EXIT_NO_RESULT
    outputs = [args.output / folder.resolve().name for folder in folders]
    if len(set(outputs)) < len(outputs):
        raise UsageError("run: capture-set folders must have different names (each gets OUTPUT/NAME)")
    cluster = options.cluster_config(args)
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


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths(folders=[("-o", args.output)])
