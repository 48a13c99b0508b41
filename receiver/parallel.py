"""The per-frame work of a batch (channel estimate, body recovery, SI DFT) on one or more threads.

Once the frame windows of a batch are placed (:meth:`receiver.tracking.FrameTracker.predict`),
each frame's header-window derotation, channel estimate (:mod:`receiver.channel_estimate`,
and the path tracker's wider span of it, or its views, when asked for), body recovery
(:mod:`receiver.body`) and SI carriers (:mod:`receiver.ofdm`) depend on that frame's
samples only; the timing loop, the estimators and the path tracker
(:mod:`receiver.paths`), which link consecutive frames, run afterwards, in order, on
the main thread.

A batch is cut into blocks of :data:`FRAME_BLOCK` frames. The blocks are the same
whatever the number of threads, each is computed by one thread with its own buffers
(the numba kernels release the GIL), and the results are put back in frame order, so
the output is bit-identical for any ``jobs``. Blocks also keep the bodies a kernel
writes in the cache when the DFT reads them.

With more than one thread, the next batch's blocks can also start early
(:meth:`FrameWorkers.prefetch`): the caller places the next batch's windows
where the timing loop would put them before it has taken the current batch,
and the pool works on them while the calling thread runs the sequential
update. When the batch comes, each block whose inputs (windows, header
phases, coarse CFO, samples) are exactly those prefetched takes the
prefetched result, and any other is computed afresh: a block's result is a
function of its inputs alone, so prefetching changes when the work is done,
never what it gives. The path tracker's views are planned only once the batch
before is done: a block prefetched without them gets their taps on the calling
thread when the batch comes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from functools import partial
from itertools import pairwise

import numpy as np
from numba import njit

from dtmbnav_core.gb20600 import PnMode
from receiver.body import body_phases, recover_bodies
from receiver.channel_estimate import ChannelEstimates, ChannelEstimator, deconvolve_kernel, estimate_cyclic_kernel
from receiver.derotate import derotate_segments
from receiver.ofdm import OfdmDemodulator, si_dft_kernel

#: Frames per block of work: the unit one thread processes (fixed, so results do not depend on the
#: thread count), small enough that a block's bodies stay in the cache between body recovery and DFT.
FRAME_BLOCK = 32
#: Stages timed per block (:attr:`BatchFrames.seconds`), named as in :data:`receiver.pipeline.STAGES`: a block run
#: ahead in one compiled call (:meth:`FrameWorkers.prefetch`) counts as "frames" only.
BLOCK_STAGES = ("channel", "body", "fft", "frames")


@dataclass
class BatchWindows:
    """What the per-frame work of a batch reads.

    Attributes
    ----------
    samples : callable
        ``samples(start, stop)``: stream samples ``[start, stop)`` as one
        contiguous complex64 array (e.g. :meth:`receiver.pipeline.SampleQueue.view`).
        Each block asks only for its own span, so only a block that straddles
        two input chunks is copied.
    starts : ndarray, int64, (B,)
        Window start (first header sample) of each frame, stream index.
    phases : ndarray, int64, (B + 1,)
        Header phase of each frame and of the header after the last one.
    headers : ndarray, complex64, (B + 1, Ng)
        Transmitted header symbols of those phases.
    cfo_cycles_per_sample : float
        Coarse CFO, cycles per sample.
    rot : ndarray, complex64
        :func:`receiver.derotate.rotation_table` of the coarse CFO.
    first_sample : int
        First stream index ``samples`` holds: the path tracker's views
        (:meth:`FrameWorkers.run`) may reach before it at the start of the
        stream, where they read zeros.
    """

    samples: Callable[[int, int], np.ndarray]
    starts: np.ndarray
    phases: np.ndarray
    headers: np.ndarray
    cfo_cycles_per_sample: float
    rot: np.ndarray
    first_sample: int = 0


@dataclass
class SpanTaps:
    """The channel over the path tracker's delay span (:meth:`receiver.channel_estimate.ChannelEstimator.span_taps`).

    Attributes
    ----------
    raw_taps : ndarray, complex64, (B, taps_before + taps_after)
        Column ``j`` is delay ``j - taps_before`` samples.
    noise_tap : ndarray, (B,)
        Mean tap power on the lags outside the span.
    views : ndarray, complex64, (B, V, P) or None
        The taps of the views asked for (:meth:`receiver.channel_estimate.ChannelEstimator.view_taps`).
    """

    raw_taps: np.ndarray
    noise_tap: np.ndarray
    views: np.ndarray | None = None


@dataclass
class BatchFrames:
    """Per-frame results of a batch, in frame order.

    Attributes
    ----------
    channel : ChannelEstimates
    si : ndarray, complex64, (B, 36)
        SI carriers (coarse-CFO phase of each body applied).
    bodies : ndarray, complex64, (B, 3780) or None
        Recovered bodies without their coarse-CFO phase (see :func:`receiver.body.body_phases`), only when
        asked for (``ReceiverConfig.inspect``).
    span : SpanTaps or None
        The channel over the span asked for (``span`` of :meth:`FrameWorkers.run`), else None.
    seconds : dict
        Time spent per stage of :data:`BLOCK_STAGES`, summed over the blocks (over
        the threads' time when several run at once).
    """

    channel: ChannelEstimates
    si: np.ndarray
    bodies: np.ndarray | None
    span: SpanTaps | None
    seconds: dict[str, float]


class FrameWorkers:
    """Runs the per-frame work of batches in blocks, on ``jobs`` threads.

    Parameters
    ----------
    jobs : int
        Threads, the calling one included (1: everything on the calling thread).
    taps_before, taps_after : int
        Channel-estimate delay span, samples.
    tap_threshold : float
        Tap power over noise floor needed to keep a tap.
    noise_guard : int
        Lags on each side of the tap span left out of the noise floor
        (:class:`receiver.channel_estimate.ChannelEstimator`).
    """

    def __init__(self, jobs: int, taps_before: int, taps_after: int, tap_threshold: float,
                 noise_guard: int = 0) -> None:
        if jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {jobs}")
        self.jobs = jobs
        self._taps = (taps_before, taps_after, tap_threshold, noise_guard)
        self._pool = ThreadPoolExecutor(jobs - 1, thread_name_prefix="frames") if jobs > 1 else None
        self._local = threading.local()     # per thread: its estimators (one per mode) and demodulator
        #: Blocks started by prefetch(): their inputs' key -> (future of _block's result, the views' taps).
        self._prefetched: dict[tuple, tuple[Future, np.ndarray | None]] = {}
        #: Blocks of the batches run so far that a prefetch had computed, and all blocks run.
        self.prefetch_hits = 0
        self.blocks_run = 0

    def _estimator(self, mode: PnMode) -> ChannelEstimator:
        """This thread's channel estimator for ``mode`` (window placement is the same in every thread's)."""
        estimators = self._buffers()[0]
        if mode not in estimators:
            estimators[mode] = ChannelEstimator(mode, FRAME_BLOCK, *self._taps)
        return estimators[mode]

    def run(self, mode: PnMode, windows: BatchWindows, keep_bodies: bool = False,
            span: tuple[int, int] | None = None, views: tuple[int, ...] = (), generation: int = 0) -> BatchFrames:
        """Channel estimates, SI carriers (and bodies when ``keep_bodies``) of every frame of a batch.

        ``span`` = ``(taps_before, taps_after)``: also the raw taps over that delay span (the path
        tracker's, :mod:`receiver.paths`; PN420 and PN945 only), and with ``views`` (shifts,
        samples) the taps of those views. ``generation`` names the samples ``windows.samples``
        gives (the caller changes it whenever the samples at a stream index may change, e.g.
        when the stream is conjugated); blocks prefetched under another generation are not used.
        """
        count = len(windows.starts)
        blocks = _blocks(count)
        views_out = np.empty((count, len(views), mode.value.period), np.complex64) if views else None
        work = partial(self._block, mode, windows, keep_bodies=keep_bodies, span=span, views=views,
                       views_out=views_out)
        prefetched, self._prefetched = self._prefetched, {}
        hits = {}
        # Blocks prefetched without the views (the path tracker plans them only once the batch before is
        # done): their views' taps are taken here, on the calling thread (:meth:`_view_block`).
        without_views: set[tuple[int, int]] = set()
        for block in blocks if prefetched else ():
            for asked in (views, ()) if views else (views,):
                buf_start = self._block_span(mode, windows, *block, asked)[0]
                key = self._key(mode, windows, *block, buf_start, keep_bodies, span, asked, generation)
                if key in prefetched:
                    hits[block] = prefetched.pop(key)
                    if asked != views:
                        without_views.add(block)
                    break
        for future, _ in prefetched.values():   # prefetched for a batch that did not come
            future.cancel()
        self.prefetch_hits += len(hits)
        self.blocks_run += len(blocks)

        def run_share(share: list[tuple[int, int]]) -> list[tuple]:
            return [work(*block) for block in share]

        if hits:
            # This thread takes back the prefetched blocks the pool has not started (the last ones first, the
            # pool takes them first to last) and does them with the ones not prefetched.
            for block in reversed(list(hits)):
                if hits[block][0].cancel():
                    del hits[block]
            missed = [block for block in blocks if block not in hits]
            done = dict(zip(missed, run_share(missed)))
            for block in without_views & hits.keys():
                self._view_block(mode, windows, *block, views, views_out)
            for (lo, hi), (future, pre_views) in hits.items():
                done[lo, hi] = future.result()
                if views_out is not None and (lo, hi) not in without_views:
                    views_out[lo:hi] = pre_views[lo:hi]
            parts = [done[block] for block in blocks]
        else:
            # Thread i takes the i-th of `jobs` consecutive shares of the blocks; this thread takes the first
            # and works while the others run theirs (one hand-off per thread and batch).
            threads = min(self.jobs if self._pool is not None else 1, len(blocks))
            edges = np.linspace(0, len(blocks), max(threads, 1) + 1).round().astype(int)
            shares = [blocks[a:b] for a, b in pairwise(edges)]
            others = [self._pool.submit(run_share, share) for share in shares[1:]] if self._pool is not None else []
            parts = run_share(shares[0]) + [part for future in others for part in future.result()]
        channel = ChannelEstimates(**{f.name: np.concatenate([getattr(p[0], f.name) for p in parts])
                                      for f in fields(ChannelEstimates)})
        si = np.concatenate([p[1] for p in parts])
        bodies = np.concatenate([p[2] for p in parts]) if keep_bodies else None
        spans = SpanTaps(np.concatenate([p[3][0] for p in parts]),
                         np.concatenate([p[3][1] for p in parts]), views_out) if span is not None else None
        seconds = {stage: sum(p[4][i] for p in parts) for i, stage in enumerate(BLOCK_STAGES)}
        return BatchFrames(channel, si, bodies, spans, seconds)

    def prefetch(self, mode: PnMode, windows: BatchWindows, keep_bodies: bool = False,
                 span: tuple[int, int] | None = None, views: tuple[int, ...] = (), generation: int = 0) -> None:
        """Start the blocks of a batch expected next on the pool's threads, and return at once.

        The arguments are those the next :meth:`run` is expected to get. The
        samples of every block are taken here, on the calling thread (the
        caller's sample store need not be thread-safe); blocks not used by the
        next :meth:`run` are dropped. Nothing happens with ``jobs = 1``.
        """
        if self._pool is None:
            return
        views_out = np.empty((len(windows.starts), len(views), mode.value.period), np.complex64) if views else None
        compiled = mode.value.cyclic_length > 0 and not views
        for lo, hi in _blocks(len(windows.starts)):
            buf, buf_start = self._block_samples(mode, windows, lo, hi, views)
            fixed = replace(windows, samples=_Span(buf, buf_start).samples, first_sample=buf_start)
            block = self._compiled_block if compiled else self._block
            future = self._pool.submit(block, mode, fixed, lo, hi, keep_bodies, span, views, views_out)
            key = self._key(mode, windows, lo, hi, buf_start, keep_bodies, span, views, generation)
            self._prefetched[key] = (future, views_out)

    @staticmethod
    def _key(mode: PnMode, w: BatchWindows, lo: int, hi: int, buf_start: int, keep_bodies: bool,
             span: tuple[int, int] | None, views: tuple[int, ...], generation: int) -> tuple:
        """Everything block ``lo:hi``'s result depends on (the samples by their generation and by the zero padding
        before the stream's first sample, from ``buf_start``, the first sample the block reads)."""
        return (mode, lo, hi, w.starts[lo:hi].tobytes(), w.phases[lo:hi + 1].tobytes(), w.cfo_cycles_per_sample,
                max(w.first_sample - buf_start, 0), keep_bodies, span, views, generation)

    def close(self) -> None:
        """Stop the threads (the object cannot run batches afterwards)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def _buffers(self) -> tuple[dict[PnMode, ChannelEstimator], OfdmDemodulator]:
        local = self._local
        if not hasattr(local, "ofdm"):
            local.estimators, local.ofdm = {}, OfdmDemodulator(FRAME_BLOCK)
        return local.estimators, local.ofdm

    def _block_span(self, mode: PnMode, w: BatchWindows, lo: int, hi: int,
                    views: tuple[int, ...]) -> tuple[int, int]:
        """Stream samples ``[start, stop)`` frames ``lo:hi`` read."""
        taps_before, taps_after = self._taps[:2]
        est = self._estimator(mode)
        # A frame reads from taps_before before its header (or from its earliest view's window) to the next
        # header's first taps_after samples.
        start = int(w.starts[lo]) - max(taps_before, -est.window_offset - min(views, default=0))
        return start, int(w.starts[hi - 1]) + mode.value.frame_length + taps_after + 1

    def _block_samples(self, mode: PnMode, w: BatchWindows, lo: int, hi: int,
                       views: tuple[int, ...]) -> tuple[np.ndarray, int]:
        """The samples frames ``lo:hi`` read, and the stream index of the first."""
        buf_start, buf_stop = self._block_span(mode, w, lo, hi, views)
        if buf_start < w.first_sample:
            # The stream's first frames: the earliest views reach before its first sample.
            return np.concatenate([np.zeros(w.first_sample - buf_start, np.complex64),
                                   w.samples(w.first_sample, buf_stop)]), buf_start
        return w.samples(buf_start, buf_stop), buf_start

    def _block(self, mode: PnMode, w: BatchWindows, lo: int, hi: int, keep_bodies: bool,
               span: tuple[int, int] | None, views: tuple[int, ...] = (),
               views_out: np.ndarray | None = None) -> tuple[ChannelEstimates, np.ndarray, np.ndarray | None,
                                                             tuple[np.ndarray, np.ndarray] | None, tuple[float, ...]]:
        """Frames ``lo:hi`` of a batch, on this thread's buffers (the views' taps into ``views_out[lo:hi]``)."""
        est, ofdm = self._estimator(mode), self._buffers()[1]
        taps_before = self._taps[0]
        ng = mode.value.header_length
        starts = w.starts[lo:hi]
        t0 = time.perf_counter()
        buf, buf_start = self._block_samples(mode, w, lo, hi, views)
        derotate_segments(buf, buf_start, starts + est.window_offset, est.window_length, w.cfo_cycles_per_sample,
                          w.rot, est.windows)
        ch = est.estimate(hi - lo, w.phases[lo:hi])
        span_taps = est.span_taps(hi - lo, *span) if span is not None else None
        if views_out is not None:
            est.view_taps(hi - lo, buf, buf_start, starts, views, w.phases[lo:hi], w.cfo_cycles_per_sample, w.rot,
                          views_out[lo:hi])
        t1 = time.perf_counter()
        phase = body_phases(starts, ng, taps_before, w.cfo_cycles_per_sample)
        recover_bodies(buf, buf_start, starts, ng, w.rot, phase, ch.taps, taps_before, w.headers[lo:hi],
                       w.headers[lo + 1: hi + 1], ofdm.bodies)
        t2 = time.perf_counter()
        si = ofdm.si_carriers(hi - lo, phase)
        t3 = time.perf_counter()
        bodies = ofdm.bodies[: hi - lo].copy() if keep_bodies else None
        return ch, si, bodies, span_taps, (t1 - t0, t2 - t1, t3 - t2, 0.0)

    def _view_block(self, mode: PnMode, w: BatchWindows, lo: int, hi: int, views: tuple[int, ...],
                    views_out: np.ndarray) -> None:
        """The views' taps of frames ``lo:hi`` alone (into ``views_out[lo:hi]``), as :meth:`_block` takes them.

        The frame's own window (shift 0) is read from the channel estimate's
        correlations, so those are made again; the bodies are not.
        """
        est = self._estimator(mode)
        starts = w.starts[lo:hi]
        buf, buf_start = self._block_samples(mode, w, lo, hi, views)
        derotate_segments(buf, buf_start, starts + est.window_offset, est.window_length, w.cfo_cycles_per_sample,
                          w.rot, est.windows)
        est.estimate(hi - lo, w.phases[lo:hi])
        est.view_taps(hi - lo, buf, buf_start, starts, views, w.phases[lo:hi], w.cfo_cycles_per_sample, w.rot,
                      views_out[lo:hi])

    def _compiled_block(self, mode: PnMode, w: BatchWindows, lo: int, hi: int, keep_bodies: bool,
                        span: tuple[int, int] | None, views: tuple[int, ...] = (),
                        views_out: np.ndarray | None = None) -> tuple[ChannelEstimates, np.ndarray, np.ndarray | None,
                                                                      tuple[np.ndarray, np.ndarray] | None,
                                                                      tuple[float, ...]]:
        """:meth:`_block` of a PN420/PN945 block without views, in one compiled call (:func:`frame_block_kernel`).

        Takes :meth:`_block`'s arguments (``views`` must be empty). The GIL is
        taken only to set the call up: a pool thread running it ahead does not
        wait for the thread that runs the sequential update between stages.
        Its time is reported as the ``frames`` stage.
        """
        est, ofdm = self._estimator(mode), self._buffers()[1]
        taps_before = self._taps[0]
        count, ng = hi - lo, mode.value.header_length
        starts = w.starts[lo:hi]
        t0 = time.perf_counter()
        buf, buf_start = self._block_samples(mode, w, lo, hi, views)
        phase = body_phases(starts, ng, taps_before, w.cfo_cycles_per_sample)
        ch = ChannelEstimates.empty(count, est.n_taps)
        span_bins = est.span_bins(*span) if span is not None else (est.tap_bins, est.noise_bins)
        span_taps = (np.empty((count, len(span_bins[0])), np.complex64), np.empty(count))
        si = np.empty((count, len(ofdm.slot_of_si)), np.complex64)
        frame_block_kernel(buf, buf_start, starts, est.window_offset, est.window_length,
                           w.cfo_cycles_per_sample, w.rot, est.windows, est.header_shifts(w.phases[lo:hi]),
                           est.cyclic_tables, est.summary_settings, ch.raw_taps, ch.taps, ch.snr_db, ch.noise_power,
                           ch.peak_metric, ch.centroid, span is not None, span_bins, span_taps[0], span_taps[1], ng,
                           phase, w.headers[lo:hi + 1], ofdm.bodies, ofdm.si_tables, si)
        bodies = ofdm.bodies[:count].copy() if keep_bodies else None
        return ch, si, bodies, span_taps if span is not None else None, (0.0, 0.0, 0.0, time.perf_counter() - t0)


@njit(cache=True, nogil=True)
def frame_block_kernel(buf: np.ndarray, buf_start: int, starts: np.ndarray, window_offset: int, window_length: int,
                       cfo_cycles_per_sample: float, rot: np.ndarray, windows: np.ndarray, shifts: np.ndarray, tables: tuple, settings: tuple, raw: np.ndarray, taps: np.ndarray,
                       snr_db: np.ndarray, noise_power: np.ndarray, peak: np.ndarray, centroid: np.ndarray,
                       with_span: bool, span_bins: tuple, span_raw: np.ndarray, span_noise: np.ndarray,
                       header_length: int, frame_phases: np.ndarray, headers: np.ndarray, bodies: np.ndarray,
                       si_tables: tuple, si: np.ndarray) -> None:
    """The per-frame work of one PN420/PN945 block, the kernels of :meth:`FrameWorkers._block` in its order.

    Header-window derotation (:func:`receiver.derotate.derotate_segments`),
    channel estimate (:func:`receiver.channel_estimate.estimate_cyclic_kernel`),
    the path tracker's span (:func:`receiver.channel_estimate.deconvolve_kernel`,
    when ``with_span``), body recovery (:func:`receiver.body.recover_bodies`)
    and SI DFT (:func:`receiver.ofdm.si_dft_kernel`): the same kernels on the
    same inputs, so the same outputs, without returning to Python between
    them. ``headers`` holds the header symbols of ``len(starts) + 1`` phases
    (each frame's and the next one's).
    """
    count = starts.shape[0]
    derotate_segments(buf, buf_start, starts + window_offset, window_length, cfo_cycles_per_sample, rot, windows)
    estimate_cyclic_kernel(windows[:count], shifts, tables, settings, raw, taps, snr_db, noise_power, peak, centroid)
    if with_span:
        deconvolve_kernel(tables[4][:count], span_bins[0], span_bins[1], span_raw, span_noise)
    recover_bodies(buf, buf_start, starts, header_length, rot, frame_phases, taps, settings[3], headers[:count],
                   headers[1:count + 1], bodies)
    inner_twiddles, twiddles, slot_of_si, work = si_tables
    si_dft_kernel(bodies, count, inner_twiddles, twiddles, slot_of_si, frame_phases, work, si)


def _blocks(count: int) -> list[tuple[int, int]]:
    """The blocks ``(lo, hi)`` of a batch of ``count`` frames (the same for any number of threads)."""
    return [(lo, min(lo + FRAME_BLOCK, count)) for lo in range(0, count, FRAME_BLOCK)]


@dataclass(frozen=True)
class _Span:
    """Samples taken ahead for one block: ``samples(start, stop)`` over the stream indices they cover."""

    buf: np.ndarray
    first: int

    def samples(self, start: int, stop: int) -> np.ndarray:
        return self.buf[start - self.first: stop - self.first]
