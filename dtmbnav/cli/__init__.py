"""The ``dtmbnav`` command line: one entry point, one subcommand per job.

Exit codes
----------
0    success
1    the job ran but found nothing usable (e.g. no DTMB lock in a capture),
     or a check it ran failed (``results --check``: a regression)
2    bad command-line usage, found before any work: an invalid option value,
     a missing option, an output path that names an input
3    bad input: a file that is missing, truncated, malformed or inconsistent
     (or of another walk), or an output location that cannot be written
4    internal error: a bug; one line on stderr, the traceback with ``--debug``
130  interrupted by SIGINT (Ctrl-C); 143: by SIGTERM

On every failure nothing is left at the output path, with one exception:
``receive`` keeps the frames received before an interruption or before a
stream (stdin) broke, in a complete file whose ``/receiver/frames``
attribute ``ended_early`` says why (exit 130/143, or 3 for a broken stream;
a stream that ends inside an IQ pair is its end: a warning, exit 0).

Diagnostics go to stderr; ``-`` means stdin/stdout where a stream makes sense.
Global options (``-q``, ``--debug``) go before or after the subcommand. Heavy
imports (numba kernels) happen inside the handlers so that ``--help`` stays
instant, and after :func:`dtmbnav.cli.numba_cache.configure_numba_cache` has
given numba a writable cache.

Each subcommand is a module of this package with its parser (``add_parser``),
its handler (``run``) and its files (``io_paths``); :mod:`dtmbnav.cli.options`
holds what several share. This package is the only one that knows the command
line's option names: it turns them into the libraries' typed configs.
"""

from __future__ import annotations

import argparse
import re
import sys
import traceback

from dtmbnav.chain.errors import NoResult
from dtmbnav.cli import (
    bench,
    demo,
    doppler_map,
    evaluate,
    fuse,
    live,
    pdr,
    receive,
    report,
    results,
    run,
    sensors,
    simulate,
    towers,
)
from dtmbnav.cli.exits import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_NO_RESULT,
    EXIT_OK,
    EXIT_USAGE,
    UsageError,
)
from dtmbnav.cli.paths import check_paths, check_usage

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_NO_RESULT", "EXIT_OK", "EXIT_USAGE",
           "build_parser", "main", "run_command"]

#: The subcommands' modules, in the order of ``--help``.
COMMANDS = (simulate, receive, pdr, sensors, fuse, towers, live, run, report, doppler_map, evaluate, bench, results,
            demo)

EXAMPLES = """\
examples:
  dtmbnav demo                                   # simulate park-loop, receive, fuse, report
  dtmbnav simulate park-loop --seconds 5 -o out/ # 5 s SigMF capture + truth.h5
  dtmbnav simulate street-back --no-iq -o out/   # IMU, GNSS and truth only
  dtmbnav simulate park-loop --no-iq --phone-log gnsslogger -o out/  # and the phone's own log of the walk
  dtmbnav receive out/park-loop-cw.sigmf-meta -o out/rx.h5
  dtmbnav receive cap.ci8 --format ci8 --rate 10e6 --center 666e6 -o rx.h5
  rtl_sdr ... | dtmbnav receive - --format cu8 --rate 2.4e6 --center 666e6 -o rx.h5
  dtmbnav pdr out/truth.h5 -o out/pdr.h5
  dtmbnav fuse --receiver out/rx.h5 --sensors out/truth.h5 -o out/fused.h5
  dtmbnav sensors gnss_log.txt -o sensors.h5      # a phone's GnssLogger (or Sensor Logger) log -> /imu, /gnss
  dtmbnav towers calibrate rx.h5 sensors.h5 --towers towers.csv -o surveyed.csv  # SFN delays from a GNSS walk
  dtmbnav run captures/                          # the whole chain on the bundled capture set
  dtmbnav report out/results.h5 -o out/report
  dtmbnav evaluate park-loop --seeds 20 --json table.json
  dtmbnav evaluate all --level iq --seeds 10      # IQ-level Monte Carlo on a local Dask cluster
  dtmbnav bench --json bench.json
  dtmbnav results --readme README.md             # every result table into docs/results.md
"""


class _Version(argparse.Action):
    """``--version``: the installed package's version, read only when asked for."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs) -> None:
        super().__init__(option_strings, dest=dest, nargs=0, help="print the version and exit", **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from dtmbnav import package_version

        print(f"dtmbnav {package_version()}")
        parser.exit()


def _add_global_options(p: argparse.ArgumentParser, default) -> None:
    """``-q`` and ``--debug``: on the main parser with real defaults, on each subcommand with SUPPRESS
    (so that a subcommand that does not see them keeps the value given before it)."""
    p.add_argument("-q", "--quiet", action="store_true", default=default, help="no progress bars")
    p.add_argument("--debug", action="store_true", default=default,
                   help="print the traceback of an error (internal errors are otherwise one line)")


def build_parser() -> argparse.ArgumentParser:
    """The ``dtmbnav`` parser: its global options, then each subcommand's parser, in the order of ``--help``."""
    parser = argparse.ArgumentParser(
        prog="dtmbnav", description="DTMB (GB 20600) Doppler-ranging receiver and PDR fusion for pedestrian "
                                    "navigation.", epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version)
    _add_global_options(parser, False)
    common = argparse.ArgumentParser(add_help=False)
    _add_global_options(common, argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(sub, common)
    return parser


def _fail(args: argparse.Namespace, label: str, exc: BaseException) -> None:
    """One line per error on stderr (plus the notes it carries); the traceback first under ``--debug``."""
    if args.debug:
        traceback.print_exception(exc)
    print(f"dtmbnav {args.command}: {label}{exc}", file=sys.stderr)
    for note in getattr(exc, "__notes__", ()):
        print(f"dtmbnav {args.command}: {note}", file=sys.stderr)


def run_command(args: argparse.Namespace) -> int:
    """Run a parsed command line's handler and map what it raises to an exit code (module docstring)."""
    from dtmbnav_core.interrupt import Interrupted

    try:
        check_paths(args)
        return args.handler(args)
    except Interrupted as exc:
        _fail(args, "", exc)
        return exc.exit_code
    except KeyboardInterrupt as exc:
        _fail(args, "interrupted", exc)
        return EXIT_INTERRUPTED
    except UsageError as exc:
        _fail(args, "error: ", exc)
        return EXIT_USAGE
    except NoResult as exc:
        _fail(args, "", exc)
        return EXIT_NO_RESULT
    except (ValueError, OSError) as exc:
        _fail(args, "error: ", exc)
        return EXIT_BAD_INPUT
    except Exception as exc:
        _fail(args, f"internal error (a bug; please report it{'' if args.debug else ', with the --debug output'}): "
                    f"{type(exc).__name__}: ", exc)
        return EXIT_INTERNAL


#: Options whose value is a list of coordinates, which may start with a minus sign.
COORDINATE_OPTIONS = ("--tower", "--tower-ll", "--start", "--origin")
_NEGATIVE_VALUE = re.compile(r"-\d[\d.,eE+-]*")


def _joined_coordinates(argv: list[str]) -> list[str]:
    """``--start -2.5,3`` as ``--start=-2.5,3``: argparse takes a value like ``-2.5,3`` (a west or south
    coordinate) for an option, unless it is joined to its option's name."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in COORDINATE_OPTIONS and _NEGATIVE_VALUE.fullmatch(arg):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dtmbnav`` console script."""
    from dtmbnav.cli.numba_cache import configure_numba_cache
    from dtmbnav_core.interrupt import interrupts_raise

    parser = build_parser()
    args = parser.parse_args(_joined_coordinates(sys.argv[1:] if argv is None else list(argv)))
    # Before anything imports numba (the usage check reads capture metadata through the receiver).
    note = configure_numba_cache()
    problem = check_usage(args)
    if problem:
        args.parser.error(problem)
    if note:
        print(f"dtmbnav: warning: {note}", file=sys.stderr)
    with interrupts_raise():
        return run_command(args)

