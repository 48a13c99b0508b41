"""Per-frame CFO estimators: the SI-carrier method (eq. 5-8) and the PN headers.

**SI carriers (docs/method.md §1).** The 36 SI carriers carry the same symbols in
consecutive frames, so the phase of
``Theta_m = sum_k conj(Y_m(k)) Y_{m-1}(k) exp(j 2 pi k (delta_m - delta_{m-1}) / N)``
(eq. 6, written for the pair (m-1, m)) is ``-2 pi df (n_m - n_{m-1}) T_rx``.
Here ``n_m`` is the integer start of frame m's FFT window and
``delta_m = n_m - tau_m`` its offset from the tracked (fractional) frame
timing: a body cut ``delta`` samples late gains ``exp(j 2 pi k delta / N)``
on carrier k. This is the eq. 6 eta term in the form the tracker measures it:
the paper's ``Ns * eta`` per frame is the drift ``delta_m - delta_{m-1}`` of
our window offset; it also covers whole-sample window re-alignments. Then
(eq. 5) ``df_m = -angle(Theta_m) / (2 pi (n_m - n_{m-1}) T_rx)`` with the
receiver's sample period ``T_rx = T / (1 + eta)`` (eta from the tracked frame
period); with eta = 0 and a constant window this is eq. 7-8. The estimate is
unambiguous over +-1/(2 Ns T) (+-900 Hz for PN420): it measures the residual
after the coarse CFO removal, and the total is coarse + residual.

**Scatter.** The 36 products that make Theta each carry the same phase; their
spread about it measures how noisy this frame's estimate is, whatever the
cause (thermal noise, interference, data folded onto the SI carriers):
``var = sum_k Im(z_k conj(Theta))^2 / |Theta|^4`` (rad^2, first order) with
``z_k`` the terms of Theta. Thermal noise alone gives
``(1 + 1 / (2 gamma)) / (36 gamma)`` at a per-carrier SNR gamma
(:func:`expected_phase_variance`); the receiver flags frames whose scatter
exceeds that by a wide margin.

**Telescoping.** Summed over frames, eq. 5's phase advances should add up
to the SI phase of the last frame minus the first's, so that the noise of
each frame cancels from the range (docs/method.md §2). The angle of a sum of
products of two noisy frames does so to first order only: its second-order
terms (the noise of one frame times the noise of the other; the LO phase
noise's inter-carrier interference times the thermal noise) are independent
from pair to pair, so the summed angles random-walk by about
``1 / (6 sqrt(2) gamma)`` rad a frame, and the f_s of the static window (the
mean CFO over it) carries that walk divided by the window's length, an error
that grows the range linearly over the rest of the walk. Each frame's SI
phase is therefore measured against a *reference* ``R``: the exponential
average (gain :data:`dtmbnav_core.constants.SI_REFERENCE_GAIN`) of the previous frames' carriers,
each with its window offset (the ``delta`` term) and its own measured phase
taken out, so ``R`` holds the channel's pattern over the 36 carriers at
phase zero. Frame m's phase is ``psi_m = angle(R^H Z_m)`` with
``Z_m(k) = Y_m(k) exp(-j 2 pi k delta_m / N)``, and its advance
``psi_m - psi_{m-1}`` (wrapped to +-pi, as eq. 5's angle) takes the place of
``-angle(Theta_m)``: the advances telescope exactly, to the last frame's
phase minus the first's, and only ``R``'s own phase wanders, by the gain
times each frame's phase noise (first order, far below the second-order
walk). With a gain of 1 the reference is the previous frame and this is eq. 6.
Theta's terms still give the scatter below.

**PN headers.** The channel taps of consecutive headers (estimated against
the known, phase-correct PN) rotate by the same residual CFO:
``angle(sum_l conj(h_m[l]) h_{m-1}[l])`` gives an independent estimate from
the header energy (840 symbols at power 2 per PN420 frame against 36 SI
symbols at power 1).

**SI word.** Equalising the SI carriers with the PN-based channel estimate and
correlating with the 24 known words identifies the transmission mode; the sign
is absolute (the PN estimate anchors it), as docs/dtmb.md §3.2 asks.

**I/Q orientation.** A front end that swaps I and Q delivers the conjugate of
the signal: carrier k then holds what was sent on carrier -k (docs/dtmb.md
§3.3: the SI sits on k = -18..17), and after equalisation with the header's
channel estimate (conjugated too) the SI symbols come out in mirrored carrier
order, with the same sign. The SI sum therefore matches a word only in the
right orientation; in the wrong one it matches the mirrored words at best
about half as well (another word, not the complement). The detector scores
both.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import BODY_LENGTH, SYMBOL_RATE_HZ
from receiver.ofdm import si_carrier_numbers




@njit(cache=True, nogil=True)
def si_phase_kernel(y_prev: np.ndarray, y: np.ndarray, k: np.ndarray, delta_prev: float, delta: np.ndarray,
                    reference: np.ndarray, phase_prev: float, gain: float) -> tuple[np.ndarray, np.ndarray, float]:
    """SI phase advance of each frame of a batch against the reference, and the scatter of eq. 6's terms.

    Parameters
    ----------
    y_prev : (36,) complex64
        SI carriers of the frame before the batch.
    y : (B, 36) complex64
        SI carriers of the batch.
    k : (36,) float64
        Signed carrier numbers.
    delta_prev : float
        Window offset of the frame before the batch, samples.
    delta : (B,) float64
        Window offsets ``n_m - tau_m`` of the batch's frames.
    reference : (36,) complex128
        The SI reference before the batch (module docstring, "Telescoping"; zeros at the start of a lock);
        updated in place to the reference after the batch.
    phase_prev : float
        Phase of the frame before the batch against the reference, rad.
    gain : float
        Weight of each new frame in the reference (1: the previous frame, eq. 6).

    Returns
    -------
    advance : (B,) float64
        Phase advance of each frame over the one before it, rad, in (-pi, pi].
    phase_var : (B,) float64
        Variance of ``angle(Theta)`` (eq. 6, each frame with the one before
        it) measured from the spread of its terms, rad^2 (module
        docstring); inf where theta is 0.
    phase : float
        Phase of the batch's last frame against the updated reference, rad.
    """
    count = y.shape[0]
    n_si = y.shape[1]
    advance = np.empty(count, dtype=np.float64)
    phase_var = np.empty(count, dtype=np.float64)
    terms = np.empty(n_si, dtype=np.complex128)
    # Z (module docstring) of the frame before and of the current one: conj(Z_m) Z_{m-1} are eq. 6's terms.
    z_old = np.empty(n_si, dtype=np.complex128)
    z = np.empty(n_si, dtype=np.complex128)
    scale = 2.0 * np.pi / 3780.0
    for s in range(n_si):
        z_old[s] = np.complex128(y_prev[s]) * np.exp(-1j * scale * delta_prev * k[s])
    phase = phase_prev
    for b in range(count):
        acc = 0j
        projection = 0j
        for s in range(n_si):
            z[s] = np.complex128(y[b, s]) * np.exp(-1j * scale * delta[b] * k[s])
            terms[s] = np.conj(z[s]) * z_old[s]
            acc += terms[s]
            projection += np.conj(reference[s]) * z[s]
        size2 = acc.real * acc.real + acc.imag * acc.imag
        quad = 0.0
        for s in range(n_si):
            q = terms[s].imag * acc.real - terms[s].real * acc.imag
            quad += q * q
        phase_var[b] = quad / (size2 * size2) if size2 > 0 else np.inf
        advance[b] = np.angle(projection * np.exp(-1j * phase))
        phase = np.angle(projection)
        turn = gain * np.exp(-1j * phase)
        for s in range(n_si):
            reference[s] = (1.0 - gain) * reference[s] + turn * z[s]
            z_old[s] = z[s]
    return advance, phase_var, phase


def si_phase_reference(y_prev: np.ndarray, y: np.ndarray, k: np.ndarray, delta_prev: float, delta: np.ndarray,
                       reference: np.ndarray, phase_prev: float, gain: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Plain-numpy :func:`si_phase_kernel` (the reference updated in place alike)."""
    d = np.concatenate([[delta_prev], delta])
    aligned = np.vstack([y_prev[None, :], y]).astype(np.complex128) * np.exp(
        -1j * 2 * np.pi / BODY_LENGTH * d[:, None] * k[None, :])
    terms = np.conj(aligned[1:]) * aligned[:-1]
    theta = np.sum(terms, axis=1)
    size2 = np.abs(theta) ** 2
    quad = np.sum(np.imag(terms * np.conj(theta)[:, None]) ** 2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        phase_var = np.where(size2 > 0, quad / size2 ** 2, np.inf)
    phases = np.empty(len(y) + 1)
    phases[0] = phase_prev
    for b, z in enumerate(aligned[1:]):     # each frame's phase needs the reference the frames before it made
        phases[b + 1] = np.angle(np.vdot(reference, z))
        reference[:] = (1.0 - gain) * reference + gain * np.exp(-1j * phases[b + 1]) * z
    return np.angle(np.exp(1j * np.diff(phases))), phase_var, float(phases[-1])


def expected_phase_variance(si_snr_db: np.ndarray, n_carriers: int = gb20600.SI_LENGTH) -> np.ndarray:
    """Variance of ``angle(Theta)`` that thermal noise alone gives at a per-carrier SNR, rad^2.

    Each term ``(a + n1) conj(b + n2)`` (|a| = |b|, noise power N per
    carrier) has quadrature noise ``|a|^2 N + N^2 / 2``; over ``n_carriers``
    terms the phase of the sum varies by ``(1 + 1 / (2 gamma)) / (n gamma)``
    with ``gamma = |a|^2 / N`` (``si_snr_db`` in dB, the SNR the receiver
    writes per frame).
    """
    gamma = 10.0 ** (np.asarray(si_snr_db, dtype=np.float64) / 10.0)
    return (1.0 + 0.5 / gamma) / (n_carriers * gamma)


@njit(cache=True, nogil=True)
def pn_theta_kernel(taps_prev: np.ndarray, taps: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``sum_l conj(h_m[l]) h_{m-1}[l + s_m]`` for each frame of a batch.

    ``taps_prev`` are the taps of the frame before the batch. A path at a
    fixed place in the frame sits ``s_m = (n_m - n_{m-1}) - round(period)``
    taps later in frame m-1's estimate than in frame m's when the window
    start stepped by one sample more (or less) than the frame period, so
    the taps are aligned by ``s_m`` before they are compared.
    """
    count, n_taps = taps.shape
    theta = np.empty(count, dtype=np.complex128)
    for b in range(count):
        s = shift[b]
        acc = 0j
        for lag in range(max(0, -s), min(n_taps, n_taps - s)):
            old = taps_prev[lag + s] if b == 0 else taps[b - 1, lag + s]
            acc += np.conj(np.complex128(taps[b, lag])) * old
        theta[b] = acc
    return theta


def pn_theta_reference(taps_prev: np.ndarray, taps: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Plain-numpy :func:`pn_theta_kernel`."""
    both = np.vstack([taps_prev[None, :], taps]).astype(np.complex128)
    n_taps = both.shape[1]
    theta = np.empty(len(taps), dtype=np.complex128)
    for s in np.unique(shift):
        rows = np.flatnonzero(shift == s)
        lo, hi = max(0, -s), min(n_taps, n_taps - s)
        theta[rows] = np.sum(np.conj(both[rows + 1, lo:hi]) * both[rows, lo + s: hi + s], axis=1)
    return theta


def cfo_from_advance(advance_rad: np.ndarray, window_step: np.ndarray, eta: np.ndarray | float,
                     coarse_hz: float) -> np.ndarray:
    """Total CFO (eq. 5): coarse + ``advance / (2 pi window_step T_rx)``, Hz.

    Parameters
    ----------
    advance_rad : ndarray
        Carrier phase advance of each frame over the one before it, rad.
    window_step : ndarray
        ``n_m - n_{m-1}``, samples of the receiver clock.
    eta : ndarray or float
        Normalised sampling offset (receiver samples per nominal sample - 1).
    coarse_hz : float
        CFO removed before the FFT.
    """
    sample_period_s = 1.0 / (SYMBOL_RATE_HZ * (1.0 + np.asarray(eta)))
    return coarse_hz + np.asarray(advance_rad) / (2 * np.pi * np.asarray(window_step) * sample_period_s)


def cfo_from_theta(theta: np.ndarray, window_step: np.ndarray, eta: np.ndarray | float, coarse_hz: float) -> np.ndarray:
    """Total CFO (eq. 5) from Theta, the sum of products of two frames: :func:`cfo_from_advance` of
    ``-angle(Theta)``, Hz (arguments as there)."""
    return cfo_from_advance(-np.angle(theta), window_step, eta, coarse_hz)


class SiWordDetector:
    """Accumulates equalised SI carriers and names the SI word sent.

    Parameters
    ----------
    taps_before : int
        Delay of the first tap column, samples (the channel estimator's span).
    n_taps : int
        Tap columns.
    polarity : {+1, -1}
        SI chip polarity convention (gb20600.si_symbols).
    """

    def __init__(self, taps_before: int, n_taps: int, polarity: int = 1) -> None:
        lags = np.arange(-taps_before, n_taps - taps_before)
        k = si_carrier_numbers()
        # H(k) = sum_l h[l] exp(-j 2 pi k l / N) at the SI carriers.
        self._dft = np.exp(-2j * np.pi * np.outer(lags, k) / BODY_LENGTH)
        self._words = np.array([gb20600.si_symbols(i, polarity=polarity) for i in sorted(gb20600.SI_WORDS)])
        # The words as a conjugated capture shows them: SI position s holds the symbol sent on carrier -k_s;
        # carrier +18 is a data carrier, so the position of k = -18 holds no SI (0).
        slot = {int(kk): s for s, kk in enumerate(k)}
        mirror = np.array([slot.get(-int(kk), -1) for kk in k])
        self._mirrored_words = np.where(mirror >= 0, self._words[:, np.maximum(mirror, 0)], 0)
        self._indices = np.array(sorted(gb20600.SI_WORDS))
        self._sum = np.zeros(gb20600.SI_LENGTH, dtype=np.complex128)
        self.frames = 0

    def add(self, si: np.ndarray, taps: np.ndarray) -> None:
        """Add frames: SI carriers ``(B, 36)`` and their channel taps ``(B, L)``."""
        h = taps.astype(np.complex128) @ self._dft
        self._sum += np.sum(np.conj(h) * si, axis=0)
        self.frames += len(si)

    def scores(self, conjugated: bool = False) -> np.ndarray:
        """Normalised correlation of the accumulated SI with each word (words 1..24), -1..1.

        ``conjugated``: with the words as a capture with swapped I and Q shows them (module docstring).
        """
        words = self._mirrored_words if conjugated else self._words
        norm = np.linalg.norm(self._sum) * np.linalg.norm(self._words[0])
        return np.real(words.conj() @ self._sum) / max(norm, 1e-30)

    def conjugated(self) -> bool:
        """Whether the SI matches a word better with I and Q swapped than as received."""
        return bool(self.frames) and float(np.max(self.scores(True))) > float(np.max(self.scores()))

    def best(self) -> int:
        """SI word with the highest score (0 when no frame was added)."""
        return int(self._indices[np.argmax(self.scores())]) if self.frames else 0
