"""``dtmbnav receive``: IQ capture -> per-frame CFO, Doppler, range (HDF5): its options and its handler."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from dtmbnav.cli import options
from dtmbnav.cli.exits import EXIT_NO_RESULT, EXIT_OK, UsageError
from dtmbnav.cli.paths import IoPaths, given_paths


def add_parser(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``dtmbnav receive`` and its options."""
    p = options.command_parser(subparsers, common, "receive", "IQ capture -> per-frame CFO, Doppler, range (HDF5)")
    p.add_argument("capture", help="SigMF .sigmf-meta/.sigmf-data, raw file (+ .json sidecar), - for stdin, or "
                                   "rtl_tcp://HOST[:PORT] for an RTL-SDR served by rtl_tcp (port 1234 by default; "
                                   "needs --rate and --center; runs until the server goes away or Ctrl-C)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output HDF5 file")
    p.add_argument("--format", choices=options.IQ_FORMATS, help="sample format of a raw file/stdin")
    p.add_argument("--rate", type=options.positive, help="sample rate of a raw file/stdin, Hz")
    p.add_argument("--center", type=options.positive, help="RF centre frequency, Hz (needed for velocity and range)")
    p.add_argument("--channel", type=options.positive, metavar="HZ",
                   help="centre of the DTMB channel, Hz, for a capture tuned beside it (default: the channel the "
                        "capture's metadata records, else its centre frequency)")
    p.add_argument("--start-time", type=options.utc_time, metavar="ISO8601",
                   help="UTC time of the capture's first sample, e.g. 2026-12-05T10:00:00.250Z, for a capture "
                        "that does not record it (a raw file): fuse aligns the phone's log with it")
    p.add_argument("--csv", metavar="FILE", help="also write the frame table as CSV ('-' for stdout)")
    p.add_argument("--dump", metavar="FILE", type=Path,
                   help="also write the stages' intermediate outputs, one row per frame, to an HDF5 file")
    p.add_argument("--dump-stages", metavar="LIST",
                   help="stages to dump, comma-separated from channel, tracking, body, ofdm, paths (default "
                        "channel,tracking,paths; body is 30 kB a frame)")
    p.add_argument("--dump-window", metavar="START:STOP", type=options.seconds_window,
                   help="dump only the frames within these capture seconds")
    g = p.add_argument_group("rtl_tcp")
    g.add_argument("--gain", type=options.number, metavar="DB",
                   help="tuner gain, dB (the tuner takes its nearest step; default: the tuner's automatic gain)")
    g.add_argument("--ppm", type=int, metavar="N", help="frequency correction sent to the dongle, ppm (default 0)")
    options.add_receiver_options(p)
    p.set_defaults(handler=run, io_paths=io_paths, usage_problem=usage_problem)


def run(args: argparse.Namespace) -> int:
    """Run ``dtmbnav receive``; its exit code."""
    from dtmbnav.chain.receive import receive_capture
    from receiver.capture import MissingCaptureOptions, open_capture
    from receiver.rtl_tcp import RtlTcpSource, parse_url

    address = parse_url(args.capture)
    try:
        source = (RtlTcpSource(*address, sample_rate_hz=args.rate, center_hz=args.center, gain_db=args.gain,
                               ppm=args.ppm or 0) if address is not None else
                  open_capture(args.capture, sample_format=args.format, sample_rate_hz=args.rate,
                               center_hz=args.center))
    except MissingCaptureOptions as exc:
        raise UsageError(f"{exc} (--format, --rate)") from None
    if source.center_hz is None:
        raise UsageError(f"{args.capture}: the capture does not say its RF centre frequency; give --center")
    if args.start_time is not None:
        if source.start_utc_unix_ns is not None and source.start_utc_unix_ns != args.start_time:
            raise UsageError(f"{args.capture}: the capture says it starts at another time than --start-time")
        source.start_utc_unix_ns = args.start_time
    config = options.receiver_config(args)
    channel_hz = options.channel_centre(args, source, args.capture)
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
        options.warn(args, note)
    if address is not None:
        _warn_outages(args, source)
    if summary.ended_early:
        options.warn(args, f"the input ended early ({summary.ended_early}); {args.output} holds the "
                           f"{summary.frames} frame(s) received before it and says so (attribute ended_early)")
    return EXIT_OK if summary.frames else EXIT_NO_RESULT


def _warn_outages(args: argparse.Namespace, source) -> None:
    """The rtl_tcp connection's outages and end, one line each."""
    for outage in source.outages:
        unfilled = outage.lost_samples - outage.filled_samples
        options.warn(args, f"connection lost at stream second {outage.sample_index / source.sample_rate_hz:.2f} "
                           f"({outage.reason}) for {outage.duration_s:.2f} s: {outage.lost_samples} samples lost, "
                           "handed on as zeros (the first frame after them is flagged GAP)"
                           + (f"; {unfilled} of them beyond the fill limit: the frames after it are early by "
                              f"{unfilled / source.sample_rate_hz:.2f} s" if unfilled else ""))
    if source.end_reason:
        options.warn(args, f"the stream ended: {source.end_reason}")


def io_paths(args: argparse.Namespace) -> IoPaths:
    """The command's inputs and outputs (:mod:`dtmbnav.cli.paths`); the inputs are every file the capture
    stands for (both SigMF files, a raw file's sidecar), so that no output can overwrite one of them."""
    from receiver.capture import capture_files

    if args.capture.startswith("rtl_tcp://"):
        return given_paths([], [("-o", args.output), ("--csv", args.csv), ("--dump", args.dump)])
    return given_paths([("CAPTURE", str(f)) for f in capture_files(args.capture)],
                       [("-o", args.output), ("--csv", args.csv), ("--dump", args.dump)])


def usage_problem(args: argparse.Namespace) -> str | None:
    """Option combinations argparse cannot see; None when fine."""
    from dtmbnav_core.rtltcp import SAMPLE_FORMAT
    from receiver.rtl_tcp import parse_url

    try:
        live = parse_url(args.capture) is not None
    except ValueError as exc:
        return str(exc)
    if live:
        if args.rate is None or args.center is None:
            return "rtl_tcp:// needs --rate and --center (they are sent to the dongle)"
        if args.format not in (None, SAMPLE_FORMAT):
            return f"rtl_tcp streams {SAMPLE_FORMAT}, not --format {args.format}"
        if args.start_time is not None:
            return "--start-time does not go with rtl_tcp:// (the host's clock gives the start time)"
        for name, value in (("--rate", args.rate), ("--center", args.center)):
            if value != round(value) or value >= 2 ** 32:
                return f"{name} {value:g}: rtl_tcp takes a whole number of Hz below 2**32"
    elif args.gain is not None or args.ppm is not None:
        return "--gain and --ppm are sent to an rtl_tcp:// server; a capture cannot take them"
    if args.capture == "-" and (args.format is None or args.rate is None):
        return "reading stdin (-) needs --format and --rate"
    if args.static_window <= 0 and args.clock_offset is None:
        return "--static-window must be positive unless --clock-offset gives f_s"
    if args.dump is None and (args.dump_stages is not None or args.dump_window is not None):
        return "--dump-stages and --dump-window need --dump FILE"
    return None
