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
blocks of absolute grid indices, and linearly interpolated per sample inside
:func:`sim.transmitter.multipath_kernel`. The grid step is 1 ms, or less so
that no path's carrier phase moves more than ``MAX_GRID_PHASE_STEP_RAD`` per
step (linear interpolation of a unit phasor then loses < 0.03 % amplitude);
walking needs < 0.06 rad at 1 ms. Everything is a pure function of absolute
indices, so the output does not depend on the chunking.
Random streams: ``default_rng([seed, STREAM_*, index, 1])``; the symbol data
uses :class:`sim.frames.FrameSource` with the same seed.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from dtmbnav.core import gb20600
from dtmbnav.core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav.core.gb20600 import PnMode
from dtmbnav.core.records import ColumnRecord, Track
from sim.channel import Channel
from sim.frames import FrameConfig, FrameSource
from sim.frontend import FrontEnd, mean_signal_power
from sim.oscillator import scenario_oscillator
from sim.scenario import Scenario
from sim.transmitter import multipath_kernel, symbol_range

#: Random stream ids (second element of every seed sequence of this package).
STREAM_CLOCK = 0xC10C
STREAM_CHANNEL = 0xC4A1
STREAM_NOISE = 0x0A15E

#: Grid columns per cached block.
GRID_BLOCK = 512
#: Largest carrier-phase change of any path between grid points, rad.
MAX_GRID_PHASE_STEP_RAD = 0.05


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
        SRRC half-length, symbols.
    grid_step_s : float, optional
        Channel/clock interpolation grid, s; default: 1 ms or finer (module docstring).
    """

    def __init__(self, scenario: Scenario, track: Track, *, seconds: float | None = None, start_s: float = 0.0,
                 sample_rate_hz: float | None = None, sample_format: str | None = None,
                 pn_mode: str | PnMode | None = None, seed: int | None = None, pulse_span: int = 16,
                 grid_step_s: float | None = None) -> None:
        self.scenario = scenario
        self.seed = int(scenario.seed if seed is None else seed)
        self.sample_rate_hz = float(sample_rate_hz or scenario.receiver.sample_rate_hz)
        self.sample_format = sample_format or scenario.receiver.sample_format
        self.carrier_hz = scenario.tower.carrier_hz
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
        if grid_step_s is None:
            max_doppler_hz = self.channel.max_doppler_hz()
            grid_step_s = 1e-3
            if max_doppler_hz > 0:
                grid_step_s = min(grid_step_s, MAX_GRID_PHASE_STEP_RAD / (2.0 * np.pi * max_doppler_hz))
        self.grid_step_s = float(grid_step_s)
        self.signal_power = mean_signal_power(self.frame_config)
        self.frontend = FrontEnd(scenario.receiver, self.signal_power, self.sample_rate_hz, self.sample_format,
                                 self.seed, STREAM_NOISE, pulse_span)
        self.frames = FrameSource(self.frame_config)
        self.pulse = self.frontend.pulse
        self._grid_block = lru_cache(maxsize=4)(self._build_grid_block)

        first_u = self._grid(self.first_sample, 1)[0].min()
        if first_u < self.pulse.span:
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

    def _grid(self, first_sample: int, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Grid columns covering samples ``[first_sample, first_sample + count)`` and the first column's index."""
        g_lo = int(np.floor(first_sample / self.sample_rate_hz / self.grid_step_s))
        g_hi = int(np.floor((first_sample + count - 1) / self.sample_rate_hz / self.grid_step_s)) + 1
        blocks = [self._grid_block(b) for b in range(g_lo // GRID_BLOCK, g_hi // GRID_BLOCK + 1)]
        path_u, coef, phase = (np.concatenate(parts, axis=-1) for parts in zip(*blocks))
        return path_u, coef, phase, (g_lo // GRID_BLOCK) * GRID_BLOCK

    def kernel_arguments(self, first_sample: int, count: int) -> KernelArguments:
        """Arguments of the shaping + channel kernel for absolute sample indices (also for benchmarks)."""
        path_u, coef, phase, grid_first = self._grid(first_sample, count)
        lo = int(np.floor(first_sample / self.sample_rate_hz / self.grid_step_s)) - grid_first
        hi = int(np.floor((first_sample + count - 1) / self.sample_rate_hz / self.grid_step_s)) - grid_first + 2
        first_symbol, stop_symbol = symbol_range(path_u[:, lo:hi].min(), path_u[:, lo:hi].max(), self.pulse.span)
        symbols = self.frames.symbols(first_symbol, stop_symbol)
        common = (first_sample, count, self.sample_rate_hz, grid_first, self.grid_step_s, path_u, coef, phase,
                  symbols, first_symbol)
        return KernelArguments(kernel=(*common, self.pulse.polyphase, self.pulse.oversampling),
                               reference=(*common, self.pulse))

    @property
    def num_paths(self) -> int:
        """Number of propagation paths the channel kernel sums."""
        return self.channel.num_paths

    def clean_samples(self, first_sample: int, count: int) -> np.ndarray:
        """Noise-free received samples (complex128, before AGC) for absolute sample indices."""
        return multipath_kernel(*self.kernel_arguments(first_sample, count).kernel)

    def chunks(self, chunk_samples: int) -> Iterator[np.ndarray]:
        """The capture as complex64 chunks at full scale 1 (after AGC), before quantisation."""
        if chunk_samples <= 0:
            raise ValueError(f"chunk_samples must be positive, got {chunk_samples}")
        for offset in range(0, self.num_samples, chunk_samples):
            count = min(chunk_samples, self.num_samples - offset)
            start = self.first_sample + offset
            yield self.frontend.apply(self.clean_samples(start, count), start)

    def quantised_chunks(self, chunk_samples: int) -> Iterator[np.ndarray]:
        """The capture as interleaved rails of the sample format (``.tobytes()`` is the file)."""
        for chunk in self.chunks(chunk_samples):
            yield self.frontend.quantise(chunk)

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
