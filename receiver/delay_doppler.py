"""Delay-Doppler map of the PN-header CIR over a few hundred to a few thousand frames (``docs/paths.md``).

Paths closer than a chip merge in one frame's CIR (the delay fit of
:mod:`receiver.paths` separates them only down to about a third of a chip);
over many frames they separate by their Doppler, the rate of their carrier
phase. For frames ``n = 0..N-1`` and a grid of physical delays ``d``, the CIR
is read at lag ``d - o_n`` (``o_n``: how far frame n's window start has moved
from the nominal frame grid, so a path at a fixed delay stays in one column),
Hann-windowed along the frames and Fourier transformed: each path becomes a
line at its Doppler (plus the receiver's common carrier offset), at its
delay. :func:`doppler_lines` lists the lines.

``dtmbnav doppler-map`` runs it on a stage dump (``dtmbnav receive --dump``,
stage ``paths``: :func:`receiver.dump.map_from_dump`), and the path tracker
uses it for its first path (:class:`FirstPathDoppler`, ``docs/paths.md``,
"Separating paths by Doppler").
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ


@dataclass(frozen=True)
class DelayDopplerMap:
    """The CIR's spectrum along the frames at each delay.

    Attributes
    ----------
    doppler_hz : ndarray, (K,)
        Frequency of each row, Hz (the path's Doppler plus the receiver's
        carrier offset left in the CIR; increasing).
    delay_samples : ndarray of int, (L,)
        Physical delay of each column, 7.56 Msps samples after the first
        frame's window start.
    spectrum : ndarray of complex, (K, L)
        Windowed DFT along the frames, normalised so that a constant tap of
        amplitude ``a`` gives ``|a|`` at 0 Hz.
    """

    doppler_hz: np.ndarray
    delay_samples: np.ndarray
    spectrum: np.ndarray

    @property
    def power(self) -> np.ndarray:
        """``|spectrum|^2``, (K, L)."""
        return np.abs(self.spectrum) ** 2


@dataclass(frozen=True)
class DopplerLine:
    """A peak of the map's power summed over the delays.

    Attributes
    ----------
    doppler_hz : float
        Its frequency, Hz.
    power_db : float
        Its delay-summed power relative to the strongest line, dB.
    delay_samples : int
        The delay of its strongest column.
    profile_db : ndarray, (L,)
        Its power at each delay of the map, dB relative to its strongest column.
    row : int
        Its row of the map (``spectrum[row]`` is its complex delay profile).
    """

    doppler_hz: float
    power_db: float
    delay_samples: int
    profile_db: np.ndarray
    row: int


def window_offsets(window_start: np.ndarray, frame_index: np.ndarray, frame_length: int) -> np.ndarray:
    """How far each frame's window start has moved from the first frame's nominal frame grid, samples.

    A path at a fixed delay appears at CIR lag ``delay - offset`` in each frame.
    """
    start = np.asarray(window_start, dtype=np.int64)
    index = np.asarray(frame_index, dtype=np.int64)
    return (start - start[0]) - (index - index[0]) * frame_length


def doppler_spectrum(x: np.ndarray, size: int) -> np.ndarray:
    """Hann-windowed DFT of ``x`` along its first axis (frames), ``size`` points, zero frequency centred,
    normalised so that a constant ``a`` gives ``|a|`` at 0 Hz."""
    window = np.hanning(len(x))
    shape = (-1,) + (1,) * (np.ndim(x) - 1)
    return np.fft.fftshift(np.fft.fft(x * window.reshape(shape), size, axis=0), axes=0) / window.sum()


def delay_doppler_map(taps: np.ndarray, window_start: np.ndarray, frame_index: np.ndarray, lag0: int,
                      frame_length: int, delays: np.ndarray, oversample: int = 4) -> DelayDopplerMap:
    """Delay-Doppler map of consecutive frames' CIRs (module docstring).

    Parameters
    ----------
    taps : (N, M) complex
        CIR of each frame over lags ``lag0 .. lag0 + M - 1`` (the ``paths``
        stage of a dump: :meth:`receiver.channel_estimate.ChannelEstimator.span_taps`).
    window_start : (N,) int
        Window start of each frame, stream samples (7.56 Msps).
    frame_index : (N,) int
        Frame counter (consecutive frames differ by 1; a gap is refused).
    lag0 : int
        Lag of ``taps``' first column.
    frame_length : int
        Nominal frame length, samples (PN420: 4200).
    delays : (L,) int
        Physical delays to map, samples after the first frame's window start.
    oversample : int
        Zero-padding factor of the DFT (interpolates the frequency axis).

    Returns
    -------
    DelayDopplerMap

    Raises
    ------
    ValueError
        If the frames are not consecutive, or a delay falls outside the CIR
        span in some frame.
    """
    taps = np.asarray(taps)
    n = len(taps)
    frame_index = np.asarray(frame_index, dtype=np.int64)
    if n < 2 or np.any(np.diff(frame_index) != 1):
        raise ValueError("delay_doppler_map: needs two or more consecutive frames (frame_index step 1)")
    offsets = window_offsets(window_start, frame_index, frame_length)
    delays = np.asarray(delays, dtype=np.int64)
    columns = delays[None, :] - offsets[:, None] - lag0
    if columns.min() < 0 or columns.max() >= taps.shape[1]:
        raise ValueError(f"delay_doppler_map: delays {delays.min()}..{delays.max()} leave the CIR span "
                         f"{lag0}..{lag0 + taps.shape[1] - 1} in some frame (window offsets "
                         f"{offsets.min()}..{offsets.max()})")
    size = oversample * n
    spectrum = doppler_spectrum(taps[np.arange(n)[:, None], columns], size)
    doppler = np.fft.fftshift(np.fft.fftfreq(size, frame_length / SYMBOL_RATE_HZ))
    return DelayDopplerMap(doppler, delays, spectrum)


def doppler_lines(dd_map: DelayDopplerMap, floor_db: float = -25.0, max_lines: int = 8) -> list[DopplerLine]:
    """The map's lines: local maxima of the delay-summed power within ``floor_db`` of the strongest, strongest first."""
    total = dd_map.power.sum(axis=1)
    strongest = total.max()
    inner = np.arange(1, len(total) - 1)
    peaks = inner[(total[inner] >= total[inner - 1]) & (total[inner] > total[inner + 1])
                  & (total[inner] >= strongest * 10.0 ** (floor_db / 10.0))]
    lines = []
    for k in peaks[np.argsort(-total[peaks])][:max_lines]:
        profile = dd_map.power[k]
        lines.append(DopplerLine(float(dd_map.doppler_hz[k]), float(10.0 * np.log10(total[k] / strongest)),
                                 int(dd_map.delay_samples[np.argmax(profile)]),
                                 10.0 * np.log10(np.maximum(profile, 1e-300) / profile.max()), int(k)))
    return lines


def line_components(profile: np.ndarray, delays: np.ndarray, table: np.ndarray, oversampling: int,
                    max_paths: int = 3, step: float = 1.0 / 32.0) -> tuple[np.ndarray, np.ndarray]:
    """Super-resolved paths of one Doppler line: delays (samples) and powers of up to ``max_paths`` pulses.

    The line's complex delay profile is fitted with ``max_paths`` copies of the
    pulse ``table`` (:func:`receiver.paths.pulse_tables`) by least squares:
    each new path starts where the residual projects best, then every delay is
    refined in turn over +-half a sample (coordinate descent; for each
    candidate the residual after projecting out the other paths and the
    candidate, all candidates at once). Paths closer than a chip that share
    the line's Doppler (a direct path under a scatter cluster) separate here
    at the line's SNR, which is the frames' combined SNR.
    """
    period = (len(table) - 1) // oversampling
    grid_x = np.arange(len(table) - 1) / oversampling
    d = np.asarray(delays, dtype=np.float64)
    candidates = np.arange(d[0] + 1.0, d[-1] - 1.0, step)
    bank = np.interp(np.mod(d[:, None] - candidates[None, :], period), grid_x, table[:-1], period=period)
    y = np.asarray(profile, dtype=np.complex128)
    half = int(round(0.5 / step))
    chosen: list[int] = []

    def best_with(others: list[int], near: np.ndarray) -> int:
        """The candidate in ``near`` that, with the paths ``others``, leaves the least residual."""
        if others:
            q, _ = np.linalg.qr(bank[:, others])
            y_perp = y - q @ (q.T @ y)
            b_perp = bank[:, near] - q @ (q.T @ bank[:, near])
        else:
            y_perp, b_perp = y, bank[:, near]
        gain = np.abs(b_perp.T @ y_perp) ** 2 / np.maximum(np.sum(b_perp ** 2, axis=0), 1e-30)
        return int(near[int(np.argmax(gain))])

    for _ in range(max_paths):
        chosen.append(best_with(chosen, np.arange(len(candidates))))
        for _sweep in range(4):
            for i in range(len(chosen)):
                near = np.arange(max(chosen[i] - half, 0), min(chosen[i] + half + 1, len(candidates)))
                chosen[i] = best_with(chosen[:i] + chosen[i + 1:], near)
    amplitudes = np.linalg.lstsq(bank[:, chosen], y, rcond=None)[0]
    order = np.argsort(candidates[chosen])
    return candidates[chosen][order], (np.abs(amplitudes) ** 2)[order]


#: Frames per map when the check is on (PN420: 2048 = 1.14 s, 0.22 Hz bins with 4x padding).
CHECK_FRAMES = 2048


@dataclass(frozen=True)
class DopplerConfig:
    """Settings of :class:`FirstPathDoppler`.

    Attributes
    ----------
    frames : int
        Frames per map (0, the default: the check is off; :data:`CHECK_FRAMES`
        turns it on: ``dtmbnav receive --doppler-check``). It is off by default
        because on held-out street layouts it made the fusion worse
        (``docs/paths.md``; ``docs/decisions.md``, D6).
    hop_frames : int
        Frames between maps (the correction is held in between).
    line_floor_db : float
        Lines within this of the strongest line are compared, dB.
    component_floor_db : float
        A line's super-resolved path counts if within this of the map's
        strongest path, dB.
    own_floor_db : float
        ... and within this of its own line's strongest path, dB (a fit's
        stray path in a weak line is not a path).
    margin : float
        The earliest line's first path must precede both the tracked first
        path and the first path of the line it follows by this much, samples.
    separation_bins : float
        The two lines must be at least this many DFT bins (``1 / map length``)
        apart: closer lines share a main lobe, and a pair that close drifts
        apart by less than a cycle in a map's length anyway.
    max_lines : int
        Strongest lines fitted.
    """

    frames: int = 0
    hop_frames: int = 1024
    line_floor_db: float = -12.0
    component_floor_db: float = -25.0
    own_floor_db: float = -20.0
    margin: float = 0.25
    separation_bins: float = 2.0
    max_lines: int = 3


class FirstPathDoppler:
    """The frequency correction that moves a first path from the strongest Doppler line to the earliest one.

    The path tracker's first path is the earliest path it can resolve in
    delay; when a reflection arrives less than about a third of a chip after
    a weaker direct path, the two are one tracked path whose phase follows the
    stronger, the reflection. Over the last ``frames`` frames this keeps the
    CIR around that path, maps it in delay and Doppler
    (:func:`delay_doppler_map`), super-resolves each strong line's delay
    profile (:func:`line_components`) and finds the line whose earliest
    significant path comes first. When that is not the line the tracked first
    path follows (the peak of its amplitude's own spectrum), and its first
    path precedes both that line's and the tracked one by ``margin`` samples
    (the tracker resolves anything farther apart itself), and the two lines lie at least
    ``separation_bins`` apart, the first path's frequency is off by the
    difference of the two lines' frequencies: :meth:`update` returns it (0
    otherwise), held until the next map.

    Parameters
    ----------
    config : DopplerConfig
    table : ndarray
        The pulse table (:func:`receiver.paths.pulse_tables`).
    oversampling : int
        Its points per sample.
    lag0 : int
        Lag of the CIR's first column.
    frame_length : int
        Nominal frame length, samples.
    """

    def __init__(self, config: DopplerConfig, table: np.ndarray, oversampling: int, lag0: int,
                 frame_length: int) -> None:
        self.config = config
        self._table, self._oversampling = table, oversampling
        self._lag0, self._frame_length = lag0, frame_length
        self._batches: deque[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = deque()
        self._since = 0
        self.correction_hz = 0.0

    def update(self, taps: np.ndarray, window_start: np.ndarray, frame_index: np.ndarray,
               first_lag: float | None, first_amplitude: np.ndarray | None) -> float:
        """Keep a batch's CIRs; every ``hop_frames`` frames map them again. Returns the correction, Hz.

        ``first_lag``: the first path's lag in the batch's last frame;
        ``first_amplitude``: its fitted amplitude in each frame (None: no
        first path, the correction is dropped).
        """
        cfg = self.config
        if self._batches and frame_index[0] != self._batches[-1][2][-1] + 1:
            self._batches.clear()          # frames must be consecutive: start again after a gap
        amplitude = np.zeros(len(frame_index), complex) if first_amplitude is None else first_amplitude
        self._batches.append((taps, np.asarray(window_start), np.asarray(frame_index), amplitude))
        while self._held() - len(self._batches[0][2]) >= cfg.frames:
            self._batches.popleft()
        self._since += len(frame_index)
        if first_lag is None or first_amplitude is None:
            self.correction_hz = 0.0
        elif self._held() >= cfg.frames and self._since >= cfg.hop_frames:
            self._since = 0
            self.correction_hz = self._resolve(first_lag)
        return self.correction_hz

    def restart(self) -> None:
        """Forget the kept CIRs (their phases no longer continue into the next frame's)."""
        self._batches.clear()

    def _held(self) -> int:
        """Frames kept."""
        return sum(len(batch[2]) for batch in self._batches)

    def _resolve(self, first_lag: float) -> float:
        cfg = self.config
        start = np.concatenate([b[1] for b in self._batches])[-cfg.frames:]
        index = np.concatenate([b[2] for b in self._batches])[-cfg.frames:]
        amplitude = np.concatenate([b[3] for b in self._batches])[-cfg.frames:]
        offsets = window_offsets(start, index, self._frame_length)
        tracked = first_lag + int(offsets[-1])       # the first path's delay in the map's frame (its first frame)
        delays = np.arange(int(round(tracked)) - 6, int(round(tracked)) + 9)
        # Only the columns the map reads are gathered (the span has ten times as many).
        lo = int(delays[0] - offsets.max()) - self._lag0
        hi = int(delays[-1] - offsets.min()) - self._lag0 + 1
        if lo < 0 or hi > self._batches[-1][0].shape[1]:
            return 0.0                               # the first path near the span's edge: nothing to say
        taps = np.concatenate([b[0][:, lo:hi] for b in self._batches])[-cfg.frames:]
        dd_map = delay_doppler_map(taps, start, index, self._lag0 + lo, self._frame_length, delays)
        lines = doppler_lines(dd_map, cfg.line_floor_db, cfg.max_lines)
        if len(lines) < 2:
            return 0.0
        # The frequency the tracked first path follows: the peak of its own amplitude's spectrum.
        followed = dd_map.doppler_hz[int(np.argmax(np.abs(doppler_spectrum(amplitude, len(dd_map.doppler_hz)))))]
        bin_hz = SYMBOL_RATE_HZ / (self._frame_length * len(amplitude))   # 1 / the map's length
        if all(abs(line.doppler_hz - followed) < cfg.separation_bins * bin_hz for line in lines):
            return 0.0                               # no line far enough from the followed one to be another path
        fitted = [line_components(dd_map.spectrum[line.row], dd_map.delay_samples, self._table, self._oversampling)
                  for line in lines]
        strongest = max(float(power.max()) for _, power in fitted)
        earliest = np.full(len(lines), np.inf)
        for k, (delays, power) in enumerate(fitted):
            real = (power >= strongest * 10.0 ** (cfg.component_floor_db / 10.0)) & \
                (power >= power.max() * 10.0 ** (cfg.own_floor_db / 10.0))
            if real.any():
                earliest[k] = delays[real].min()
        direct = int(np.argmin(earliest))
        own = int(np.argmin([abs(line.doppler_hz - followed) for line in lines]))
        # The tracked first path is the earliest path the delay fit resolves: a line must show one before it.
        if (direct == own or earliest[direct] > min(earliest[own], tracked) - cfg.margin
                or abs(lines[direct].doppler_hz - followed) < cfg.separation_bins * bin_hz):
            return 0.0
        return lines[direct].doppler_hz - followed
