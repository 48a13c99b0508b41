"""``dtmbnav fuse``: receiver range + PDR -> corrected trajectory: its options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK, UsageError
from dtmbnav.cli.paths import IoPaths, given_paths
from fusion import CLOCK_MODELS, DEFAULT_CLOCK_MODEL, DEFAULT_PARTICLES, FILTER_NAMES


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav fuse`` and its options."""
    p = options.command_parser(subparsers, common, "fuse", "receiver range + PDR -> corrected trajectory")
    p.add_argument("--receiver", required=True, help="HDF5 file with /receiver/frames")
    p.add_argument("--sensors", required=True, help="HDF5 file with /imu and /gnss (start fix)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file (/pdr, /fusion/<filter>)")
    p.add_argument("--filters", type=options.filter_list(FILTER_NAMES), default=FILTER_NAMES, help=options.FILTERS_HELP)
    tower = p.add_mutually_exclusive_group()
    tower.add_argument("--tower", type=options.xy, metavar="X,Y",
                       help="tower position, ENU m (default: from the sensors file)")
    tower.add_argument("--tower-ll", type=options.geodetic, metavar="LAT,LON[,H]",
                       help="tower position, WGS84 deg, and its antenna's height above the ellipsoid, m; put into the "
                            "ENU frame of a sensors file written by 'dtmbnav sensors' (without H its height above "
                            "the receiver is 0, as with --tower)")
    tower.add_argument("--towers", metavar="FILE",
                       help="towers file, TOML ([[towers]]) or CSV (name,lat_deg,lon_deg,height_m and optional "
                            "channel_hz, transmit_delay_s, transmit_delay_sigma_s): its first tower (or the first "
                            "--tower-name) ranges, the others are the SFN's further towers; put into the ENU frame "
                            "of a sensors file written by 'dtmbnav sensors' (docs/cli.md)")
    p.add_argument("--tower-name", type=options.tower_names, metavar="NAME[,NAME...]",
                   help="with --towers: the towers to use, the ranging tower first (default: all of the file's)")
    p.add_argument("--start", type=options.xy, metavar="X,Y", help="start fix P0, ENU m (default: from /gnss)")
    p.add_argument("--time-offset", type=options.number, metavar="S",
                   help="where the capture starts on the IMU log's clock, s (default: from the two files' start "
                        "times, refined from the motion; a simulation's own record where it has one)")
    p.add_argument("--particles", type=options.positive_int, help=f"particle-filter Np (default {DEFAULT_PARTICLES})")
    p.add_argument("--seed", type=options.seed, default=0, help="particle-filter seed")
    p.add_argument("--clock-model", choices=CLOCK_MODELS, default=DEFAULT_CLOCK_MODEL,
                   help="the receiver's clock: disciplined (GNSS/GPSDO; the default) or free-running (a TCXO: the "
                        "filters carry its frequency as a state and, in an SFN, eq. 15 uses the tower difference)")
    options.add_range_use_options(p)
    options.add_settings_option(p)
    options.add_pdr_options(p)
    p.set_defaults(handler=run, io_paths=io_paths, usage_problem=usage_problem)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav fuse``; its exit code."""
    from dtmbnav.chain.fuse import fuse_files
    from dtmbnav_core.sensors import read_fix_count

    if args.start is None and read_fix_count(args.sensors) == 0:
        raise UsageError(f"{args.sensors}: /gnss holds no fixes (the phone log had none), so no start fix: give "
                         "--start X,Y (ENU m; with --tower-ll or --towers, about the origin 'sensors --origin' gave)")
    config = options.fusion_config(args, seed=args.seed, clock_model=args.clock_model)
    tower, tower_height_m = args.tower, 0.0
    if args.tower_ll is not None:
        from dtmbnav_core.geodetic import tower_in_sensors_frame

        x_m, y_m, tower_height_m = tower_in_sensors_frame(args.sensors, args.tower_ll)
        tower = (x_m, y_m)
    other_towers, transmit_delays = (), None
    if args.towers is not None:
        from dtmbnav.field.towers import towers_for_fuse

        layout = towers_for_fuse(args.towers, args.tower_name, args.receiver, args.sensors)
        if layout.note:
            options.warn(args, layout.note)
        print(f"towers: {', '.join(layout.names)} (ranging on {layout.names[0]})", file=sys.stderr)
        tower, tower_height_m = layout.tower_xy_m, layout.tower_height_m
        other_towers, transmit_delays = layout.other_towers, layout.transmit_delays
    options.say_pdr_choices(args)
    result, alignment = fuse_files(args.receiver, args.sensors, args.output, filters=args.filters,
                                   pdr_config=options.pdr_config(args), tower_xy_m=tower, start_xy_m=args.start,
                                   config=config, tower_height_m=tower_height_m, other_towers=other_towers,
                                   transmit_delays=transmit_delays, time_offset_s=args.time_offset)
    print(f"time alignment: {alignment.describe()}", file=sys.stderr)
    if result.code_offsets is not None and len(result.code_offsets.source):
        print(f"transmit delay offsets: {result.code_offsets.describe()}", file=sys.stderr)
    if alignment.disagrees:
        shift_s = alignment.fine_offset_s - alignment.coarse_offset_s
        options.warn(args, f"the motion puts the capture's start {shift_s:+.3f} s from where the two files' start "
                           "times put it, more than their uncertainty: check both clocks, or give --time-offset")
    print(f"initial heading {result.heading.describe()}", file=sys.stderr)
    print(f"fused {', '.join(result.tracks)} -> {args.output}", file=sys.stderr)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths([("--receiver", args.receiver), ("--sensors", args.sensors), ("--towers", args.towers)],
                       [("-o", args.output)])


def usage_problem(args: argparse.Namespace) -> str | None:
    """Option combinations argparse cannot see; None when fine."""
    if args.tower_name is not None and args.towers is None:
        return "--tower-name needs --towers FILE"
    return None
