"""TDS-OFDM frame-body recovery (``docs/dtmb.md`` §5).

The tails of the current and next headers convolved with the channel taps
(:mod:`receiver.channel_estimate`) are subtracted from the body window, and
the body's own convolution tails that fell outside the window (after the
body, and before it for pre-cursor taps) are folded back ("cyclic
reconstruction"): the 3780 samples then equal the body circularly convolved
with the channel, as the FFT assumes.

The hot loop is a numba kernel over a whole batch of frames, with a
plain-numpy reference (``*_reference``) used by the tests and the benchmark.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dtmbnav_core.gb20600 import BODY_LENGTH
from receiver.derotate import derotate_segments_reference


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


@njit(cache=True, fastmath=True, nogil=True)
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
