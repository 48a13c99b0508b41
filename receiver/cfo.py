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


@njit(cache=True)
def si_theta_kernel(y_prev: np.ndarray, y: np.ndarray, k: np.ndarray, delta_prev: float,
                    delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Theta (eq. 6) of each frame of a batch with the one before it, and the scatter of its phase.

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

    Returns
    -------
    theta : (B,) complex128
    phase_var : (B,) float64
        Variance of ``angle(theta)`` measured from the spread of its terms,
        rad^2 (module docstring); inf where theta is 0.
    """
    count = y.shape[0]
    n_si = y.shape[1]
    theta = np.empty(count, dtype=np.complex128)
    phase_var = np.empty(count, dtype=np.float64)
    terms = np.empty(n_si, dtype=np.complex128)
    scale = 2.0 * np.pi / 3780.0
    for b in range(count):
        d_old = delta_prev if b == 0 else delta[b - 1]
        step = scale * (delta[b] - d_old)
        acc = 0j
        for s in range(n_si):
            old = y_prev[s] if b == 0 else y[b - 1, s]
            terms[s] = np.conj(np.complex128(y[b, s])) * old * np.exp(1j * step * k[s])
            acc += terms[s]
        theta[b] = acc
        size2 = acc.real * acc.real + acc.imag * acc.imag
        quad = 0.0
        for s in range(n_si):
            q = terms[s].imag * acc.real - terms[s].real * acc.imag
            quad += q * q
        phase_var[b] = quad / (size2 * size2) if size2 > 0 else np.inf
    return theta, phase_var


def si_theta_reference(y_prev: np.ndarray, y: np.ndarray, k: np.ndarray, delta_prev: float,
                       delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plain-numpy :func:`si_theta_kernel`."""
    both = np.vstack([y_prev[None, :], y]).astype(np.complex128)
    d = np.concatenate([[delta_prev], delta])
    phase = np.exp(1j * 2 * np.pi / BODY_LENGTH * np.diff(d)[:, None] * k[None, :])
    terms = np.conj(both[1:]) * both[:-1] * phase
    theta = np.sum(terms, axis=1)
    size2 = np.abs(theta) ** 2
    quad = np.sum(np.imag(terms * np.conj(theta)[:, None]) ** 2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        phase_var = np.where(size2 > 0, quad / size2 ** 2, np.inf)
    return theta, phase_var


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


@njit(cache=True)
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


def cfo_from_theta(theta: np.ndarray, window_step: np.ndarray, eta: np.ndarray | float, coarse_hz: float) -> np.ndarray:
    """Total CFO (eq. 5): coarse + ``-angle(Theta) / (2 pi window_step T_rx)``, Hz.

    Parameters
    ----------
    theta : ndarray, complex
        Theta of each frame pair.
    window_step : ndarray
        ``n_m - n_{m-1}``, samples of the receiver clock.
    eta : ndarray or float
        Normalised sampling offset (receiver samples per nominal sample - 1).
    coarse_hz : float
        CFO removed before the FFT.
    """
    sample_period_s = 1.0 / (SYMBOL_RATE_HZ * (1.0 + np.asarray(eta)))
    return coarse_hz - np.angle(theta) / (2 * np.pi * np.asarray(window_step) * sample_period_s)


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
