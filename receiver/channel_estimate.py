"""PN-header channel estimation (``docs/dtmb.md`` §5).

Per frame, on the 7.56 Msps stream derotated by the coarse CFO, the known
header is correlated with the received header. PN420/PN945: a core-period
window just after the preamble sees the m-sequence circularly convolved with
the channel (the preamble is its cyclic prefix), so one P-point circular
correlation gives the taps; PN595 (no cyclic part): least squares over the
header rows free of the previous body. Taps at delays
``-taps_before .. taps_after - 1`` (relative to the frame's window start) are
kept where their power exceeds ``threshold`` times the noise floor measured on
the other lags. The taps also give the SNR, the share of the window power they
capture (``peak_metric``) and the power centroid (sub-sample timing for the
tracker).

For the path tracker's guard-interval span (``docs/paths.md``, "The CIR") the
same correlation is also taken on core-period windows shifted by whole
samples ("views", :meth:`ChannelEstimator.view_taps`): a view shifted by s
sees the paths at lags ``s - postamble .. s + preamble`` as cleanly as the
frame's own window sees those around its start.

The hot loops are numba kernels over a whole batch of frames; the reference
path (FFT correlation) is used by the tests and the benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import PnMode
from receiver.derotate import derotate_segments

#: Default delay span of the estimate before and after the frame's window start, samples.
#: Symmetric because the frame timing follows the taps' power centroid: in a
#: single-frequency network the first tower sits that far before the centroid
#: (a second tower 44 chips later and 4 dB weaker puts it 12-17 samples
#: before as the two fade); a span that loses the first tower takes its
#: share out of the header metric, which then collapses to the second
#: tower's share and loses the lock (docs/decisions.md, D8).
TAPS_BEFORE = 48
TAPS_AFTER = 48
#: Default tap power over the noise floor needed to keep a tap.
TAP_THRESHOLD = 10.0


def view_first_lag(mode: PnMode) -> int:
    """Lag of a view's first column relative to its shift (:meth:`ChannelEstimator.view_taps`; PN420/PN945).

    A view reads all P lags of its circular correlation: the header's cyclic
    extension around its shift (``-postamble .. preamble - 1``), where a path
    has all of its header chips in the window, and the rest of the period
    split evenly before and after it.
    """
    m = mode.value
    return -(m.postamble + (m.period - m.postamble - m.preamble) // 2)


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

    @classmethod
    def empty(cls, count: int, n_taps: int) -> ChannelEstimates:
        """Uninitialised estimates of ``count`` frames of ``n_taps`` taps (for a kernel to fill)."""
        return cls(taps=np.empty((count, n_taps), np.complex64), raw_taps=np.empty((count, n_taps), np.complex64),
                   snr_db=np.empty(count, np.float32), noise_power=np.empty(count),
                   peak_metric=np.empty(count, np.float32), centroid=np.empty(count))


class ChannelEstimator:
    """Batched PN-header channel estimation for one header mode.

    PN420/PN945: circular correlation of a core-period window with the
    phase-correct m-sequence (a fast Walsh-Hadamard transform,
    :func:`m_sequence_correlation_kernel`; the reference path uses FFTs),
    corrected for the m-sequence's -1/P sidelobes (exact deconvolution); the
    lags outside the tap span (and its guard) measure the noise floor. PN595: least squares over
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
    noise_guard : int
        PN420/PN945: lags on each side of the tap span left out of the noise
        floor (a band-limited capture's paths ring beyond the span).
    """

    def __init__(self, mode: PnMode, batch: int, taps_before: int = TAPS_BEFORE, taps_after: int = TAPS_AFTER,
                 threshold: float = TAP_THRESHOLD, noise_guard: int = 0) -> None:
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
            guard = np.arange(-taps_before - noise_guard, taps_after + noise_guard) % m.period
            self.noise_bins = np.setdiff1d(np.arange(m.period), guard)
            self._sample_slot, self._shift_slot = hadamard_slots(gb20600.pn_core(mode))
            # Every header phase's core window is alpha * (1 - 2 c[(n + preamble + phase) mod P]):
            # the correlation is conj(alpha) / energy times the +-1 m-sequence correlation.
            alpha = (1.0 + 1.0j) * m.header_amplitude
            self._hadamard_scale = np.complex64(np.conj(alpha) / (m.period * abs(alpha) ** 2))
            self._windows = np.zeros((batch, m.period), dtype=np.complex64)
            self._corr = np.empty((batch, m.period), dtype=np.complex64)
            self._hadamard_work = np.empty(m.period + 1, dtype=np.complex64)
            # Views (view_taps): their own window and correlation buffers, the frame's stay for span_taps.
            self._view_windows = np.zeros((batch, m.period), dtype=np.complex64)
            self._view_corr = np.empty((batch, m.period), dtype=np.complex64)
            self._view_power = np.empty(batch)
            first = view_first_lag(mode)
            self._view_bins = (first + np.arange(m.period)) % m.period
            self._view_span = (-m.postamble - first, m.preamble - first)
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
        self._span_cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

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
        out = ChannelEstimates.empty(count, self.n_taps)
        if self.cyclic:
            estimate_cyclic_kernel(windows, self.header_shifts(phases), self.cyclic_tables, self.summary_settings,
                                   out.raw_taps, out.taps, out.snr_db, out.noise_power, out.peak_metric, out.centroid)
            return out
        power_in = np.mean(windows.real ** 2 + windows.imag ** 2, axis=1)
        out.raw_taps[:] = windows @ self._pinv_t
        summarise_taps_kernel(out.raw_taps, self._ls_noise_tap(out.raw_taps, power_in), power_in,
                              *self.summary_settings, out.taps, out.snr_db, out.noise_power, out.peak_metric,
                              out.centroid)
        return out

    def header_shifts(self, phases: np.ndarray) -> np.ndarray:
        """Cyclic shift of each header phase's m-sequence against the window (:func:`m_sequence_correlation_kernel`)."""
        m = self.mode.value
        return (np.asarray(phases, dtype=np.int64) + m.preamble) % m.period

    @property
    def cyclic_tables(self) -> tuple:
        """The tables and buffers :func:`estimate_cyclic_kernel` uses (PN420/PN945): Hadamard slots and scale,
        its scratch row, the correlation rows (read again by :meth:`span_taps`), the tap and noise lags."""
        return (self._sample_slot, self._shift_slot, self._hadamard_scale, self._hadamard_work, self._corr,
                self.tap_bins, self.noise_bins)

    @property
    def summary_settings(self) -> tuple[float, float, int, int]:
        """:func:`summarise_taps_kernel`'s settings: tap threshold, header power ratio, reference length, taps
        before the window start."""
        return self.threshold, self.header_power, self.reference_length, self.taps_before

    def span_taps(self, count: int, taps_before: int, taps_after: int) -> tuple[np.ndarray, np.ndarray]:
        """Raw taps over another delay span, from the correlations of the last :meth:`estimate` (PN420/PN945).

        The path tracker (:mod:`receiver.paths`) reads the channel over a
        wider span than body recovery needs (up to the header's whole cyclic
        extension, where every path's estimate is still free of the previous
        body and of the header tails); the same correlations give it, with the
        m-sequence sidelobes removed over that span (:func:`deconvolve_kernel`).

        Returns
        -------
        raw : ndarray, complex64, (count, taps_before + taps_after)
            Column ``j`` is delay ``j - taps_before`` samples.
        noise_tap : ndarray, (count,)
            Mean tap power on the lags outside the span (the tap noise floor).
        """
        tap_bins, noise_bins = self.span_bins(taps_before, taps_after)
        raw = np.empty((count, len(tap_bins)), np.complex64)
        noise_tap = np.empty(count)
        deconvolve_kernel(self._corr[:count], tap_bins, noise_bins, raw, noise_tap)
        return raw, noise_tap

    def view_taps(self, count: int, buf: np.ndarray, buf_start: int, starts: np.ndarray, shifts: tuple[int, ...],
                  phases: np.ndarray, cfo_cycles_per_sample: float, rot: np.ndarray, out: np.ndarray) -> None:
        """Raw taps of ``count`` frames over views shifted by ``shifts`` samples (PN420/PN945; into ``out``).

        View s correlates the core period that starts s samples after the
        frame's own window (:attr:`window_offset`) with the frame's
        m-sequence phase, so a path at lag l lands on correlation lag
        ``l - s`` (mod P). All P lags are read, as lags
        ``s + view_first_lag .. s + view_first_lag + P - 1``; the m-sequence
        sidelobes are removed as in :meth:`span_taps`, with the header's
        cyclic extension around s as the span (:func:`view_readout_kernel`).
        Shift 0 reuses the correlations of the last :meth:`estimate`.

        Parameters
        ----------
        buf, buf_start
            Stream samples and the index of ``buf[0]``; they must hold every view's window.
        starts : (count,) int64
            Window start of each frame, stream index.
        shifts : tuple of int
            The views' shifts, samples.
        phases : (count,) int64
            Header phase of each frame.
        cfo_cycles_per_sample, rot
            Coarse CFO and its rotation table (:func:`receiver.derotate.derotate_segments`).
        out : (>= count, len(shifts), P) complex64
            Column ``j`` of view ``v`` is lag ``shifts[v] + view_first_lag(mode) + j``.
        """
        m = self.mode.value
        if not self.cyclic:
            raise ValueError(f"{self.mode.name}: views need a cyclic header")
        shift_slots = (np.asarray(phases, dtype=np.int64) + m.preamble) % m.period
        for v, shift in enumerate(shifts):
            corr = self._corr
            if shift != 0:
                corr = self._view_corr
                derotate_segments(buf, buf_start, starts + self.window_offset + shift, m.period, cfo_cycles_per_sample,
                                  rot, self._view_windows)
                m_sequence_correlation_kernel(self._view_windows[:count], shift_slots, self._sample_slot,
                                              self._shift_slot, self._hadamard_scale, self._hadamard_work, corr,
                                              self._view_power)
            view_readout_kernel(corr[:count], self._view_bins, *self._view_span, out[:count, v])

    def span_bins(self, taps_before: int, taps_after: int) -> tuple[np.ndarray, np.ndarray]:
        """Correlation lags of a span and the noise lags outside it (:meth:`span_taps`; made once per span)."""
        key = (taps_before, taps_after)
        if key not in self._span_cache:
            self._span_cache[key] = self._make_span_bins(taps_before, taps_after)
        return self._span_cache[key]

    def _make_span_bins(self, taps_before: int, taps_after: int) -> tuple[np.ndarray, np.ndarray]:
        m = self.mode.value
        if not self.cyclic or taps_after > m.preamble or taps_before > m.postamble or taps_before + taps_after < 1:
            raise ValueError(f"{self.mode.name}: a path span of -{taps_before}..{taps_after} samples needs a cyclic "
                             f"header (span within -{m.postamble}..{m.preamble})")
        tap_bins = np.arange(-taps_before, taps_after) % m.period
        return tap_bins, np.setdiff1d(np.arange(m.period), tap_bins)

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


@njit(cache=True, fastmath=True, nogil=True)
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


@njit(cache=True, nogil=True)
def estimate_cyclic_kernel(windows: np.ndarray, shifts: np.ndarray, tables: tuple, settings: tuple,
                           raw: np.ndarray, taps: np.ndarray, snr_db: np.ndarray, noise_power: np.ndarray,
                           peak: np.ndarray, centroid: np.ndarray) -> None:
    """:meth:`ChannelEstimator.estimate` of ``len(shifts)`` PN420/PN945 windows in one call (into the given arrays).

    The m-sequence correlation, the deconvolution over the estimator's span
    and the summary, as :attr:`ChannelEstimator.cyclic_tables` and
    :attr:`ChannelEstimator.summary_settings` set them up; the correlations
    stay in the tables' rows for :meth:`ChannelEstimator.span_taps`.
    """
    sample_slot, shift_slot, scale, work, corr, tap_bins, noise_bins = tables
    threshold, header_power, reference_length, taps_before = settings
    count = shifts.shape[0]
    power_in = np.empty(count)
    noise_tap = np.empty(count)
    m_sequence_correlation_kernel(windows, shifts, sample_slot, shift_slot, scale, work, corr, power_in)
    deconvolve_kernel(corr[:count], tap_bins, noise_bins, raw, noise_tap)
    summarise_taps_kernel(raw, noise_tap, power_in, threshold, header_power, reference_length, taps_before, taps,
                          snr_db, noise_power, peak, centroid)


@njit(cache=True, fastmath=True, nogil=True)
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


@njit(cache=True, fastmath=True, nogil=True)
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


@njit(cache=True, fastmath=True, nogil=True)
def view_readout_kernel(corr: np.ndarray, bins: np.ndarray, span_from: int, span_to: int, out: np.ndarray) -> None:
    """Taps of a batch over every correlation lag, in the order ``bins`` (into ``out``).

    :func:`deconvolve_kernel`'s sidelobe removal with the sum of the channel
    taken over ``bins[span_from:span_to]`` (a view's cyclic extension), applied to all lags.
    """
    p = corr.shape[1]
    n_span = span_to - span_from
    scale = p / (p + 1.0)
    for b in range(corr.shape[0]):
        total = 0j
        for j in range(span_from, span_to):
            total += corr[b, bins[j]]
        offset = total / (1.0 - (n_span - 1.0) / p) / (p + 1.0)
        for j in range(bins.shape[0]):
            out[b, j] = corr[b, bins[j]] * scale + offset


@njit(cache=True, fastmath=True, nogil=True)
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
