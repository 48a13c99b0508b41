"""``dtmbnav simulate``: scenario -> IQ capture + IMU + GNSS + truth.h5: its options and its handler."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_OK, UsageError
from dtmbnav.cli.paths import IoPaths, given_paths
from dtmbnav.evaluation.seeds import REPORTING_SEEDS
from dtmbnav_core.phone import DEFAULT_CLOCK_DRIFT_PPM, DEFAULT_CLOCK_OFFSET_S, PHONE_LOG_FORMATS


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav simulate`` and its options."""
    p = options.command_parser(subparsers, common, "simulate", "scenario -> IQ capture + IMU + GNSS + truth.h5")
    p.add_argument("scenario", type=options.scenario,
                   help="park-loop, park-loop-ccw, street, street-back, or a scenario .toml file")
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--seconds", type=options.positive, help="segment length, s (default: the whole walk)")
    p.add_argument("--start", type=options.non_negative, default=0.0, help="segment start, s (default 0)")
    p.add_argument("--rate", type=options.positive, help="sample rate, Hz (default: the scenario's)")
    p.add_argument("--format", choices=options.IQ_FORMATS, help="sample format")
    p.add_argument("--pn-mode", choices=options.PN_MODES, help="header mode")
    walk = p.add_mutually_exclusive_group()
    walk.add_argument("--seed", type=options.seed, help="seed (default: the scenario's)")
    walk.add_argument("--walk", type=options.index, metavar="K",
                      help="the walk of Monte Carlo index K as dtmbnav evaluate draws it: its seed and its own "
                           f"layout (e.g. {REPORTING_SEEDS.start}: the first reporting walk)")
    p.add_argument("--container", choices=["sigmf", "raw"], default="sigmf", help="raw = raw file + JSON sidecar")
    p.add_argument("--device", metavar="NAME", type=options.device,
                   help="record with this SDR's front end: its rate, format, oscillator and impairments "
                        "(rtl-sdr, hackrf-one, plutosdr, ...: docs/devices.md); --rate and --format still override")
    p.add_argument("--no-iq", action="store_true", help="write IMU, GNSS and truth only")
    p.add_argument("--jobs", type=options.positive_int, default=1,
                   help="threads generating the IQ (same bytes for any N)")
    phone = p.add_argument_group("phone log")
    phone.add_argument("--phone-log", choices=PHONE_LOG_FORMATS,
                       help="also write the walk's IMU and GNSS as this phone app logs them (GnssLogger's text log "
                            "gnss_log_*.txt, or a Sensor Logger export folder), for dtmbnav sensors")
    phone.add_argument("--phone-clock-offset", type=options.number, metavar="S",
                       help="the phone's UTC clock minus the capture's at the log's start, s "
                            f"(default {DEFAULT_CLOCK_OFFSET_S:g}; needs --phone-log)")
    phone.add_argument("--phone-clock-drift", type=options.number, metavar="PPM",
                       help="how much faster the phone's clock runs than the capture's, ppm "
                            f"(default {DEFAULT_CLOCK_DRIFT_PPM:g}; needs --phone-log)")
    p.set_defaults(handler=run, io_paths=io_paths)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav simulate``; its exit code."""
    from dtmbnav.simulation.capture_set import simulate_capture_set
    from sim.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    if args.walk is not None:
        from dtmbnav.evaluation.evaluate import seed_scenario

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


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    return given_paths(folders=[("-o", args.output)])
