"""``dtmbnav results``: every result table, kept as data in docs/results.json and rendered into docs/results.md: its
options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_NO_RESULT, EXIT_OK, UsageError
from dtmbnav.cli.paths import IoPaths, given_paths
from dtmbnav.evaluation.seeds import REPORTING_SEEDS


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav results`` and its options."""
    from dtmbnav.evaluation.seeds import CHECK_SEEDS, IQ_SEEDS, OBS_SEEDS
    from dtmbnav.evaluation.seeds import RESULT_SECTIONS as SECTIONS

    p = options.command_parser(subparsers, common, "results",
                               "every result table, kept as data and rendered into one Markdown file")
    p.add_argument("-o", "--output", type=Path, default=Path("docs/results.md"),
                   help="the results file (default docs/results.md), rendered from the data file; sections not run "
                        "are kept as they are")
    p.add_argument("--data", type=Path, metavar="FILE",
                   help="the results data the Markdown file is rendered from (default: the output's name with "
                        ".json, docs/results.json)")
    p.add_argument("--sections", type=options.filter_list(SECTIONS, "section"), default=SECTIONS,
                   help=f"comma-separated sections to run (default: all, {','.join(SECTIONS)})")
    p.add_argument("--iq-seeds", type=options.positive_int, default=IQ_SEEDS,
                   help=f"Monte Carlo walks per scenario at the IQ level (default {IQ_SEEDS})")
    p.add_argument("--obs-seeds", type=options.positive_int, default=OBS_SEEDS,
                   help=f"Monte Carlo walks per scenario at the observation and exact levels (default {OBS_SEEDS})")
    p.add_argument("--first-seed", type=options.index, default=REPORTING_SEEDS.start, metavar="N",
                   help=f"first Monte Carlo index (default {REPORTING_SEEDS.start}, the reporting range)")
    p.add_argument("--step-data", type=Path, metavar="DIR",
                   help="a checkout of the Oxford step counter data set, for the steps section "
                        "(git clone https://github.com/Oxford-step-counter/DataSet)")
    p.add_argument("--readme", type=Path, metavar="FILE",
                   help="also rewrite the headline table between this README's results markers")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--status", action="store_true",
                      help="write nothing: say for each printed section whether the files it ran are unchanged "
                           "(up to date), which changed (out of date), or that this cannot be told (unknown)")
    mode.add_argument("--check", action="store_true",
                      help="write nothing: print --status, then run the first walks of each printed section again "
                           "(the walks its data names; --first-seed, --iq-seeds and --obs-seeds do not apply) and "
                           "compare with its figures; exit 1 on a regression beyond the walks' spread "
                           "(docs/evaluation.md)")
    p.add_argument("--check-seeds", type=options.positive_int, default=CHECK_SEEDS, metavar="N",
                   help=f"with --check: walks of each scenario run again (default {CHECK_SEEDS})")
    options.add_cluster_options(p)
    p.set_defaults(handler=run, io_paths=io_paths)


def _data_file(args: argparse.Namespace) -> Path:
    from dtmbnav.evaluation.results_data import data_path

    return args.data or data_path(args.output)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav results``; its exit code."""
    from dtmbnav.evaluation.results import ResultsConfig, write_results

    if (args.check or args.status) and args.readme is not None:
        raise UsageError(f"--{'check' if args.check else 'status'} writes nothing, so it cannot rewrite --readme")
    if args.status:
        from dtmbnav.evaluation.results_data import ResultsData
        from dtmbnav.evaluation.results_status import statuses

        for status in statuses(ResultsData.load(_data_file(args)), args.sections):
            print(status.line())
        return EXIT_OK
    if "steps" in args.sections and args.step_data is None and not args.check:
        raise UsageError("the steps section needs --step-data DIR, a checkout of the Oxford step counter data set "
                         "(git clone https://github.com/Oxford-step-counter/DataSet), or leave it out of --sections")
    config = ResultsConfig(iq_seeds=args.iq_seeds, obs_seeds=args.obs_seeds, first_seed=args.first_seed,
                           cluster=options.cluster_config(args), progress=not args.quiet, step_data=args.step_data)
    if args.check:
        from dtmbnav.evaluation.results_check import check_results

        report = check_results(_data_file(args), args.sections, args.check_seeds, config)
        print("\n".join(status.line() for status in report.statuses) + "\n")
        print(report.table())
        for note in report.notes:
            print(f"dtmbnav results: {note}", file=sys.stderr)
        print(f"dtmbnav {report.summary()}", file=sys.stderr)
        return EXIT_NO_RESULT if report.failed else EXIT_OK
    write_results(args.output, args.sections, config, readme=args.readme, data_file=args.data)
    print(f"results written to {args.output} (data: {_data_file(args)})", file=sys.stderr)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths(files=[("-o", args.output), ("--data", args.data), ("--readme", args.readme)])
