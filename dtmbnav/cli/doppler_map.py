"""``dtmbnav doppler-map``: Doppler lines of the CIR around the first path: its options and its handler."""

from __future__ import annotations

import argparse

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav doppler-map`` and its options."""
    p = options.command_parser(subparsers, common, "doppler-map",
                 "Doppler lines of the CIR around the first path, from a receive --dump file")
    p.add_argument("dump", help="HDF5 file from receive --dump (with the paths stage)")
    p.add_argument("--at", type=options.non_negative, required=True, metavar="T",
                   help="centre of the window, capture s")
    p.add_argument("--seconds", type=options.positive, default=1.0, help="window length, s (default 1: 1.1 Hz bins)")
    p.add_argument("--delays", type=options.int_range, metavar="A:B",
                   help="delays to map, samples after the window's first frame (default: around the strongest; "
                        "write --delays=-3:3 when A is negative)")
    p.add_argument("--floor", type=float, default=-25.0, help="lines within this many dB of the strongest (-25)")
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav doppler-map``; its exit code."""
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


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths()
