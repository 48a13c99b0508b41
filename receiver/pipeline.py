"""The streaming DTMB receiver: IQ chunks in, per-frame results out.

Data path (each stage its own module)::

    input chunks -> [shift onto the channel (mixer.py)] -> resample (resample.py) -> acquisition (acquisition.py)
      -> per batch of frames, per frame on ``jobs`` threads (parallel.py):
         header windows + channel estimate (channel_estimate.py),
         header-tail removal + cyclic reconstruction (body.py), SI carriers (ofdm.py)
      -> timing loop / loss of lock (tracking.py)
      -> SI and PN CFO estimates (cfo.py) -> f_s, Doppler, range (ranging.py)
      beside them: the paths in the header CIR, their delays and carrier phases,
      the first path's range and the towers' range differences (paths.py)

The receiver works on the 7.56 Msps stream in fixed batches of
``batch_frames`` frames, processed only when all their samples have arrived,
and starts acquisition attempts at fixed stream positions: the output is
identical whatever the input chunk size, and memory stays flat (the buffer
holds about one batch). A batch reads only buffered samples (the buffer
refuses any other range), so no result depends on memory that was never
written. ``ReceiverConfig.inspect`` receives each stage's intermediate output
per batch, for debugging and plots.

**Narrowband captures.** A capture below 7.56 Msps (an RTL-SDR at 2.048-3.2
Msps) holds only the band-limited centre of the channel; it is resampled to
7.56 Msps like any other and received the same way: the 36 SI carriers lie
within +-36 kHz of DC, and the band-limited PN headers still give the frame
grid. The SI SNR is measured against the noise per carrier (the noise the
resampler lets through, scaled by its noise bandwidth); what such a capture
cannot give (the header SNR and the channel taps cover only the recorded
band, so paths closer than a few chips merge) is stated in the attributes
(``narrowband``, ``bandwidth_hz``) and in :meth:`Receiver.notes`. The path
tracker is switched off there (``path_tracking`` false): its "first path"
would be a blend of merged paths whose phase wanders.

**Off-centre tuning.** With ``ReceiverConfig.channel_offset_hz`` (channel
centre minus capture centre, Hz) non-zero, the input is first shifted by
that much (:class:`receiver.mixer.StreamMixer`, phase from the absolute input
sample index) so that the channel lies at DC; at 0 no such stage runs. A
front end that swaps I and Q mirrors the spectrum, the channel's place
included, so an off-centre capture's orientation is given
(``iq_orientation``; ``"auto"`` takes it as normal and says so) and a
conjugated input is conjugated before the shift. The
carrier handed to :class:`Receiver` is the channel's (eq. 10 converts
Doppler with it), not the capture's centre.

**I/Q orientation.** With ``iq_orientation = "auto"`` the rows of the first
lock are held until the SI word has been scored in both orientations
(:class:`receiver.cfo.SiWordDetector`); if it decodes only conjugated, the
buffered samples are conjugated and the lock is made again from its
acquisition window, so the output is what ``"conjugate"`` gives.

**Segments.** Each lock is a segment (``segment_id``: 0 for the first lock,
+1 at each re-acquisition); the range is held flat across the gap between
segments (:mod:`receiver.ranging`).

**Dropped samples** (:mod:`receiver.drops`). A frame timing that jumps by
other than whole frames is a drop. Inside a lock the batch ends before the
drop and the timing loop's grid moves by it, so the next batch's windows are
aligned; a drop too long for the channel window ends the lock, and the
re-acquisition is measured against the grid the lost lock coasted on. The
lost input samples are added to ``t_s`` from then on (the real clock), the
frame after the drop is flagged DROP (no CFO pair), the ranges bridge the
drop with the recent Doppler, and a re-acquisition that only skipped a short
drop continues the segment and its paths.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any

import numpy as np
from tqdm import tqdm

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SI_REFERENCE_GAIN
from dtmbnav_core.gb20600 import BODY_LENGTH, SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.records import FrameBatch, FrameFlag, PathBatch
from receiver import DEFAULT_CFO_SEARCH_HZ, DEFAULT_STATIC_WINDOW_S
from receiver.acquisition import CFO_OUTSIDE_SEARCH, Acquisition, search_window, window_length
from receiver.capture import CaptureSource
from receiver.cfo import (SiWordDetector, cfo_from_advance, cfo_from_theta, expected_phase_variance,
                          pn_theta_kernel, si_phase_kernel)
from receiver.channel_estimate import TAP_THRESHOLD, TAPS_AFTER, TAPS_BEFORE, ChannelEstimates
from receiver.derotate import rotation_table
from receiver.drops import MAX_BRIDGE_S, MAX_IN_LOCK_STEP, MIN_STEP, DropLog, find_in_lock_drop, lost_input_samples
from receiver.frontend_correction import FrontEndCorrector, frontend_warnings
from receiver.mixer import StreamMixer
from receiver.ofdm import si_carrier_numbers, si_snr_db
from receiver.parallel import BatchWindows, FrameWorkers
from receiver.paths import PathConfig, PathTracker
from receiver.ranging import FIRST_PATH_COLUMNS, PathRanging, RangeIntegrator
from receiver.reader import read_ahead
from receiver.resample import StreamResampler
from receiver.tracking import FrameTracker, LockMonitor
from receiver.writer import FrameSink

#: The stages handed to ``ReceiverConfig.inspect``, in the order of the data path.
INSPECT_STAGES = ("channel", "tracking", "body", "ofdm", "paths")

#: Search position after the end of the stream (no acquisition window can fit).
END_OF_STREAM = np.iinfo(np.int64).max // 4
#: Stage names of :attr:`Receiver.stage_seconds`: front-end correction (DC and I/Q), resampling, acquisition
#: (searches and lock set-up, a one-off cost per lock) and, per batch, sync (timing loop), channel estimate,
#: body recovery, SI DFT, estimators, path tracking; and "frames", the per-frame work (channel estimate, body
#: recovery, SI DFT) of the blocks run ahead on other threads with ``jobs`` > 1 (receiver.parallel).
STAGES = ("frontend", "resample", "acquisition", "sync", "channel", "body", "fft", "estimators", "paths", "frames")
#: Lags on each side of the channel-estimate span kept out of the noise floor for a narrowband
#: capture: its paths' spectrum ends at the capture's band edge, so each path rings for tens of
#: samples, which would otherwise read as noise (and lower the SNRs).
NARROWBAND_NOISE_GUARD = 32
#: Per-carrier SNR above which the SI phase scatter is compared with its value here, dB: far above the
#: noise, residues other than thermal noise (the channel's change over a frame, leakage) set the
#: scatter, and the CFO is far better than needed.
SCATTER_SNR_CEILING_DB = 30.0
#: Values of ``ReceiverConfig.iq_orientation``.
IQ_ORIENTATIONS = ("auto", "normal", "conjugate")
#: Frames of SI (at least; whole batches) on which ``iq_orientation = "auto"`` decides.
ORIENTATION_FRAMES = 64
#: A frame whose SI phase scatter exceeds this many times the thermal-noise expectation at its SI SNR
#: is flagged LOW_QUALITY (receiver.cfo). For a clean frame the ratio is a chi-square of about 35
#: degrees of freedom over its mean, widened by the noise of the SI SNR estimate: 4 leaves both far behind.
CFO_SCATTER_LIMIT = 4.0


@dataclass
class ReceiverConfig:
    """Receiver settings.

    Attributes
    ----------
    pn_mode : PnMode or None
        Header mode, or None to detect it.
    constant_phase : int
        Header phase assumed when the header does not rotate.
    acquisition_frames : int
        Frames folded by the acquisition metrics.
    acquisition_threshold : float
        Normalised grid metric needed to declare a signal (0..1).
    track_threshold : float
        Header ``peak_metric`` below which a tracked frame is weak.
    loss_frames : int
        Consecutive weak frames that mean loss of lock.
    batch_frames : int
        Frames per processing batch.
    taps_before, taps_after : int
        Channel-estimate delay span around the frame start, samples.
    tap_threshold : float
        Tap power over noise floor needed to keep a tap.
    static_window_s : float
        Static window for the f_s estimate, s.
    clock_offset_hz : float or None
        f_s given by the user (skips the static window).
    iq_orientation : {"auto", "normal", "conjugate"}
        ``"conjugate"``: the front end swaps I and Q, conjugate the input;
        ``"normal"``: take the input as it is; ``"auto"``: decide from the
        SI word of the first lock (module docstring).
    cfo_search_hz : float
        Half-width of the acquisition's carrier-offset search, Hz.
    channel_offset_hz : float
        Centre of the DTMB channel minus the capture's centre frequency, Hz
        (a capture tuned beside the channel); 0 runs no shift stage.
    remove_dc, correct_iq : bool
        Remove the front end's DC offset / LO leakage, and correct its I/Q
        gain and phase imbalance, blindly from the input
        (:mod:`receiver.frontend_correction`; the imbalance is estimated and
        reported either way); both off runs no such stage. The estimate
        leaves out the PN headers, which are not circular (E6 there).
    cfo_scatter_limit : float
        SI phase scatter over its thermal-noise expectation above which a
        frame is flagged LOW_QUALITY.
    si_polarity : int
        SI chip polarity convention for the SI word detector.
    si_frames : int
        Frames after each lock used to identify the SI word.
    loop_alpha, loop_beta : float
        Timing-loop gains.
    jobs : int
        Threads for the per-frame work of each batch (:mod:`receiver.parallel`);
        the output is the same for any number.
    track_paths : bool
        Run the path tracker (``receiver.paths``: ``/receiver/paths`` and the
        first-path columns); PN420 and PN945 only.
    paths : PathConfig
        Path-tracker settings.
    inspect : callable or None
        ``inspect(stage, arrays)`` called per batch with intermediate outputs
        (e.g. :class:`receiver.dump.StageDump`): stages ``channel``,
        ``tracking``, ``body``, ``ofdm`` and ``paths`` (the path tracker's
        span of the CIR), one row per frame, each with ``window_start``.
    inspect_stages : frozenset of str or None
        The stages ``inspect`` is called for (None: all). The bodies are kept
        for it only when ``body`` is among them (they cost a copy per frame).
    """

    pn_mode: PnMode | None = None
    constant_phase: int = 0
    acquisition_frames: int = 16
    acquisition_threshold: float = 0.3
    track_threshold: float = 0.15
    loss_frames: int = 16
    batch_frames: int = 128
    taps_before: int = TAPS_BEFORE
    taps_after: int = TAPS_AFTER
    tap_threshold: float = TAP_THRESHOLD
    static_window_s: float = DEFAULT_STATIC_WINDOW_S
    clock_offset_hz: float | None = None
    iq_orientation: str = "auto"
    cfo_search_hz: float = DEFAULT_CFO_SEARCH_HZ
    channel_offset_hz: float = 0.0
    remove_dc: bool = True
    correct_iq: bool = True
    cfo_scatter_limit: float = CFO_SCATTER_LIMIT
    si_polarity: int = 1
    si_frames: int = 256
    loop_alpha: float = 0.05
    loop_beta: float = 0.001
    jobs: int = 1
    track_paths: bool = True
    paths: PathConfig = field(default_factory=PathConfig)
    inspect: Callable[[str, Mapping[str, np.ndarray]], None] | None = field(default=None, repr=False)
    inspect_stages: frozenset[str] | None = None

    def inspects(self, stage: str) -> bool:
        """Whether the inspect hook wants ``stage``."""
        return self.inspect is not None and (self.inspect_stages is None or stage in self.inspect_stages)

    def __post_init__(self) -> None:
        if self.pn_mode is not None:
            self.pn_mode = PnMode.parse(self.pn_mode)
        for name in ("acquisition_frames", "loss_frames", "batch_frames", "taps_after", "si_frames", "jobs"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"ReceiverConfig.{name} must be >= 1, got {getattr(self, name)!r}")
        if self.taps_before < 0:
            raise ValueError("ReceiverConfig.taps_before must be >= 0")
        if self.iq_orientation not in IQ_ORIENTATIONS:
            raise ValueError(f"ReceiverConfig.iq_orientation must be one of {', '.join(IQ_ORIENTATIONS)}, "
                             f"got {self.iq_orientation!r}")
        if not np.isfinite(self.channel_offset_hz):
            raise ValueError(f"ReceiverConfig.channel_offset_hz must be a finite frequency, got "
                             f"{self.channel_offset_hz!r}")
        for name in ("cfo_search_hz", "cfo_scatter_limit"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"ReceiverConfig.{name} must be a positive number, got {value!r}")


class SampleQueue:
    """The buffered part of the 7.56 Msps stream, kept as the chunks that arrived.

    Chunks are held by reference (not copied): a contiguous view of a range
    is free when it lies inside one chunk, and only ranges that straddle
    chunk boundaries are stitched (the frame blocks of
    :mod:`receiver.parallel` ask for their own span each, so at most one
    block of samples per boundary). The caller must not modify a chunk after
    handing it over. Reading (:meth:`view`) is safe from several threads
    while nothing is appended or dropped.
    """

    def __init__(self) -> None:
        self._segments: list[tuple[int, np.ndarray]] = []
        self.start = 0
        self.end = 0

    def append(self, samples: np.ndarray) -> None:
        """Add the next samples of the stream."""
        if len(samples):
            self._segments.append((self.end, samples))
            self.end += len(samples)

    def holds(self, start: int, stop: int) -> bool:
        """Whether stream indices ``[start, stop)`` are buffered."""
        return self.start <= start and stop <= self.end

    def view(self, start: int, stop: int) -> np.ndarray:
        """Samples ``[start, stop)`` as one contiguous complex64 array.

        Raises
        ------
        RuntimeError
            If the range is not buffered: a short array would make the
            kernels read past its end.
        """
        if not self.holds(start, stop):
            raise RuntimeError(f"receiver: samples [{start}, {stop}) requested, [{self.start}, {self.end}) buffered")
        parts = [seg[max(start - s0, 0): stop - s0] for s0, seg in self._segments
                 if s0 < stop and s0 + len(seg) > start]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def conjugate(self) -> None:
        """Conjugate the buffered samples (into new arrays: the chunks handed over stay as they are)."""
        self._segments = [(s0, np.conj(seg)) for s0, seg in self._segments]

    def drop_before(self, index: int) -> None:
        """Forget samples before stream index ``index``."""
        self.start = max(self.start, min(index, self.end))
        while self._segments and self._segments[0][0] + len(self._segments[0][1]) <= self.start:
            self._segments.pop(0)


def _head(record: Any, count: int) -> Any:
    """A dataclass of per-frame arrays cut to its first ``count`` frames."""
    return replace(record, **{f.name: getattr(record, f.name)[:count] for f in fields(record)
                              if isinstance(getattr(record, f.name), np.ndarray)})


class _Lock:
    """Everything that holds while one acquisition stays locked."""

    def __init__(self, acq: Acquisition, config: ReceiverConfig, first_frame_index: int, acquired_from: int) -> None:
        m = acq.mode.value
        self.acq = acq
        self.acquired_from = acquired_from
        self.mode = acq.mode
        self.tracker = FrameTracker(float(acq.frame_start), float(m.frame_length), m.frame_length,
                                    config.loop_alpha, config.loop_beta)
        self.monitor = LockMonitor(config.track_threshold, config.loss_frames)
        self.next_frame_index = first_frame_index
        self.cfo_cycles_per_sample = acq.coarse_cfo_hz / SYMBOL_RATE_HZ
        span = BODY_LENGTH + config.taps_before + config.taps_after
        self.rot = rotation_table(acq.coarse_cfo_hz, max(span, m.header_length + config.taps_before + config.taps_after))
        self._header_phase0 = -(m.period // 2) if m.rotates else 0
        phases = np.arange(self._header_phase0, m.period // 2 + 1) if m.rotates else np.zeros(1, np.int64)
        self._headers = np.array([gb20600.header_symbols(acq.mode, int(p)) for p in phases], dtype=np.complex64)
        # Carried from the last processed frame: SI carriers, taps, window start and offset.
        self.prev_si: np.ndarray | None = None
        self.prev_taps: np.ndarray | None = None
        self.prev_start = 0
        self.prev_delta = 0.0
        #: The SI reference and the last frame's SI phase against it (receiver.cfo, "Telescoping").
        self.si_reference = np.zeros(gb20600.SI_LENGTH, dtype=np.complex128)
        self.si_phase = 0.0
        #: Measured timing of the last processed frame (for the drop detector, receiver.drops).
        self.prev_measured: float | None = None
        #: The next frame follows samples the front end dropped: it has no CFO pair.
        self.drop_pending = False
        #: This lock was acquired across a drop and continues the segment before it.
        self.bridges_drop = False

    def phases(self, frame_index: np.ndarray) -> np.ndarray:
        """Header phase of each frame counter value."""
        if self.acq.rotating:
            return np.asarray(gb20600.header_phase(self.mode, frame_index), dtype=np.int64)
        return np.full(len(frame_index), self.acq.constant_phase, dtype=np.int64)

    def header_symbols(self, phases: np.ndarray) -> np.ndarray:
        """Transmitted header symbols (complex64, (len(phases), Ng)) of each header phase."""
        rows = phases - self._header_phase0 if len(self._headers) > 1 else np.zeros(len(phases), np.int64)
        return self._headers[rows]


class Receiver:
    """Streaming receiver: feed chunks with :meth:`process`, end with :meth:`finish`.

    Parameters
    ----------
    sample_rate_hz : float
        Input sample rate, Hz (resampled to 7.56 Msps).
    carrier_hz : float
        RF carrier of the tower, Hz (for eq. 10-11): the channel's centre, also
        when the capture is tuned beside it.
    config : ReceiverConfig, optional

    Raises
    ------
    ValueError
        ``config.channel_offset_hz`` puts the SI carriers outside the recorded
        band (:func:`receiver.mixer.check_channel_offset`).
    """

    def __init__(self, sample_rate_hz: float, carrier_hz: float, config: ReceiverConfig | None = None) -> None:
        self.config = config or ReceiverConfig()
        self.sample_rate_hz = float(sample_rate_hz)
        self.carrier_hz = float(carrier_hz)
        #: DC / LO-leakage removal and I/Q-imbalance correction of the raw input (None when both are off).
        self.corrector = (FrontEndCorrector(self.sample_rate_hz, self.config.remove_dc, self.config.correct_iq,
                                            keep_history=False)
                          if self.config.remove_dc or self.config.correct_iq else None)
        #: Shift onto the channel of a capture tuned beside it (None when tuned on it: no stage).
        self.mixer = (StreamMixer(self.config.channel_offset_hz, self.sample_rate_hz)
                      if self.config.channel_offset_hz != 0.0 else None)
        self.resampler = StreamResampler(sample_rate_hz)
        self.ranging = RangeIntegrator(carrier_hz, self.config.clock_offset_hz, self.config.static_window_s)
        #: The capture holds only the centre of the channel (module docstring).
        self.narrowband = self.sample_rate_hz < SYMBOL_RATE_HZ
        # The path tracker needs the whole channel: a narrowband capture's taps merge paths a few chips apart,
        # and the "first path" the fit follows is a blend whose phase wanders.
        self.paths_off_narrowband = self.narrowband and self.config.track_paths
        if self.paths_off_narrowband:
            self.config = replace(self.config, track_paths=False)
        #: Width of the recorded part of the channel, Hz.
        self.bandwidth_hz = min(self.sample_rate_hz, SYMBOL_RATE_HZ)
        # Noise per received sample -> noise per carrier (in per-sample units): white noise fills the
        # 7.56 Msps band only up to the resampler's noise bandwidth.
        self._carrier_noise_scale = SYMBOL_RATE_HZ / self.resampler.noise_bandwidth_hz
        # The first path's eq. 9-11 (f_s from the same window: the steadiest path's there, or the first path's
        # own; the SI f_s if it had no frame there).
        self.path_ranging = PathRanging(carrier_hz)
        steadiest = self.config.paths.clock_path == "steadiest"
        self.first_path_ranging = RangeIntegrator(
            carrier_hz, self.config.clock_offset_hz, self.config.static_window_s, FIRST_PATH_COLUMNS,
            fallback=self.ranging, calibration=self.path_ranging.steadiest_path_offset_hz if steadiest else None)
        self._path_tracker: PathTracker | None = None
        self._paths_out: list[PathBatch] = []
        self._modes = (self.config.pn_mode,) if self.config.pn_mode else tuple(PnMode)
        self._acq_window = window_length(self.config.acquisition_frames)
        self._queue = SampleQueue()
        #: Names the samples the frame workers read and the lock they are read for: a new value with either, so
        #: a block prefetched for the old ones is never used for the new ones (FrameWorkers.prefetch).
        self._generation = 0
        self._search_from = 0
        self._lock: _Lock | None = None
        self._workers = FrameWorkers(self.config.jobs, self.config.taps_before, self.config.taps_after,
                                     self.config.tap_threshold, NARROWBAND_NOISE_GUARD if self.narrowband else 0)
        self._k_si = si_carrier_numbers().astype(np.float64)
        self._si_detector: SiWordDetector | None = None
        self._frame_counter: int | None = None   # frame_index of the next frame, across locks
        self._last_start: int | None = None       # stream index of the last emitted frame
        self._lock_starts_gap = False               # the current lock follows a loss of lock
        #: Samples the front end dropped (receiver.drops), and their count so far (input samples).
        self.drops = DropLog()
        self._lost_input = 0
        self._segment = -1                          # segment_id of the current lock
        # (timing, period, frame index) the lost lock was coasting on, and its last row's t_s: the grid a
        # re-acquisition is measured against (receiver.drops).
        self._coast: tuple[float, float, int, float] | None = None
        self._last_row_t_s = np.nan                 # t_s of the last row out
        #: The input is conjugated (given, or decided by ``iq_orientation = "auto"``).
        self.conjugated = self.config.iq_orientation == "conjugate"
        # An off-centre capture is shifted before anything can tell its orientation, and a front end that swaps
        # I and Q mirrors the channel's place too: there the orientation must be given, not detected.
        self._orientation_pending = self.config.iq_orientation == "auto" and self.mixer is None
        self._held: list[FrameBatch] = []           # rows of the lock the orientation is decided on
        self._restart: tuple | None = None          # state before that lock's acquisition
        self.acquisitions: list[Acquisition] = []
        #: Acquisition windows by outcome (receiver.acquisition).
        self.search_outcomes: dict[str, int] = {}
        #: Frames flagged LOW_QUALITY for an SI phase scatter above the noise expectation.
        self.scatter_flagged = 0
        self.frames_out = 0
        self.stage_seconds = dict.fromkeys(STAGES, 0.0)

    # ---- public API -------------------------------------------------------------------

    def process(self, chunk: np.ndarray) -> list[FrameBatch]:
        """Feed input samples; return the frame batches completed by them."""
        chunk = np.asarray(chunk)
        if chunk.ndim != 1 or not np.iscomplexobj(chunk):
            raise ValueError(f"chunk must be a 1-D complex array, got {chunk.dtype} shape {chunk.shape}")
        self._take(chunk)
        return self._run(final=False)

    def _take(self, chunk: np.ndarray, corrected: bool = False) -> None:
        """Front-end correction (unless ``corrected``), shift onto the channel and resampling, into the queue."""
        t0 = time.perf_counter()
        if self.corrector is not None and not corrected:
            chunk = self.corrector.process(chunk)
        t1 = time.perf_counter()
        if self.mixer is not None:
            # A front end that swaps I and Q mirrors the spectrum: the channel sits at minus the offset, so the
            # input is conjugated before the shift (never after it; the orientation is given, not detected).
            samples = self.resampler.process(self.mixer.process(np.conj(chunk) if self.conjugated else chunk))
        else:
            samples = self.resampler.process(chunk)
            # The resampler's filter is real, so conjugating its output is conjugating its input.
            samples = np.conj(samples) if self.conjugated else samples
        t2 = time.perf_counter()
        self.stage_seconds["frontend"] += t1 - t0
        self.stage_seconds["resample"] += t2 - t1
        self._queue.append(samples)

    def finish(self) -> list[FrameBatch]:
        """End of stream: process the frames still complete, release the rest."""
        if self.corrector is not None:   # the corrector holds back the last partial block
            tail = self.corrector.flush()
            if len(tail):
                self._take(tail, corrected=True)
        out = self._run(final=True)
        if self._orientation_pending and self._held:   # the stream ended before the orientation was decided
            out.extend(self._decide_orientation())
            out.extend(self._run(final=True))
        out.extend(self._range_paths(self.ranging.flush()))
        if self._path_tracker is not None:
            out.extend(self.first_path_ranging.flush())
            self._release_paths(np.inf)
        self._workers.close()
        return out

    def pop_paths(self) -> PathBatch:
        """The ``/receiver/paths`` rows ranged since the last call (frame order)."""
        rows = PathBatch.concatenate(self._paths_out)
        self._paths_out = []
        return rows

    @property
    def pn_mode(self) -> PnMode | None:
        """Header mode of the last lock (None before any)."""
        return self.acquisitions[-1].mode if self.acquisitions else None

    @property
    def si_index(self) -> int:
        """SI word identified (0 before any lock)."""
        return self._si_detector.best() if self._si_detector else 0

    def notes(self) -> list[str]:
        """What the user should know about this capture's output, one line each (the CLI prints them)."""
        out = []
        if self.narrowband:
            out.append(f"narrowband capture: {self.sample_rate_hz / 1e6:g} Msps records the central "
                       f"{self.bandwidth_hz / 1e6:g} MHz of the {SYMBOL_RATE_HZ / 1e6:g} MHz channel; the SI-carrier "
                       f"CFO, velocity and range are unaffected, but snr_db covers the recorded band only and "
                       f"the channel taps merge paths closer than {SYMBOL_RATE_HZ / self.bandwidth_hz:.1f} chips "
                       f"(no delay resolution for path separation)"
                       + ("; path tracking is off (no first-path ranges)" if self.paths_off_narrowband else ""))
        if self.config.iq_orientation == "auto" and self.conjugated:
            out.append("I and Q are swapped in this capture (its SI word decodes only conjugated): "
                       "received conjugated, as --conjugate would")
        if self.config.iq_orientation == "auto" and self.mixer is not None:
            out.append("off-centre capture: its I/Q orientation is taken as normal, not detected (a front end "
                       "that swaps I and Q also mirrors where the channel lies; say so with --conjugate)")
        if not self.acquisitions and self.search_outcomes.get(CFO_OUTSIDE_SEARCH):
            out.append(f"a DTMB frame grid was found but its headers show at no carrier offset within "
                       f"+-{self.config.cfo_search_hz / 1e3:g} kHz: the offset lies outside the search "
                       f"(ReceiverConfig.cfo_search_hz)")
        if self.corrector is not None and self.corrector.emitted:
            out.extend(frontend_warnings(self.corrector.estimate()))
        if self.drops.samples:
            out.append(f"{len(self.drops.samples)} drop(s) in the capture, {self.drops.total} samples lost in all "
                       f"(found in the frame timing): t_s counts them, the frames after each are flagged DROP")
        if self.frames_out and self.scatter_flagged > 0.01 * self.frames_out:
            out.append(f"{self.scatter_flagged} of {self.frames_out} frames flagged LOW_QUALITY: their CFO "
                       f"scatters more than their SI SNR explains (interference or aliasing in the front end)")
        return out

    def attributes(self) -> dict[str, Any]:
        """Parameters for the ``/receiver/frames`` attributes."""
        acq = self.acquisitions[0] if self.acquisitions else None
        return {
            "pn_mode": acq.mode.name if acq else "none",
            "rotating_header": bool(acq.rotating) if acq else False,
            "si_index": self.si_index,
            "sample_rate_hz": self.sample_rate_hz,
            "carrier_hz": self.carrier_hz,
            "clock_offset_hz": np.nan if self.ranging.clock_offset_hz is None else self.ranging.clock_offset_hz,
            "coarse_cfo_hz": acq.coarse_cfo_hz if acq else np.nan,
            "cfo_search_hz": self.config.cfo_search_hz,
            "resample_up": self.resampler.up,
            "resample_down": self.resampler.down,
            "narrowband": self.narrowband,
            "bandwidth_hz": self.bandwidth_hz,
            "acquisitions": len(self.acquisitions),
            "iq_orientation": self.config.iq_orientation,
            "conjugate_iq": self.conjugated,
            "static_window_s": self.config.static_window_s,
            "notes": "\n".join(self.notes()),
            "path_tracking": self._path_tracker is not None,
            "first_path_clock_offset_hz": (np.nan if self.first_path_ranging.clock_offset_hz is None
                                           else self.first_path_ranging.clock_offset_hz),
            **self.drops.attributes(),
            **self._frontend_attributes(),
            # Only for a capture tuned beside the channel (a file tuned on it stays as it was).
            **({"channel_offset_hz": self.mixer.channel_offset_hz, "channel_hz": self.carrier_hz}
               if self.mixer is not None else {}),
        }

    def _frontend_attributes(self) -> dict[str, Any]:
        """What the front-end corrector measured on the input (its estimate at the end of the stream)."""
        if self.corrector is None or not self.corrector.emitted:
            return {}
        est = self.corrector.estimate()
        return {"dc_offset": est.dc_offset, "dc_offset_dbc": est.dc_offset_dbc, "iq_gain_db": est.iq_gain_db,
                "iq_phase_deg": est.iq_phase_deg, "image_rejection_db": est.image_rejection_db,
                "dc_removed": est.dc_removed, "iq_corrected": est.iq_corrected}

    def path_attributes(self) -> dict[str, Any]:
        """Parameters for the ``/receiver/paths`` attributes (the tracker's settings and span)."""
        tracker = self._path_tracker
        attrs: dict[str, Any] = {"carrier_hz": self.carrier_hz, "clock_offset_hz": np.nan if
                                 self.first_path_ranging.clock_offset_hz is None else
                                 self.first_path_ranging.clock_offset_hz}
        if tracker is not None:
            for key, value in vars(tracker.config).items():
                if is_dataclass(value):   # a nested group of settings: doppler_frames, ...
                    attrs.update({f"{key}_{k}": v for k, v in vars(value).items() if v is not None})
                elif value is not None:
                    attrs[key] = value
            attrs.update(taps_before=tracker.taps_before, taps_after=tracker.taps_after)
        return attrs

    # ---- driver -----------------------------------------------------------------------

    def _run(self, final: bool) -> list[FrameBatch]:
        out: list[FrameBatch] = []
        while True:
            if self._lock is None:
                t0 = time.perf_counter()
                acquired = self._try_acquire()
                self.stage_seconds["acquisition"] += time.perf_counter() - t0
                if not acquired:
                    break
                continue
            batch = self._next_batch(final)
            if batch is None:
                break
            if self._orientation_pending:
                self._held.append(batch)
                assert self._si_detector is not None
                if self._si_detector.frames and (self._si_detector.frames >= ORIENTATION_FRAMES or self._lock is None):
                    out.extend(self._decide_orientation())
                continue
            out.extend(self._emit(batch))
        self._trim()
        return out

    def _emit(self, batch: FrameBatch) -> list[FrameBatch]:
        self.frames_out += len(batch)
        return self._range_paths(self.ranging.push(batch))

    def _decide_orientation(self) -> list[FrameBatch]:
        """Release the held rows, or conjugate the buffer and lock again from the held lock's window."""
        assert self._si_detector is not None and self._restart is not None
        self._orientation_pending = False
        held, self._held = self._held, []
        if not self._si_detector.conjugated():
            return [row for batch in held for row in self._emit(batch)]
        self.conjugated = not self.conjugated
        self._queue.conjugate()
        self._generation += 1
        (self._search_from, self._frame_counter, self._last_start, self._lock_starts_gap,
         acquisitions, self.search_outcomes, self.scatter_flagged, self._segment, self._coast, self._lost_input,
         drops) = self._restart
        del self.acquisitions[acquisitions:]
        for column in (self.drops.t_s, self.drops.sample_index, self.drops.samples):
            del column[drops:]
        self._lock = None
        self._si_detector = None
        return []

    def _range_paths(self, batches: list[FrameBatch]) -> list[FrameBatch]:
        """Eq. 9-11 on the first path of SI-ranged batches; the path rows up to them leave with their range."""
        if self._path_tracker is None:
            return batches
        out = [b for batch in batches for b in self.first_path_ranging.push(batch)]
        if out:
            self._release_paths(float(out[-1].t_s[-1]))
        return out

    def _release_paths(self, until_t_s: float) -> None:
        rows = self.path_ranging.release(self.first_path_ranging.clock_offset_hz, until_t_s)
        if len(rows):
            self._paths_out.append(rows)

    def _try_acquire(self) -> bool:
        start, stop = self._search_from, self._search_from + self._acq_window
        if not self._queue.holds(start, stop):
            return False
        cfg = self.config
        result = search_window(self._queue.view(start, stop), start, acquisition_frames=cfg.acquisition_frames,
                               lock_threshold=cfg.acquisition_threshold, modes=self._modes,
                               constant_phase=cfg.constant_phase, cfo_search_hz=cfg.cfo_search_hz,
                               lead=cfg.taps_before)
        acq = result.acquisition
        if acq is None:
            self.search_outcomes[result.outcome] = self.search_outcomes.get(result.outcome, 0) + 1
            self._search_from += self._acq_window // 2
            return True
        if self._orientation_pending:
            self._restart = (start, self._frame_counter, self._last_start, self._lock_starts_gap,
                             len(self.acquisitions), dict(self.search_outcomes), self.scatter_flagged,
                             self._segment, self._coast, self._lost_input, len(self.drops.samples))
        self.search_outcomes[result.outcome] = self.search_outcomes.get(result.outcome, 0) + 1
        self.acquisitions.append(acq)
        m = acq.mode.value
        if self._frame_counter is None:
            index = acq.frame_in_superframe
        else:  # keep counting frame periods across the gap; agree with the superframe position
            elapsed = round((acq.frame_start - self._last_start) / m.frame_length)
            index = self._frame_counter - 1 + elapsed
            if acq.rotating:
                f = m.frames_per_superframe
                index += (acq.frame_in_superframe - index + f // 2) % f - f // 2
        self._lock = _Lock(acq, self.config, index, start)
        self._generation += 1
        self._lock_starts_gap = self._frame_counter is not None
        if self._frame_counter is None:
            self._segment = 0
        if self.config.track_paths and acq.mode.value.cyclic_length > 0:
            if self._path_tracker is None:
                self._path_tracker = PathTracker(acq.mode, self.carrier_hz, self.config.paths,
                                                 (self.resampler.up, self.resampler.down), acq.rotating)
            elif self._coast is None or acq.mode != self._path_tracker.mode:
                self._path_tracker.new_lock(acq.mode, acq.rotating)
            # else the lock's first batch decides: the paths go on across a drop (_after_loss)
        if self._si_detector is None:
            self._si_detector = SiWordDetector(self.config.taps_before, self.config.taps_before + self.config.taps_after,
                                               self.config.si_polarity)
        return True

    def _prefetch_next(self, lock: _Lock, first_frame: int, work: dict[str, Any]) -> None:
        """Start the next batch's per-frame work on the pool while this thread finishes the current batch.

        Called once the timing loop has taken the current batch: the windows
        are those the next batch will have unless the estimators or the path
        tracker end the lock first. :meth:`FrameWorkers.run` uses a prefetched
        block only when its inputs are exactly those of the batch; the views
        of the guard-interval span are planned per batch, so the blocks are
        prefetched without them and their views' taps are taken when the
        batch comes.
        """
        starts = np.rint(lock.tracker.predict(self.config.batch_frames)).astype(np.int64)
        if self._frame_stops(lock, starts)[-1] > self._queue.end:
            return
        self._workers.prefetch(lock.mode, self._batch_windows(lock, starts, first_frame), **work)

    def _frame_stops(self, lock: _Lock, starts: np.ndarray) -> np.ndarray:
        """The stream index each frame's samples end before: its header, body and the next header's first
        ``taps_after`` samples."""
        return starts + lock.mode.value.frame_length + self.config.taps_after + 1

    def _batch_windows(self, lock: _Lock, starts: np.ndarray, first_frame: int) -> BatchWindows:
        """The per-frame work's inputs for frames ``first_frame, ...`` at window starts ``starts``."""
        phases = lock.phases(first_frame + np.arange(len(starts) + 1))
        return BatchWindows(self._queue.view, starts, phases, lock.header_symbols(phases), lock.cfo_cycles_per_sample,
                            lock.rot, self._queue.start)

    def _trim(self) -> None:
        """Drop buffered samples no future batch or acquisition can need."""
        if self._lock is None:
            keep = self._search_from
        else:
            # The path tracker's views may read further before a frame than its channel estimate.
            lead = max(self.config.taps_before, 0 if self._path_tracker is None else self._path_tracker.view_lead)
            keep = int(np.floor(self._lock.tracker.tau)) - lead - 64
        if self._orientation_pending and self._restart is not None:
            keep = min(keep, self._restart[0])   # the held lock may have to be made again
        self._queue.drop_before(keep)

    # ---- one batch --------------------------------------------------------------------

    def _next_batch(self, final: bool) -> FrameBatch | None:
        lock = self._lock
        assert lock is not None
        cfg = self.config
        size = cfg.batch_frames
        # With threads to spare a batch waits until the next one's samples are there too, so that the next
        # one can be prefetched (_prefetch_next); the batches are the same.
        ahead = 2 if self._workers.jobs > 1 and not final else 1
        starts = np.rint(lock.tracker.predict(ahead * size)).astype(np.int64)
        count = int(np.searchsorted(self._frame_stops(lock, starts), self._queue.end, side="right"))
        if count < ahead * size and not (final and count > 0):
            return None
        count = min(count, size)
        starts = starts[:count]
        frame_index = lock.next_frame_index + np.arange(count)
        windows = self._batch_windows(lock, starts, lock.next_frame_index)
        phases = windows.phases
        tracker = self._path_tracker
        if tracker is not None and lock.mode != tracker.mode:
            tracker = None
        work = {"keep_bodies": cfg.inspects("body"),
                "span": None if tracker is None else (tracker.taps_before, tracker.taps_after),
                "generation": self._generation}
        views = () if tracker is None else tracker.plan_views()
        frames = self._workers.run(lock.mode, windows, views=views, **work)
        ch, si = frames.channel, frames.si
        for name, dt in frames.seconds.items():
            self.stage_seconds[name] += dt
        t1 = time.perf_counter()
        measured = starts + ch.centroid
        strong = ch.peak_metric >= cfg.track_threshold
        if lock.prev_measured is None and self._coast is not None:
            self._after_loss(lock, measured[0], int(frame_index[0]))
        # The previous batch ended at a drop: this batch's first frame pairs across it.
        after_drop, lock.drop_pending = lock.drop_pending, False
        # A drop inside the batch (receiver.drops): the batch ends before it, the loop's grid moves by it, and
        # the next batch starts on the frame after it with aligned windows.
        drop = find_in_lock_drop(measured, strong, lock.tracker.period, lock.prev_measured, ch.raw_taps,
                                 lock.prev_taps, starts, lock.prev_start)
        shift = 0.0
        lost = 0
        resume_at = None
        if drop is not None:
            cut, step = drop
            lost = lost_input_samples(step, self.sample_rate_hz)
            resume_at = int(starts[cut])
            if step <= MAX_IN_LOCK_STEP and lost >= 1:
                # The frames before the drop keep the time base they had; the batch after it counts the drop.
                shift = self._stream_samples(lost)
                self._log_drop(float(measured[cut]), lost)
                resume_at = None
            count = cut
            starts, frame_index, measured, strong, si = (starts[:cut], frame_index[:cut], measured[:cut],
                                                         strong[:cut], si[:cut])
            phases = phases[:cut + 1]
            ch = _head(ch, cut)
            frames = replace(frames, channel=ch, si=si, bodies=None if frames.bodies is None else frames.bodies[:cut],
                             span=None if frames.span is None else _head(frames.span, cut))
            if cut == 0:
                if shift:
                    self._lost_input += lost
                return self._cut_before_batch(lock, shift, resume_at)
        smoothed, periods = lock.tracker.update(measured, strong)
        lost_at = lock.monitor.check(ch.peak_metric)
        if resume_at is not None and lost_at is None:   # a drop too long to follow: the lock ends before it
            lost_at = count
        lock.prev_measured = float(measured[-1]) - shift
        if shift:
            lock.tracker.tau -= shift
            lock.drop_pending = True
        if self._workers.jobs > 1 and count == size and lost_at is None:
            self._prefetch_next(lock, int(frame_index[-1]) + 1, work)
        t2 = time.perf_counter()
        self.stage_seconds["sync"] += t2 - t1
        for stage, arrays in (("channel", {"taps": ch.taps, "snr_db": ch.snr_db, "peak_metric": ch.peak_metric}),
                              ("tracking", {"measured": measured, "smoothed": smoothed}),
                              ("body", {"bodies": frames.bodies})):
            if cfg.inspects(stage):
                cfg.inspect(stage, {"window_start": starts, "frame_index": frame_index, **arrays})
        t3 = time.perf_counter()
        rows, scattered = self._estimate(lock, starts, smoothed, periods, si, ch, frame_index, phases[:-1])
        if after_drop:   # the frame pair straddles the drop: no CFO from it
            rows.cfo_hz[0] = rows.cfo_pn_hz[0] = np.nan
            rows.flags[0] |= FrameFlag.DROP
        t4 = time.perf_counter()
        self.stage_seconds["estimators"] += t4 - t3
        if tracker is not None:  # sequential (its loops link the frames): on this thread, in frame order
            assert frames.span is not None
            if cfg.inspects("paths"):
                cfg.inspect("paths", {"window_start": starts, "frame_index": frame_index, "taps": frames.span.raw_taps,
                                      "noise_tap": frames.span.noise_tap, "lag0": np.int64(tracker.lag0)})
            if rows.flags[0] & FrameFlag.DROP:
                tracker.break_phase()
            # The paths' delays are kept on the real clock: the window starts plus the samples dropped so far.
            real_starts = starts + self._stream_samples(self._lost_input) if self._lost_input else starts
            found = tracker.update(frames.span.raw_taps, frames.span.noise_tap, real_starts, frame_index,
                                   periods / lock.tracker.nominal_period - 1.0, rows.t_s, lock.acq.coarse_cfo_hz,
                                   frames.span.views)
            rows = replace(rows, **found.first_path)
            # A frame without a header (a fade, the frames before a loss of lock) has no path phase to trust.
            rows.first_path_cfo_hz[~strong] = np.nan
            keep = len(rows) if lost_at is None else lost_at
            self.path_ranging.push(found.rows.select(found.rows.frame_index < frame_index[0] + keep))
            self.stage_seconds["paths"] += time.perf_counter() - t4
        if cfg.inspects("ofdm"):
            cfg.inspect("ofdm", {"window_start": starts, "frame_index": frame_index, "si_carriers": si})
        lock.next_frame_index += count
        if lost_at is not None:
            rows, scattered = rows.select(slice(0, lost_at)), scattered[:lost_at]
            # Search again from the first weak frame, but always past this lock's acquisition window
            # (a signal that acquires but cannot be tracked must not be re-acquired forever).
            first_weak = resume_at if lost_at == count else int(starts[lost_at])
            self._search_from = max(first_weak, lock.acquired_from + self._acq_window // 2)
            self._lose_lock(lock, rows)
        elif count < size and drop is None:  # end of stream: the partial batch was the last one; nothing more to search
            self._lock = None
            self._search_from = END_OF_STREAM
        self.scatter_flagged += int(np.count_nonzero(scattered))
        if len(rows):
            self._last_row_t_s = float(rows.t_s[-1])
        if shift:
            self._lost_input += lost
        return rows

    def _cut_before_batch(self, lock: _Lock, shift: float, resume_at: int | None) -> FrameBatch:
        """A drop right before the batch's first frame: move the grid (or end the lock) and process nothing yet."""
        if resume_at is not None:
            self._search_from = max(resume_at, lock.acquired_from + self._acq_window // 2)
            self._lose_lock(lock, FrameBatch.empty())
        else:
            lock.tracker.tau -= shift
            assert lock.prev_measured is not None
            lock.prev_measured -= shift
            lock.drop_pending = True
        return FrameBatch.empty()

    def _lose_lock(self, lock: _Lock, rows: FrameBatch) -> None:
        """End the lock; keep the grid it was coasting on for the next lock to be measured against."""
        last_t = float(rows.t_s[-1]) if len(rows) else self._last_row_t_s
        self._coast = (float(lock.tracker.tau), float(lock.tracker.period), lock.next_frame_index, last_t)
        self._lock = None

    def _stream_samples(self, input_samples: int) -> float:
        """Input samples as 7.56 Msps stream samples."""
        return input_samples * SYMBOL_RATE_HZ / self.sample_rate_hz

    def _log_drop(self, measured: float, lost: int) -> float:
        """Record a drop of ``lost`` input samples before the frame measured at ``measured`` (stream samples).

        Returns that frame's real-clock time, s (the drops before it and this one counted).
        """
        t_s = measured / SYMBOL_RATE_HZ + (self._lost_input + lost) / self.sample_rate_hz
        self.drops.add(t_s, int(self.resampler.input_index(np.array([int(measured)]))[0]), lost)
        return t_s

    def _after_loss(self, lock: _Lock, measured: float, frame_index: int) -> None:
        """First batch of a re-acquisition: samples dropped during the loss, a bridged drop or a gap (receiver.drops)."""
        assert self._coast is not None
        tau, period, next_index, last_t = self._coast
        self._coast = None
        # Where the lost lock's grid puts this frame, minus where it is: positive when samples were lost.
        early = tau + (frame_index - next_index) * period - measured
        if not lock.acq.rotating and early < -MIN_STEP:
            early += lock.mode.value.frame_length   # a constant header phase leaves whole frames unknown
        lost = lost_input_samples(early, self.sample_rate_hz) if early > MIN_STEP else 0
        bridged = False
        if lost >= 1:
            t_first = self._log_drop(measured, lost)
            self._lost_input += lost
            bridged = np.isfinite(last_t) and t_first - last_t <= MAX_BRIDGE_S
        tracker = self._path_tracker
        if bridged:   # the paths go on: the lock's first frame is flagged DROP, which breaks their phases
            self._lock_starts_gap = False
            lock.bridges_drop = True
        else:
            self._segment += 1
            if tracker is not None and tracker.mode == lock.mode:
                tracker.new_lock(lock.mode, lock.acq.rotating)

    def _estimate(self, lock: _Lock, starts: np.ndarray, smoothed: np.ndarray, periods: np.ndarray, si: np.ndarray,
                  ch: ChannelEstimates, frame_index: np.ndarray, phases: np.ndarray) -> tuple[FrameBatch, np.ndarray]:
        """CFO estimates (eq. 5-8 and PN), flags and the rows of a batch; carries state to the next batch.

        Also returns which frames are flagged for their SI phase scatter.
        """
        count = len(starts)
        delta = starts - smoothed
        first_of_lock = lock.prev_si is None
        prev_si = si[0] if first_of_lock else lock.prev_si
        prev_taps = ch.raw_taps[0] if first_of_lock else lock.prev_taps
        prev_start = starts[0] if first_of_lock else lock.prev_start
        prev_delta = float(delta[0]) if first_of_lock else lock.prev_delta
        advance, phase_var, lock.si_phase = si_phase_kernel(prev_si, si, self._k_si, prev_delta, delta,
                                                            lock.si_reference, lock.si_phase, SI_REFERENCE_GAIN)
        step = np.diff(np.concatenate([[prev_start], starts]))
        eta = periods / lock.tracker.nominal_period - 1.0
        cfo = cfo_from_advance(advance, np.maximum(step, 1), eta, lock.acq.coarse_cfo_hz)
        shift = step - np.rint(periods).astype(np.int64)
        cfo_pn = cfo_from_theta(pn_theta_kernel(prev_taps, ch.raw_taps, shift), np.maximum(step, 1), eta,
                                lock.acq.coarse_cfo_hz)
        si_snr = si_snr_db(si, ch.noise_power * self._carrier_noise_scale)
        # Eq. 5-8's noise is known from the SI SNR; a frame whose terms scatter more carries something else.
        # A frame's own SI SNR estimate scatters too; one that reads above the batch's median would make
        # the expectation too strict, so the lower of the two is used (a real fade lowers both).
        reference_snr = np.minimum(np.minimum(si_snr, np.median(si_snr)), SCATTER_SNR_CEILING_DB)
        expected = expected_phase_variance(reference_snr)
        scattered = phase_var > self.config.cfo_scatter_limit * expected
        weak = (ch.peak_metric < self.config.track_threshold) | scattered
        flags = np.where(weak, FrameFlag.LOW_QUALITY, 0).astype(np.uint8)
        if first_of_lock:
            cfo[0] = cfo_pn[0] = np.nan
            flags[0] |= FrameFlag.LOCK_START | (FrameFlag.GAP if self._lock_starts_gap else 0)
            if lock.bridges_drop:   # a re-acquisition across a drop
                flags[0] |= FrameFlag.DROP
        lock.prev_si, lock.prev_taps = si[-1].copy(), ch.raw_taps[-1].copy()
        lock.prev_start, lock.prev_delta = int(starts[-1]), float(delta[-1])
        assert self._si_detector is not None
        if self._si_detector.frames < self.config.si_frames:
            self._si_detector.add(si, ch.taps)
        self._frame_counter = int(frame_index[-1]) + 1
        self._last_start = int(starts[-1])
        nan = np.full(count, np.nan)
        return FrameBatch(
            t_s=starts / SYMBOL_RATE_HZ + self._lost_input / self.sample_rate_hz,
            sample_index=self.resampler.input_index(starts), frame_index=frame_index,
            pn_phase=phases.astype(np.int32), cfo_hz=cfo, cfo_pn_hz=cfo_pn, doppler_hz=nan, velocity_mps=nan.copy(),
            range_change_m=nan.copy(), snr_db=ch.snr_db, si_snr_db=si_snr, peak_metric=ch.peak_metric, flags=flags,
            segment_id=np.full(count, self._segment, dtype=np.int32)), scattered


def receive_stream(chunks: Iterable[np.ndarray], sample_rate_hz: float, carrier_hz: float,
                   config: ReceiverConfig | None = None, receiver: Receiver | None = None) -> Iterator[FrameBatch]:
    """Run the receiver over a stream of IQ chunks, yielding frame batches as they complete.

    Parameters
    ----------
    chunks : iterable of complex arrays
        Input samples at ``sample_rate_hz``.
    sample_rate_hz, carrier_hz : float
        Input rate and RF carrier, Hz.
    config : ReceiverConfig, optional
    receiver : Receiver, optional
        A receiver to drive (to read its attributes afterwards); made from the
        other arguments when omitted.

    Only the frames come out: the path tracker's rows are dropped as they
    come (memory stays flat); :func:`receive_into_sink` writes them, or drive
    :meth:`Receiver.process` and :meth:`Receiver.pop_paths` directly.
    """
    rx = receiver or Receiver(sample_rate_hz, carrier_hz, config)
    for chunk in chunks:
        yield from rx.process(chunk)
        rx.pop_paths()
    yield from rx.finish()
    rx.pop_paths()


def receive_file(capture: CaptureSource, out_path: str | os.PathLike | None, config: ReceiverConfig | None = None, *,
                 carrier_hz: float | None = None, csv_path: str | os.PathLike | None = None,
                 chunk_samples: int = 1 << 20, progress: bool = True) -> tuple[FrameSink, dict[str, Any]]:
    """Receive a whole capture and write ``/receiver/frames`` (and optionally CSV).

    Rows are written batch by batch as the receiver produces them, so memory
    stays flat however long the capture is. A stream (stdin) that breaks
    keeps the frames received before the break (:func:`receive_into_sink`);
    a file that does is bad input and leaves nothing. The capture's project
    metadata (scenario name and seed of a simulated capture) is recorded, so
    that a receiver file can be matched with its sensors file.

    Parameters
    ----------
    capture : CaptureSource
        From :func:`receiver.capture.open_capture`.
    out_path : path or None
        HDF5 file to write (None: do not write).
    config : ReceiverConfig, optional
    carrier_hz : float, optional
        RF carrier of the channel; defaults to the capture's centre frequency
        plus ``config.channel_offset_hz``.
    csv_path : path, optional
        Also write the rows as CSV (``"-"`` for stdout).
    chunk_samples : int
        Samples read at a time.
    progress : bool
        Show a tqdm progress bar on stderr.

    Returns
    -------
    sink : FrameSink
        The finished writer: ``frames``, ``gaps``, ``first_t_s``, ``last_t_s``.
    attributes : dict
        The ``/receiver/frames`` attributes.
    """
    from dtmbnav_core import schema

    offset = config.channel_offset_hz if config is not None else 0.0
    carrier = carrier_hz if carrier_hz is not None else capture.center_hz
    if carrier_hz is None and carrier is not None and offset != 0.0:
        carrier = carrier + offset
    if carrier is None:
        raise ValueError(f"{capture.path}: the capture has no centre frequency; give carrier_hz")
    identity: dict[str, Any] = {}
    scenario, seed = capture.project_value("scenario"), capture.project_value("seed")
    if isinstance(scenario, str):
        identity[schema.CAPTURE_SCENARIO_ATTR] = scenario
    if isinstance(seed, int) and not isinstance(seed, bool):
        identity[schema.CAPTURE_SEED_ATTR] = seed
    if capture.start_utc_unix_ns is not None:   # the coarse time alignment with a phone's log
        identity[schema.START_UTC_NS_ATTR] = np.int64(capture.start_utc_unix_ns)
    rx = Receiver(capture.sample_rate_hz, carrier, config)
    sink = FrameSink(out_path, csv_path)
    # A pipe's bytes cannot be read again: on SIGINT/SIGTERM what was read ahead is received too.
    chunks = read_ahead(capture.chunks(chunk_samples), keep_read_on_stop=capture.is_stream)
    attrs = receive_into_sink(rx, chunks, sink, source=str(capture.path), total_samples=capture.num_samples,
                              progress=progress, attrs=identity, keep_on_input_error=capture.is_stream)
    return sink, attrs


def receive_into_sink(rx: Receiver, chunks: Iterable[np.ndarray], sink: FrameSink, *, source: str,
                      total_samples: int | None = None, progress: bool = True, attrs: Mapping[str, Any] | None = None,
                      keep_on_input_error: bool = False) -> dict[str, Any]:
    """Drive ``rx`` over ``chunks``, writing every batch to ``sink``, and close it.

    The input can end early in three ways; in each, the frames of every
    sample received so far are kept (the receiver is finished as at the end
    of the input, the files are completed) when there is at least one, and
    the ``ended_early`` attribute says why:

    - SIGINT or SIGTERM (:class:`dtmbnav_core.interrupt.DeferredStop`: a chunk
      being processed is finished first, a stream reader waiting for data
      gives up; a second signal aborts): after the files are closed,
      :class:`~dtmbnav_core.interrupt.Interrupted` is raised with what was
      kept;
    - a stream that ends inside an IQ pair
      (:class:`~receiver.capture.TruncatedStream`): the end of the input, the
      call returns normally;
    - with ``keep_on_input_error`` (streams, which cannot be read again), an
      OSError or ValueError raised while reading: the error is re-raised with
      a note saying what was kept.

    Any other error drops the sink's partial files and is re-raised.

    Parameters
    ----------
    rx : Receiver
    chunks : iterable of complex arrays
        The input.
    sink : FrameSink
    source : str
        Name of the input (``source`` attribute, progress bar).
    total_samples : int, optional
        Input length for the progress bar.
    progress : bool
        Show a tqdm progress bar on stderr.
    attrs : mapping, optional
        Further ``/receiver/frames`` attributes.
    keep_on_input_error : bool
        Keep the frames received before an error raised by ``chunks``.

    Returns
    -------
    dict
        The attributes written (the receiver's, ``source``, ``attrs`` and
        ``ended_early`` when the input ended early).
    """
    from dtmbnav_core import schema
    from dtmbnav_core.interrupt import DeferredStop, Interrupted
    from receiver.capture import TruncatedStream

    ended_early: str | None = None
    input_error: BaseException | None = None
    stop = DeferredStop()
    try:
        with stop, tqdm(total=total_samples, unit="S", unit_scale=True, disable=not progress, file=sys.stderr,
                        desc=f"receive {os.path.basename(source)}") as bar:
            received = 0
            inputs = stop.until_stopped(chunks)
            while True:
                try:
                    chunk = next(inputs)
                except StopIteration:
                    break
                except TruncatedStream as exc:
                    ended_early = f"the stream ended inside an IQ pair after sample {exc.samples}"
                    break
                except (OSError, ValueError) as exc:  # the input broke (the receiver's own errors are not caught)
                    if not keep_on_input_error:
                        raise
                    input_error = exc
                    ended_early = f"input error after sample {received}: {exc}"
                    break
                for batch in rx.process(chunk):
                    sink.append(batch)
                sink.append_paths(rx.pop_paths())
                received += len(chunk)
                bar.update(len(chunk))
            for batch in rx.finish():
                sink.append(batch)
            sink.append_paths(rx.pop_paths())
            if stop.signum is not None:
                ended_early = f"{Interrupted(stop.signum)} after sample {received}"
            if ended_early is not None and sink.frames == 0 and (input_error or stop.signum is not None):
                raise input_error or Interrupted(stop.signum)  # nothing worth keeping
    except BaseException as exc:
        sink.abort(exc)
        raise
    out = {**rx.attributes(), "source": source, **(attrs or {})}
    if ended_early is not None:
        out[schema.ENDED_EARLY_ATTR] = ended_early
    sink.close(out, {**rx.path_attributes(), "source": source} if rx.config.track_paths else None)
    kept = (f"kept the {sink.frames} frames received before it"
            + (f" in {sink.h5_path} (attribute {schema.ENDED_EARLY_ATTR})" if sink.h5_path is not None else ""))
    if input_error is not None:
        input_error.add_note(kept)
        raise input_error
    if stop.signum is not None:
        raise Interrupted(stop.signum, kept)
    return out
