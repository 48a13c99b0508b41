"""``dtmbnav evaluate``: Monte Carlo accuracy table of every filter against truth: its options and its handler."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_NO_RESULT, EXIT_OK, UsageError
from dtmbnav.cli.paths import IoPaths, given_paths
from dtmbnav.evaluation.seeds import LEVELS, REPORTING_SEEDS, TUNING_SEEDS
from dtmbnav_core.constants import TRANSMIT_DELAY_KNOWLEDGE
from fusion import DEFAULT_PARTICLES, FILTER_NAMES, FOOT_INS


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav evaluate`` and its options."""
    p = options.command_parser(subparsers, common, "evaluate",
                               "Monte Carlo accuracy table of every filter against truth")
    p.add_argument("scenarios", nargs="+", help="scenario names/files; 'all', 'park-loop', 'street' = groups")
    p.add_argument("--seeds", type=options.positive_int, default=20, help="walks per scenario (default 20)")
    p.add_argument("--filters", type=options.filter_list((*FILTER_NAMES, FOOT_INS)), default=FILTER_NAMES,
                   help=f"{options.FILTERS_HELP}; {FOOT_INS} adds the foot-mounted ZUPT INS")
    p.add_argument("--particles", type=options.positive_int, help=f"particle-filter Np (default {DEFAULT_PARTICLES})")
    p.add_argument("--filter-seed", type=options.seed, default=0,
                   help="particle-filter seed (default 0): other seeds show the filter's own Monte Carlo spread")
    options.add_range_use_options(p)
    options.add_settings_option(p)
    p.add_argument("--json", metavar="FILE", help="also write the table as JSON ('-' for stdout)")
    p.add_argument("--walks", metavar="FILE",
                   help="also write each walk's figures as a JSON line when it finishes (a stopped run keeps them)")
    p.add_argument("--pdr", action="store_true", help="only the PDR figures (steps, step length, drift, error)")
    p.add_argument("--first-seed", type=options.index, default=REPORTING_SEEDS.start, metavar="N",
                   help=f"first Monte Carlo index (default {REPORTING_SEEDS.start}: the reporting range "
                        f"{REPORTING_SEEDS.start}-{REPORTING_SEEDS[-1]}; tuning range "
                        f"{TUNING_SEEDS.start}-{TUNING_SEEDS[-1]})")
    p.add_argument("--level", choices=LEVELS, default="obs",
                   help="range from the observation-level model (obs, default), the IQ transmitter, channel "
                        "and receiver (iq), or the direct path's exact range change (exact: the filters' bound "
                        "with a perfect receiver)")
    p.add_argument("--vary-geometry", action=argparse.BooleanOptionalAction, default=True,
                   help="each walk gets its own scene orientation and tower bearing and distance (default on)")
    p.add_argument("--transmit-delays", choices=TRANSMIT_DELAY_KNOWLEDGE, default=None,
                   help="what the fusion is given of an SFN's transmit delay offsets: unknown (estimated at the "
                        "start fix), plan (the network plan's, its error as sigma) or exact (the walk's true "
                        "ones); default: the scenario's [network] known")
    options.add_cluster_options(p)
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav evaluate``; its exit code."""
    from dtmbnav.evaluation import evaluate
    from dtmbnav_core.h5io import atomic_path

    scenarios = evaluate.expand_scenarios(args.scenarios)
    for name in scenarios:
        problem = options.unknown_scenario(name)
        if problem:
            raise UsageError(f"SCENARIO: {problem} (or a group: {', '.join(evaluate.GROUPS)})")
    if args.pdr:
        from dtmbnav.evaluation.pdr_table import pdr_table

        print(pdr_table(scenarios))
        return EXIT_OK
    config = options.fusion_config(args, seed=args.filter_seed)
    with contextlib.ExitStack() as stack:
        on_walk = None
        if args.walks:
            # One line per walk as it finishes, flushed: a run that is stopped keeps every finished walk.
            walks = stack.enter_context(open(args.walks, "w", encoding="utf-8"))

            def on_walk(record: dict) -> None:
                walks.write(json.dumps(record) + "\n")
                walks.flush()
        outcome = evaluate.evaluate_many(scenarios, args.seeds, args.filters, level=args.level, config=config,
                                         first_seed=args.first_seed, vary_geometry=args.vary_geometry,
                                         cluster=options.cluster_config(args), progress=not args.quiet, on_walk=on_walk,
                                         transmit_delays=args.transmit_delays)
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
            with atomic_path(args.json) as tmp:
                tmp.write_text(evaluate.rows_to_json(rows))
    return EXIT_NO_RESULT if outcome.failures else EXIT_OK


def _rerun_walk(args: argparse.Namespace, failure) -> str:
    """The command that runs one failed Monte Carlo walk alone, in this process."""
    options = [f"--seeds 1 --first-seed {failure.first_seed + failure.k}", f"--level {args.level}",
               f"--filters {','.join(args.filters)}", "--workers 0"]
    if args.particles is not None:
        options.append(f"--particles {args.particles}")
    if args.filter_seed:
        options.append(f"--filter-seed {args.filter_seed}")
    if not args.vary_geometry:
        options.append("--no-vary-geometry")
    if args.transmit_delays is not None:
        options.append(f"--transmit-delays {args.transmit_delays}")
    options += [f"--set {name}={value}" for name, value in args.set]
    return f"dtmbnav evaluate {failure.argument} {' '.join(options)}"


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("SCENARIO", name) for name in args.scenarios],
                       [("--json", args.json), ("--walks", args.walks)])
