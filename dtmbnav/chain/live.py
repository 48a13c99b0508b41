"""``dtmbnav live``'s work: an SDR stream and a phone's sensor stream in, positions as the walk happens.

Two threads share the work. The main thread runs the receiver on the SDR stream
(:func:`dtmbnav.chain.receive.receive_stream`: SIGINT and SIGTERM end a stream cleanly, and only the main
thread may take signals), writing ``/receiver/frames`` to ``receiver.h5`` as ``dtmbnav receive`` does, and
hands every batch's SI-carrier range to the fusion thread (:class:`LiveWalk`). The fusion thread polls the
phone, runs the streaming PDR (:class:`fusion.pdr.streaming.StreamingPdr`), makes the ENU frame (about the
phone's first fix) and the start fix (its fixes while the phone stood still before the walk: the rule of
``dtmbnav sensors``, :func:`dtmbnav.field.sensors_import.choose_start_fix`), feeds the streaming fusion
(:class:`fusion.streaming.StreamingFusion`) and gives every position to the outputs: CSV and GeoJSON
lines (:mod:`dtmbnav.field.live_positions`), the live page (:mod:`dtmbnav.field.live_page`) and the
terminal's status line. The settled positions trail the newest samples by the PDR's settling delay; the
newest position is a now-cast past the last settled step (:meth:`LiveWalk.nowcast_rows`).

The capture's clock is put on the phone's by the two streams' UTC stamps (the SDR host's clock at the first
sample, the phone's at its first sample), or by a given offset. At the end the phone's ``/imu`` and
``/gnss`` (with the start fix), the streamed ``/pdr`` steps and the live tracks (``/fusion/<filter>``)
go to ``live.h5``: with ``receiver.h5`` a recorded walk that ``dtmbnav fuse`` reads again.
"""

from __future__ import annotations

import dataclasses
import math
import os
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from dtmbnav.chain.live_records import (
    PRE_START_FRAMES_S,
    STAGE_FILTERED,
    STAGE_HEADING,
    STAGE_NOWCAST,
    LiveResult,
    LiveSetup,
    LiveStatus,
    output_paths,
)
from dtmbnav.chain.receive import receive_stream
from dtmbnav.field.live_page import LiveView, ViewRow, ViewScene, ellipse_95
from dtmbnav.field.live_positions import GeoPositions, LivePositionWriter
from dtmbnav.field.phone_grid import PhoneChunk, PhoneStream
from dtmbnav.field.sensors_import import choose_start_fix, walk_start_s
from dtmbnav.field.towers import TowerLayout, towers_about
from dtmbnav_core import schema
from dtmbnav_core.geodetic import GeodeticPoint, to_enu
from dtmbnav_core.h5io import atomic_h5, write_columns
from dtmbnav_core.interrupt import Interrupted
from dtmbnav_core.records import FrameFlag, GeodeticFixes, GnssLog, ImuLog, PdrSteps, RangeSeries
from dtmbnav_core.resampling import interpolate
from dtmbnav_core.sensors import write_gnss, write_imu
from dtmbnav_core.start_fix import CombinedFix
from fusion.pdr.pipeline import has_magnetometer
from fusion.pdr.streaming import StreamingPdr
from fusion.streaming import LivePositions, StreamingFusion, hold_position
from receiver.observables import ranges_from_frames
from receiver.pipeline import Receiver, ReceiverConfig
from receiver.rtl_tcp import RtlTcpSource
from receiver.writer import FrameSink


class _UntilFailed(Iterator[np.ndarray]):
    """An input that ends when the live walk's fusion thread has failed (a stream's read-ahead kept as it is:
    ``ends_on_stop`` passed on, :class:`dtmbnav_core.interrupt.DeferredStop`)."""

    def __init__(self, chunks: Iterator[np.ndarray], walk: LiveWalk) -> None:
        self._chunks, self._walk = chunks, walk
        self.ends_on_stop = getattr(chunks, "ends_on_stop", False)

    def __next__(self) -> np.ndarray:
        if self._walk.failed:
            raise StopIteration
        return next(self._chunks)


class RangeTee(FrameSink):
    """A :class:`receiver.writer.FrameSink` that also hands each batch's range rows to a callback."""

    def __init__(self, h5_path: str | os.PathLike, on_batch) -> None:
        super().__init__(h5_path)
        self._on_batch = on_batch

    def append(self, batch) -> None:
        super().append(batch)
        if len(batch):
            self._on_batch(batch.columns())


class LiveWalk:
    """The fusion thread's side of ``dtmbnav live`` (module docstring).

    Parameters
    ----------
    phone : PhoneStream
    setup : LiveSetup
    writer : LivePositionWriter
    view : LiveView or None
    progress : bool
        Redraw the status line on stderr.
    capture_start_utc_ns : callable
        Gives the capture's first sample's UTC, ns since the Unix epoch, once known (None before).
    """

    def __init__(self, phone: PhoneStream, setup: LiveSetup, writer: LivePositionWriter, view: LiveView | None,
                 progress: bool = True, capture_start_utc_ns: Callable[[], int | None] = lambda: None) -> None:
        self.phone, self.setup, self.writer, self.view, self.progress = phone, setup, writer, view, progress
        self.status = LiveStatus()
        self.notes: list[str] = []
        self.pdr = StreamingPdr(setup.pdr)
        self.fusion: StreamingFusion | None = None
        self.origin: GeodeticPoint | None = setup.start.with_height(0.0) if setup.start is not None and \
            setup.start.height_m is None else setup.start
        self.layout: TowerLayout | None = None
        self.start_fix: CombinedFix | None = None
        self.capture_start_utc_ns = capture_start_utc_ns
        #: The receiver's f_s once measured (set by :func:`run_live`; read each update).
        self.receiver_clock_hz: Callable[[], float | None] = lambda: None
        self._frames: queue.Queue[dict[str, np.ndarray]] = queue.Queue()
        self._held_ranges: list[RangeSeries] = []
        self._held_steps: list[PdrSteps] = []
        self._imu: list[ImuLog] = []
        self._fixes: list[GeodeticFixes] = []
        self._steps: list[PdrSteps] = []
        self._walk_start_s = math.inf
        self._newest_position_s = -math.inf
        self._last_write: float | None = None
        self._last_settled: LivePositions | None = None
        self._last_imu: ImuLog | None = None
        self._grid_dt: float | None = None
        self._first_frame_cpu_s: float | None = None
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._result: LiveResult | None = None
        self._thread = threading.Thread(target=self._run, name="dtmbnav-live-fusion", daemon=True)

    # ------------------------------------------------------------ the receiver's side (main thread)

    def on_frames(self, columns: dict[str, np.ndarray]) -> None:
        """Take one receiver batch's frame columns (called by :class:`RangeTee`)."""
        if self._first_frame_cpu_s is None:   # the process's start-up (imports, compiled kernels) is behind it
            self._first_frame_cpu_s = time.process_time()
        self._frames.put(columns)

    def start(self) -> None:
        """Start the fusion thread."""
        self._thread.start()

    @property
    def failed(self) -> bool:
        """Whether the fusion thread ended on an error (:meth:`stop` raises it)."""
        return self._error is not None

    def until_failed(self, chunks: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
        """``chunks`` until the fusion thread fails: the receiver then ends its stream as at its end."""
        return _UntilFailed(chunks, self)

    def stop(self) -> LiveResult:
        """End the walk: the phone's rest, the PDR's last steps, the final tracks; re-raise the thread's error."""
        self._stop.set()
        self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._result is not None
        return self._result

    # ------------------------------------------------------------ the fusion thread

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                began = time.monotonic()
                self._tick(self.phone.poll())
                self._stop.wait(max(self.setup.tick_s - (time.monotonic() - began), 0.0))
            self._tick(self.phone.close())
            self._result = self._finish()
            self._result.cpu_s["fusion"] = time.thread_time()
        except BaseException as exc:  # handed to the main thread by stop()
            self._error = exc

    def _tick(self, chunk: PhoneChunk | None) -> None:
        if chunk is not None:
            self._take_phone(chunk)
        self._take_frames()
        self._try_start()
        self._feed()
        self._write(self._poll_positions(), self.nowcast_rows())
        if self.progress:
            print("\r" + self.status.line(), end="", file=sys.stderr, flush=True)

    def _take_phone(self, chunk: PhoneChunk) -> None:
        for gap in chunk.gaps:
            self.notes.append(f"phone: no {gap.sensor} samples from {gap.start_s:.2f} to {gap.end_s:.2f} s: "
                              "bridged linearly for the PDR, as the file importer does")
        self.notes.extend(chunk.notes)
        if len(chunk.fixes.t_s):
            self._fixes.append(chunk.fixes)
        imu = self._bridged(chunk.imu)
        if not len(imu.t_s):
            return
        if not self._imu and not has_magnetometer(imu) and self.setup.pdr.attitude.use_magnetometer:
            # A stream without a magnetometer gives zeros (the importers' rule): not a field to steer by.
            self.notes.append("phone: no magnetometer in the stream: the PDR's attitude comes from the gyro and "
                              "accelerometer alone (its heading drifts with the gyro's bias)")
            self.pdr = StreamingPdr(dataclasses.replace(self.setup.pdr, attitude=dataclasses.replace(
                self.setup.pdr.attitude, use_magnetometer=False)))
        self._imu.append(imu)
        self._last_imu = imu
        self.status.walk_s = float(imu.t_s[-1])
        if not math.isfinite(self._walk_start_s):
            everything = ImuLog.concatenate(self._imu)
            rate_hz = (len(everything.t_s) - 1) / max(float(np.ptp(everything.t_s)), 1e-9)
            self._walk_start_s = walk_start_s(everything.t_s, everything.acc_mps2, rate_hz)
        steps = self.pdr.add(imu)
        if len(steps):
            self._steps.append(steps)
            self._held_steps.append(steps)
            self.status.steps += len(steps)

    def _bridged(self, imu: ImuLog) -> ImuLog:
        """``imu`` with the grid times a phone gap left out put back (before it or inside it), linear across the
        gap as the file importer makes them: the PDR takes one uniform grid."""
        last = self._last_imu
        if not len(imu.t_s):
            return imu
        known = imu if last is None or not len(last.t_s) else ImuLog.concatenate([last.select(slice(-1, None)), imu])
        steps = np.diff(known.t_s)
        if self._grid_dt is None and len(imu.t_s) > 2:   # the phone grid's spacing, from the first chunk
            self._grid_dt = float(np.median(np.diff(imu.t_s)))
        dt = self._grid_dt
        if dt is None or not len(steps) or np.all(np.abs(steps - dt) <= 0.5 * dt):
            return imu
        grid = known.t_s[0] + dt * np.arange(round((known.t_s[-1] - known.t_s[0]) / dt) + 1)
        if last is not None and len(last.t_s):
            grid = grid[1:]   # the last sample of the previous chunk was handed on already
        return ImuLog(t_s=grid, **{name: interpolate(known.t_s, getattr(known, name), grid)
                                   for name in ("acc_mps2", "gyro_radps", "mag_ut")})

    def _take_frames(self) -> None:
        batches = []
        while True:
            try:
                batches.append(self._frames.get_nowait())
            except queue.Empty:
                break
        if not batches:
            return
        columns = {k: np.concatenate([b[k] for b in batches]) for k in batches[0]}
        ranges = ranges_from_frames(columns)
        self._held_ranges.append(ranges)
        self.status.frames += len(ranges)
        self.status.gaps += int(np.count_nonzero(columns["flags"].astype(np.int64) & int(FrameFlag.GAP)))
        self.status.snr_db = float(np.median(ranges.snr_db))
        clock_hz = self.receiver_clock_hz()
        self.status.clock_offset_hz = math.nan if clock_hz is None else float(clock_hz)
        self.status.capture_s = float(ranges.t_s[-1])
        if self.fusion is None:   # keep only what a fusion about to start could need
            held = RangeSeries.concatenate(self._held_ranges)
            self._held_ranges = [held.select(held.t_s >= held.t_s[-1] - PRE_START_FRAMES_S)]

    def _time_offset_s(self) -> float | None:
        if self.setup.time_offset_s is not None:
            return self.setup.time_offset_s
        capture_utc_ns = self.capture_start_utc_ns()
        if capture_utc_ns is None or self.phone.t0_utc_ns is None:
            return None
        return (capture_utc_ns - self.phone.t0_utc_ns) * 1e-9

    def _try_start(self) -> None:
        """Start the fusion once the frame, the start fix and the clock offset are known."""
        if self.fusion is not None or self._time_offset_s() is None or not math.isfinite(self._walk_start_s):
            return
        fixes = GeodeticFixes.concatenate(self._fixes) if self._fixes else None
        if self.origin is None:
            if fixes is None:
                return
            height = float(fixes.height_m[0]) if math.isfinite(fixes.height_m[0]) else 0.0
            self.origin = GeodeticPoint(float(fixes.lat_deg[0]), float(fixes.lon_deg[0]), height)
        if self.setup.start is not None:
            start_xy, start_sigma = (0.0, 0.0), None
        else:
            if fixes is None or not np.any(fixes.t_s <= self._walk_start_s + 1.0) and not len(self._steps):
                return   # no fix of the standstill yet: wait for one (or for the walk to settle a step)
            self.start_fix = choose_start_fix(self._in_frame(fixes), fixes.accuracy_m, self._walk_start_s, "phone stream", self.notes,
                                              self.setup.start_window_s)
            start_xy, start_sigma = (self.start_fix.fix.x_m, self.start_fix.fix.y_m), self.start_fix.fix.sigma_m
        self.layout = towers_about(self.setup.towers, self.origin)
        self.fusion = StreamingFusion(start_xy, self.layout.tower_xy_m, self.setup.filters,
                                      tower_height_m=self.layout.tower_height_m,
                                      other_towers=self.layout.other_towers, start_sigma_m=start_sigma,
                                      config=self.setup.fusion)
        if self.view is not None:
            self.view.set_scene(_scene(start_xy, start_sigma, self.layout))

    def _in_frame(self, fixes: GeodeticFixes) -> GnssLog:
        """``fixes`` in the walk's east/north frame (about :attr:`origin`); a fix without a height at the origin's,
        as the file importer places it."""
        height = np.where(np.isfinite(fixes.height_m), fixes.height_m, self.origin.height_m)
        east, north, _ = to_enu(fixes.lat_deg, fixes.lon_deg, height, self.origin)
        return GnssLog(t_s=fixes.t_s, x_m=east, y_m=north, cn0_dbhz=fixes.cn0_dbhz)

    def _feed(self) -> None:
        if self.fusion is None:
            return
        offset = self._time_offset_s()
        if self._held_ranges:
            ranges = RangeSeries.concatenate(self._held_ranges)
            self._held_ranges = []
            self.fusion.add_ranges(dataclasses.replace(ranges, t_s=ranges.t_s + offset))
        if self._held_steps:
            self.fusion.add_steps(PdrSteps.concatenate(self._held_steps))
            self._held_steps = []

    def _poll_positions(self) -> list[GeoPositions]:
        if self.fusion is None:
            return []
        rows = self.fusion.poll()
        if not len(rows):
            return []
        self._last_settled = rows
        stage = np.where(rows.filtered, STAGE_FILTERED, STAGE_HEADING)
        return [self._geo(rows, stage)]

    def nowcast_rows(self) -> list[GeoPositions]:
        """The now-cast past the last settled step (the PDR's provisional steps), held on to the newest sample."""
        if self.fusion is None:
            return []
        provisional = self.pdr.provisional()
        self.status.provisional_steps = len(provisional)
        newest_step = provisional.t_s[-1] if len(provisional) else (self._steps[-1].t_s[-1] if self._steps else None)
        if newest_step is not None:
            self.status.step_lag_s = self.status.walk_s - float(newest_step)
        rows = self.fusion.nowcast(provisional) if len(provisional) else LivePositions.empty()
        last = rows if len(rows) else self._last_settled
        if last is not None and len(last) and self.status.walk_s > float(last.t_s[-1]):
            rows = LivePositions.concatenate([rows, hold_position(last, self.status.walk_s)]) if len(rows) else \
                hold_position(last, self.status.walk_s)
        return [self._geo(rows, np.full(len(rows), STAGE_NOWCAST))] if len(rows) else []

    def _geo(self, rows: LivePositions, stage: np.ndarray) -> GeoPositions:
        return GeoPositions.from_track(self.fusion.live_filter, stage, rows, self.origin, self.phone.t0_utc_ns or 0)

    def _write(self, settled: list[GeoPositions], head: list[GeoPositions]) -> None:
        for positions in settled + head:
            self.writer.write(positions)
            self.status.positions += len(positions.track)
            self.status.stage = str(positions.stage[-1])
            radius = float(positions.track.accuracy_radius_m()[-1])
            self.status.position = (f"{positions.lat_deg[-1]:.6f}, {positions.lon_deg[-1]:.6f} +- {radius:.1f} m "
                                    "(95 %)")
        self._keep_time(max((float(p.track.t_s[-1]) for p in settled + head), default=-math.inf))
        if self.view is not None:
            for positions in settled:
                self.view.add_rows(_view_rows(positions))
            self.view.set_head([row for positions in head for row in _view_rows(positions)])
            self.view.set_status(**{"frames": self.status.frames, "SNR dB": round(self.status.snr_db, 1)
                                    if math.isfinite(self.status.snr_db) else None,
                                    "steps": self.status.steps})

    def _keep_time(self, newest_s: float) -> None:
        """Update the lag figures with this update's newest position time, s (-inf: none)."""
        now = time.monotonic()
        if newest_s > -math.inf:
            if self.fusion is not None and self.fusion.heading is not None and self._last_write is not None:
                self.status.longest_silence_s = max(self.status.longest_silence_s, now - self._last_write)
            self._last_write = now
            self._newest_position_s = max(self._newest_position_s, newest_s)
        self.status.lag_s = self.status.walk_s - self._newest_position_s

    def _finish(self) -> LiveResult:
        steps = self.pdr.finish()
        if len(steps):
            self._steps.append(steps)
            self._held_steps.append(steps)
            self.status.steps += len(steps)
        self._take_frames()
        self._try_start()
        result = None
        if self.fusion is not None:
            self._feed()
            try:
                result = self.fusion.finish()
            except ValueError as exc:
                self.notes.append(f"fusion: {exc}")
            self._write(self._poll_positions(), [])
        elif self._time_offset_s() is None:
            self.notes.append("no position: the capture's start time or the phone's never came (no samples?)")
        else:
            self.notes.append("no position: no start fix (the phone gave no fix; give --start LAT,LON)")
        if self.progress:
            print(file=sys.stderr)
        return LiveResult(result, self.status, self.notes, self.start_fix, self.origin, self._time_offset_s())

    # ------------------------------------------------------------ the recording

    def write_recording(self, path: str | os.PathLike, result: LiveResult) -> None:
        """``/imu``, ``/gnss`` (and its start fix), ``/pdr`` and ``/fusion/<filter>`` of the walk, to ``path``."""
        with atomic_h5(path) as h5:
            if self._imu:
                write_imu(h5, ImuLog.concatenate(self._imu), {schema.START_UTC_NS_ATTR: np.int64(self.phone.t0_utc_ns),
                                                  schema.HAS_MAGNETOMETER_ATTR: True, "source": "live phone stream"})
            if self._fixes and self.origin is not None:
                fixes = GeodeticFixes.concatenate(self._fixes)
                write_gnss(h5, self._in_frame(fixes),
                           self.start_fix.fix if self.start_fix else None,
                           {**dict(zip(schema.ORIGIN_ATTRS, (self.origin.lat_deg, self.origin.lon_deg,
                                                             self.origin.height_m))),
                            schema.WALK_START_ATTR: self._walk_start_s},
                           extra_columns={"accuracy_m": fixes.accuracy_m, "lat_deg": fixes.lat_deg,
                                          "lon_deg": fixes.lon_deg})
            if self._steps:
                write_columns(h5, schema.PDR, PdrSteps.concatenate(self._steps), {"source": "streaming PDR (settled steps)"})
            if result.fusion is not None:
                from dtmbnav.chain.fuse import write_fusion

                write_fusion(h5, result.fusion)
                h5.require_group(schema.FUSION).attrs.update({"time_offset_s": result.time_offset_s or np.nan,
                                                              "live": True})


def _scene(start_xy: tuple[float, float], start_sigma: float | None, layout: TowerLayout) -> ViewScene:
    towers = [layout.tower_xy_m, *[(x, y) for x, y, _ in layout.other_towers]]
    de = [(x - start_xy[0], y - start_xy[1]) for x, y in towers]
    return ViewScene(start_xy[0], start_xy[1], math.nan if start_sigma is None else start_sigma,
                     [math.degrees(math.atan2(e, n)) % 360.0 for e, n in de], [math.hypot(e, n) for e, n in de])


def _view_rows(positions: GeoPositions) -> list[ViewRow]:
    t = positions.track
    rows = []
    for k in range(len(t)):
        major, minor, angle = ellipse_95(t.var_x_m2[k], t.var_y_m2[k], t.cov_xy_m2[k]) \
            if np.isfinite(t.var_x_m2[k]) else (math.nan, math.nan, 0.0)
        rows.append(ViewRow(float(t.t_s[k]), float(t.x_m[k]), float(t.y_m[k]), float(positions.lat_deg[k]),
                            float(positions.lon_deg[k]), major, minor, angle, str(positions.stage[k])))
    return rows


def run_live(source: RtlTcpSource, phone: PhoneStream, setup: LiveSetup, folder: str | os.PathLike,
             receiver_config: ReceiverConfig, carrier_hz: float, view: LiveView | None = None,
             progress: bool = True) -> LiveResult:
    """``dtmbnav live``: receive ``source`` on this thread while :class:`LiveWalk` fuses on its own, then write
    the recording (module docstring). ``carrier_hz``: the DTMB channel's centre, Hz.

    On SIGINT or SIGTERM the stream ends, the walk is finished and written as at the stream's end, and
    :class:`~dtmbnav_core.interrupt.Interrupted` is raised after. Open an rtl_tcp source first
    (``source.open()``) to have no output folder made for a server that does not answer.
    """
    paths = output_paths(folder)
    Path(folder).mkdir(parents=True, exist_ok=True)
    interrupted: Interrupted | None = None
    with LivePositionWriter(paths["csv"], paths["geojson"]) as writer:
        walk = LiveWalk(phone, setup, writer, view, progress, capture_start_utc_ns=lambda: source.start_utc_unix_ns)
        walk.start()
        receiver_cpu_s = time.thread_time()
        try:
            rx = Receiver(source.sample_rate_hz, carrier_hz, receiver_config)
            walk.receiver_clock_hz = lambda: rx.ranging.clock_offset_hz
            receive_stream(source, rx, RangeTee(paths["receiver"], walk.on_frames), progress=False,
                           until=walk.until_failed)
        except Interrupted as exc:
            interrupted = exc
        finally:
            receiver_cpu_s = time.thread_time() - receiver_cpu_s
            result = walk.stop()
            result.cpu_s.update(receiver=receiver_cpu_s, process=time.process_time())
            if walk._first_frame_cpu_s is not None:
                result.cpu_s["after_first_frame"] = result.cpu_s["process"] - walk._first_frame_cpu_s
        walk.write_recording(paths["live"], result)
    if interrupted is not None:
        raise interrupted
    return result
