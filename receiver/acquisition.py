"""Acquisition: header mode, frame grid, superframe position and bulk CFO.

Works on a fixed window of the 7.56 Msps stream (``acquisition_frames`` + 1
frames of the longest mode), with metrics that do not depend on the carrier
phase, so a CFO of tens of kHz and echoes do not stop it (docs/dtmb.md §5):

1. **Mode and grid.** PN420/PN945 headers repeat their first
   ``header - period`` chips one period P later, whatever the header phase:
   the lag-P product ``conj(r[n]) r[n+P]``, summed over that cyclic part and
   folded over the window's frames, peaks at the frame start; its magnitude
   does not depend on the CFO, and its angle is ``2 pi f P T``, which gives
   the CFO modulo ``Rs / P`` (+-14.8 kHz for PN420, +-7.4 kHz for PN945).
   PN595 has no cyclic part and a constant header: the lag-1 product
   ``conj(r[n]) r[n+1]`` correlated with the header's own lag-1 pattern,
   folded over frames, plays the same role (for the grid only: its angle is
   biased by multipath). Each metric is normalised to [0, 1]; the best mode
   above ``lock_threshold`` wins, otherwise there is no DTMB signal
   ("no lock").
2. **CFO ambiguity, header phase and superframe position** (PN420/945). The
   CFO candidates are the lag-P estimate plus every multiple of ``Rs / P``
   inside the search (``+-cfo_search_hz``). Each frame's core window is
   circularly correlated with the m-sequence: a candidate off by ``k Rs / P``
   turns the window through k whole cycles, which is a shift of its P-point
   spectrum by k bins, so one FFT per window serves every candidate, and the
   wrong ones smear the correlation peak over all lags. For each candidate
   the hypotheses "constant phase" and "rotating, frame 0 of the window is
   frame i of the superframe" (every i), each with a timing offset, are
   scored by the summed peak power over all frames; the best candidate and
   hypothesis win. Testing whole hypotheses over several frames, instead of
   chaining each frame's strongest peak, keeps echoes from making the lock
   jump. The winner also refines the frame start to the sample, and tells
   which frames show a header: a window that straddles the start of the
   signal locks on its first such frame, and one where fewer than
   ``MIN_PRESENT_SHARE`` of the frames show one is rejected. A frame grid
   whose headers show at no candidate means a carrier offset outside the
   search.
3. **PN595 timing and CFO.** The known header, correlated in short coherent
   segments, gives the timing (summed segment power) and the CFO (phase step
   between consecutive segments, unambiguous over +-44 kHz), after
   derotation by each search centre (``PN595_CFO_STEP_HZ`` apart) in turn.

The lock starts on a frame whose channel-estimate span (``lead`` samples
before the frame start) lies inside the window: samples before the window
may no longer be buffered, or precede the stream.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from receiver import DEFAULT_CFO_SEARCH_HZ

#: Largest timing correction, samples, tested around the grid metric's peak.
MAX_TIMING_OFFSET = 32
#: Header correlation peak over the mean of the frame's lags that counts as "header present".
PRESENCE_RATIO = 10.0
#: Share of the window's frames that must show a header (the window may straddle a signal edge).
MIN_PRESENT_SHARE = 0.75
#: Coherent segments of the PN595 header for its timing and CFO (85 chips: +-44 kHz unambiguous).
PN595_SEGMENTS = 7
#: Spacing of the PN595 CFO search centres, Hz: a residual of at most half of it turns an 85-chip
#: segment by a sixth of a cycle, so the segments stay coherent.
PN595_CFO_STEP_HZ = 30e3

#: Outcomes of :func:`search_window`.
LOCKED = "locked"
NO_SIGNAL = "no signal"
TOO_FEW_HEADERS = "too few headers"
CFO_OUTSIDE_SEARCH = "cfo outside search"


@dataclass(frozen=True)
class Acquisition:
    """What acquisition found.

    Attributes
    ----------
    mode : PnMode
        Header mode.
    frame_start : int
        Stream index (7.56 Msps) of the first header sample of the first
        whole frame in the window.
    rotating : bool
        Whether the header phase rotates through the superframe.
    frame_in_superframe : int
        Place of that frame in the superframe (0 when the phase is constant:
        the position is then unknown).
    constant_phase : int
        Header phase assumed when it does not rotate.
    coarse_cfo_hz : float
        Bulk carrier offset, Hz (positive: received carrier above nominal).
    metric : float
        Normalised grid metric of the winning mode, 0..1.
    """

    mode: PnMode
    frame_start: int
    rotating: bool
    frame_in_superframe: int
    constant_phase: int
    coarse_cfo_hz: float
    metric: float


@dataclass(frozen=True)
class SearchResult:
    """What one acquisition window gave.

    Attributes
    ----------
    acquisition : Acquisition or None
        The lock, or None.
    outcome : str
        :data:`LOCKED`, :data:`NO_SIGNAL` (no frame grid above the
        threshold), :data:`TOO_FEW_HEADERS` (a grid, but headers in too few
        of its frames: the window straddles the signal's start or end) or
        :data:`CFO_OUTSIDE_SEARCH` (a grid whose headers show at no CFO
        candidate of the search).
    """

    acquisition: Acquisition | None
    outcome: str


def window_length(acquisition_frames: int) -> int:
    """Samples acquisition needs: ``acquisition_frames + 1`` frames of the longest mode."""
    longest = max(m.value.frame_length for m in PnMode)
    return (acquisition_frames + 1) * longest


def _moving_sum(x: np.ndarray, length: int) -> np.ndarray:
    """``out[n] = sum(x[n : n + length])`` for every full window."""
    c = np.concatenate([np.zeros(1, dtype=x.dtype), np.cumsum(x)])
    return c[length:] - c[:-length]


def _fold(x: np.ndarray, period: int) -> np.ndarray:
    """Sum ``x`` over whole periods: ``out[n] = sum_f x[n + f * period]``."""
    frames = len(x) // period
    return x[: frames * period].reshape(frames, period).sum(axis=0)


def cyclic_grid_metric(r: np.ndarray, mode: PnMode) -> tuple[np.ndarray, np.ndarray]:
    """Folded lag-P metric of a cyclic-header mode (PN420, PN945).

    Returns
    -------
    rho : ndarray, shape (frame_length,)
        ``|sum conj(r[n]) r[n+P]| / mean energy`` over the cyclic part, folded.
    lag_sum : ndarray of complex, shape (frame_length,)
        The folded complex sums (their angle gives the coarse CFO).
    """
    m = mode.value
    rr = r.astype(np.complex128)
    lag = np.conj(rr[:-m.period]) * rr[m.period:]
    power = np.abs(rr) ** 2
    energy = 0.5 * (power[:-m.period] + power[m.period:])
    usable = (len(lag) - m.cyclic_length + 1 - m.frame_length) // m.frame_length * m.frame_length + m.frame_length
    lag_sum = _fold(_moving_sum(lag, m.cyclic_length)[:usable], m.frame_length)
    energy_sum = _fold(_moving_sum(energy, m.cyclic_length)[:usable], m.frame_length)
    return np.abs(lag_sum) / np.maximum(energy_sum, 1e-30), lag_sum


def differential_grid_metric(r: np.ndarray, mode: PnMode) -> tuple[np.ndarray, np.ndarray]:
    """Folded lag-1 correlation with the header's own lag-1 pattern (PN595).

    Same outputs as :func:`cyclic_grid_metric` (the lag sums are not used
    for the CFO: multipath biases their angle).
    """
    m = mode.value
    header = gb20600.header_symbols(mode, 0)
    pattern = np.real(np.conj(header[:-1]) * header[1:]) / np.abs(header[0]) ** 2
    rr = r.astype(np.complex128)
    diff = np.conj(rr[:-1]) * rr[1:]
    n_out = len(diff) - len(pattern) + 1
    frames = (n_out - m.frame_length) // m.frame_length + 1
    usable = frames * m.frame_length
    # The correlation is linear, so fold first: sum_f corr[n + f L] = sum_j pattern[j] D[n + j] with
    # D[k] = sum_f diff[k + f L], k < L + len(pattern) - 1. One frame-long correlation instead of a
    # window-long one.
    span = m.frame_length + len(pattern) - 1
    folded = np.sum(diff[np.arange(frames)[:, None] * m.frame_length + np.arange(span)[None, :]], axis=0)
    nfft = 1 << int(np.ceil(np.log2(span + len(pattern))))
    lag_sum = np.fft.ifft(np.fft.fft(folded, nfft) * np.conj(np.fft.fft(pattern, nfft)))[:m.frame_length]
    energy_sum = _fold(_moving_sum(np.abs(diff), len(pattern))[:usable], m.frame_length)
    return np.abs(lag_sum) / np.maximum(energy_sum, 1e-30), lag_sum


def _derotate(r: np.ndarray, cfo_hz: float, first_index: int = 0) -> np.ndarray:
    n = first_index + np.arange(len(r))
    return r * np.exp(-2j * np.pi * cfo_hz / SYMBOL_RATE_HZ * n)


def cfo_candidates(base_hz: float, mode: PnMode, search_hz: float) -> np.ndarray:
    """Shifts k (integers) with ``|base_hz + k Rs / P| <= search_hz``: the CFOs the lag-P angle allows."""
    step = SYMBOL_RATE_HZ / mode.value.period
    reach = int(np.ceil((search_hz + abs(base_hz)) / step))
    k = np.arange(-reach, reach + 1)
    return k[np.abs(base_hz + k * step) <= search_hz]


def _phase_hypotheses(r: np.ndarray, mode: PnMode, grid: int, frames: int, constant_phase: int,
                      shifts: np.ndarray) -> tuple[float, int, bool, int, int, np.ndarray]:
    """Best (score, CFO shift k, rotating, frame_in_superframe, timing offset, header present per frame).

    ``r`` is derotated by the lag-P CFO estimate; ``shifts`` are the CFO
    candidates' multiples k of ``Rs / P`` (module docstring step 2);
    ``grid`` is the grid metric's peak (frame 0 start, samples into ``r``).
    """
    m = mode.value
    period = m.period
    core = gb20600.chips_to_symbols(gb20600.pn_core(mode), 1.0)
    starts = grid + m.preamble + m.frame_length * np.arange(frames)
    spectra = np.fft.fft(r[starts[:, None] + np.arange(period)[None, :]], axis=1)
    reference = np.conj(np.fft.fft(core))[None, :]
    offsets = np.arange(-MAX_TIMING_OFFSET, MAX_TIMING_OFFSET + 1)
    f_idx = np.arange(frames)
    # Peak of frame f sits at s = tau - preamble - phase_f (mod P).
    positions = np.arange(m.frames_per_superframe)[:, None] + f_idx[None, :]
    phases = np.asarray(gb20600.header_phase(mode, positions))                 # (hyp, frames)
    idx = (offsets[None, None, :] - m.preamble - phases[:, :, None]) % period
    const_idx = (offsets[None, :] - m.preamble - constant_phase) % period
    best: tuple[float, int, bool, int, int, np.ndarray] | None = None
    for k in shifts:
        # Derotating by k Rs / P more shifts each window's spectrum by k bins (a constant phase per window aside).
        power = np.abs(np.fft.ifft(np.roll(spectra, -int(k), axis=1) * reference, axis=1)) ** 2   # (frames, P)
        rotating_scores = power[f_idx[None, :, None], idx].sum(axis=1)         # (hyp, offsets)
        constant_scores = power[f_idx[:, None], const_idx].sum(axis=0)         # (offsets,)
        hyp, j = np.unravel_index(np.argmax(rotating_scores), rotating_scores.shape)
        j_const = int(np.argmax(constant_scores))
        if constant_scores[j_const] >= rotating_scores[hyp, j]:
            found = (float(constant_scores[j_const]), int(k), False, 0, int(offsets[j_const]),
                     _present(power[f_idx, const_idx[:, j_const]], power))
        else:
            found = (float(rotating_scores[hyp, j]), int(k), True, int(hyp), int(offsets[j]),
                     _present(power[f_idx, idx[hyp, :, j]], power))
        if best is None or found[0] > best[0]:
            best = found
    assert best is not None
    return best


def _present(peaks: np.ndarray, power: np.ndarray) -> np.ndarray:
    """Whether each frame's header shows at the chosen hypothesis (peak well above its lags' mean)."""
    return peaks > PRESENCE_RATIO * np.mean(power, axis=1)


def _pn595_timing_and_cfo(r: np.ndarray, mode: PnMode, grid: int, frames: int,
                          search_hz: float) -> tuple[float, int, np.ndarray]:
    """CFO, timing offset and header presence per frame for the constant PN595 header.

    The header is correlated in ``PN595_SEGMENTS`` coherent segments (short
    enough to stay coherent under tens of kHz of CFO); the timing maximises
    the segments' summed power, and the phase step between consecutive
    segments gives the CFO, unambiguous over +-Rs / (2 * segment length).
    This is done after derotation by each search centre (``PN595_CFO_STEP_HZ``
    apart, inside ``+-search_hz``); the centre with the most summed power wins.
    """
    header = gb20600.header_symbols(mode, 0)
    seg = len(header) // PN595_SEGMENTS
    reference = np.conj(header[: seg * PN595_SEGMENTS]).reshape(PN595_SEGMENTS, seg)
    offsets = np.arange(-MAX_TIMING_OFFSET, MAX_TIMING_OFFSET + 1)
    starts = grid + MAX_TIMING_OFFSET + mode.value.frame_length * np.arange(frames)
    idx = starts[:, None, None] + offsets[None, :, None] + np.arange(seg * PN595_SEGMENTS)[None, None, :]
    reach = int(np.floor(search_hz / PN595_CFO_STEP_HZ))
    best: tuple[float, float, int, np.ndarray] | None = None
    for centre in PN595_CFO_STEP_HZ * np.arange(-reach, reach + 1):
        # Zeros in front so that early timing offsets of frame 0 stay inside the array.
        y = np.concatenate([np.zeros(MAX_TIMING_OFFSET, np.complex128), _derotate(r.astype(np.complex128), centre)])
        z = np.einsum("fosj,sj->fos", y[idx].reshape(frames, len(offsets), PN595_SEGMENTS, seg), reference)
        power = np.sum(np.abs(z) ** 2, axis=2)                                 # (frames, offsets)
        k = int(np.argmax(power.sum(axis=0)))
        score = float(power[:, k].sum())
        if best is None or score > best[0]:
            step = np.sum(np.conj(z[:, k, :-1]) * z[:, k, 1:])
            cfo = centre + float(np.angle(step)) * SYMBOL_RATE_HZ / (2 * np.pi * seg)
            best = (score, cfo, int(offsets[k]), _present(power[:, k], power))
    assert best is not None
    return best[1], best[2], best[3]


def search_window(r: np.ndarray, first_index: int, *, acquisition_frames: int = 16, lock_threshold: float = 0.3,
                  modes: tuple[PnMode, ...] = tuple(PnMode), constant_phase: int = 0,
                  cfo_search_hz: float = DEFAULT_CFO_SEARCH_HZ, lead: int = 0) -> SearchResult:
    """Search a window of the 7.56 Msps stream for a DTMB signal.

    Parameters
    ----------
    r : ndarray of complex
        ``window_length(acquisition_frames)`` samples (at least).
    first_index : int
        Stream index of ``r[0]``.
    acquisition_frames : int
        Frames folded by the metrics.
    lock_threshold : float
        Smallest normalised grid metric accepted as a signal.
    modes : tuple of PnMode
        Modes to test (all by default).
    constant_phase : int
        Header phase assumed for constant-phase PN420/PN945.
    cfo_search_hz : float
        Half-width of the carrier-offset search, Hz.
    lead : int
        Samples before its start that the locked frame needs inside the
        window (the channel estimate's span before the frame start).

    Returns
    -------
    SearchResult
    """
    if len(r) < window_length(acquisition_frames):
        raise ValueError(f"acquisition needs {window_length(acquisition_frames)} samples, got {len(r)}")
    best: tuple[float, PnMode, int, complex] | None = None
    for mode in modes:
        metric = differential_grid_metric if mode.value.cyclic_length == 0 else cyclic_grid_metric
        rho, lag_sum = metric(r, mode)
        n = int(np.argmax(rho))
        if best is None or rho[n] > best[0]:
            best = (float(rho[n]), mode, n, complex(lag_sum[n]))
    assert best is not None
    rho_best, mode, grid, lag_sum = best
    if rho_best < lock_threshold:
        return SearchResult(None, NO_SIGNAL)
    m = mode.value
    frames = acquisition_frames - 1
    if m.cyclic_length:
        base = float(np.angle(lag_sum)) * SYMBOL_RATE_HZ / (2 * np.pi * m.period)
        shifts = cfo_candidates(base, mode, cfo_search_hz)
        if not len(shifts):
            return SearchResult(None, CFO_OUTSIDE_SEARCH)
        _, k, rotating, position, offset, present = _phase_hypotheses(_derotate(r, base), mode, grid, frames,
                                                                      constant_phase, shifts)
        coarse = base + k * SYMBOL_RATE_HZ / m.period
    else:
        coarse, offset, present = _pn595_timing_and_cfo(r, mode, grid, frames, cfo_search_hz)
        rotating, position = False, 0
        if abs(coarse) > cfo_search_hz:
            return SearchResult(None, CFO_OUTSIDE_SEARCH)
    if not present.any():
        return SearchResult(None, CFO_OUTSIDE_SEARCH)
    # Lock on the first frame that shows a header (the window may begin before the signal does),
    # on a whole frame, and with the channel estimate's span inside the window.
    eligible = present & (grid + offset + m.frame_length * np.arange(frames) >= lead)
    if present.mean() < MIN_PRESENT_SHARE or not eligible.any():
        return SearchResult(None, TOO_FEW_HEADERS)
    first = int(np.argmax(eligible))
    start = grid + offset + first * m.frame_length
    position = (position + first) % m.frames_per_superframe if rotating else 0
    return SearchResult(Acquisition(mode=mode, frame_start=first_index + start, rotating=rotating,
                                    frame_in_superframe=position,
                                    constant_phase=constant_phase if m.rotates else 0, coarse_cfo_hz=coarse,
                                    metric=rho_best), LOCKED)


def acquire(r: np.ndarray, first_index: int, **options) -> Acquisition | None:
    """The :class:`Acquisition` of :func:`search_window` (same arguments), or None without a lock."""
    return search_window(r, first_index, **options).acquisition
