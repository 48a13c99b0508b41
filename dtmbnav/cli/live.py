"""``dtmbnav live``: an RTL-SDR on rtl_tcp and a phone's sensor stream -> positions as the walk happens."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_NO_RESULT, EXIT_OK
from dtmbnav.cli.paths import IoPaths, given_paths
from fusion import STREAMING_FILTERS

#: The phone sources ``--phone`` takes.
PHONE_HELP = ("the phone's sensor stream: sensorlogger:[HOST:]PORT to receive Sensor Logger's HTTP push on this "
              "machine (its Settings > Data Streaming > HTTP Push URL http://<this machine>:PORT/), or "
              "gnsslogger:FILE to read a GnssLogger log while it grows")
#: Sensor Logger's push port when ``sensorlogger:`` names none.
DEFAULT_PUSH_PORT = 8000


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav live`` and its options."""
    p = options.command_parser(subparsers, common, "live",
                               "rtl_tcp SDR + phone sensor stream -> positions as the walk happens")
    p.add_argument("sdr", metavar="rtl_tcp://HOST[:PORT]", help="the RTL-SDR, served by rtl_tcp (port 1234 by default)")
    p.add_argument("--phone", required=True, type=phone_source, metavar="SOURCE", help=PHONE_HELP)
    p.add_argument("--towers", required=True, metavar="FILE",
                   help="towers file, TOML ([[towers]]) or CSV, as for fuse --towers: its first tower (or the first "
                        "--tower-name) ranges")
    p.add_argument("--tower-name", type=options.tower_names, metavar="NAME[,NAME...]",
                   help="the towers to use, the ranging tower first (default: all of the file's)")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output folder: live.csv and live.geojsonl (a row per position as it comes), receiver.h5 "
                        "(/receiver/frames), live.h5 (/imu, /gnss, /pdr, /fusion/<filter> at the end)")
    p.add_argument("--rate", type=options.positive, default=2.4e6, help="sample rate set on the dongle, Hz "
                                                                         "(default 2.4e6)")
    p.add_argument("--center", type=options.positive, required=True, help="centre frequency set on the dongle, Hz")
    p.add_argument("--channel", type=options.positive, metavar="HZ",
                   help="centre of the DTMB channel, Hz, when tuned beside it (default: --center)")
    p.add_argument("--gain", type=options.number, metavar="DB", help="tuner gain, dB (default: automatic)")
    p.add_argument("--ppm", type=int, default=0, metavar="N", help="frequency correction sent to the dongle, ppm")
    p.add_argument("--web", type=web_address, metavar="[HOST:]PORT",
                   help="serve the live page (the track and its error on a map) at this address, e.g. 8080 "
                        "(this machine) or 0.0.0.0:8080 (the network too)")
    p.add_argument("--filters", type=options.filter_list(STREAMING_FILTERS), default=("pf",),
                   help=f"streaming filters, the first the live one (default pf; from {', '.join(STREAMING_FILTERS)})")
    p.add_argument("--particles", type=options.positive_int, help="particle-filter Np")
    p.add_argument("--start", type=options.geodetic, metavar="LAT,LON",
                   help="the start position (default: the phone's fixes while it stood still before the walk)")
    p.add_argument("--start-window", type=options.non_negative, metavar="S",
                   help="make the start fix of the standstill's last S seconds of fixes only")
    p.add_argument("--time-offset", type=options.number, metavar="S",
                   help="where the capture starts on the phone's clock, s (default: from the SDR host's and the "
                        "phone's UTC clocks)")
    p.add_argument("--reconnects", type=options.index, default=6, metavar="N",
                   help="reconnect tries after the rtl_tcp connection is lost, before the walk ends (default 6)")
    options.add_range_use_options(p)
    options.add_settings_option(p)
    options.add_pdr_options(p)
    options.add_receiver_options(p)
    p.set_defaults(handler=run, io_paths=io_paths, usage_problem=usage_problem)


def phone_source(text: str) -> tuple[str, str]:
    """An argparse type: ``sensorlogger:[HOST:]PORT`` or ``gnsslogger:FILE`` as (kind, rest)."""
    kind, _, rest = text.partition(":")
    if kind not in ("sensorlogger", "gnsslogger") or not rest:
        raise argparse.ArgumentTypeError(f"expected sensorlogger:[HOST:]PORT or gnsslogger:FILE, got {text!r}")
    if kind == "sensorlogger":
        web_address(rest)
    return kind, rest


def web_address(text: str) -> tuple[str, int]:
    """An argparse type: ``[HOST:]PORT`` (host default 127.0.0.1) as (host, port)."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT with a port 0-65535, got {text!r}")
    return host or "127.0.0.1", number


def open_phone(source: tuple[str, str]):
    """The phone stream ``--phone`` names (:mod:`dtmbnav.field.phone_stream`)."""
    from dtmbnav.field.phone_stream import GnssLoggerTail, SensorLoggerPush

    kind, rest = source
    if kind == "gnsslogger":
        return GnssLoggerTail(rest)
    host, port = web_address(rest) if ":" in rest else ("0.0.0.0", int(rest))
    return SensorLoggerPush(host=host, port=port)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav live``; its exit code."""
    from dtmbnav.chain.live import LiveSetup, run_live
    from dtmbnav.field.live_page import LiveView
    from dtmbnav.field.towers import choose_towers, read_towers
    from receiver.rtl_tcp import DEFAULT_POLICY, RtlTcpSource, parse_url

    host, port = parse_url(args.sdr)
    towers, note = choose_towers(read_towers(args.towers), args.towers, args.tower_name,
                                 args.channel or args.center)
    if note:
        options.warn(args, note)
    pdr = options.pdr_config(args)
    if pdr.step_model == "weinberg" and pdr.weinberg_k_m is None:
        options.warn(args, "no calibrated Weinberg gain (give --walker FILE or --weinberg-k K): step lengths from "
                           "the step-frequency model")
        pdr = dataclasses.replace(pdr, step_model="frequency")
    setup = LiveSetup(towers=towers, filters=args.filters, fusion=options.fusion_config(args), pdr=pdr,
                      time_offset_s=args.time_offset, start=args.start, start_window_s=args.start_window)
    source = RtlTcpSource(host, port, sample_rate_hz=args.rate, center_hz=args.center, gain_db=args.gain,
                          ppm=args.ppm, channel_hz=args.channel,
                          policy=dataclasses.replace(DEFAULT_POLICY, reconnects=args.reconnects))
    source.open()   # no output, and no phone server, before the SDR's server answers
    phone = open_phone(args.phone)
    view = LiveView(*args.web) if args.web is not None else None
    try:
        if view is not None:
            print(f"live page: {view.url}", file=sys.stderr)
        if args.phone[0] == "sensorlogger":
            print(f"phone: Sensor Logger's HTTP push to {phone.url}", file=sys.stderr)
        result = run_live(source, phone, setup, args.output, options.receiver_config(args),
                          options.channel_centre(args, source, args.sdr), view=view, progress=not args.quiet)
    finally:
        if view is not None:
            view.close()
    for note in result.notes:
        options.warn(args, note)
    for outage in source.outages:
        options.warn(args, f"rtl_tcp connection lost at stream second {outage.sample_index / source.sample_rate_hz:.2f}"
                           f" for {outage.duration_s:.2f} s ({outage.reason}): a gap, then the stream resumed")
    if result.fusion is None:
        print(f"no position; what was received is in {args.output}", file=sys.stderr)
        return EXIT_NO_RESULT
    print(f"initial heading {result.fusion.heading.describe()}", file=sys.stderr)
    print(f"{result.status.positions} positions -> {args.output}; CPU: receiver {result.cpu_s['receiver']:.1f} s, "
          f"fusion {result.cpu_s.get('fusion', float('nan')):.1f} s, the whole process {result.cpu_s['process']:.1f} s "
          f"({result.cpu_s.get('after_first_frame', float('nan')):.1f} s from the first frame on)",
          file=sys.stderr)
    return EXIT_OK


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`)."""
    phone_file = args.phone[1] if args.phone[0] == "gnsslogger" else None
    return given_paths([("--towers", args.towers), ("--phone", phone_file)], [], [("-o", args.output)])


def usage_problem(args: argparse.Namespace) -> str | None:
    """Option combinations argparse cannot see; None when fine."""
    from receiver.rtl_tcp import parse_url

    try:
        if parse_url(args.sdr) is None:
            return f"{args.sdr}: expected rtl_tcp://HOST[:PORT]"
    except ValueError as exc:
        return str(exc)
    if args.tower_name is not None and not args.towers:
        return "--tower-name needs --towers FILE"
    return None
