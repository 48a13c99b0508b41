"""Blind front-end correction of the raw input: DC offset / LO leakage and I/Q imbalance.

A zero-IF SDR adds a constant at the capture's DC (LO leakage, ADC offset)
and records its Q rail with a gain and phase error against the I rail. The
corrector runs on the raw input samples (complex64, any rate), before every
other stage of the receiver, and removes both blindly: the DTMB signal and
the thermal noise are circular (proper) complex signals, so the true
baseband ``z = I + jQ`` has zero mean and zero pseudo-covariance,
``E[z^2] = 0``, i.e. ``E[I^2] = E[Q^2]`` and ``E[I Q] = 0``; whatever breaks
that in the input is the front end's.

**Impairment model** (the simulator's front end uses the same convention,
its ``iq_gain_db`` and ``iq_phase_deg``): for the ideal ``z = I + jQ`` the
front end records

    (M1)  ``y = d + I + j g (Q cos(phi) - I sin(phi))``,
          ``g = 10 ** (iq_gain_db / 20)``, ``phi = radians(iq_phase_deg)``,

with ``d`` the DC offset; equivalently ``y - d = mu z + nu conj(z)``,
``mu = (1 + g exp(-j phi)) / 2``, ``nu = (1 - g exp(j phi)) / 2``, and the
front end's image rejection is ``IRR = |mu|^2 / |nu|^2``.

**Estimator** (moment-based, from the circularity of ``z``). With the
DC-free rails ``y_I = Re(y - d)``, ``y_Q = Im(y - d)``:

    (E1)  ``d = E[y]``
    (E2)  ``P_I = E[y_I^2] = s^2``,  ``P_Q = E[y_Q^2] = g^2 s^2``,
          ``C = E[y_I y_Q] = -g s^2 sin(phi)``   (``s^2 = E[I^2] = E[Q^2]``)
    (E3)  ``g = sqrt(P_Q / P_I)``,  ``sin(phi) = -C / sqrt(P_I P_Q)``
    (E4)  ``I' = y_I``,  ``Q' = (y_Q / g + y_I sin(phi)) / cos(phi)``

**Headers left out** (E6). The DTMB signal is not quite circular: its PN
headers are ``+-(1 + j)`` chips, so during a header ``y^2`` turns at twice
the carrier offset with a header's whole power behind it, and wherever that
turn stays slow over the estimate's time (an offset near zero, or near a
multiple of half the frame rate) the headers read as an imbalance of
degrees. Each block is therefore cut into segments of about a third of a
PN420 header (:data:`SEGMENT_S`); a segment's normalised pseudo-covariance
``rho = (sum (y_I^2 - y_Q^2) + 2 j sum y_I y_Q) / sum |y|^2`` (moments about
the block's mean) scatters about the front end's own by ``2 / L`` in
squared magnitude for ``L`` circular samples, and a segment further from the
running estimate's ``rho`` (the stream's first block: from its segments'
median) than :data:`TRIM_LEVEL` times that is left out of ``P_I``, ``P_Q``
and ``C``: a header's segments stand out by about the header's power share,
a body segment almost never (``exp(-TRIM_LEVEL)``). The DC (E1) and the
signal power take every sample.

(E4) inverts (M1) exactly, and its output has ``E[I'^2] = E[Q'^2]`` and
``E[I' Q'] = 0`` for the estimated moments: it is the closed-form,
frequency-independent case of the circularity-based compensation of
L. Anttila, M. Valkama and M. Renfors, "Circularity-based I/Q imbalance
compensation in wideband direct-conversion receivers", IEEE Trans. Vehicular
Technology 57(4), 2008 (the compensator that makes the output's
pseudo-covariance vanish), written as the moment / Gram-Schmidt estimator of
F. E. Churchill, G. W. Ogar and B. J. Thompson, "The correction of I and Q
errors in a coherent processor", IEEE Trans. Aerospace and Electronic
Systems AES-17(1), 1981 (also N. A. Moseley and C. H. Slump, "A
low-complexity feed-forward I/Q imbalance compensation algorithm", ProRISC
2006). The I rail is left at its own scale, not normalised: (E4) then gives
back the ideal ``z`` of (M1) itself, and the input's full-scale units (and
its clipping level on the I rail) keep their meaning downstream; the Q rail
is brought to the I rail's power. Only a frequency-independent imbalance is
modelled (one real gain and one phase for the whole band), not a mismatch of
the I and Q filters' responses.

**Streaming, chunk invariance.** The stream is cut into fixed blocks of
``BLOCK`` absolute input samples. Each block's sums (``sum y``,
``sum y_I^2``, ``sum y_Q^2``, ``sum y_I y_Q``) give its mean and its
second moments about its own mean; these are folded into exponentially
weighted running sums once per block,

    (E5)  ``W <- lam W + n``,  ``M <- lam M + n m_block``,  ``lam = exp(-n / (FORGET_TIME_S fs))``

(``n`` the block's samples, ``m_block`` its mean and centred moments), and
(E1)-(E3) are read from ``M / W``. Block ``k`` is corrected with the
estimate of the blocks before it (the stream's first block, with none
before it, with its own), so a stream cut short corrects every sample it
holds as the whole stream did, after its first block. The stage still holds
back up to one block (a block's statistics are its NaN check and its
history row): :meth:`FrontEndCorrector.process` returns the corrected
samples of every block completed so far (possibly none),
:meth:`FrontEndCorrector.flush` the last, partial block. Every output sample
is then a function of the input samples up to the end of its block and
nothing else, so any chunking of the stream gives bit-identical output. The second moments are taken about each block's own
mean rather than about the running DC, so a DC that moves (an AGC step that
scales the leakage) does not leak into the I/Q estimate; the
sub-``fs / BLOCK`` content that this leaves out is a vanishing part of a
channel that fills the band.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

#: Samples per statistics block (absolute input indices): the stage's latency, and the step at which the
#: estimate moves. Big enough that the per-block work outside the sample loops is negligible and the block's
#: own estimate (which corrects the first block) is already far better than the warning thresholds; small
#: enough that the block and its output stay in the core's L2 cache between the statistics pass and the
#: correction pass, and that the latency stays in the tens of milliseconds at 1 Msps.
BLOCK = 1 << 16
#: Time constant of the running estimate, s (E5). A time, not a number of blocks: the impairments drift with
#: temperature and gain settings in seconds whatever the capture's rate. Short enough to follow an AGC step
#: within a second; long enough that even at 1 Msps the estimate holds a few hundred thousand samples,
#: which puts its noise (of the DC and of the image left after correction) far below the thermal noise.
FORGET_TIME_S = 0.25
#: Duration of a segment of (E6), s: a third of a PN420 header (55.6 us), so that most of a header's
#: segments hold only header.
SEGMENT_S = 18e-6
#: Fewest samples in a segment of (E6) (its noise grows as the segment shortens).
SEGMENT_MIN = 32
#: A segment is left out of the I/Q moments (E6) when the squared distance of its normalised
#: pseudo-covariance from the running estimate's exceeds this many times its noise variance ``2 / L``: for a
#: circular segment of ``L`` Gaussian samples that distance is exponential, so ``exp(-TRIM_LEVEL)`` (about
#: 1e-4) of the signal's own segments are lost.
TRIM_LEVEL = 9.0
#: Largest gain error the corrector applies a correction for, dB: beyond it (and beyond
#: ``MAX_CORRECTABLE_PHASE_DEG``) the input is not a circular signal through an imbalanced front end (a dead
#: rail, a real-valued or otherwise non-circular capture) and "correcting" it would only distort it; such a
#: block's I/Q is passed as it is (the DC is still removed) and the estimate is reported.
MAX_CORRECTABLE_GAIN_DB = 6.0
#: The I/Q correction runs only where the estimated imbalance leaves an image above this rejection, dB:
#: what (E6) leaves of the headers' pseudo-covariance must not be "corrected" into an image. An imbalance
#: with a rejection above this (about 0.5 dB and 3 deg) changes the CFO by a tenth of a hertz or less, which
#: the f_s calibration takes in while it is constant.
CORRECT_BELOW_IRR_DB = 30.0
#: Largest phase error the corrector applies a correction for, degrees (``MAX_CORRECTABLE_GAIN_DB``).
MAX_CORRECTABLE_PHASE_DEG = 30.0
#: DC offset relative to the signal RMS above which :func:`frontend_warnings` warns, dB. Each of the 3780
#: carriers holds about -36 dB of the signal power, and the 36 SI carriers the CFO is measured on lie within
#: +-36 kHz of DC: a DC tone at this level is comparable with one of them.
WARN_DC_DBC = -40.0
#: Gain error above which :func:`frontend_warnings` warns, dB: on its own it leaves an image about 30 dB
#: below the signal, and the image of a channel tuned on DC falls on the channel's mirror (SI carrier -k on
#: +k): an interference floor near the per-carrier SNR above which the receiver already takes residues other
#: than thermal noise to set the SI phase scatter (``receiver.pipeline.SCATTER_SNR_CEILING_DB``).
WARN_GAIN_DB = 0.5
#: Phase error above which :func:`frontend_warnings` warns, degrees: an image about 32 dB below the signal
#: on its own (``WARN_GAIN_DB``).
WARN_PHASE_DEG = 3.0
#: Columns of a history row (:class:`FrontEndEstimate`).
HISTORY_COLUMNS = ("dc_i", "dc_q", "iq_gain_db", "iq_phase_deg", "signal_rms")

# Reassociation lets LLVM vectorise the float64 reductions, contraction lets it fuse multiply-adds; both fix
# the order of operations at compile time (lanes by loop index, not by thread or address), so a rerun on the
# same machine and any chunking give bit-identical sums. No nnan/ninf: NaN must survive to be caught.
_FASTMATH = {"reassoc", "contract"}


#: Running sums of the estimate (E5), in this order: the weight of the DC and of the signal power, W times
#: the mean of I and of Q, W times the centred signal power, then the weight of the moments the headers'
#: segments were left out of (E6) and W times ``P_I``, ``P_Q`` and ``C``.
ACC_SIZE = 8


@njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _estimate_kernel(acc: np.ndarray, row: np.ndarray) -> None:
    """(E1)-(E3) from the running sums ``acc`` (``ACC_SIZE``) into ``row`` (``HISTORY_COLUMNS``)."""
    w = acc[0]
    row[0] = acc[1] / w
    row[1] = acc[2] / w
    row[4] = np.sqrt(max(acc[3] / w, 0.0))
    w2 = acc[4]
    p_i = acc[5] / w2 if w2 > 0.0 else 0.0
    p_q = acc[6] / w2 if w2 > 0.0 else 0.0
    c = acc[7] / w2 if w2 > 0.0 else 0.0
    if p_i > 0.0 and p_q > 0.0:
        row[2] = 10.0 * np.log10(p_q / p_i)
        s = min(max(-c / np.sqrt(p_i * p_q), -1.0), 1.0)   # rounding can push it past Cauchy-Schwarz
        row[3] = np.degrees(np.arcsin(s))
    else:   # a rail without power: nothing to estimate
        row[2] = np.nan
        row[3] = np.nan


@njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def correct_blocks(x: np.ndarray, out: np.ndarray, block: int, segment: int, acc: np.ndarray,
                   decay_per_sample: float, remove_dc: bool, correct_iq: bool, rows: np.ndarray) -> int:
    """Fold each block's statistics into the running estimate and correct the block with it.

    The statistics pass is also the input check: a NaN or inf sample makes
    the block's sum of squares non-finite (a finite float32 squared in
    float64 cannot overflow), and the kernel stops before folding that
    block.

    Parameters
    ----------
    x : complex64 ndarray
        Consecutive blocks of ``block`` input samples (full scale +-1); the
        last may be shorter (the end of the stream).
    out : complex64 ndarray
        Corrected samples, same length as ``x``.
    block : int
        Samples per block.
    segment : int
        Samples per segment of (E6) (:func:`segment_samples`).
    acc : float64 ndarray, shape (ACC_SIZE,)
        Running sums (E5), updated in place (``ACC_SIZE``).
    decay_per_sample : float
        ``1 / (FORGET_TIME_S * fs)``, 1/samples: a block of ``n`` samples
        multiplies the sums by ``exp(-n * decay_per_sample)`` first.
    remove_dc, correct_iq : bool
        Apply (E1) and (E4) (the estimate is made either way).
    rows : float64 ndarray, shape (blocks, 5)
        Each block's estimate after its fold (``HISTORY_COLUMNS``).

    Returns
    -------
    int
        -1 when every block was corrected; else the first block holding NaN
        or inf (it and the blocks after it are left out: neither folded nor
        written).
    """
    n_total = x.shape[0]
    use = np.empty(rows.shape[1])
    sums = np.empty((-(-block // segment), 5))
    centred = np.empty((sums.shape[0], 3))
    rho = np.empty((2, sums.shape[0]))
    for k in range(-(-n_total // block)):
        start = k * block
        n = min(block, n_total - start)
        xb = x[start: start + n]
        ob = out[start: start + n]
        n_seg = -(-n // segment)
        for g in range(n_seg):
            # A view from 0: LLVM vectorises the loop over it (not one that starts at g * segment).
            part = xb[g * segment: min((g + 1) * segment, n)]
            s_i = 0.0
            s_q = 0.0
            s_ii = 0.0
            s_qq = 0.0
            s_iq = 0.0
            for j in range(part.shape[0]):
                v = part[j]
                re = np.float64(v.real)
                im = np.float64(v.imag)
                s_i += re
                s_q += im
                s_ii += re * re
                s_qq += im * im
                s_iq += re * im
            sums[g, 0] = s_i
            sums[g, 1] = s_q
            sums[g, 2] = s_ii
            sums[g, 3] = s_qq
            sums[g, 4] = s_iq
        s_i = 0.0
        s_q = 0.0
        s_ii = 0.0
        s_qq = 0.0
        for g in range(n_seg):
            s_i += sums[g, 0]
            s_q += sums[g, 1]
            s_ii += sums[g, 2]
            s_qq += sums[g, 3]
        if not np.isfinite(s_ii + s_qq):
            return k
        # Causal: the block is corrected with the estimate of the blocks before it (the stream's first block,
        # with nothing before it, with its own), so a stream cut short corrects what it holds as the whole
        # stream did.
        first = acc[0] == 0.0
        if not first:
            _estimate_kernel(acc, use)
        m_i = s_i / n
        m_q = s_q / n
        # (E6): each segment's moments about the block's mean; a segment whose normalised pseudo-covariance
        # lies off the running estimate's (the stream's first block: off its segments' median) by more than
        # noise explains (a PN header's) is left out.
        for g in range(n_seg):
            length = min((g + 1) * segment, n) - g * segment
            c_ii = sums[g, 2] - 2.0 * m_i * sums[g, 0] + length * m_i * m_i
            c_qq = sums[g, 3] - 2.0 * m_q * sums[g, 1] + length * m_q * m_q
            c_iq = sums[g, 4] - m_i * sums[g, 1] - m_q * sums[g, 0] + length * m_i * m_q
            p = c_ii + c_qq
            centred[g, 0] = c_ii
            centred[g, 1] = c_qq
            centred[g, 2] = c_iq
            if first:   # only the stream's first block centres its test on the segments themselves
                rho[0, g] = (c_ii - c_qq) / p if p > 0.0 else 0.0
                rho[1, g] = 2.0 * c_iq / p if p > 0.0 else 0.0
        if first:
            ref_re = np.median(rho[0, :n_seg])
            ref_im = np.median(rho[1, :n_seg])
        else:
            p_ref = acc[5] + acc[6]
            ref_re = (acc[5] - acc[6]) / p_ref if p_ref > 0.0 else 0.0
            ref_im = 2.0 * acc[7] / p_ref if p_ref > 0.0 else 0.0
        k_n = 0.0
        k_ii = 0.0
        k_qq = 0.0
        k_iq = 0.0
        for g in range(n_seg):
            length = min((g + 1) * segment, n) - g * segment
            c_ii = centred[g, 0]
            c_qq = centred[g, 1]
            c_iq = centred[g, 2]
            p = c_ii + c_qq
            d_re = (c_ii - c_qq) - ref_re * p
            d_im = 2.0 * c_iq - ref_im * p
            if d_re * d_re + d_im * d_im <= TRIM_LEVEL * 2.0 / length * p * p:
                k_n += length
                k_ii += c_ii
                k_qq += c_qq
                k_iq += c_iq
        lam = np.exp(-n * decay_per_sample)
        acc[0] = lam * acc[0] + n
        acc[1] = lam * acc[1] + s_i
        acc[2] = lam * acc[2] + s_q
        acc[3] = lam * acc[3] + (s_ii - s_i * m_i) + (s_qq - s_q * m_q)
        acc[4] = lam * acc[4] + k_n
        acc[5] = lam * acc[5] + k_ii
        acc[6] = lam * acc[6] + k_qq
        acc[7] = lam * acc[7] + k_iq
        row = rows[k]
        _estimate_kernel(acc, row)
        if first:
            use[:] = row
        a = 1.0
        b = 0.0
        if (correct_iq and abs(use[2]) <= MAX_CORRECTABLE_GAIN_DB
                and abs(use[3]) <= MAX_CORRECTABLE_PHASE_DEG):   # NaN compares False: no correction
            phi = np.radians(use[3])
            cos_phi = np.cos(phi)
            g = 10.0 ** (use[2] / 20.0)
            # |mu|^2 / |nu|^2 (M1) below CORRECT_BELOW_IRR_DB: a real imbalance, not the headers' residue.
            if (1.0 + g * g + 2.0 * g * cos_phi) < (1.0 + g * g - 2.0 * g * cos_phi) * 10.0 ** (
                    CORRECT_BELOW_IRR_DB / 10.0):
                a = 1.0 / (g * cos_phi)
                b = np.sin(phi) / cos_phi
        d_i = use[0] if remove_dc else 0.0
        d_q = use[1] if remove_dc else 0.0
        # (E4) on the DC-free rails, folded into one multiply-add per rail: Q' = a y_Q + b y_I + c.
        c = -(a * d_q + b * d_i)
        a32 = np.float32(a)
        b32 = np.float32(b)
        c32 = np.float32(c)
        d32 = np.float32(d_i)
        for j in range(n):
            v = xb[j]
            ob[j] = complex(v.real - d32, a32 * v.imag + b32 * v.real + c32)
    return -1


@njit(cache=True, nogil=True, fastmath={"reassoc"})
def _non_finite(f: np.ndarray) -> bool:
    """Whether any of the float32 values is NaN or inf (``v - v`` is 0 for the others; vectorises)."""
    s = np.float32(0.0)
    for i in range(f.shape[0]):
        s += f[i] - f[i]
    return s != 0.0 or np.isnan(s)


def _estimate_reference(acc: np.ndarray) -> np.ndarray:
    """(E1)-(E3) from the running sums: DC I and Q, gain dB, phase deg, signal RMS (``HISTORY_COLUMNS``)."""
    dc = acc[1:3] / acc[0]
    p_i, p_q, c = acc[5:8] / acc[4] if acc[4] > 0 else np.zeros(3)
    gain_db = phase_deg = np.nan
    if p_i > 0 and p_q > 0:
        gain_db = 10.0 * np.log10(p_q / p_i)                                          # (E3)
        phase_deg = np.degrees(np.arcsin(np.clip(-c / np.sqrt(p_i * p_q), -1.0, 1.0)))
    return np.array([dc[0], dc[1], gain_db, phase_deg, np.sqrt(max(acc[3] / acc[0], 0.0))])


def correct_blocks_reference(x: np.ndarray, acc: np.ndarray, decay_per_sample: float, remove_dc: bool,
                             correct_iq: bool, block: int = BLOCK,
                             segment: int = SEGMENT_MIN) -> tuple[np.ndarray, np.ndarray]:
    """Plain-numpy :func:`correct_blocks` (tests and benchmark): returns ``(out, rows)``, updates ``acc``.

    Same arguments as :func:`correct_blocks`, without the output arrays.
    """
    x = np.asarray(x, dtype=np.complex64)
    blocks = -(-len(x) // block)
    out = np.empty(len(x), dtype=np.complex64)
    rows = np.empty((blocks, len(HISTORY_COLUMNS)))
    for k in range(blocks):
        xb = x[k * block: (k + 1) * block]
        n = len(xb)
        re, im = xb.real.astype(np.float64), xb.imag.astype(np.float64)
        m_i, m_q = re.mean(), im.mean()
        y_i, y_q = re - m_i, im - m_q
        # (E6): segments whose normalised pseudo-covariance is off the running estimate's (the first block: off
        # the segments' median) by more than noise.
        edges = np.arange(0, n, segment)
        lengths = np.diff(np.append(edges, n))
        c_ii, c_qq, c_iq = (np.add.reduceat(v, edges) for v in (y_i * y_i, y_q * y_q, y_i * y_q))
        p = c_ii + c_qq
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = np.where(p > 0, (c_ii - c_qq + 2j * c_iq) / p, 0j)
        p_acc = acc[5] + acc[6]
        if acc[0] == 0.0:
            rho_ref = complex(np.median(rho.real), np.median(rho.imag))
        else:
            rho_ref = complex(acc[5] - acc[6], 2.0 * acc[7]) / p_acc if p_acc > 0 else 0j
        keep = np.abs((c_ii - c_qq + 2j * c_iq) - rho_ref * p) ** 2 <= TRIM_LEVEL * 2.0 / lengths * p * p
        # (E5): the block's mean and its moments about its own mean, weighted by its length.
        sums = np.array([n, n * m_i, n * m_q, np.sum(y_i * y_i) + np.sum(y_q * y_q), lengths[keep].sum(),
                         c_ii[keep].sum(), c_qq[keep].sum(), c_iq[keep].sum()])
        before = _estimate_reference(acc) if acc[0] != 0.0 else None   # causal (see correct_blocks)
        acc[:] = np.exp(-n * decay_per_sample) * acc + sums
        rows[k] = _estimate_reference(acc)
        dc_i, dc_q, gain_db, phase_deg, _ = rows[k] if before is None else before
        d_i, d_q = (dc_i, dc_q) if remove_dc else (0.0, 0.0)
        y_i, y_q = re - d_i, im - d_q
        if (correct_iq and abs(gain_db) <= MAX_CORRECTABLE_GAIN_DB and abs(phase_deg) <= MAX_CORRECTABLE_PHASE_DEG
                and image_rejection_db(gain_db, phase_deg) < CORRECT_BELOW_IRR_DB):
            g, phi = 10.0 ** (gain_db / 20.0), np.radians(phase_deg)
            y_q = (y_q / g + y_i * np.sin(phi)) / np.cos(phi)                               # (E4)
        out[k * block: k * block + n] = y_i + 1j * y_q
    return out, rows


def segment_samples(sample_rate_hz: float) -> int:
    """Samples per segment of (E6) at ``sample_rate_hz``: :data:`SEGMENT_S`, at least :data:`SEGMENT_MIN`."""
    return max(SEGMENT_MIN, int(round(SEGMENT_S * sample_rate_hz)))


def image_rejection_db(iq_gain_db: float, iq_phase_deg: float) -> float:
    """Image rejection of a front end with this imbalance (M1), dB: ``10 log10(|mu|^2 / |nu|^2)``.

    ``inf`` for a perfect front end, NaN for a NaN estimate.
    """
    g, phi = 10.0 ** (iq_gain_db / 20.0), np.radians(iq_phase_deg)
    mu = abs(1.0 + g * np.exp(-1j * phi)) ** 2
    nu = abs(1.0 - g * np.exp(1j * phi)) ** 2
    if not np.isfinite(mu + nu):
        return float("nan")
    with np.errstate(divide="ignore"):
        return float(10.0 * np.log10(mu / nu)) if nu > 0 else float("inf")


@dataclass(frozen=True, eq=False)   # arrays: compare the fields, not the records
class FrontEndEstimate:
    """The corrector's estimate of the front end: the latest, and one row per block.

    The scalars are the running estimate after the last folded block (NaN
    before any block); the arrays hold one row per block, in stream order.

    Attributes
    ----------
    dc_offset : complex
        DC offset / LO leakage (E1), input full-scale units (+-1 per rail).
    dc_offset_dbfs : float
        ``20 log10(|dc_offset|)``, dB relative to full scale.
    dc_offset_dbc : float
        ``20 log10(|dc_offset| / signal_rms)``, dB relative to the signal.
    signal_rms : float
        RMS of the DC-free input, ``sqrt(P_I + P_Q)``, full-scale units.
    iq_gain_db : float
        Q rail's gain over the I rail's (E3), dB.
    iq_phase_deg : float
        Quadrature error of the Q rail (E3), degrees (the sign of (M1)).
    image_rejection_db : float
        The front end's image rejection before correction, dB
        (:func:`image_rejection_db`).
    dc_removed, iq_corrected : bool
        Whether the corrector applies (E1) and (E4) (the estimates are made
        either way).
    samples : int
        Input samples folded into the estimate so far.
    block_start : int64 ndarray
        Absolute input index of each block's first sample.
    dc_i, dc_q : float64 ndarray
        DC offset of each rail after the block, full-scale units.
    gain_db, phase_deg : float64 ndarray
        Gain and phase estimate after the block, dB and degrees.
    rms : float64 ndarray
        Signal RMS after the block, full-scale units.
    """

    dc_offset: complex
    dc_offset_dbfs: float
    dc_offset_dbc: float
    signal_rms: float
    iq_gain_db: float
    iq_phase_deg: float
    image_rejection_db: float
    dc_removed: bool
    iq_corrected: bool
    samples: int
    block_start: np.ndarray
    dc_i: np.ndarray
    dc_q: np.ndarray
    gain_db: np.ndarray
    phase_deg: np.ndarray
    rms: np.ndarray

    def history_columns(self) -> dict[str, np.ndarray]:
        """The per-block rows as columns, for a writer (``block_start`` then ``HISTORY_COLUMNS``)."""
        return {"block_start": self.block_start, "dc_i": self.dc_i, "dc_q": self.dc_q, "iq_gain_db": self.gain_db,
                "iq_phase_deg": self.phase_deg, "signal_rms": self.rms}


def frontend_warnings(estimate: FrontEndEstimate) -> list[str]:
    """One line per impairment large enough to tell the user about (empty when none).

    The thresholds are ``WARN_DC_DBC``, ``WARN_GAIN_DB`` and
    ``WARN_PHASE_DEG``; each line says whether the corrector removed it.
    """
    out: list[str] = []
    if estimate.samples == 0:
        return out
    if estimate.dc_offset_dbc > WARN_DC_DBC:
        done = "removed" if estimate.dc_removed else "not removed"
        out.append(f"DC offset / LO leakage of {estimate.dc_offset_dbfs:.1f} dBFS "
                   f"({estimate.dc_offset_dbc:+.1f} dB relative to the signal) at the capture's centre: {done}")
    gain, phase = estimate.iq_gain_db, estimate.iq_phase_deg
    if not (np.isfinite(gain) and np.isfinite(phase)):
        out.append("I/Q imbalance not estimated: a rail of the capture carries no power")
        return out
    if abs(gain) > WARN_GAIN_DB or abs(phase) > WARN_PHASE_DEG:
        if abs(gain) > MAX_CORRECTABLE_GAIN_DB or abs(phase) > MAX_CORRECTABLE_PHASE_DEG:
            done = "left uncorrected (too large for a front end's imbalance: is the capture's signal circular?)"
        else:
            done = "corrected" if estimate.iq_corrected else "not corrected"
        out.append(f"I/Q imbalance of {gain:+.2f} dB gain and {phase:+.2f} deg phase (image rejection "
                   f"{estimate.image_rejection_db:.1f} dB): {done}")
    return out


class FrontEndCorrector:
    """Remove the DC offset and the I/Q imbalance of a stream, chunk by chunk (module docstring).

    Parameters
    ----------
    sample_rate_hz : float
        Input rate, samples/s (sets the forgetting per block).
    remove_dc : bool
        Subtract the estimated DC (E1).
    correct_iq : bool
        Apply the I/Q correction (E4).
    keep_history : bool
        Keep every block's estimate for :meth:`estimate` (False: only the
        latest, for a stream of any length).

    Attributes
    ----------
    position : int
        Absolute index of the next input sample.
    emitted : int
        Absolute index of the next output sample (``position`` minus the
        samples held back, fewer than ``BLOCK``).

    Raises
    ------
    ValueError
        A sample rate that is not a positive number.
    """

    def __init__(self, sample_rate_hz: float, remove_dc: bool = True, correct_iq: bool = True,
                 keep_history: bool = True) -> None:
        if not (np.isfinite(sample_rate_hz) and sample_rate_hz > 0):
            raise ValueError(f"sample_rate_hz must be a positive number, got {sample_rate_hz!r}")
        self.sample_rate_hz = float(sample_rate_hz)
        self.remove_dc = bool(remove_dc)
        self.correct_iq = bool(correct_iq)
        #: Keep the per-block rows for :meth:`estimate` (off: only the latest estimate, memory flat).
        self.keep_history = bool(keep_history)
        self.decay_per_sample = 1.0 / (FORGET_TIME_S * self.sample_rate_hz)
        self.position = 0
        self.emitted = 0
        self.segment = segment_samples(self.sample_rate_hz)
        self._acc = np.zeros(ACC_SIZE)
        self._pending = np.empty(BLOCK, dtype=np.complex64)   # the block being filled (reused)
        self._fill = 0
        self._finished = False
        self._latest = np.full(len(HISTORY_COLUMNS), np.nan)
        self._rows: list[np.ndarray] = []          # history rows not yet popped
        self._row_starts: list[np.ndarray] = []

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """The next input samples; returns the corrected samples of every block they complete.

        The returned array is new (complex64, a multiple of ``BLOCK`` long,
        possibly empty): the caller may keep it. The caller's chunk is left
        as it is.

        Raises
        ------
        ValueError
            A chunk that is not 1-D and complex, or holds NaN or inf (the
            corrector is then left as before the call).
        RuntimeError
            After :meth:`flush`.
        """
        if self._finished:
            raise RuntimeError("FrontEndCorrector: process() after flush()")
        chunk = np.asarray(chunk)
        if chunk.ndim != 1 or not np.iscomplexobj(chunk):
            raise ValueError(f"chunk must be a 1-D complex array, got {chunk.dtype} shape {chunk.shape}")
        x = np.ascontiguousarray(chunk, dtype=np.complex64)
        size = len(x)
        head = min(BLOCK - self._fill, size) if self._fill else 0      # completes the pending block
        whole = (size - head) // BLOCK * BLOCK                          # whole blocks, straight from the chunk
        tail = head + whole                                             # the rest waits in the pending block
        completes = self._fill + head == BLOCK
        # The kernel checks the samples it folds; those it does not see in this call (the tail, or the whole
        # chunk when it does not complete the pending block) are checked here, before anything changes.
        unseen = tail if completes or not self._fill else 0
        if _non_finite(x[unseen:].view(np.float32)):
            self._reject(x, unseen)
        saved = (self._acc.copy(), self.emitted, len(self._rows), self._latest)
        out = np.empty((self._fill + size) // BLOCK * BLOCK, dtype=np.complex64)
        o = 0
        ok = True
        if head:
            self._pending[self._fill: self._fill + head] = x[:head]
            if completes:
                ok = self._correct(self._pending, out[:BLOCK])
                o = BLOCK
        if ok and whole:
            ok = self._correct(x[head: tail], out[o: o + whole])
        if not ok:   # back to the state before the call (pending[:fill] is untouched)
            self._acc[:], self.emitted, kept, self._latest = saved
            del self._rows[kept:], self._row_starts[kept:]
            self._reject(x, 0)
        self._fill = (self._fill + head) % BLOCK
        if tail < size:
            self._pending[: size - tail] = x[tail:]
            self._fill = size - tail
        self.position += size
        return out

    def _reject(self, x: np.ndarray, start: int) -> None:
        """Raise the ValueError for the first NaN or inf of ``x`` at or after ``start``."""
        first = start + int(np.argmin(np.isfinite(x[start:])))
        raise ValueError(f"NaN or inf in the input at sample {self.position + first}")

    def flush(self) -> np.ndarray:
        """End of stream: the held-back partial block, corrected with its own statistics folded in.

        Further calls return an empty array; :meth:`process` may not follow.
        """
        self._finished = True
        out = np.empty(self._fill, dtype=np.complex64)
        if self._fill:
            self._correct(self._pending[: self._fill], out)   # checked when it arrived
            self._fill = 0
        return out

    def _correct(self, x: np.ndarray, out: np.ndarray) -> bool:
        """Run the kernel on whole blocks (a partial one at the end of the stream); False on NaN or inf."""
        blocks = -(-len(x) // BLOCK)
        rows = np.empty((blocks, len(HISTORY_COLUMNS)))
        if correct_blocks(x, out, BLOCK, self.segment, self._acc, self.decay_per_sample, self.remove_dc,
                          self.correct_iq, rows) >= 0:
            return False
        if self.keep_history:
            self._rows.append(rows)
            self._row_starts.append(self.emitted + BLOCK * np.arange(blocks, dtype=np.int64))
        self._latest = rows[-1].copy()
        self.emitted += len(x)
        return True

    def estimate(self, pop: bool = False) -> FrontEndEstimate:
        """The running estimate and the history rows of the blocks folded in so far.

        Parameters
        ----------
        pop : bool
            Forget the history rows returned, so that the next call returns
            only the blocks after them (a writer that stores them as it goes
            keeps the memory flat). The scalars are unaffected.
        """
        rows = np.concatenate(self._rows) if self._rows else np.empty((0, len(HISTORY_COLUMNS)))
        starts = np.concatenate(self._row_starts) if self._row_starts else np.empty(0, dtype=np.int64)
        if pop:
            self._rows, self._row_starts = [], []
        else:   # one array from now on, so that repeated calls do not concatenate again
            self._rows, self._row_starts = [rows], [starts]
        dc_i, dc_q, gain, phase, rms = (float(v) for v in self._latest)
        dc = complex(dc_i, dc_q)
        with np.errstate(divide="ignore", invalid="ignore"):
            dbfs = float(20.0 * np.log10(abs(dc))) if np.isfinite(abs(dc)) else float("nan")
            dbc = float(20.0 * np.log10(abs(dc) / rms)) if rms > 0 else float("nan")
        return FrontEndEstimate(
            dc_offset=dc, dc_offset_dbfs=dbfs, dc_offset_dbc=dbc, signal_rms=rms, iq_gain_db=gain,
            iq_phase_deg=phase, image_rejection_db=image_rejection_db(gain, phase), dc_removed=self.remove_dc,
            iq_corrected=self.correct_iq, samples=self.emitted, block_start=starts, dc_i=rows[:, 0].copy(),
            dc_q=rows[:, 1].copy(), gain_db=rows[:, 2].copy(), phase_deg=rows[:, 3].copy(), rms=rows[:, 4].copy())
