"""PN-based channel estimation and TDS-OFDM body recovery (dtmb.md §5).

Per frame, on the 7.56 Msps stream derotated by the coarse CFO:

1. **Channel estimate.** The known header is correlated with the received
   header. PN420/PN945: a core-period window just after the preamble sees the
   m-sequence circularly convolved with the channel (the preamble is its
   cyclic prefix), so one P-point circular correlation gives the taps; PN595
   (no cyclic part): least squares over the header rows free of the previous
   body. Taps at delays
   ``-taps_before .. taps_after - 1`` (relative to the frame's window start)
   are kept where their power exceeds ``threshold`` times the noise floor
   measured on the other lags. The taps also give the SNR, the share of the
   window power they capture (``peak_metric``) and the power centroid
   (sub-sample timing for the tracker).
2. **Body recovery.** The tails of the current and next headers convolved
   with the taps are subtracted from the body window, and the body's own
   convolution tails that fell outside the window (after the body, and
   before it for pre-cursor taps) are folded back ("cyclic reconstruction"):
   the 3780 samples then equal the body circularly convolved with the
   channel, as the FFT assumes.

Both hot loops are numba kernels over a whole batch of frames, each with a
plain-numpy reference (``*_reference``) used by the tests and the benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from receiver import gb20600
from receiver.gb20600 import BODY_LENGTH, SYMBOL_RATE_HZ, PnMode

@njit(cache=True, fastmath=True)
def derotate_segments(buf: np.ndarray, buf_start: int, seg_starts: np.ndarray, length: int,
                      cfo_cycles_per_sample: float, rot: np.ndarray, out: np.ndarray) -> None:
    """Copy ``length`` samples from each segment start, removing the coarse CFO.

    ``out[b, i] = buf[s_b + i] * exp(-j 2 pi f T (s_b + i))`` with ``s_b`` global
    stream indices (``buf[0]`` is index ``buf_start``). The phase of the first
    sample is computed in float64 from the absolute index (no accumulated
    drift); ``rot[i] = exp(-j 2 pi f T i)`` carries it along the segment.
    """
    for b in range(seg_starts.shape[0]):
        s = seg_starts[b]
        cycles = cfo_cycles_per_sample * s
        cycles -= np.floor(cycles)
        base = np.complex64(np.exp(-2j * np.pi * cycles))
        # 1-D slices with non-negative loop indices: the loop vectorises (no wraparound checks).
        src, dst = buf[s - buf_start: s - buf_start + length], out[b]
        for i in range(length):
            dst[i] = src[i] * rot[i] * base


def derotate_segments_reference(buf: np.ndarray, buf_start: int, seg_starts: np.ndarray, length: int,
                                cfo_cycles_per_sample: float) -> np.ndarray:
    """Plain-numpy :func:`derotate_segments` (returns the ``(B, length)`` array)."""
    n = seg_starts[:, None] + np.arange(length)[None, :]
    return buf[n - buf_start] * np.exp(-2j * np.pi * cfo_cycles_per_sample * n)


def rotation_table(cfo_hz: float, length: int) -> np.ndarray:
    """``exp(-j 2 pi f T i)``, ``i < length`` (complex64), for :func:`derotate_segments`."""
    return np.exp(-2j * np.pi * cfo_hz / SYMBOL_RATE_HZ * np.arange(length)).astype(np.complex64)


@dataclass
class ChannelEstimates:
    """Channel taps and header quality of a batch of frames.

    Attributes
    ----------
    taps : ndarray, complex64, (B, taps_before + taps_after)
        Thresholded taps; column ``j`` is delay ``j - taps_before`` samples.
    raw_taps : ndarray, complex64, same shape
        Taps before thresholding (for the PN CFO estimate).
    snr_db : ndarray (B,)
        Body SNR: tap power over the noise power per sample, dB.
    noise_power : ndarray (B,)
        Noise power per received sample (the SNR's denominator), in the
        units of the received samples.
    peak_metric : ndarray (B,)
        Share of the header-window power the kept taps explain, 0..1.
    centroid : ndarray (B,)
        Power centroid of the kept taps, samples after the window start.
    """

    taps: np.ndarray
    raw_taps: np.ndarray
    snr_db: np.ndarray
    noise_power: np.ndarray
    peak_metric: np.ndarray
    centroid: np.ndarray


class ChannelEstimator:
    """Batched PN-header channel estimation for one header mode.

    PN420/PN945: circular correlation of a core-period window with the
    phase-correct m-sequence (a fast Walsh-Hadamard transform,
    :func:`m_sequence_correlation_kernel`; the reference path uses FFTs),
    corrected for the m-sequence's -1/P sidelobes (exact deconvolution); the
    lags outside the tap span measure the noise floor. PN595: least squares over
    the header rows that only header chips reach (a precomputed
    pseudo-inverse; an aperiodic correlation would leave -28 dB sidelobes per
    path), the residual measures the noise.

    Parameters
    ----------
    mode : PnMode
        Header mode.
    batch : int
        Frames per call.
    taps_before, taps_after : int
        Delay span of the estimate around the frame's window start, samples.
    threshold : float
        Keep taps whose power exceeds ``threshold`` times the noise floor.
    """

    def __init__(self, mode: PnMode, batch: int, taps_before: int = 16, taps_after: int = 48,
                 threshold: float = 10.0) -> None:
        m = mode.value
        self.mode = mode
        self.taps_before, self.taps_after, self.threshold = taps_before, taps_after, threshold
        self.n_taps = taps_before + taps_after
        self.cyclic = m.cyclic_length > 0
        self.header_power = m.header_power_ratio
        if self.cyclic and (taps_after > m.preamble or taps_before > m.postamble):
            raise ValueError(f"{mode.name}: the delay span must fit in the header's cyclic extension")
        self.phases = np.arange(-(m.period // 2), m.period // 2 + 1) if m.rotates else np.zeros(1, np.int64)
        if self.cyclic:
            # Window: the core period after the preamble (the preamble is its cyclic prefix).
            self.window_offset, self.window_length = m.preamble, m.period
            lags = np.arange(-taps_before, taps_after)
            self.tap_bins = lags % m.period
            self.noise_bins = np.setdiff1d(np.arange(m.period), self.tap_bins)
            self._sample_slot, self._shift_slot = hadamard_slots(gb20600.pn_core(mode))
            # Every header phase's core window is alpha * (1 - 2 c[(n + preamble + phase) mod P]):
            # the correlation is conj(alpha) / energy times the +-1 m-sequence correlation.
            alpha = (1.0 + 1.0j) * m.header_amplitude
            self._hadamard_scale = np.complex64(np.conj(alpha) / (m.period * abs(alpha) ** 2))
            self._windows = np.zeros((batch, m.period), dtype=np.complex64)
            self._corr = np.empty((batch, m.period), dtype=np.complex64)
            self._hadamard_work = np.empty(m.period + 1, dtype=np.complex64)
        else:
            # Rows n + taps_after - 1 + i only see header chips i .. i + n_taps - 1.
            self.window_offset, self.window_length = taps_after - 1, m.header_length - self.n_taps + 1
            header = gb20600.header_symbols(mode, 0)
            rows = np.arange(self.window_length)[:, None] + self.n_taps - 1 - np.arange(self.n_taps)[None, :]
            model = header[rows]
            self._pinv_t = np.linalg.pinv(model).T.astype(np.complex64)         # (rows, taps)
            self._gram = (model.conj().T @ model).astype(np.complex64)          # A^H A
            self._model = model
            self._windows = np.zeros((batch, self.window_length), dtype=np.complex64)
        self.reference_length = self.window_length

    @cached_property
    def _references(self) -> np.ndarray:
        """Per header phase: conj(FFT(core window reference)) / (P * energy): the inverse FFT gives taps.

        Only :meth:`estimate_reference` uses the table; it is made on first use.
        """
        m = self.mode.value
        refs = np.array([gb20600.header_symbols(self.mode, int(p))[m.preamble: m.preamble + m.period]
                         for p in self.phases])
        norm = np.sum(np.abs(refs) ** 2, axis=1, keepdims=True)
        return (np.conj(np.fft.fft(refs, axis=1)) / (norm * m.period)).astype(np.complex64)

    def phase_rows(self, phases: np.ndarray) -> np.ndarray:
        """Row of each header phase in the reference table."""
        return np.asarray(phases) - self.phases[0] if len(self.phases) > 1 else np.zeros(len(phases), np.int64)

    @property
    def windows(self) -> np.ndarray:
        """The ``(batch, window_length)`` buffer to fill with derotated header windows."""
        return self._windows

    def estimate(self, count: int, phases: np.ndarray) -> ChannelEstimates:
        """Estimate the channel of the first ``count`` windows in :attr:`windows`."""
        windows = self._windows[:count]
        if self.cyclic:
            power_in = np.empty(count)
            m = self.mode.value
            shifts = (np.asarray(phases, dtype=np.int64) + m.preamble) % m.period
            m_sequence_correlation_kernel(windows, shifts, self._sample_slot, self._shift_slot, self._hadamard_scale,
                                          self._hadamard_work, self._corr, power_in)
            raw = np.empty((count, self.n_taps), np.complex64)
            noise_tap = np.empty(count)
            deconvolve_kernel(self._corr[:count], self.tap_bins, self.noise_bins, raw, noise_tap)
        else:
            power_in = np.mean(windows.real ** 2 + windows.imag ** 2, axis=1)
            raw = windows @ self._pinv_t
            noise_tap = self._ls_noise_tap(raw, power_in)
        out = ChannelEstimates(taps=np.empty((count, self.n_taps), np.complex64), raw_taps=raw.astype(np.complex64),
                               snr_db=np.empty(count, np.float32), noise_power=np.empty(count),
                               peak_metric=np.empty(count, np.float32), centroid=np.empty(count))
        summarise_taps_kernel(out.raw_taps, noise_tap, power_in, self.threshold, self.header_power,
                              self.reference_length, self.taps_before, out.taps, out.snr_db, out.noise_power,
                              out.peak_metric, out.centroid)
        return out

    def _deconvolve(self, corr: np.ndarray) -> np.ndarray:
        """Remove the m-sequence sidelobes from the correlation (exact for a channel inside the tap span).

        The periodic autocorrelation of an m-sequence is P at lag 0 and -1
        elsewhere, so ``corr[s] = h[s] (1 + 1/P) - S / P`` with ``S = sum(h)``.
        Summing over the L tap lags gives ``S = sum_taps(corr) / (1 - (L - 1) / P)``,
        then ``h[s] = (P corr[s] + S) / (P + 1)``. Taking S from the tap lags
        only (not from all P lags) keeps the noise of every lag out of it.
        Without the correction the -S/P sidelobes of a strong path would sit on
        the noise floor (a 20 dB ceiling on the SNR estimate).
        """
        p = self.window_length
        total = corr[:, self.tap_bins].sum(axis=1, keepdims=True) / (1.0 - (self.n_taps - 1.0) / p)
        return (corr * p + total) / (p + 1.0)

    def _ls_noise_tap(self, raw: np.ndarray, power_in: np.ndarray) -> np.ndarray:
        """Noise variance of a tap from the LS residual ``|y|^2 - h^H A^H A h`` (per sample, then per tap)."""
        explained = np.real(np.einsum("bi,ij,bj->b", raw.conj(), self._gram, raw))
        residual = (power_in * self.window_length - explained) / (self.window_length - self.n_taps)
        return np.maximum(residual, 0.0) / (self.header_power * self.reference_length)

    def estimate_reference(self, windows: np.ndarray, phases: np.ndarray) -> ChannelEstimates:
        """Plain-numpy :meth:`estimate` of ``windows`` (``(B, window_length)``): ``np.fft`` / ``lstsq``."""
        power_in = np.mean(np.abs(windows) ** 2, axis=1)
        if self.cyclic:
            corr = np.fft.ifft(np.fft.fft(windows, axis=1) * self._references[self.phase_rows(phases)] * self.window_length,
                               axis=1)
            taps_all = self._deconvolve(corr)
            raw = taps_all[:, self.tap_bins]
            noise_tap = np.mean(np.abs(taps_all[:, self.noise_bins]) ** 2, axis=1)
        else:
            raw = np.linalg.lstsq(self._model, windows.T, rcond=None)[0].T
            noise_tap = self._ls_noise_tap(raw, power_in)
        return self.summarise_reference(raw, noise_tap, power_in)

    def summarise_reference(self, raw: np.ndarray, noise_tap: np.ndarray, power_in: np.ndarray) -> ChannelEstimates:
        """Thresholded taps and header quality (plain numpy; :func:`summarise_taps_kernel` does the same).

        A tap's noise variance is the per-sample noise power divided by the
        reference energy (``header_power * reference_length``): that converts
        the tap noise floor to the SNR's noise per sample.
        """
        power = np.abs(raw) ** 2
        keep = power > self.threshold * noise_tap[:, None]
        kept = np.where(keep, power, 0.0)
        signal = np.sum(np.where(keep, power - noise_tap[:, None], 0.0), axis=1)
        noise_sample = noise_tap * self.header_power * self.reference_length
        snr_db = 10 * np.log10(np.maximum(signal, 1e-30) / np.maximum(noise_sample, 1e-30))
        peak = np.clip(signal * self.header_power / np.maximum(power_in, 1e-30), 0.0, 1.0)
        total = np.sum(kept, axis=1)
        lags = np.arange(-self.taps_before, self.taps_after)
        centroid = np.where(total > 0, kept @ lags / np.where(total > 0, total, 1.0), 0.0)
        return ChannelEstimates(taps=np.where(keep, raw, 0).astype(np.complex64), raw_taps=raw.astype(np.complex64),
                                snr_db=snr_db.astype(np.float32), noise_power=noise_sample,
                                peak_metric=peak.astype(np.float32), centroid=centroid)


def hadamard_slots(chips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Permutations that turn circular correlation with an m-sequence into a Walsh-Hadamard transform.

    For an m-sequence ``c`` of period ``P = 2^d - 1`` (chips 0/1, signs
    ``x = 1 - 2c``), the state ``u(m) = sum_i c[m + i] 2^i`` (``i < d``) runs
    over all nonzero d-bit words, and every shifted chip is a linear function
    of it: ``c[m + t] = parity(v(t) & u(m))``, with ``v(t)`` read off the
    positions whose state is a single bit. Then ``x[m + t] = H[v(t), u(m)]``
    with ``H`` the ``2^d`` Sylvester-Hadamard matrix, so
    ``sum_m w[m] x[(m + t) mod P] = (H W)[v(t)]`` where ``W[u(m)] = w[m]``,
    ``W[0] = 0`` (M. Cohn and A. Lempel, "On fast M-sequence transforms",
    IEEE Trans. Inf. Theory, 1977): all P lags for ``d 2^d`` additions.

    Parameters
    ----------
    chips : ndarray of 0/1, (P,)
        One period of the m-sequence.

    Returns
    -------
    sample_slot : ndarray of int64, (P,)
        ``u(m)``: where sample m goes in the transform's input.
    shift_slot : ndarray of int64, (P,)
        ``v(t)``: where the correlation at shift t is in its output.

    Raises
    ------
    ValueError
        If ``chips`` is not an m-sequence (the states are not all distinct
        or a shift is not linear in the state).
    """
    c = np.asarray(chips, dtype=np.int64)
    period = len(c)
    degree = int(np.log2(period + 1))
    if period != 2 ** degree - 1:
        raise ValueError(f"chips: an m-sequence has period 2^d - 1, got {period}")
    n = np.arange(period)
    sample_slot = sum(c[(n + i) % period] << i for i in range(degree))
    if not np.array_equal(np.sort(sample_slot), np.arange(1, period + 1)):
        raise ValueError("chips: not an m-sequence (the register states repeat)")
    position = np.empty(period + 1, dtype=np.int64)
    position[sample_slot] = n
    shift_slot = sum(c[(position[1 << i] + n) % period] << i for i in range(degree))
    parity = np.array([bin(x).count("1") & 1 for x in range(period + 1)])
    predicted = parity[shift_slot[None, :] & sample_slot[:, None]]       # [m, t]
    if not np.array_equal(predicted, c[(n[:, None] + n[None, :]) % period]):
        raise ValueError("chips: not an m-sequence (a shifted chip is not linear in the state)")
    return sample_slot, shift_slot


@njit(cache=True, fastmath=True)
def walsh_hadamard_inplace(work: np.ndarray) -> None:
    """Unnormalised fast Walsh-Hadamard transform (Sylvester order) of ``work``, length a power of 2, in place.

    Radix-4 passes (half the memory passes of radix-2), then one radix-2
    pass when the length is an odd power of 2.
    """
    size = work.shape[0]
    q = 1
    while 4 * q <= size:
        for start in range(0, size, 4 * q):
            for i in range(start, start + q):
                a, b, c, d = work[i], work[i + q], work[i + 2 * q], work[i + 3 * q]
                ab_sum, ab_diff, cd_sum, cd_diff = a + b, a - b, c + d, c - d
                work[i] = ab_sum + cd_sum
                work[i + q] = ab_diff + cd_diff
                work[i + 2 * q] = ab_sum - cd_sum
                work[i + 3 * q] = ab_diff - cd_diff
        q *= 4
    if q < size:
        for i in range(q):
            a, b = work[i], work[i + q]
            work[i] = a + b
            work[i + q] = a - b


@njit(cache=True, fastmath=True)
def m_sequence_correlation_kernel(windows: np.ndarray, shifts: np.ndarray, sample_slot: np.ndarray,
                                  shift_slot: np.ndarray, scale: complex, work: np.ndarray, corr: np.ndarray,
                                  power_in: np.ndarray) -> None:
    """Circular correlation of each window with its phase of the m-sequence, by fast Walsh-Hadamard transform.

    With ``x`` the m-sequence's signs (see :func:`hadamard_slots`),
    ``corr[b, s] = scale * sum_m w_b[m] x[(m - s + shifts[b]) mod P]``, i.e.
    ``sum_n w_b[n + s] conj(ref_b[n]) / energy`` for the reference
    ``ref_b[n] = alpha x[(n + shifts[b]) mod P]`` and
    ``scale = conj(alpha) / energy``: what the FFT correlation of
    :meth:`ChannelEstimator.estimate_reference` gives. Also the mean power of
    each window (``power_in``). ``work`` is a ``(P + 1,)`` scratch buffer;
    ``len(shifts)`` windows are processed.
    """
    period = windows.shape[1]
    for b in range(shifts.shape[0]):
        row = windows[b]
        work[0] = 0
        acc = 0.0
        for m in range(period):
            w = row[m]
            work[sample_slot[m]] = w
            acc += w.real * w.real + w.imag * w.imag
        power_in[b] = acc / period
        walsh_hadamard_inplace(work)
        out = corr[b]
        shift = shifts[b]
        for s in range(period):
            t = shift - s
            out[s] = work[shift_slot[t if t >= 0 else t + period]] * scale


@njit(cache=True, fastmath=True)
def deconvolve_kernel(corr: np.ndarray, tap_bins: np.ndarray, noise_bins: np.ndarray, raw: np.ndarray,
                      noise_tap: np.ndarray) -> None:
    """Taps and noise floor of a batch from m-sequence correlations (into ``raw``, ``noise_tap``).

    Same arithmetic as ``ChannelEstimator._deconvolve`` followed by the tap
    gather and the noise-lag mean power, without the temporaries.
    """
    p = corr.shape[1]
    n_taps = tap_bins.shape[0]
    scale = p / (p + 1.0)
    for b in range(corr.shape[0]):
        total = 0j
        for i in tap_bins:
            total += corr[b, i]
        offset = total / (1.0 - (n_taps - 1.0) / p) / (p + 1.0)
        for j in range(n_taps):
            raw[b, j] = corr[b, tap_bins[j]] * scale + offset
        acc = 0.0
        for i in noise_bins:
            v = corr[b, i] * scale + offset
            acc += v.real * v.real + v.imag * v.imag
        noise_tap[b] = acc / noise_bins.shape[0]


@njit(cache=True, fastmath=True)
def summarise_taps_kernel(raw: np.ndarray, noise_tap: np.ndarray, power_in: np.ndarray, threshold: float,
                          header_power: float, reference_length: int, taps_before: int, taps: np.ndarray,
                          snr_db: np.ndarray, noise_power: np.ndarray, peak: np.ndarray, centroid: np.ndarray) -> None:
    """Thresholded taps, SNR, noise power, peak metric and centroid of a batch (into the given arrays).

    Same arithmetic as :meth:`ChannelEstimator.summarise_reference`.
    """
    for b in range(raw.shape[0]):
        noise = noise_tap[b]
        signal = 0.0
        total = 0.0
        moment = 0.0
        for j in range(raw.shape[1]):
            v = raw[b, j]
            p = v.real * v.real + v.imag * v.imag
            if p > threshold * noise:
                taps[b, j] = v
                signal += p - noise
                total += p
                moment += p * (j - taps_before)
            else:
                taps[b, j] = 0
        noise_sample = noise * header_power * reference_length
        noise_power[b] = noise_sample
        snr_db[b] = 10.0 * np.log10(max(signal, 1e-30) / max(noise_sample, 1e-30))
        peak[b] = min(max(signal * header_power / max(power_in[b], 1e-30), 0.0), 1.0)
        centroid[b] = moment / total if total > 0 else 0.0


def body_phases(frame_starts: np.ndarray, header_length: int, taps_before: int,
                cfo_cycles_per_sample: float) -> np.ndarray:
    """Coarse-CFO phase ``exp(-j 2 pi f T s)`` at each body segment's first sample (complex64).

    :func:`recover_bodies` leaves this constant per-frame factor out of the
    body samples (one multiply per sample less); multiply each frame's
    carriers by it after the FFT.
    """
    first = frame_starts + header_length - taps_before
    cycles = np.mod(cfo_cycles_per_sample * first.astype(np.float64), 1.0)
    return np.exp(-2j * np.pi * cycles).astype(np.complex64)


@njit(cache=True, fastmath=True)
def recover_bodies(buf: np.ndarray, buf_start: int, frame_starts: np.ndarray, header_length: int,
                   rot: np.ndarray, phases: np.ndarray, taps: np.ndarray, taps_before: int,
                   headers_now: np.ndarray, headers_next: np.ndarray, out: np.ndarray) -> None:
    """Header-tail removal and cyclic reconstruction of a batch of bodies.

    With ``z[u]`` the derotated sample at body offset ``u`` (``u`` in
    ``[-taps_before, 3780 + taps_after)``) and ``c_now``/``c_next`` the current
    and next headers convolved with the taps, the body's linear convolution is
    ``z - c_now - c_next``; its parts outside ``[0, 3780)`` are folded back:
    ``out[t] = sum over u = t (mod 3780) of (z - c_now - c_next)[u]``.
    The output omits each frame's constant phase ``phases[b]`` (see
    :func:`body_phases`): ``out[b] * phases[b]`` is the derotated body.

    Parameters
    ----------
    buf, buf_start
        Stream samples and the index of ``buf[0]``.
    frame_starts : (B,) int64
        Window start (first header sample) of each frame, stream index.
    header_length : int
        Ng.
    rot : complex64
        ``exp(-j 2 pi f T i)`` over ``3780 + n_taps`` samples (coarse CFO).
    phases : (B,) complex64
        :func:`body_phases` of the frames.
    taps : (B, L) complex64
        Thresholded taps (on derotated samples); column j is delay ``j - taps_before``.
    headers_now, headers_next : (B, Ng) complex64
        Transmitted header symbols of each frame and of the next one.
    out : (>=B, 3780) complex64
        Recovered bodies (the FFT input buffer).
    """
    n = out.shape[1]
    n_taps = taps.shape[1]
    taps_after = n_taps - taps_before
    span = n + n_taps
    for b in range(frame_starts.shape[0]):
        # 1-D slices with non-negative loop indices: the loops vectorise (no wraparound checks).
        off = frame_starts[b] + header_length - taps_before - buf_start   # body offset -taps_before
        z_in = buf[off: off + span]
        z_rot = rot[:span]
        dst = out[b]
        body_in, body_rot = z_in[taps_before: taps_before + n], z_rot[taps_before: taps_before + n]
        for t in range(n):
            dst[t] = body_in[t] * body_rot[t]
        for t in range(taps_after):  # the body's tail after the window
            dst[t] += z_in[taps_before + n + t] * z_rot[taps_before + n + t]
        for t in range(taps_before):  # pre-cursor spill before the window
            dst[n - taps_before + t] += z_in[t] * z_rot[t]
        unphase = np.conj(phases[b])
        now, nxt = headers_now[b], headers_next[b]
        for j in range(n_taps):
            if taps[b, j] == 0:
                continue
            h = taps[b, j] * unphase
            lag = j - taps_before
            # Current header sample src lands at u = src - Ng + lag, inside [-taps_before, lag),
            # folded to t = u + n for u < 0 and t = u for u >= 0.
            for u in range(-taps_before, min(lag, 0)):
                dst[u + n] -= h * now[header_length + u - lag]
            for u in range(0, min(lag, taps_after)):
                dst[u] -= h * now[header_length + u - lag]
            # Next header sample src lands at u = n + src + lag, inside [n + lag, n + taps_after),
            # folded to t = u for u < n and t = u - n for u >= n.
            for u in range(max(n + lag, n - taps_before), n):
                dst[u] -= h * nxt[u - n - lag]
            for u in range(max(n + lag, n), n + taps_after):
                dst[u - n] -= h * nxt[u - n - lag]


def recover_bodies_reference(buf: np.ndarray, buf_start: int, frame_starts: np.ndarray, header_length: int,
                             cfo_cycles_per_sample: float, taps: np.ndarray, taps_before: int,
                             headers_now: np.ndarray, headers_next: np.ndarray) -> np.ndarray:
    """Plain-numpy :func:`recover_bodies`: full convolutions and an explicit fold (returns (B, 3780))."""
    n = BODY_LENGTH
    n_taps = taps.shape[1]
    taps_after = n_taps - taps_before
    out = np.empty((len(frame_starts), n), dtype=np.complex128)
    for b, start in enumerate(frame_starts):
        first = start + header_length - taps_before
        z = derotate_segments_reference(buf, buf_start, np.array([first]), n + n_taps, cfo_cycles_per_sample)[0]
        # Both headers placed on the body-offset axis u = -Ng .. n + Ng, then convolved with the taps.
        axis = np.zeros(2 * header_length + n, dtype=np.complex128)
        axis[:header_length] = headers_now[b]
        axis[header_length + n:] = headers_next[b]
        conv = np.convolve(axis, taps[b])   # conv[i] is delay-aligned to axis[i - (lag + taps_before)]
        # Delay lag = j - taps_before: header sample at u contributes at u + lag.
        u = np.arange(-taps_before, n + taps_after)
        headers_conv = conv[u + header_length + taps_before]
        linear = z - headers_conv
        folded = linear[taps_before: taps_before + n].copy()
        folded[:taps_after] += linear[taps_before + n:]
        folded[n - taps_before:] += linear[:taps_before]
        out[b] = folded
    return out
