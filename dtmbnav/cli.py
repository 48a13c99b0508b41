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
instant, and after :func:`dtmbnav.numba_cache.configure_numba_cache` has
given numba a writable cache. This module is the only one that knows the
command line's option names: it turns them into the libraries' typed configs.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import re
import os
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from dtmbnav_core.constants import TRANSMIT_DELAY_KNOWLEDGE
from dtmbnav_core.phone import DEFAULT_CLOCK_DRIFT_PPM, DEFAULT_CLOCK_OFFSET_S, PHONE_LOG_FORMATS
from dtmbnav_core.settings import parse_setting, with_settings
from dtmbnav.errors import NoResult, UsageError
from dtmbnav.seeds import LEVELS, REPORTING_SEEDS, TUNING_SEEDS
from fusion import (CLOCK_MODELS, DEFAULT_CLOCK_MODEL, DEFAULT_HEADING_RANGE, DEFAULT_PARTICLES,
                    DEFAULT_SI_RANGE_USE, FILTER_NAMES, FOOT_INS, HEADING_RANGES, SI_RANGE_USES)
from receiver import CLOCK_PATHS, DEFAULT_CLOCK_PATH, DEFAULT_STATIC_WINDOW_S

if TYPE_CHECKING:  # the fusion's modules are imported by the handlers that run them (module docstring)
    from dtmbnav.geodetic import GeodeticPoint
    from fusion.run import FusionConfig

EXIT_OK = 0
EXIT_NO_RESULT = 1
EXIT_USAGE = 2
EXIT_BAD_INPUT = 3
EXIT_INTERNAL = 4
#: Ctrl-C without the handlers of ``dtmbnav_core.interrupt`` (outside the main thread): 128 + SIGINT.
EXIT_INTERRUPTED = 130

IQ_FORMATS = ["cu8", "ci8", "ci16", "cf32"]
PN_MODES = ["PN420", "PN595", "PN945"]

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
  dtmbnav run captures/                          # the whole chain on the bundled capture set
  dtmbnav report out/results.h5 -o out/report
  dtmbnav evaluate park-loop --seeds 20 --json table.json
  dtmbnav evaluate all --level iq --seeds 10      # IQ-level Monte Carlo on a local Dask cluster
  dtmbnav bench --json bench.json
  dtmbnav results --readme README.md             # every result table into docs/results.md
"""



# --- option types: every value checked at parse time (exit 2 before any work) ------------------------

def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def _utc_time(text: str) -> int:
    from receiver.capture import parse_utc

    try:
        return parse_utc("--start-time", text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _positive(text: str) -> float:
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def _non_negative(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {text!r}")
    return value


def _whole(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    return _whole(text, 1)


def _seed(text: str) -> int:
    return _whole(text, 0)


def _index(text: str) -> int:
    return _whole(text, 0)


def _setting(text: str) -> tuple[str, str]:
    try:
        return parse_setting(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _xy(text: str) -> tuple[float, float]:
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}")
    try:
        x, y = (_number(v) for v in parts)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected X,Y as two finite numbers in metres, got {text!r}") from None
    return x, y


def _geodetic(text: str) -> GeodeticPoint:
    """An argparse type: ``LAT,LON[,HEIGHT_M]`` on WGS84 (deg, deg, m above the ellipsoid), as a GeodeticPoint."""
    from dtmbnav.geodetic import parse_point

    try:
        return parse_point(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _colon_pair(text: str, convert: Callable[[str], float], expected: str) -> tuple[float, float]:
    """``A:B`` with ``convert(A) < convert(B)``, else an argparse error naming ``expected``."""
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError(text)
        low, high = (convert(v) for v in parts)
    except (ValueError, argparse.ArgumentTypeError):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
    if not low < high:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return low, high


def _seconds_window(text: str) -> tuple[float, float]:
    return _colon_pair(text, _non_negative, "START:STOP in seconds, 0 <= START < STOP")


def _int_range(text: str) -> tuple[int, int]:
    low, high = _colon_pair(text, int, "A:B, whole numbers with A < B")
    return int(low), int(high)


def _filter_list(known: tuple[str, ...], what: str = "filter") -> Callable[[str], tuple[str, ...]]:
    """An argparse type: comma-separated names, each one of ``known`` (``what`` names them in the error)."""
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(name for name in text.split(",") if name)
        unknown = [name for name in names if name not in known]
        if unknown or not names:
            raise argparse.ArgumentTypeError(f"unknown {what}(s) {unknown or [text]}; choose from {','.join(known)}")
        return names
    return parse


def _tower_names(text: str) -> tuple[str, ...]:
    """An argparse type: ``NAME[,NAME...]``, towers of a towers file, each named once."""
    names = tuple(name.strip() for name in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(f"expected NAME[,NAME...] without empty names, got {text!r}")
    if len(set(names)) < len(names):
        raise argparse.ArgumentTypeError(f"a tower is named twice in {text!r}")
    return names


def _looks_like_path(text: str) -> bool:
    return text.endswith(".toml") or os.sep in text or Path(text).exists()


def _unknown_scenario(name: str) -> str | None:
    """Why ``name`` is not a scenario name, None when it is one (or a path, which loading checks)."""
    if _looks_like_path(name):
        return None
    from sim.scenario import ALIASES, packaged_scenarios

    known = packaged_scenarios()
    if name in known or name in ALIASES:
        return None
    return f"unknown scenario {name!r}; packaged: {', '.join(known)} (aliases: {', '.join(ALIASES)}), or a .toml path"


def _scenario(text: str) -> str:
    """An argparse type: a packaged scenario name or alias, or a path (the simulator only reads it later)."""
    problem = _unknown_scenario(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def _device(name: str) -> str:
    """An argparse type: an SDR device preset's name (sim.devices; imported only when the option is given)."""
    from sim.devices import DEVICES

    if name not in DEVICES:
        raise argparse.ArgumentTypeError(f"unknown SDR device {name!r}; known: {', '.join(DEVICES)}")
    return name


# --- paths: outputs never name an input (exit 2); inputs and output places exist (exit 3) ---------------

def _same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    except OSError:
        pass
    return pa.resolve() == pb.resolve()


def _io_paths(args: argparse.Namespace) -> tuple[list[tuple[str, str]], list[tuple[str, str]], list[tuple[str, str]]]:
    """(inputs, file outputs, folder outputs) of a command line, each as (option, path); ``-`` left out.

    Inputs include every file an input stands for (both SigMF files, a raw
    file's sidecar), so that no output can overwrite one of them.
    """
    from receiver.capture import capture_files

    command = args.command
    inputs: list[tuple[str, str]] = []
    files: list[tuple[str, str]] = []
    folders: list[tuple[str, str]] = []
    if command == "receive":
        inputs = [("CAPTURE", str(f)) for f in capture_files(args.capture)]
        files = [("-o", args.output), ("--csv", args.csv), ("--dump", args.dump)]
    elif command == "pdr":
        inputs, files = [("SENSORS", args.sensors)], [("-o", args.output), ("--csv", args.csv)]
    elif command == "fuse":
        inputs, files = [("--receiver", args.receiver), ("--sensors", args.sensors),
                         ("--towers", args.towers)], [("-o", args.output)]
    elif command == "sensors":
        inputs, files = [("LOG", log) for log in args.logs], [("-o", args.output)]
    elif command == "report":
        inputs, folders = [("RESULTS", args.results), ("--truth", args.truth)], [("-o", args.output)]
    elif command == "evaluate":
        inputs, files = [("SCENARIO", name) for name in args.scenarios], [("--json", args.json),
                                                                           ("--walks", args.walks)]
    elif command == "bench":
        files = [("--json", args.json)]
    elif command == "results":
        files = [("-o", args.output), ("--readme", args.readme)]
    elif command in ("simulate", "run", "demo"):
        folders = [("-o", args.output)]
    keep = [(o, str(v)) for o, v in inputs if v is not None and str(v) != "-"]
    return keep, [(o, str(v)) for o, v in files if v is not None and str(v) != "-"], \
        [(o, str(v)) for o, v in folders if v is not None]


def check_usage(args: argparse.Namespace) -> str | None:
    """Usage errors argparse cannot see (option combinations, outputs naming inputs); None when fine."""
    if args.command == "receive":
        if args.capture == "-" and (args.format is None or args.rate is None):
            return "reading stdin (-) needs --format and --rate"
        if args.static_window <= 0 and args.clock_offset is None:
            return "--static-window must be positive unless --clock-offset gives f_s"
        if args.dump is None and (args.dump_stages is not None or args.dump_window is not None):
            return "--dump-stages and --dump-window need --dump FILE"
    if args.command == "fuse" and args.tower_name is not None and args.towers is None:
        return "--tower-name needs --towers FILE"
    if getattr(args, "output", None) is not None and str(args.output) == "-" and args.command in ("receive", "pdr",
                                                                                                  "fuse", "sensors"):
        hint = " (use --csv - for the rows)" if hasattr(args, "csv") else ""
        return f"-o -: an HDF5 file cannot be written to stdout{hint}"
    inputs, files, folders = _io_paths(args)
    outputs = files + folders
    for out_option, out in outputs:
        for in_option, src in inputs:
            if _same_path(out, src):
                return f"{out_option} {out} names the input {src} ({in_option}); choose another output path"
    for i, (option_a, a) in enumerate(outputs):
        for option_b, b in outputs[i + 1:]:
            if _same_path(a, b):
                return f"{option_a} and {option_b} name the same path {a}"
    return None


def check_paths(args: argparse.Namespace) -> None:
    """Outputs that cannot be written (a folder as a file, a missing or non-folder parent): ValueError (exit 3).

    Inputs are checked by the readers, which name what is wrong with them.
    """
    _, files, folders = _io_paths(args)
    for option, text in files:
        path = Path(text)
        if path.is_dir():
            raise ValueError(f"{option} {path}: is a folder; give a file name")
        if not path.parent.is_dir():
            raise ValueError(f"{option} {path}: folder {path.parent} does not exist" if not path.parent.exists()
                             else f"{option} {path}: {path.parent} is not a folder")
    for option, text in folders:
        path = Path(text)
        if path.exists() and not path.is_dir():
            raise ValueError(f"{option} {path}: exists and is not a folder")
        ancestor = path.parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise ValueError(f"{option} {path}: {ancestor} is not a folder")


# --- handlers -----------------------------------------------------------------------------------------------

def _warn(args: argparse.Namespace, message: str) -> None:
    print(f"dtmbnav {args.command}: warning: {message}", file=sys.stderr)


def cmd_simulate(args: argparse.Namespace) -> int:
    from dtmbnav.simulation import simulate_capture_set
    from sim.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    if args.walk is not None:
        from dtmbnav.evaluate import seed_scenario

        scenario = seed_scenario(scenario, args.walk, first_seed=0)  # Monte Carlo index 0 + K
    if args.device is not None:
        from sim.devices import apply_device

        scenario = apply_device(scenario, args.device)
    result = simulate_capture_set(scenario, args.output, seconds=args.seconds, start_s=args.start,
                                  sample_rate_hz=args.rate, sample_format=args.format, pn_mode=args.pn_mode,
                                  seed=args.seed, container=args.container, with_iq=not args.no_iq,
                                  progress=not args.quiet, jobs=args.jobs, phone_log=args.phone_log,
                                  phone_clock=_phone_clock(args))
    if result.capture_path is not None:
        print(f"capture: {result.capture_path}", file=sys.stderr)
    print(f"truth:   {result.truth_path}", file=sys.stderr)
    print(f"towers:  {result.towers_path}", file=sys.stderr)
    if result.phone_log_path is not None:
        print(f"phone:   {result.phone_log_path}", file=sys.stderr)
    return EXIT_OK


def _phone_clock(args: argparse.Namespace):
    """The phone's clock of ``simulate --phone-log`` (its defaults where an option is not given)."""
    from dtmbnav_core.phone import PhoneClock

    given = {name: value for name, value in (("offset_s", args.phone_clock_offset),
                                              ("drift_ppm", args.phone_clock_drift)) if value is not None}
    if given and args.phone_log is None:
        raise UsageError("--phone-clock-offset and --phone-clock-drift need --phone-log")
    try:
        return PhoneClock(**given)
    except ValueError as exc:
        raise UsageError(f"--phone-clock-drift: {exc}") from None


def _receiver_config(args: argparse.Namespace):
    from receiver.delay_doppler import CHECK_FRAMES, DopplerConfig
    from receiver.paths import PathConfig
    from receiver.pipeline import ReceiverConfig

    doppler = DopplerConfig(frames=CHECK_FRAMES if args.doppler_check else 0)
    return ReceiverConfig(pn_mode=args.pn_mode, static_window_s=args.static_window,
                          clock_offset_hz=args.clock_offset,
                          iq_orientation="conjugate" if args.conjugate else "auto", jobs=args.jobs,
                          track_paths=not args.no_paths, paths=PathConfig(doppler=doppler, clock_path=args.clock_path),
                          remove_dc=not args.keep_dc, correct_iq=args.correct_iq)


def _pdr_config(args: argparse.Namespace):
    from fusion.pdr import PdrConfig

    return PdrConfig(step_model=args.step_model, weinberg_k_m=args.weinberg_k)


def _channel_centre(args: argparse.Namespace, source) -> float:
    """The DTMB channel's centre, Hz: ``--channel``, else the capture's record of it, else its centre.

    A channel whose SI carriers lie outside the recorded band is refused: a
    usage error for ``--channel``, bad input when the file says so.
    """
    from receiver.mixer import check_channel_offset

    channel = args.channel if args.channel is not None else source.channel_hz
    if channel is None:
        return source.center_hz
    try:
        check_channel_offset(channel - source.center_hz, source.sample_rate_hz)
    except ValueError as exc:
        if args.channel is not None:
            raise UsageError(f"--channel {args.channel:g}: {exc} (capture centre {source.center_hz:g} Hz)") from None
        raise ValueError(f"{args.capture}: the recorded channel centre {channel:g} Hz: {exc} "
                         f"(capture centre {source.center_hz:g} Hz)") from None
    return float(channel)


def cmd_receive(args: argparse.Namespace) -> int:
    from dtmbnav.receive import receive_capture
    from receiver.capture import MissingCaptureOptions, open_capture

    try:
        source = open_capture(args.capture, sample_format=args.format, sample_rate_hz=args.rate,
                              center_hz=args.center)
    except MissingCaptureOptions as exc:
        raise UsageError(f"{exc} (--format, --rate)") from None
    if source.center_hz is None:
        raise UsageError(f"{args.capture}: the capture does not say its RF centre frequency; give --center")
    if args.start_time is not None:
        if source.start_utc_unix_ns is not None and source.start_utc_unix_ns != args.start_time:
            raise UsageError(f"{args.capture}: the capture says it starts at another time than --start-time")
        source.start_utc_unix_ns = args.start_time
    config = _receiver_config(args)
    channel_hz = _channel_centre(args, source)
    if channel_hz != source.center_hz:
        config = dataclasses.replace(config, channel_offset_hz=channel_hz - source.center_hz)
    dump = None
    if args.dump is not None:
        from receiver.dump import DEFAULT_DUMP_STAGES, StageDump

        try:
            stages = (DEFAULT_DUMP_STAGES if args.dump_stages is None
                      else [name.strip() for name in args.dump_stages.split(",")])
            dump = StageDump(args.dump, stages, args.dump_window)
        except ValueError as exc:
            raise UsageError(f"--dump-stages/--dump-window: {exc}") from None
        config = dataclasses.replace(config, inspect=dump, inspect_stages=dump.stages)
    try:
        summary = receive_capture(source, args.output, config, csv_path=args.csv, progress=not args.quiet,
                                  carrier_hz=channel_hz)
    except BaseException:
        if dump is not None:
            dump.close(complete=False)
        raise
    if dump is not None:
        dump.close()
    print(summary.describe(), file=sys.stderr)
    for note in filter(None, str(summary.attrs.get("notes", "")).split("\n")):
        _warn(args, note)
    if summary.ended_early:
        _warn(args, f"the input ended early ({summary.ended_early}); {args.output} holds the {summary.frames} "
                    "frame(s) received before it and says so (attribute ended_early)")
    return EXIT_OK if summary.frames else EXIT_NO_RESULT


def _say_pdr_choices(args: argparse.Namespace) -> None:
    """Say what the sensors file makes the PDR do in place of the settings: gyro-and-accelerometer attitude
    without a magnetometer, the step-frequency model without a calibrated Weinberg gain."""
    from dtmbnav_core.sensors import read_has_magnetometer, read_weinberg_k_m

    if not read_has_magnetometer(args.sensors):
        _warn(args, f"{args.sensors}: no magnetometer in the log: the PDR's attitude comes from the gyro and "
                    "accelerometer alone (its heading drifts with the gyro's bias)")
    if args.step_model == "weinberg" and args.weinberg_k is None and read_weinberg_k_m(args.sensors) is None:
        _warn(args, f"{args.sensors}: no calibrated Weinberg gain (give --weinberg-k K): step lengths from the "
                    "step-frequency model")


def cmd_pdr(args: argparse.Namespace) -> int:
    from dtmbnav.chain import run_pdr_file

    _say_pdr_choices(args)
    result = run_pdr_file(args.sensors, args.output, _pdr_config(args), csv_path=args.csv)
    for note in result.notes:
        _warn(args, f"{args.sensors}: {note}")
    print(f"pdr: {len(result.steps)} steps, {result.steps.step_length_m.sum():.1f} m walked -> {args.output}",
          file=sys.stderr)
    return EXIT_OK if len(result.steps) else EXIT_NO_RESULT


def cmd_sensors(args: argparse.Namespace) -> int:
    from dtmbnav.sensors_import import describe, gap_warnings, import_phone_log

    result = import_phone_log(args.logs, args.output, rate_hz=args.rate, origin=args.origin)
    for line in describe(result):
        print(f"sensors: {line}", file=sys.stderr)
    for message in [*gap_warnings(result), *result.notes]:
        _warn(args, message)
    print(f"sensors: -> {args.output}", file=sys.stderr)
    return EXIT_OK


def cmd_fuse(args: argparse.Namespace) -> int:
    from dtmbnav.chain import fuse_files

    config = _fusion_config(args, seed=args.seed, clock_model=args.clock_model)
    tower, tower_height_m = args.tower, 0.0
    if args.tower_ll is not None:
        from dtmbnav.geodetic import tower_in_sensors_frame

        x_m, y_m, tower_height_m = tower_in_sensors_frame(args.sensors, args.tower_ll)
        tower = (x_m, y_m)
    other_towers, transmit_delays = (), None
    if args.towers is not None:
        from dtmbnav.towers import towers_for_fuse

        layout = towers_for_fuse(args.towers, args.tower_name, args.receiver, args.sensors)
        if layout.note:
            _warn(args, layout.note)
        print(f"towers: {', '.join(layout.names)} (ranging on {layout.names[0]})", file=sys.stderr)
        tower, tower_height_m = layout.tower_xy_m, layout.tower_height_m
        other_towers, transmit_delays = layout.other_towers, layout.transmit_delays
    _say_pdr_choices(args)
    result, alignment = fuse_files(args.receiver, args.sensors, args.output, filters=args.filters,
                                   pdr_config=_pdr_config(args), tower_xy_m=tower, start_xy_m=args.start,
                                   config=config, tower_height_m=tower_height_m, other_towers=other_towers,
                                   transmit_delays=transmit_delays, time_offset_s=args.time_offset)
    print(f"time alignment: {alignment.describe()}", file=sys.stderr)
    if result.code_offsets is not None and len(result.code_offsets.source):
        print(f"transmit delay offsets: {result.code_offsets.describe()}", file=sys.stderr)
    if alignment.disagrees:
        _warn(args, f"the motion puts the capture's start {alignment.fine_offset_s - alignment.coarse_offset_s:+.3f} "
                    "s from where the two files' start times put it, more than their uncertainty: check both "
                    "clocks, or give --time-offset")
    print(f"initial heading {result.heading.describe()}", file=sys.stderr)
    print(f"fused {', '.join(result.tracks)} -> {args.output}", file=sys.stderr)
    return EXIT_OK


def cmd_run(args: argparse.Namespace) -> int:
    from dtmbnav.chain import run_directory
    from dtmbnav.distributed import Task, run_tasks

    folders = args.directory or [Path("captures")]
    if len(folders) == 1 and args.scheduler is None and args.workers is None:
        outcome = run_directory(folders[0], args.output, filters=args.filters, progress=not args.quiet)
        print(outcome.summary, file=sys.stderr if args.json else sys.stdout)
        return EXIT_OK if outcome.found else EXIT_NO_RESULT
    outputs = [args.output / folder.resolve().name for folder in folders]
    if len(set(outputs)) < len(outputs):
        raise UsageError("run: capture-set folders must have different names (each gets OUTPUT/NAME)")
    cluster = _cluster(args)
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


def _cluster(args: argparse.Namespace):
    from dtmbnav.distributed import ClusterConfig

    return ClusterConfig(workers=args.workers, scheduler=args.scheduler)


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


def cmd_report(args: argparse.Namespace) -> int:
    from dtmbnav.chain import write_report_folder

    folder = write_report_folder(args.results, args.output, truth_path=args.truth, origin=args.origin)
    print(f"report written to {folder}", file=sys.stderr)
    return EXIT_OK


def cmd_doppler_map(args: argparse.Namespace) -> int:
    from receiver.delay_doppler import doppler_lines
    from receiver.dump import map_from_dump

    delays = None if args.delays is None else range(args.delays[0], args.delays[1] + 1)
    dd_map = map_from_dump(args.dump, args.at, args.seconds, delays)
    lines = doppler_lines(dd_map, args.floor)
    d = dd_map.delay_samples
    print(f"{args.dump}: paths stage, {args.seconds:g} s around {args.at:g} s, delays {d[0]}..{d[-1]} samples, "
          f"Doppler resolution {dd_map.doppler_hz[1] - dd_map.doppler_hz[0]:.3f} Hz per bin (Hann, 4x padded)")
    print(f"{'doppler_hz':>10s} {'power_db':>8s} {'delay':>5s}  profile_db at delays {d[0]}..{d[-1]}")
    for line in lines:
        profile = " ".join(f"{v:6.1f}" for v in line.profile_db)
        print(f"{line.doppler_hz:10.2f} {line.power_db:8.1f} {line.delay_samples:5d}  {profile}")
    return EXIT_OK


def cmd_evaluate(args: argparse.Namespace) -> int:
    from dtmbnav import evaluate
    from dtmbnav_core.h5io import atomic_path

    scenarios = evaluate.expand_scenarios(args.scenarios)
    for name in scenarios:
        problem = _unknown_scenario(name)
        if problem:
            raise UsageError(f"SCENARIO: {problem} (or a group: {', '.join(evaluate.GROUPS)})")
    if args.pdr:
        from dtmbnav.pdr_table import pdr_table

        print(pdr_table(scenarios))
        return EXIT_OK
    config = _fusion_config(args, seed=args.filter_seed)
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
                                         cluster=_cluster(args), progress=not args.quiet, on_walk=on_walk,
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


def cmd_bench(args: argparse.Namespace) -> int:
    from dtmbnav.bench import run_benchmarks
    from dtmbnav_core.h5io import atomic_path

    if args.json in (None, "-"):
        return run_benchmarks(json_path=args.json, quick=args.quick)
    with atomic_path(args.json) as tmp:
        return run_benchmarks(json_path=str(tmp), quick=args.quick)


def cmd_results(args: argparse.Namespace) -> int:
    from dtmbnav.results import ResultsConfig, write_results

    config = ResultsConfig(iq_seeds=args.iq_seeds, obs_seeds=args.obs_seeds, first_seed=args.first_seed,
                           cluster=_cluster(args), progress=not args.quiet)
    if args.check:
        from dtmbnav.results_check import check_results

        if args.readme is not None:
            raise UsageError("--check writes nothing, so it cannot rewrite --readme")
        report = check_results(args.output, args.sections, args.check_seeds, config)
        print(report.table())
        for note in report.notes:
            print(f"dtmbnav results: {note}", file=sys.stderr)
        print(f"dtmbnav {report.summary()}", file=sys.stderr)
        return EXIT_NO_RESULT if report.failed else EXIT_OK
    write_results(args.output, args.sections, config, readme=args.readme)
    print(f"results written to {args.output}", file=sys.stderr)
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    from dtmbnav.demo import run_demo

    run_demo(args.output, scenario=args.scenario, seconds=args.seconds, progress=not args.quiet, jobs=args.jobs)
    return EXIT_OK


FILTERS_HELP = f"comma-separated filters (default: all, {','.join(FILTER_NAMES)})"


# --- parser -------------------------------------------------------------------------------

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


def _add_receiver_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("receiver")
    g.add_argument("--pn-mode", choices=PN_MODES, help="header mode (default: detect)")
    g.add_argument("--static-window", type=_non_negative, default=DEFAULT_STATIC_WINDOW_S, metavar="S",
                   help="seconds at the start during which the receiver stands still; f_s is measured there "
                        f"(default {DEFAULT_STATIC_WINDOW_S:g})")
    g.add_argument("--clock-offset", type=_number, metavar="HZ",
                   help="oscillator offset f_s in Hz, if known (skips the static window)")
    g.add_argument("--conjugate", action="store_true", help="the front end swaps I and Q")
    g.add_argument("--no-paths", action="store_true",
                   help="skip the path tracker (/receiver/paths, first-path and range-difference columns)")
    g.add_argument("--keep-dc", action="store_true",
                   help="do not remove the DC offset / LO leakage at the capture's centre (removed by default)")
    g.add_argument("--correct-iq", action=argparse.BooleanOptionalAction, default=True,
                   help="correct the I/Q gain and phase imbalance the receiver estimates from the signal's "
                        "circularity, headers left out (reported either way; default: on)")


def _add_range_use_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--heading-range", choices=HEADING_RANGES, default=DEFAULT_HEADING_RANGE,
                   help="the range eq. 15's initial heading is solved on with a disciplined clock: the SI "
                        f"carriers' (the paper's) or tower 0's first path, the SI carriers where there is none "
                        f"(default {DEFAULT_HEADING_RANGE})")
    p.add_argument("--si-range", choices=SI_RANGE_USES, default=DEFAULT_SI_RANGE_USE,
                   help="where the filters take the SI-carrier range: at every epoch, or only where no first "
                        f"path is observed (default {DEFAULT_SI_RANGE_USE}; the same without a path tracker)")


def _add_settings_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", type=_setting, action="append", default=[], metavar="NAME=VALUE",
                   help="any other fusion setting by its dotted name, e.g. integrity.rate_sigma_mps=0.05 or "
                        "noise.heading_rad=0.01 (repeatable; an unknown name lists the known ones)")


def _fusion_config(args: argparse.Namespace, **fields: object) -> FusionConfig:
    """The fusion's configuration from the command's flags (``--particles``, the range uses, ``fields``) and
    its ``--set`` settings, built before any work starts so that a bad setting costs nothing."""
    from fusion.run import FusionConfig

    try:
        return with_settings(FusionConfig(n_particles=args.particles or DEFAULT_PARTICLES,
                                          heading_range=args.heading_range, si_range=args.si_range, **fields),
                             args.set)
    except ValueError as exc:
        raise UsageError(f"--set: {exc}") from None


def _add_pdr_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("PDR")
    g.add_argument("--step-model", choices=["weinberg", "frequency"], default="weinberg",
                   help="step-length model (default weinberg)")
    g.add_argument("--weinberg-k", type=_positive, metavar="K",
                   help="calibrated Weinberg gain; default: read from the sensors file's calibration "
                        "attribute, else the frequency model is used")


def _add_cluster_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("Dask")
    g.add_argument("--workers", type=_index, metavar="N",
                   help="local Dask worker processes (default: one per CPU core; 0: in this process, no Dask)")
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="use an existing Dask cluster")


def _command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser, name: str,
             help_text: str) -> argparse.ArgumentParser:
    """A subcommand's parser, which takes the global options of ``common`` (``-q``, ``--debug``) too."""
    p = subparsers.add_parser(name, help=help_text, parents=[common])
    p.set_defaults(parser=p)  # for usage errors found after parsing (check_usage)
    return p


def _add_simulate_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav simulate`` and its options."""
    p = _command(subparsers, common, "simulate", "scenario -> IQ capture + IMU + GNSS + truth.h5")
    p.add_argument("scenario", type=_scenario,
                   help="park-loop, park-loop-ccw, street, street-back, or a scenario .toml file")
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--seconds", type=_positive, help="segment length, s (default: the whole walk)")
    p.add_argument("--start", type=_non_negative, default=0.0, help="segment start, s (default 0)")
    p.add_argument("--rate", type=_positive, help="sample rate, Hz (default: the scenario's)")
    p.add_argument("--format", choices=IQ_FORMATS, help="sample format")
    p.add_argument("--pn-mode", choices=PN_MODES, help="header mode")
    walk = p.add_mutually_exclusive_group()
    walk.add_argument("--seed", type=_seed, help="seed (default: the scenario's)")
    walk.add_argument("--walk", type=_index, metavar="K",
                      help="the walk of Monte Carlo index K as dtmbnav evaluate draws it: its seed and its own "
                           f"layout (e.g. {REPORTING_SEEDS.start}: the first reporting walk)")
    p.add_argument("--container", choices=["sigmf", "raw"], default="sigmf", help="raw = raw file + JSON sidecar")
    p.add_argument("--device", metavar="NAME", type=_device,
                   help="record with this SDR's front end: its rate, format, oscillator and impairments "
                        "(rtl-sdr, hackrf-one, plutosdr, ...: docs/devices.md); --rate and --format still override")
    p.add_argument("--no-iq", action="store_true", help="write IMU, GNSS and truth only")
    p.add_argument("--jobs", type=_positive_int, default=1, help="threads generating the IQ (same bytes for any N)")
    phone = p.add_argument_group("phone log")
    phone.add_argument("--phone-log", choices=PHONE_LOG_FORMATS,
                       help="also write the walk's IMU and GNSS as this phone app logs them (GnssLogger's text log "
                            "gnss_log_*.txt, or a Sensor Logger export folder), for dtmbnav sensors")
    phone.add_argument("--phone-clock-offset", type=_number, metavar="S",
                       help="the phone's UTC clock minus the capture's at the log's start, s "
                            f"(default {DEFAULT_CLOCK_OFFSET_S:g}; needs --phone-log)")
    phone.add_argument("--phone-clock-drift", type=_number, metavar="PPM",
                       help="how much faster the phone's clock runs than the capture's, ppm "
                            f"(default {DEFAULT_CLOCK_DRIFT_PPM:g}; needs --phone-log)")
    p.set_defaults(handler=cmd_simulate)


def _add_receive_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav receive`` and its options."""
    p = _command(subparsers, common, "receive", "IQ capture -> per-frame CFO, Doppler, range (HDF5)")
    p.add_argument("capture", help="SigMF .sigmf-meta/.sigmf-data, raw file (+ .json sidecar), or - for stdin")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file")
    p.add_argument("--format", choices=IQ_FORMATS, help="sample format of a raw file/stdin")
    p.add_argument("--rate", type=_positive, help="sample rate of a raw file/stdin, Hz")
    p.add_argument("--center", type=_positive, help="RF centre frequency, Hz (needed for velocity and range)")
    p.add_argument("--channel", type=_positive, metavar="HZ",
                   help="centre of the DTMB channel, Hz, for a capture tuned beside it (default: the channel the "
                        "capture's metadata records, else its centre frequency)")
    p.add_argument("--start-time", type=_utc_time, metavar="ISO8601",
                   help="UTC time of the capture's first sample, e.g. 2026-12-05T10:00:00.250Z, for a capture "
                        "that does not record it (a raw file): fuse aligns the phone's log with it")
    p.add_argument("--csv", metavar="FILE", help="also write the frame table as CSV ('-' for stdout)")
    p.add_argument("--jobs", type=_positive_int, default=1, metavar="N",
                   help="threads for the per-frame work, the next batch's run ahead of the current one's "
                        "sequential update (default 1); the output is the same for any N")
    p.add_argument("--doppler-check", action="store_true",
                   help="move the first path to the Doppler line whose earliest path comes first (off by default: "
                        "it helped the street walk it was set on and hurt held-out ones; docs/paths.md)")
    p.add_argument("--clock-path", choices=CLOCK_PATHS, default=DEFAULT_CLOCK_PATH,
                   help="measure the path ranges' f_s at the standstill on the first path or on the path whose "
                        f"phase is steadiest there (default {DEFAULT_CLOCK_PATH}; docs/paths.md)")
    p.add_argument("--dump", metavar="FILE", type=Path,
                   help="also write the stages' intermediate outputs, one row per frame, to an HDF5 file")
    p.add_argument("--dump-stages", metavar="LIST",
                   help="stages to dump, comma-separated from channel, tracking, body, ofdm, paths (default "
                        "channel,tracking,paths; body is 30 kB a frame)")
    p.add_argument("--dump-window", metavar="START:STOP", type=_seconds_window,
                   help="dump only the frames within these capture seconds")
    _add_receiver_options(p)
    p.set_defaults(handler=cmd_receive)


def _add_pdr_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav pdr`` and its options."""
    p = _command(subparsers, common, "pdr", "IMU log (/imu of an HDF5 file) -> pedestrian dead reckoning")
    p.add_argument("sensors", help="HDF5 file with /imu (e.g. truth.h5 from simulate)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/pdr)")
    p.add_argument("--csv", metavar="FILE", help="also write the steps as CSV ('-' for stdout)")
    _add_pdr_options(p)
    p.set_defaults(handler=cmd_pdr)


def _add_sensors_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav sensors`` and its options."""
    p = _command(subparsers, common, "sensors", "a phone's own log (GnssLogger, Sensor Logger) -> sensors file "
                                                 "(/imu, /gnss)")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="a GnssLogger text log, or a Sensor Logger export (its folder, zip, or CSV files)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/imu, /gnss)")
    p.add_argument("--rate", type=_positive, default=100.0, help="rate of the resampled /imu, Hz (default 100)")
    p.add_argument("--origin", type=_geodetic, metavar="LAT,LON[,H]",
                   help="origin of the ENU frame, WGS84 deg and m above the ellipsoid (default: the first fix; "
                        "without H, the first fix's height)")
    p.set_defaults(handler=cmd_sensors)


def _add_fuse_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav fuse`` and its options."""
    p = _command(subparsers, common, "fuse", "receiver range + PDR -> corrected trajectory")
    p.add_argument("--receiver", required=True, help="HDF5 file with /receiver/frames")
    p.add_argument("--sensors", required=True, help="HDF5 file with /imu and /gnss (start fix)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/pdr, /fusion/<filter>)")
    p.add_argument("--filters", type=_filter_list(FILTER_NAMES), default=FILTER_NAMES, help=FILTERS_HELP)
    tower = p.add_mutually_exclusive_group()
    tower.add_argument("--tower", type=_xy, metavar="X,Y", help="tower position, ENU m (default: from the sensors file)")
    tower.add_argument("--tower-ll", type=_geodetic, metavar="LAT,LON[,H]",
                       help="tower position, WGS84 deg, and its antenna's height above the ellipsoid, m; put into the "
                            "ENU frame of a sensors file written by 'dtmbnav sensors' (without H its height above "
                            "the receiver is 0, as with --tower)")
    tower.add_argument("--towers", metavar="FILE",
                       help="towers file, TOML ([[towers]]) or CSV (name,lat_deg,lon_deg,height_m and optional "
                            "channel_hz, transmit_delay_s, transmit_delay_sigma_s): its first tower (or the first "
                            "--tower-name) ranges, the others are the SFN's further towers; put into the ENU frame "
                            "of a sensors file written by 'dtmbnav sensors' (docs/cli.md)")
    p.add_argument("--tower-name", type=_tower_names, metavar="NAME[,NAME...]",
                   help="with --towers: the towers to use, the ranging tower first (default: all of the file's)")
    p.add_argument("--start", type=_xy, metavar="X,Y", help="start fix P0, ENU m (default: from /gnss)")
    p.add_argument("--time-offset", type=_number, metavar="S",
                   help="where the capture starts on the IMU log's clock, s (default: from the two files' start "
                        "times, refined from the motion; a simulation's own record where it has one)")
    p.add_argument("--particles", type=_positive_int, help=f"particle-filter Np (default {DEFAULT_PARTICLES})")
    p.add_argument("--seed", type=_seed, default=0, help="particle-filter seed")
    p.add_argument("--clock-model", choices=CLOCK_MODELS, default=DEFAULT_CLOCK_MODEL,
                   help="the receiver's clock: disciplined (GNSS/GPSDO; the default) or free-running (a TCXO: the "
                        "filters carry its frequency as a state and, in an SFN, eq. 15 uses the tower difference)")
    _add_range_use_options(p)
    _add_settings_option(p)
    _add_pdr_options(p)
    p.set_defaults(handler=cmd_fuse)


def _add_run_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav run`` and its options."""
    p = _command(subparsers, common, "run", "the whole chain (receive, PDR, fuse, report) on capture sets")
    p.add_argument("directory", nargs="*", type=Path,
                   help="folders, each with one capture and its sensors/truth file (default: captures/); "
                        "several run as Dask tasks")
    p.add_argument("-o", "--output", type=Path, default=Path("out/run"),
                   help="output folder (default out/run; OUTPUT/NAME per folder when several or on Dask)")
    p.add_argument("--filters", type=_filter_list(FILTER_NAMES), default=FILTER_NAMES, help=FILTERS_HELP)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    _add_cluster_options(p)
    p.set_defaults(handler=cmd_run)


def _add_report_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav report`` and its options."""
    p = _command(subparsers, common, "report", "plots and a summary table from a results file")
    p.add_argument("results", help="HDF5 file from run/fuse")
    p.add_argument("-o", "--output", required=True, type=Path, help="report folder")
    p.add_argument("--truth", help="truth.h5 (default: the truth group inside the results file)")
    p.add_argument("--origin", type=_geodetic, metavar="LAT,LON[,H]",
                   help="place the results' ENU frame on WGS84 for the map files (tracks.geojson, tracks.gpx, "
                        "map.html): its origin, deg, and height above the ellipsoid, m (default 0); default: the "
                        "origin the results file holds (fused from a 'dtmbnav sensors' file), else no map files")
    p.set_defaults(handler=cmd_report)


def _add_doppler_map_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav doppler-map`` and its options."""
    p = _command(subparsers, common, "doppler-map",
                 "Doppler lines of the CIR around the first path, from a receive --dump file")
    p.add_argument("dump", help="HDF5 file from receive --dump (with the paths stage)")
    p.add_argument("--at", type=_non_negative, required=True, metavar="T", help="centre of the window, capture s")
    p.add_argument("--seconds", type=_positive, default=1.0, help="window length, s (default 1: 1.1 Hz bins)")
    p.add_argument("--delays", type=_int_range, metavar="A:B",
                   help="delays to map, samples after the window's first frame (default: around the strongest; "
                        "write --delays=-3:3 when A is negative)")
    p.add_argument("--floor", type=float, default=-25.0, help="lines within this many dB of the strongest (-25)")
    p.set_defaults(handler=cmd_doppler_map)


def _add_evaluate_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav evaluate`` and its options."""
    p = _command(subparsers, common, "evaluate", "Monte Carlo accuracy table of every filter against truth")
    p.add_argument("scenarios", nargs="+", help="scenario names/files; 'all', 'park-loop', 'street' = groups")
    p.add_argument("--seeds", type=_positive_int, default=20, help="walks per scenario (default 20)")
    p.add_argument("--filters", type=_filter_list((*FILTER_NAMES, FOOT_INS)), default=FILTER_NAMES,
                   help=f"{FILTERS_HELP}; {FOOT_INS} adds the foot-mounted ZUPT INS")
    p.add_argument("--particles", type=_positive_int, help=f"particle-filter Np (default {DEFAULT_PARTICLES})")
    p.add_argument("--filter-seed", type=_seed, default=0,
                   help="particle-filter seed (default 0): other seeds show the filter's own Monte Carlo spread")
    _add_range_use_options(p)
    _add_settings_option(p)
    p.add_argument("--json", metavar="FILE", help="also write the table as JSON ('-' for stdout)")
    p.add_argument("--walks", metavar="FILE",
                   help="also write each walk's figures as a JSON line when it finishes (a stopped run keeps them)")
    p.add_argument("--pdr", action="store_true", help="only the PDR figures (steps, step length, drift, error)")
    p.add_argument("--first-seed", type=_index, default=REPORTING_SEEDS.start, metavar="N",
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
    _add_cluster_options(p)
    p.set_defaults(handler=cmd_evaluate)


def _add_bench_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav bench`` and its options."""
    p = _command(subparsers, common, "bench", "throughput of every kernel next to its plain-numpy reference")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON ('-' for stdout)")
    p.add_argument("--quick", action="store_true", help="short runs (smoke test)")
    p.set_defaults(handler=cmd_bench)


def _add_results_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav results`` and its options."""
    from dtmbnav.seeds import CHECK_SEEDS, IQ_SEEDS, OBS_SEEDS, RESULT_SECTIONS as SECTIONS

    p = _command(subparsers, common, "results", "every result table, generated into one Markdown file")
    p.add_argument("-o", "--output", type=Path, default=Path("docs/results.md"),
                   help="the results file (default docs/results.md); sections not run are kept as they are")
    p.add_argument("--sections", type=_filter_list(SECTIONS, "section"), default=SECTIONS,
                   help=f"comma-separated sections to run (default: all, {','.join(SECTIONS)})")
    p.add_argument("--iq-seeds", type=_positive_int, default=IQ_SEEDS,
                   help=f"Monte Carlo walks per scenario at the IQ level (default {IQ_SEEDS})")
    p.add_argument("--obs-seeds", type=_positive_int, default=OBS_SEEDS,
                   help=f"Monte Carlo walks per scenario at the observation and exact levels (default {OBS_SEEDS})")
    p.add_argument("--first-seed", type=_index, default=REPORTING_SEEDS.start, metavar="N",
                   help=f"first Monte Carlo index (default {REPORTING_SEEDS.start}, the reporting range)")
    p.add_argument("--readme", type=Path, metavar="FILE",
                   help="also rewrite the headline table between this README's results markers")
    p.add_argument("--check", action="store_true",
                   help="write nothing: run the first walks of each printed section again (the walks its header "
                        "names; --first-seed, --iq-seeds and --obs-seeds do not apply) and compare with the file; "
                        "exit 1 on a regression beyond the walks' spread (docs/evaluation.md)")
    p.add_argument("--check-seeds", type=_positive_int, default=CHECK_SEEDS, metavar="N",
                   help=f"with --check: walks of each scenario run again (default {CHECK_SEEDS})")
    _add_cluster_options(p)
    p.set_defaults(handler=cmd_results)


def _add_demo_command(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav demo`` and its options."""
    p = _command(subparsers, common, "demo", "simulate a walk at IQ level, receive, fuse and write a report")
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    p.add_argument("--scenario", type=_scenario, default="park-loop", help="scenario (default park-loop)")
    p.add_argument("--seconds", type=_positive, help="simulate only this many seconds (default: the whole walk)")
    p.add_argument("--jobs", type=_positive_int, metavar="N",
                   help="threads generating the IQ while the receiver runs (default: one per CPU core)")
    p.set_defaults(handler=cmd_demo)


def build_parser() -> argparse.ArgumentParser:
    """The ``dtmbnav`` parser: its global options, then each subcommand's parser, in the order of ``--help``."""
    parser = argparse.ArgumentParser(
        prog="dtmbnav", description="DTMB (GB 20600) Doppler-ranging receiver and PDR fusion for pedestrian "
                                    "navigation.", epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version)
    _add_global_options(parser, False)
    common = argparse.ArgumentParser(add_help=False)
    _add_global_options(common, argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_simulate_command(sub, common)
    _add_receive_command(sub, common)
    _add_pdr_command(sub, common)
    _add_sensors_command(sub, common)
    _add_fuse_command(sub, common)
    _add_run_command(sub, common)
    _add_report_command(sub, common)
    _add_doppler_map_command(sub, common)
    _add_evaluate_command(sub, common)
    _add_bench_command(sub, common)
    _add_results_command(sub, common)
    _add_demo_command(sub, common)
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
    from dtmbnav_core.interrupt import interrupts_raise
    from dtmbnav.numba_cache import configure_numba_cache

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


if __name__ == "__main__":
    sys.exit(main())
