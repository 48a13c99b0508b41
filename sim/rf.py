"""Streaming RF capture generator: transmitter -> channel -> clock -> front end.

Received sample k (before noise, conjugation and quantisation):

``r_k = exp(-j 2 pi fc x(t_k)) exp(j 2 pi bulk_cfo t_k) sum_p g_p(t_k) s(u_p(t_k)) exp(-j 2 pi fc tau_p(t_k))``

with ``u_p(t) = Rs (t + start_offset_s - tau_p(t))`` the transmitter symbol
time that path p delivers at true time t, ``s`` the SRRC-shaped symbol stream
(:mod:`sim.transmitter`), ``tau_p``/``g_p`` the geometric channel
(:mod:`sim.channel`), ``x`` the receiver clock's time error
(:mod:`sim.oscillator`) and ``t_k`` the true time of sample k.

Time bases (all in seconds):

- **true time** ``t``: scenario time; ``track.t_s`` is true time, 0 = start
  of the scenario;
- **transmitter time** ``t + receiver.start_offset_s``: symbol 0 of frame 0
  (a superframe start) is sent at transmitter time 0, so the scenario's
  recording starts ``start_offset_s`` into the transmission (not on a frame
  boundary);
- **receiver time** ``t + x(t)``: what the receiver's clock reads. Sample
  ``n`` of the whole scenario's capture is taken when it reads ``n / fs``.

A segment (``start_s``, ``seconds``) is the whole scenario's capture from
sample ``first_sample = round(start_s * fs)`` on, for ``round(seconds * fs)``
samples: its samples (noise included) are bit-identical to those samples of the
full capture. Capture times (``FrameTruth.t_s``, a receiver's frame times) are
receiver time minus ``first_sample / fs``: seconds since the segment's first
sample, on the receiver's clock, i.e. ``sample_index / fs``.

The channel, clock and CFO are evaluated on a receiver-time grid in fixed
blocks of absolute grid indices and are linear in between. The grid step is
1 ms, or less so that no path's carrier phase moves more than
``MAX_GRID_PHASE_STEP_RAD`` per step (linear interpolation of a unit phasor
then loses < 0.03 % amplitude); walking needs < 0.06 rad at 1 ms. Block
synthesis also keeps a step short enough that no path's delay drifts by more
than ``sim.block_synthesis.MAX_BLOCK_DRIFT_SYMBOLS`` against its FFT grid
(a clock tens of ppm off).

Two syntheses compute the samples of that model (``synthesis``):

- ``"block"`` (default, :mod:`sim.block_synthesis`): the grid is the
  boundaries of fixed blocks of output samples; each block is computed in the
  frequency domain from the symbols' DFT, every path's fractional delay a
  linear phase over the bins, its delay and coefficient slope over the block
  a first-order term, the common phase a rotation per sample;
- ``"exact"`` (:func:`sim.transmitter.multipath_kernel`, the reference twin):
  the pulse is evaluated at every sample's time for every path.

Below the symbol rate both shape with the same pulse, the transmit pulse
through the front end's anti-alias filter (:func:`sim.frontend.anti_alias_pulse`):
the exact twin tabulates the filtered pulse, the block synthesis multiplies
the pulse spectrum at its bins by the filter's response
(:func:`sim.transmitter.pulse_spectrum`).

The tests bound their difference (below -50 dB of the signal power on a
walking, multipath, free-running-clock capture). Everything is a pure
function of absolute indices, so the output does not depend on the chunking
(nor on how many threads generate it, ``jobs``).

Off-centre tuning (``receiver.tuning_offset_hz``, :mod:`sim.frontend` step
0a): the samples above are synthesised on the channel at ``factor * fs`` by a
second generator of the same scenario, seed and segment, then shifted,
filtered and decimated to ``fs`` by :meth:`sim.frontend.FrontEnd.tune`; the
truth (carrier, Doppler, clock offset) is the channel's.

Random streams: ``default_rng([seed, STREAM_*, index, 1])``; the symbol data
uses :class:`sim.frames.FrameSource` with the same seed.

The front end's impairments (:mod:`sim.frontend` steps 2 to 9: LO phase
noise, IQ imbalance, LO leakage, AGC steps, the ADC, dropped samples) are
functions of absolute sample indices on the receiver's clock too, drawn from
the ``STREAM_NOISE`` stream. Dropped runs (:meth:`CaptureGenerator.drops`)
are not rendered: the chunks of :meth:`CaptureGenerator.chunks` and
:meth:`CaptureGenerator.quantised_chunks` skip them, so the written capture
holds ``capture_samples`` samples, while ``num_samples``, the frame truth and
``FrameTruth.t_s`` stay on the receiver's clock.
"""

from __future__ import annotations

import copy
import threading
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import PnMode
from dtmbnav_core.records import ColumnRecord, Track
from sim.block_synthesis import BlockSynthesizer, choose_layout
from sim.channel import Channel
from sim.frames import FrameConfig, FrameSource
from sim.frontend import IMPAIRMENT_DEFAULTS, FrontEnd, mean_signal_power
from sim.oscillator import scenario_oscillator
from sim.scenario import Scenario
from sim.transmitter import PULSE_SPAN, multipath_kernel, symbol_range

#: Random stream ids (second element of every seed sequence of this package).
STREAM_CLOCK = 0xC10C
STREAM_CHANNEL = 0xC4A1
STREAM_NOISE = 0x0A15E

#: Grid columns per cached block.
GRID_BLOCK = 512
#: Largest carrier-phase change of any path between grid points, rad.
MAX_GRID_PHASE_STEP_RAD = 0.05
#: Longest grid step, s.
MAX_GRID_STEP_S = 1e-3
#: Syntheses of the noise-free samples (module docstring); the first is the default.
SYNTHESES = ("block", "exact")
#: Batches of block synthesis kept per thread (consecutive chunks share one).
_CACHED_BATCHES = 2


@dataclass(frozen=True)
class KernelArguments:
    """Positional arguments of :func:`sim.transmitter.multipath_kernel` and of its numpy reference."""

    kernel: tuple
    reference: tuple


@dataclass
class FrameTruth(ColumnRecord):
    """True per-frame quantities, one row per transmitted signal frame.

    Attributes
    ----------
    t_s : ndarray
        Receiver-clock arrival time of the frame's first symbol over the direct
        path, seconds since the capture's first sample (module docstring).
    range_m : ndarray
        3-D receiver-to-tower distance at that time, m.
    radial_velocity_mps : ndarray
        Closing speed ``-d range / dt``, m/s: positive towards the tower, the
        sign of eq. 10's velocity.
    doppler_hz : ndarray
        Direct-path Doppler ``-fc d tau / dt = fc * radial_velocity / c``, Hz.
    los : ndarray of bool
        Direct path unobstructed.
    clock_offset_hz : ndarray
        Apparent CFO from the receiver clock, ``-fc y(t)``, Hz; the measured
        CFO is ``doppler_hz + clock_offset_hz`` (+ the tuner's ``bulk_cfo_hz``).
    frame_number : ndarray of int64
        Absolute frame number (``% frames_per_superframe`` is the place in the
        superframe).
    """

    t_s: np.ndarray
    range_m: np.ndarray
    radial_velocity_mps: np.ndarray
    doppler_hz: np.ndarray
    los: np.ndarray
    clock_offset_hz: np.ndarray
    frame_number: np.ndarray


@dataclass
class DropTruth(ColumnRecord):
    """Runs of samples missing from the written capture (:mod:`sim.frontend` step 9), one row per run.

    Column names are ``dtmbnav_core.schema.DROP_COLUMNS``, all int64.

    Attributes
    ----------
    receiver_sample : ndarray
        Index of the run's first lost sample on the receiver's clock, samples
        since the capture's first sample (``receiver_sample / fs`` is on the
        time base of ``FrameTruth.t_s``).
    capture_sample : ndarray
        Index in the written file of the first sample after the gap (the
        file's length for a run that reaches its end).
    samples : ndarray
        Samples lost (within the capture).
    """

    receiver_sample: np.ndarray
    capture_sample: np.ndarray
    samples: np.ndarray


class CaptureGenerator:
    """The capture of a scenario (or a segment of it), generated in chunks.

    Parameters
    ----------
    scenario : Scenario
        Uses ``tower``, ``receiver`` and ``channel``.
    track : Track
        Receiver trajectory, ``t_s`` in true time from the scenario start.
    seconds : float, optional
        Capture length, s; default: to the end of the track.
    start_s : float
        Segment start (receiver time), s; rounded to a whole sample.
    sample_rate_hz, sample_format, pn_mode, seed : optional
        Override the scenario's values.
    pulse_span : int
        Pulse half-length, symbols.
    grid_step_s : float, optional
        Longest channel/clock grid step, s; default: 1 ms or finer (module
        docstring). Block synthesis makes its blocks of samples no longer.
    synthesis : str
        ``"block"`` or ``"exact"`` (module docstring).
    """

    def __init__(self, scenario: Scenario, track: Track, *, seconds: float | None = None, start_s: float = 0.0,
                 sample_rate_hz: float | None = None, sample_format: str | None = None,
                 pn_mode: str | PnMode | None = None, seed: int | None = None, pulse_span: int = PULSE_SPAN,
                 grid_step_s: float | None = None, synthesis: str = SYNTHESES[0]) -> None:
        if synthesis not in SYNTHESES:
            raise ValueError(f"synthesis must be one of {', '.join(SYNTHESES)}, got {synthesis!r}")
        self.synthesis = synthesis
        self.scenario = scenario
        self.seed = int(scenario.seed if seed is None else seed)
        self.sample_rate_hz = float(sample_rate_hz or scenario.receiver.sample_rate_hz)
        self.sample_format = sample_format or scenario.receiver.sample_format
        self.carrier_hz = scenario.tower.carrier_hz
        #: Capture centre minus channel centre, Hz (sim.frontend step 0a).
        self.tuning_offset_hz = float(scenario.receiver.tuning_offset_hz)
        if self.sample_rate_hz <= 0:
            raise ValueError(f"sample rate must be positive, got {self.sample_rate_hz}")
        if start_s < 0:
            raise ValueError(f"start_s must be >= 0, got {start_s}")
        tower = scenario.tower
        self.frame_config = FrameConfig(
            pn_mode=PnMode.parse(pn_mode or tower.pn_mode), rotating_phase=tower.rotating_phase,
            si_index=tower.si_index, si_polarity=tower.si_polarity, si_power_db=tower.si_power_db, seed=self.seed)
        self.first_sample = int(round(start_s * self.sample_rate_hz))
        track_end_s = float(track.t_s[-1])
        if seconds is None:
            seconds = track_end_s - self.first_sample / self.sample_rate_hz
        self.num_samples = int(round(seconds * self.sample_rate_hz))
        end_s = (self.first_sample + self.num_samples) / self.sample_rate_hz
        if self.num_samples <= 0:
            raise ValueError(f"capture of {seconds} s from start_s={start_s} s is empty")
        if end_s > track_end_s + 1e-6:
            raise ValueError(f"capture [{start_s}, {end_s:.3f}] s runs past the end of the track ({track_end_s:.3f} s)")
        self.start_offset_s = scenario.receiver.start_offset_s

        self.oscillator = scenario_oscillator(scenario, track_end_s + 2.0, self.seed, STREAM_CLOCK)
        self.channel = Channel(scenario, track, np.random.default_rng([self.seed, STREAM_CHANNEL, 0, 1]))
        max_doppler_hz = self.channel.max_doppler_hz()
        if grid_step_s is None:
            grid_step_s = MAX_GRID_STEP_S
            if max_doppler_hz > 0:
                grid_step_s = min(grid_step_s, MAX_GRID_PHASE_STEP_RAD / (2.0 * np.pi * max_doppler_hz))
        self.signal_power = mean_signal_power(self.frame_config)
        self.frontend = FrontEnd(scenario.receiver, self.signal_power, self.sample_rate_hz, self.sample_format,
                                 self.seed, STREAM_NOISE, pulse_span, stop_sample=self.first_sample + self.num_samples)
        # The transmit pulse through the front end's anti-alias filter: both syntheses shape with it.
        self.pulse = self.frontend.pulse
        self.layout = None
        if synthesis == "block":
            max_rate_error = np.abs(self.oscillator.y_grid).max() + max_doppler_hz / self.carrier_hz
            self.layout = choose_layout(self.sample_rate_hz, grid_step_s, max_rate_error, self.pulse)
            grid_step_s = self.layout.block_samples / self.sample_rate_hz
        self.grid_step_s = float(grid_step_s)
        self.frames = FrameSource(self.frame_config)
        #: The on-channel generator at ``tuning_factor * fs`` of an off-centre capture (None on the channel).
        self.wide: CaptureGenerator | None = None
        if self.tuning_offset_hz != 0.0:
            # Only its noise-free samples are used: its front end needs none of the impairments.
            on_channel = scenario.replace(receiver={"tuning_offset_hz": 0.0, **IMPAIRMENT_DEFAULTS})
            self.wide = CaptureGenerator(
                on_channel, track, seconds=seconds, start_s=start_s,
                sample_rate_hz=self.frontend.tuning_factor * self.sample_rate_hz, sample_format="cf32",
                pn_mode=self.frame_config.pn_mode, seed=self.seed, pulse_span=pulse_span, synthesis=synthesis)
        self._grid_block = lru_cache(maxsize=8)(self._build_grid_block)
        self._local = threading.local()

        # The earliest sample computed: block synthesis computes whole batches.
        first_computed = self.first_sample
        if self.layout is not None:
            first_computed -= self.first_sample % self.layout.batch_samples
        first_u = self._grid_columns(*self._grid_span(first_computed, 1))[0].min()
        if first_u < self.pulse.span + 1:
            raise ValueError(f"receiver.start_offset_s={self.start_offset_s} s is too small: the capture would need "
                             "symbols sent before frame 0 (raise start_offset_s above the propagation delay)")

    def _build_grid_block(self, block: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-path symbol time, coefficient and common phase on one block of grid columns."""
        receiver_t = np.arange(block * GRID_BLOCK, (block + 1) * GRID_BLOCK) * self.grid_step_s
        true_t = self.oscillator.true_time(receiver_t)
        state = self.channel.state(true_t)
        path_u = gb20600.SYMBOL_RATE_HZ * (true_t + self.start_offset_s - state.delay_s)
        phase = (-2.0 * np.pi * self.carrier_hz * self.oscillator.time_error_s(true_t)
                 + self.frontend.tuner_phase_rad(true_t))
        return path_u, state.coef, phase

    def _grid_span(self, first_sample: int, count: int) -> tuple[int, int]:
        """First and last grid column around samples ``[first_sample, first_sample + count)``."""
        g_lo = int(np.floor(first_sample / self.sample_rate_hz / self.grid_step_s))
        g_hi = int(np.floor((first_sample + count - 1) / self.sample_rate_hz / self.grid_step_s)) + 1
        return g_lo, g_hi

    def _grid_columns(self, g_lo: int, g_hi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Path symbol times, coefficients and common phase on grid columns ``g_lo .. g_hi``."""
        blocks = [self._grid_block(b) for b in range(g_lo // GRID_BLOCK, g_hi // GRID_BLOCK + 1)]
        path_u, coef, phase = (np.concatenate(parts, axis=-1) for parts in zip(*blocks))
        first = (g_lo // GRID_BLOCK) * GRID_BLOCK
        return path_u[:, g_lo - first: g_hi - first + 1], coef[:, g_lo - first: g_hi - first + 1], \
            phase[g_lo - first: g_hi - first + 1]

    def kernel_arguments(self, first_sample: int, count: int) -> KernelArguments:
        """Arguments of the exact twin's kernel for absolute sample indices (also for benchmarks)."""
        g_lo, g_hi = self._grid_span(first_sample, count)
        path_u, coef, phase = self._grid_columns(g_lo, g_hi)
        first_symbol, stop_symbol = symbol_range(path_u.min(), path_u.max(), self.pulse.span)
        symbols = self.frames.symbols(first_symbol, stop_symbol)
        common = (first_sample, count, self.sample_rate_hz, g_lo, self.grid_step_s, path_u, coef, phase,
                  symbols, first_symbol)
        return KernelArguments(kernel=(*common, self.pulse.polyphase, self.pulse.oversampling),
                               reference=(*common, self.pulse))

    @property
    def center_hz(self) -> float:
        """Centre frequency of the capture, Hz: the channel's plus ``tuning_offset_hz``."""
        return self.carrier_hz if self.tuning_offset_hz == 0.0 else self.carrier_hz + self.tuning_offset_hz

    @property
    def num_paths(self) -> int:
        """Number of propagation paths the channel kernel sums."""
        return self.channel.num_paths

    def _thread_state(self) -> threading.local:
        """This thread's synthesizer, symbol source, batch cache and front end (none of them is shared)."""
        state = self._local
        if not hasattr(state, "frontend"):
            main = threading.current_thread() is threading.main_thread()
            state.frontend = self.frontend if main else copy.copy(self.frontend)
            state.frames = self.frames if main else FrameSource(self.frame_config)
            state.synthesizer = BlockSynthesizer(self.layout) if self.layout is not None else None
            state.batches = {}
        return state

    def _batch(self, state: threading.local, index: int) -> np.ndarray:
        """Noise-free samples of block-synthesis batch ``index`` (samples from ``index * batch_samples``)."""
        if index not in state.batches:
            nb = self.layout.batch_blocks
            path_u, coef, phase = self._grid_columns(index * nb, (index + 1) * nb)
            if len(state.batches) >= _CACHED_BATCHES:
                del state.batches[next(iter(state.batches))]
            state.batches[index] = state.synthesizer.synthesize(path_u, coef, phase, state.frames.symbols)
        return state.batches[index]

    def clean_samples(self, first_sample: int, count: int) -> np.ndarray:
        """Noise-free received samples (complex128, before AGC) for absolute sample indices."""
        if self.wide is not None:
            return self.frontend.tune(self.wide.clean_samples, first_sample, count)
        if self.layout is None:
            return multipath_kernel(*self.kernel_arguments(first_sample, count).kernel)
        state = self._thread_state()
        size = self.layout.batch_samples
        out = np.empty(count, dtype=np.complex128)
        pos, stop = first_sample, first_sample + count
        while pos < stop:
            index, offset = divmod(pos, size)
            take = min(size - offset, stop - pos)
            out[pos - first_sample: pos - first_sample + take] = self._batch(state, index)[offset: offset + take]
            pos += take
        return out

    def _render(self, first_sample: int, count: int, quantise: bool) -> np.ndarray:
        """Samples after the front end (quantised rails with ``quantise``) for absolute sample indices."""
        frontend = self._thread_state().frontend
        samples = frontend.apply(self.clean_samples(first_sample, count), first_sample)
        return frontend.quantise(samples) if quantise else samples

    def drops(self) -> DropTruth:
        """The runs of samples missing from the written capture (:class:`DropTruth`; empty without drops).

        A run that starts before the segment or ends after it counts only its
        samples within the segment.
        """
        first, count = self.frontend.drop_runs
        start, stop = self.first_sample, self.first_sample + self.num_samples
        lo = np.clip(first, start, stop)
        hi = np.clip(first + count, start, stop)
        keep = hi > lo
        lo, lost = lo[keep], (hi - lo)[keep]
        # Samples kept before each run: the receiver-clock offset less the runs before it.
        before = np.cumsum(lost) - lost
        return DropTruth(receiver_sample=(lo - start).astype(np.int64),
                         capture_sample=(lo - start - before).astype(np.int64), samples=lost.astype(np.int64))

    @property
    def capture_samples(self) -> int:
        """Samples in the written capture: ``num_samples`` (receiver clock) less the dropped ones."""
        return self.num_samples - int(np.sum(self.drops().samples))

    def _kept(self, ranges: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """``(first, count)`` ranges less the dropped runs (module docstring of :mod:`sim.frontend`, step 9)."""
        drops = self.drops()
        if len(drops) == 0:
            return ranges
        gaps = [(int(a), int(a + n)) for a, n in zip(drops.receiver_sample + self.first_sample, drops.samples)]
        kept, g = [], 0
        for first, count in ranges:  # both ascending, the gaps apart: one pass
            pos, end = first, first + count
            while g < len(gaps) and gaps[g][1] <= pos:
                g += 1
            while pos < end:
                if g == len(gaps) or gaps[g][0] >= end:
                    kept.append((pos, end - pos))
                    break
                if gaps[g][0] > pos:
                    kept.append((pos, gaps[g][0] - pos))
                pos = min(gaps[g][1], end)
                if gaps[g][1] <= end:
                    g += 1
        return kept

    def _stream(self, chunk_samples: int, quantise: bool, jobs: int) -> Iterator[np.ndarray]:
        if chunk_samples <= 0:
            raise ValueError(f"chunk_samples must be positive, got {chunk_samples}")
        if jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {jobs}")
        stop = self.first_sample + self.num_samples
        if self.layout is None:
            jobs = 1  # the exact kernel runs on numba's own threads
        # Several jobs: chunk ends on batch boundaries, so that no batch is computed twice.
        align = self.layout.batch_samples if jobs > 1 else 1
        ranges = []
        pos = self.first_sample
        while pos < stop:
            end = min(-(-(pos + chunk_samples) // align) * align, stop)
            ranges.append((pos, end - pos))
            pos = end
        # Dropped runs are never rendered: their chunks are shorter, or split around the gap.
        ranges = self._kept(ranges)
        if jobs == 1:
            for first, count in ranges:
                yield self._render(first, count, quantise)
            return
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            pending: deque = deque()
            for first, count in ranges:
                pending.append(pool.submit(self._render, first, count, quantise))
                # Two chunks per job in flight: the threads stay busy and memory stays flat.
                if len(pending) >= 2 * jobs:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()

    def chunks(self, chunk_samples: int, jobs: int = 1) -> Iterator[np.ndarray]:
        """The capture as complex64 chunks at full scale 1 (after AGC), before quantisation.

        ``jobs`` threads compute chunks ahead with block synthesis (the stream
        is the same for any ``jobs``); the exact twin's kernel runs on numba's
        own threads instead. Dropped runs (:meth:`drops`) are left out: a
        chunk ends at a gap and the next begins after it, so the stream holds
        ``capture_samples`` samples.
        """
        return self._stream(chunk_samples, False, jobs)

    def quantised_chunks(self, chunk_samples: int, jobs: int = 1) -> Iterator[np.ndarray]:
        """The capture as interleaved rails of the sample format (``.tobytes()`` is the file)."""
        return self._stream(chunk_samples, True, jobs)

    def frame_truth(self) -> FrameTruth:
        """One row per signal frame whose first symbol arrives (direct path) within the capture."""
        rs = gb20600.SYMBOL_RATE_HZ
        frame_len = self.frame_config.frame_length
        capture_start = self.first_sample / self.sample_rate_hz
        capture_end = (self.first_sample + self.num_samples) / self.sample_rate_hz
        t_lo, t_hi = self.oscillator.true_time(np.array([capture_start, capture_end]))
        # Frames sent from (capture start - 1 ms) on cover every arrival (delays are tens of us).
        f_lo = max(int(np.floor((t_lo + self.start_offset_s - 1e-3) * rs / frame_len)), 0)
        f_hi = int(np.ceil((t_hi + self.start_offset_s) * rs / frame_len)) + 1
        frame_number = np.arange(f_lo, f_hi, dtype=np.int64)
        sent = frame_number * frame_len / rs - self.start_offset_s
        arrival = sent.copy()
        for _ in range(3):  # t = sent + tau(t): the delay changes by < 1e-8 per iteration
            arrival = sent + self.channel.direct(np.clip(arrival, 0.0, None)).range_m / SPEED_OF_LIGHT_MPS
        keep = arrival >= 0.0
        frame_number, arrival = frame_number[keep], arrival[keep]
        receiver_t = arrival + self.oscillator.time_error_s(arrival)
        keep = (receiver_t >= capture_start) & (receiver_t < capture_end)
        frame_number, arrival, receiver_t = frame_number[keep], arrival[keep], receiver_t[keep]
        direct = self.channel.direct(arrival)
        closing = -direct.range_rate_mps
        return FrameTruth(
            t_s=receiver_t - capture_start, range_m=direct.range_m, radial_velocity_mps=closing,
            doppler_hz=self.carrier_hz * closing / SPEED_OF_LIGHT_MPS, los=direct.los,
            clock_offset_hz=self.oscillator.clock_offset_hz(arrival, self.carrier_hz), frame_number=frame_number)
