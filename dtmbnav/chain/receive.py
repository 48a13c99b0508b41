"""The ``receive`` command's work: one capture in, ``/receiver/frames`` out, and a summary.

Kept apart from :mod:`dtmbnav.chain.fuse` so that ``dtmbnav receive`` imports the
receiver only (no fusion, no simulator, no plotting): its start-up is part of
every run's time.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from dtmbnav_core.schema import ENDED_EARLY_ATTR
from receiver.capture import CaptureSource
from receiver.pipeline import Receiver, ReceiverConfig, receive_file, receive_into_sink
from receiver.reader import read_ahead
from receiver.rtl_tcp import RtlTcpSource
from receiver.writer import FrameSink

#: Samples per block read from a live source: a tenth of a second at 2.4 Msps (the source hands on a block
#: within LinkPolicy.flush_s anyway).
LIVE_CHUNK_SAMPLES = 1 << 18


@dataclass(frozen=True)
class ReceiveSummary:
    """What one receiver run found (for the command line's diagnostics).

    Attributes
    ----------
    frames : int
        Frames written.
    attrs : dict
        The ``/receiver/frames`` attributes (mode, SI word, f_s, ...).
    gaps : int
        Frames flagged as the first after a loss of lock.
    seconds : float
        Span of the frames, s.
    ended_early : str or None
        Why the input ended before its end (an interrupt, a stream cut inside an IQ pair), None when it did not.
    path_rows : int
        Rows written to ``/receiver/paths``.
    """

    frames: int
    attrs: dict
    gaps: int
    seconds: float
    ended_early: str | None = None
    path_rows: int = 0

    def describe(self) -> str:
        if not self.frames:
            return "no lock: no DTMB signal found in the capture (no frames)"
        a = self.attrs
        text = (f"{self.frames} frames over {self.seconds:.1f} s, {a.get('pn_mode')}, SI word {a.get('si_index')}, "
                f"f_s = {a.get('clock_offset_hz', float('nan')):.2f} Hz, {self.gaps} gap(s)")
        if a.get("path_tracking"):
            text += f", {self.path_rows} path rows"
        return text


def receive_capture(source: CaptureSource, out_path: str | os.PathLike, config: ReceiverConfig,
                    csv_path: str | None = None, progress: bool = True,
                    carrier_hz: float | None = None) -> ReceiveSummary:
    """Receive a capture into ``out_path`` (``/receiver/frames``) and summarise it.

    ``carrier_hz`` is the DTMB channel's centre, Hz (default: the capture's
    centre plus ``config.channel_offset_hz``). An :class:`~receiver.rtl_tcp.RtlTcpSource` is received as
    it streams, its outages and start time (known only as the samples come) in the attributes.
    """
    if isinstance(source, RtlTcpSource):
        sink, attrs = _receive_rtl_tcp(source, out_path, config, csv_path, progress, carrier_hz)
    else:
        sink, attrs = receive_file(source, out_path, config, csv_path=csv_path, progress=progress,
                                   carrier_hz=carrier_hz)
    span = sink.last_t_s - sink.first_t_s if sink.frames else 0.0
    return ReceiveSummary(frames=sink.frames, attrs=attrs, gaps=sink.gaps, seconds=span,
                          ended_early=attrs.get(ENDED_EARLY_ATTR), path_rows=sink.paths)


def _receive_rtl_tcp(source: RtlTcpSource, out_path: str | os.PathLike, config: ReceiverConfig,
                     csv_path: str | None, progress: bool, carrier_hz: float | None) -> tuple[FrameSink, dict]:
    """:func:`receiver.pipeline.receive_file` for a live source (:func:`receive_stream`)."""
    carrier = carrier_hz if carrier_hz is not None else source.center_hz + config.channel_offset_hz
    sink = FrameSink(out_path, csv_path)
    attrs = receive_stream(source, Receiver(source.sample_rate_hz, carrier, config), sink, progress=progress)
    return sink, attrs


def receive_stream(source: RtlTcpSource, rx: Receiver, sink: FrameSink, *, progress: bool = True,
                   until: Callable[[Iterator[np.ndarray]], Iterator[np.ndarray]] | None = None) -> dict[str, Any]:
    """Receive a live source into ``sink`` as it streams, and close the source.

    Its blocks are read ahead (what was read is received on a stop request), and its attributes are taken
    after the stream, when its outages and start time are known. ``until`` may end the stream early (a live
    walk whose fusion failed: :meth:`dtmbnav.chain.live.LiveWalk.until_failed`). Returns the attributes
    written (:func:`receiver.pipeline.receive_into_sink`).
    """
    with source:
        chunks = read_ahead(source.chunks(LIVE_CHUNK_SAMPLES))
        return receive_into_sink(rx, chunks if until is None else until(chunks), sink, source=source.path,
                                 progress=progress, attrs=source.attributes(), keep_on_input_error=True)
