"""What several commands share: option values checked at parse time, shared option groups, configs built from them.

Every option type raises ``argparse.ArgumentTypeError`` on a bad value, so that a bad command line exits 2
before any work; the configs (the fusion's, the PDR's, the Dask cluster's) are built here from the flags so
that each command module keeps only its own options.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from dtmbnav.cli.exits import UsageError
from dtmbnav_core.settings import parse_setting, with_settings
from fusion import (
    DEFAULT_HEADING_RANGE,
    DEFAULT_PARTICLES,
    DEFAULT_SI_RANGE_USE,
    FILTER_NAMES,
    HEADING_RANGES,
    SI_RANGE_USES,
)
from receiver import CLOCK_PATHS, DEFAULT_CLOCK_PATH, DEFAULT_GUARD_SPAN, DEFAULT_STATIC_WINDOW_S

if TYPE_CHECKING:  # imported by the functions that use them, to keep --help instant
    from dtmbnav_core.geodetic import GeodeticPoint
    from fusion.run import FusionConfig

IQ_FORMATS = ["cu8", "ci8", "ci16", "cf32"]
PN_MODES = ["PN420", "PN595", "PN945"]
FILTERS_HELP = f"comma-separated filters (default: all, {','.join(FILTER_NAMES)})"


# --- option types: every value checked at parse time (exit 2 before any work) ------------------------

def number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def utc_time(text: str) -> int:
    from receiver.capture import parse_utc

    try:
        return parse_utc("--start-time", text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def positive(text: str) -> float:
    value = number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def non_negative(text: str) -> float:
    value = number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {text!r}")
    return value


def whole(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    return whole(text, 1)


def seed(text: str) -> int:
    return whole(text, 0)


def index(text: str) -> int:
    return whole(text, 0)


def setting(text: str) -> tuple[str, str]:
    try:
        return parse_setting(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def xy(text: str) -> tuple[float, float]:
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}")
    try:
        x, y = (number(v) for v in parts)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected X,Y as two finite numbers in metres, got {text!r}") from None
    return x, y


def geodetic(text: str) -> GeodeticPoint:
    """An argparse type: ``LAT,LON[,HEIGHT_M]`` on WGS84 (deg, deg, m above the ellipsoid), as a GeodeticPoint."""
    from dtmbnav_core.geodetic import parse_point

    try:
        return parse_point(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def colon_pair(text: str, convert: Callable[[str], float], expected: str) -> tuple[float, float]:
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


def seconds_window(text: str) -> tuple[float, float]:
    return colon_pair(text, non_negative, "START:STOP in seconds, 0 <= START < STOP")


def int_range(text: str) -> tuple[int, int]:
    low, high = colon_pair(text, int, "A:B, whole numbers with A < B")
    return int(low), int(high)


def filter_list(known: tuple[str, ...], what: str = "filter") -> Callable[[str], tuple[str, ...]]:
    """An argparse type: comma-separated names, each one of ``known`` (``what`` names them in the error)."""
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(name for name in text.split(",") if name)
        unknown = [name for name in names if name not in known]
        if unknown or not names:
            raise argparse.ArgumentTypeError(f"unknown {what}(s) {unknown or [text]}; choose from {','.join(known)}")
        return names
    return parse


def tower_names(text: str) -> tuple[str, ...]:
    """An argparse type: ``NAME[,NAME...]``, towers of a towers file, each named once."""
    names = tuple(name.strip() for name in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(f"expected NAME[,NAME...] without empty names, got {text!r}")
    if len(set(names)) < len(names):
        raise argparse.ArgumentTypeError(f"a tower is named twice in {text!r}")
    return names


def looks_like_path(text: str) -> bool:
    return text.endswith(".toml") or os.sep in text or Path(text).exists()


def unknown_scenario(name: str) -> str | None:
    """Why ``name`` is not a scenario name, None when it is one (or a path, which loading checks)."""
    if looks_like_path(name):
        return None
    from sim.scenario import ALIASES, packaged_scenarios

    known = packaged_scenarios()
    if name in known or name in ALIASES:
        return None
    return f"unknown scenario {name!r}; packaged: {', '.join(known)} (aliases: {', '.join(ALIASES)}), or a .toml path"


def scenario(text: str) -> str:
    """An argparse type: a packaged scenario name or alias, or a path (the simulator only reads it later)."""
    problem = unknown_scenario(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def device(name: str) -> str:
    """An argparse type: an SDR device preset's name (sim.devices; imported only when the option is given)."""
    from sim.devices import DEVICES

    if name not in DEVICES:
        raise argparse.ArgumentTypeError(f"unknown SDR device {name!r}; known: {', '.join(DEVICES)}")
    return name


# --- options and settings that several commands share -------------------------------------------------

def warn(args: argparse.Namespace, message: str) -> None:
    print(f"dtmbnav {args.command}: warning: {message}", file=sys.stderr)


def command_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser, name: str,
             help_text: str) -> argparse.ArgumentParser:
    """A subcommand's parser, which takes the global options of ``common`` (``-q``, ``--debug``) too."""
    p = subparsers.add_parser(name, help=help_text, parents=[common])
    p.set_defaults(parser=p)  # for usage errors found after parsing (check_usage)
    return p


def add_receiver_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("receiver")
    g.add_argument("--pn-mode", choices=PN_MODES, help="header mode (default: detect)")
    g.add_argument("--static-window", type=non_negative, default=DEFAULT_STATIC_WINDOW_S, metavar="S",
                   help="seconds at the start during which the receiver stands still; f_s is measured there "
                        f"(default {DEFAULT_STATIC_WINDOW_S:g})")
    g.add_argument("--clock-offset", type=number, metavar="HZ",
                   help="oscillator offset f_s in Hz, if known (skips the static window)")
    g.add_argument("--conjugate", action="store_true", help="the front end swaps I and Q")
    g.add_argument("--no-paths", action="store_true",
                   help="skip the path tracker (/receiver/paths, first-path and range-difference columns)")
    g.add_argument("--keep-dc", action="store_true",
                   help="do not remove the DC offset / LO leakage at the capture's centre (removed by default)")
    g.add_argument("--correct-iq", action=argparse.BooleanOptionalAction, default=True,
                   help="correct the I/Q gain and phase imbalance the receiver estimates from the signal's "
                        "circularity, headers left out (reported either way; default: on)")
    g.add_argument("--jobs", type=positive_int, default=1, metavar="N",
                   help="threads for the per-frame work, the next batch's run ahead of the current one's "
                        "sequential update (default 1); the output is the same for any N")
    g.add_argument("--doppler-check", action="store_true",
                   help="move the first path to the Doppler line whose earliest path comes first (off by default: "
                        "it helped the street walk it was set on and hurt held-out ones; docs/paths.md)")
    g.add_argument("--clock-path", choices=CLOCK_PATHS, default=DEFAULT_CLOCK_PATH,
                   help="measure the path ranges' f_s at the standstill on the first path or on the path whose "
                        f"phase is steadiest there (default {DEFAULT_CLOCK_PATH}; docs/paths.md)")
    g.add_argument("--guard-span", action=argparse.BooleanOptionalAction, default=DEFAULT_GUARD_SPAN,
                   help="track paths up to the guard interval either side of the frame timing (55.6 us in PN420, "
                        "125 us in PN945: the towers of a single-frequency network that far apart), the m-sequence "
                        "alias resolved, where the header phase rotates; --no-guard-span: the header's cyclic "
                        "extension only (-11..11 us in PN420, -29..29 us in PN945), faster (default: "
                        f"{'on' if DEFAULT_GUARD_SPAN else 'off'}; docs/paths.md)")


def receiver_config(args: argparse.Namespace):
    """The receiver's configuration from :func:`add_receiver_options`' flags."""
    from receiver.delay_doppler import CHECK_FRAMES, DopplerConfig
    from receiver.paths import PathConfig
    from receiver.pipeline import ReceiverConfig

    doppler = DopplerConfig(frames=CHECK_FRAMES if args.doppler_check else 0)
    return ReceiverConfig(pn_mode=args.pn_mode, static_window_s=args.static_window,
                          clock_offset_hz=args.clock_offset,
                          iq_orientation="conjugate" if args.conjugate else "auto", jobs=args.jobs,
                          track_paths=not args.no_paths, paths=PathConfig(doppler=doppler, clock_path=args.clock_path,
                                                                       guard_span=args.guard_span),
                          remove_dc=not args.keep_dc, correct_iq=args.correct_iq)


def channel_centre(args: argparse.Namespace, source, where: str) -> float:
    """The DTMB channel's centre, Hz: ``--channel``, else the capture's record of it, else its centre (``where``:
    the capture as the user named it, for the message).

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
        raise ValueError(f"{where}: the recorded channel centre {channel:g} Hz: {exc} "
                         f"(capture centre {source.center_hz:g} Hz)") from None
    return float(channel)


def add_range_use_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--heading-range", choices=HEADING_RANGES, default=DEFAULT_HEADING_RANGE,
                   help="the range eq. 15's initial heading is solved on with a disciplined clock: the SI "
                        f"carriers' (the paper's) or tower 0's first path, the SI carriers where there is none "
                        f"(default {DEFAULT_HEADING_RANGE})")
    p.add_argument("--si-range", choices=SI_RANGE_USES, default=DEFAULT_SI_RANGE_USE,
                   help="where the filters take the SI-carrier range: at every epoch, or only where no first "
                        f"path is observed (default {DEFAULT_SI_RANGE_USE}; the same without a path tracker)")


def add_settings_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", type=setting, action="append", default=[], metavar="NAME=VALUE",
                   help="any other fusion setting by its dotted name, e.g. integrity.rate_sigma_mps=0.05 or "
                        "noise.heading_rad=0.01 (repeatable; an unknown name lists the known ones)")


def fusion_config(args: argparse.Namespace, **fields: object) -> FusionConfig:
    """The fusion's configuration from the command's flags (``--particles``, the range uses, ``fields``) and
    its ``--set`` settings, built before any work starts so that a bad setting costs nothing."""
    from fusion.run import FusionConfig

    try:
        return with_settings(FusionConfig(n_particles=args.particles or DEFAULT_PARTICLES,
                                          heading_range=args.heading_range, si_range=args.si_range, **fields),
                             args.set)
    except ValueError as exc:
        raise UsageError(f"--set: {exc}") from None


def add_pdr_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("PDR")
    g.add_argument("--step-model", choices=["weinberg", "frequency"], default="weinberg",
                   help="step-length model (default weinberg)")
    g.add_argument("--weinberg-k", type=positive, metavar="K",
                   help="calibrated Weinberg gain; default: --walker's, else the sensors file's calibration "
                        "attribute, else the frequency model is used")
    g.add_argument("--walker", type=Path, metavar="FILE",
                   help="a walker profile (TOML) holding the walker's calibrated Weinberg gain, as 'pdr --calibrate' "
                        "writes it; not with --weinberg-k")


def weinberg_k(args: argparse.Namespace) -> float | None:
    """The Weinberg gain the user gave: ``--weinberg-k``, or ``--walker``'s profile's; None for neither.

    Raises
    ------
    UsageError
        Both are given.
    ValueError
        The profile is missing or malformed (:func:`dtmbnav.field.walker.read_walker_profile`).
    """
    if args.walker is None:
        return args.weinberg_k
    if args.weinberg_k is not None:
        raise UsageError("--weinberg-k and --walker both give the Weinberg gain: give one")
    from dtmbnav.field.walker import read_walker_profile

    return read_walker_profile(args.walker).weinberg_k_m


def pdr_config(args: argparse.Namespace):
    from fusion.pdr import PdrConfig

    k_m = weinberg_k(args)
    if args.walker is None:
        return PdrConfig(step_model=args.step_model, weinberg_k_m=k_m)
    from dtmbnav.field.walker import read_walker_profile

    by_carriage = dict(read_walker_profile(args.walker).k_by_carriage_m)
    return PdrConfig(step_model=args.step_model, weinberg_k_m=k_m, weinberg_k_by_carriage_m=by_carriage)


def say_pdr_choices(args: argparse.Namespace) -> None:
    """Say what the sensors file makes the PDR do in place of the settings: gyro-and-accelerometer attitude
    without a magnetometer, the step-frequency model without a calibrated Weinberg gain."""
    from dtmbnav_core.sensors import read_has_magnetometer, read_weinberg_k_m

    if not read_has_magnetometer(args.sensors):
        warn(args, f"{args.sensors}: no magnetometer in the log: the PDR's attitude comes from the gyro and "
                   "accelerometer alone (its heading drifts with the gyro's bias)")
    if args.step_model == "weinberg" and weinberg_k(args) is None and read_weinberg_k_m(args.sensors) is None:
        warn(args, f"{args.sensors}: no calibrated Weinberg gain (give --walker FILE or --weinberg-k K): step "
                   "lengths from the step-frequency model")


def add_cluster_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("Dask")
    g.add_argument("--workers", type=index, metavar="N",
                   help="local Dask worker processes (default: one per CPU core; 0: in this process, no Dask)")
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="use an existing Dask cluster")


def cluster_config(args: argparse.Namespace):
    from dtmbnav.evaluation.distributed import ClusterConfig

    return ClusterConfig(workers=args.workers, scheduler=args.scheduler)
