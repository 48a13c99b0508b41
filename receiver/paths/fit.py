"""The least-squares path fit: the pulse model and one delay-locked loop per path (:mod:`receiver.paths`).

The CIR of a frame is ``y[l] = sum_i a_i g(l - lambda_i) + noise``: path i
has a complex amplitude ``a_i`` (its carrier phase) and a fractional delay
``lambda_i`` (samples after the frame's window start), and ``g`` is the
known pulse seen through the header correlation: the SRRC of GB 20600
(``docs/dtmb.md`` §1; roll-off 0.05) times the resampler's response, made
periodic over the m-sequence period (the correlation is circular).
:func:`pulse_tables` builds ``g`` and ``g'`` from that spectrum.

:func:`fit_paths_kernel` (SAGE-style least squares): over runs of frames the
delays are held, the amplitudes of every frame are the least-squares fit of
the model (so two paths closer than a chip are separated by the pulse shape:
super-resolution), and every ``block_frames`` frames one Gauss-Newton step
on the delays, with the amplitudes projected out (variable projection), is
applied with a gain: a delay-locked loop per path, with a rate per path for
the drift of the receiver clock and the walker's motion. The tracker holds a
confirmed path's correction to ``steady_delay_step`` per block (paths move
by hundredths of a chip per second): a spurious neighbour cannot drag a path
away. :func:`fit_paths_reference` is the kernel's plain-numpy twin.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from numba import njit

from dtmbnav_core import gb20600
from receiver.resample import design_filter

#: Points per chip of the pulse tables (linear interpolation between them).
PULSE_OVERSAMPLING = 32


# ---- the pulse model -------------------------------------------------------------------------

def srrc_spectrum(f: np.ndarray, rolloff: float = gb20600.SRRC_ROLLOFF) -> np.ndarray:
    """Square-root raised-cosine spectrum at ``f`` cycles per chip (1 in the pass band; unit-energy pulse)."""
    f = np.abs(np.asarray(f, dtype=np.float64))
    edge = (1.0 - rolloff) / 2.0
    out = np.where(f <= edge, 1.0, 0.0)
    slope = (f > edge) & (f <= (1.0 + rolloff) / 2.0)
    return np.where(slope, np.sqrt(0.5 * (1.0 + np.cos(np.pi / rolloff * (f - edge)))), out)


def resampler_response(up: int, down: int) -> Callable[[np.ndarray], np.ndarray] | None:
    """Zero-phase response of the receiver's resampler (``receiver.resample.design_filter``) at ``f`` cycles per chip.

    None for a 7.56 Msps capture (no resampling). The prototype runs at
    ``up`` times the input rate, i.e. ``down`` samples per chip.
    """
    if up == 1 and down == 1:
        return None
    h = design_filter(up, down).astype(np.float64)
    n = np.arange(len(h)) - (len(h) - 1) // 2

    def response(f: np.ndarray) -> np.ndarray:
        return np.cos(2.0 * np.pi * np.outer(f, n) / down) @ h / up

    return response


def pulse_tables(period: int, oversampling: int = PULSE_OVERSAMPLING,
                 response: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The CIR of a unit path, ``g(x)``, and ``g'(x)`` over one period, ``oversampling`` points per chip.

    ``g`` is the pulse the header correlation sees (module docstring), made
    periodic over ``period`` chips: its Fourier series holds the pulse's
    spectrum at ``k / period`` cycles per chip, including the roll-off beyond
    half the chip rate, which the 1-sample-per-chip correlation aliases, as
    sampling the continuous pulse does. Entry ``m`` is ``x = m / oversampling``;
    one extra entry repeats the first (for interpolation).
    """
    reach = int(np.ceil((1.0 + gb20600.SRRC_ROLLOFF) / 2.0 * period))
    k = np.arange(-reach, reach + 1)
    f = k / period
    coef = srrc_spectrum(f) / period
    if response is not None:
        coef = coef * response(f)
    size = period * oversampling
    spectrum = np.zeros(size, dtype=np.complex128)
    spectrum[k % size] = coef
    g = np.real(np.fft.ifft(spectrum)) * size
    spectrum[k % size] = coef * 2j * np.pi * f
    dg = np.real(np.fft.ifft(spectrum)) * size
    return np.append(g, g[0]), np.append(dg, dg[0])


@lru_cache(maxsize=8)
def _pulse_tables_cached(period: int, up: int, down: int) -> tuple[np.ndarray, np.ndarray]:
    return pulse_tables(period, PULSE_OVERSAMPLING, resampler_response(up, down))


# ---- the least-squares fit (numba kernel and its numpy twin) ---------------------------------

@njit(cache=True, nogil=True, fastmath=True)
def _table_at(table: np.ndarray, x: float, period: int, oversampling: int) -> float:
    """Periodic table lookup with linear interpolation, ``x`` in chips."""
    pos = (x % period) * oversampling
    i0 = int(pos)
    w = pos - i0
    return table[i0] * (1.0 - w) + table[i0 + 1] * w


@njit(cache=True, nogil=True, fastmath=True)
def fit_paths_kernel(taps: np.ndarray, offsets: np.ndarray, lag0: int, delay: np.ndarray, rate: np.ndarray,
                     max_step: np.ndarray, table: np.ndarray, dtable: np.ndarray, oversampling: int,
                     block_frames: int, gain: float, rate_gain: float, max_run_move: float, amplitudes: np.ndarray,
                     lags: np.ndarray, variance: np.ndarray, residual_power: np.ndarray) -> None:
    """:func:`fit_views_kernel` on one CIR over the contiguous lags ``lag0 .. lag0 + L - 1``, every pulse at full scale.

    The path tracker's CIR over the header's cyclic extension
    (:meth:`receiver.channel_estimate.ChannelEstimator.span_taps`); the
    parameters are those of :func:`fit_views_kernel`.
    """
    lag_axis = lag0 + np.arange(taps.shape[1]).astype(np.float64)
    fit_views_kernel(taps, offsets, lag_axis, np.zeros(taps.shape[1], np.int64), np.ones((1, delay.shape[0])),
                     delay, rate, max_step, table, dtable, oversampling, block_frames, gain, rate_gain, max_run_move,
                     amplitudes, lags, variance, residual_power)


@njit(cache=True, nogil=True, fastmath=True)
def fit_views_kernel(taps: np.ndarray, offsets: np.ndarray, lag_axis: np.ndarray, column_view: np.ndarray,
                     scale: np.ndarray, delay: np.ndarray, rate: np.ndarray, max_step: np.ndarray, table: np.ndarray,
                     dtable: np.ndarray, oversampling: int, block_frames: int, gain: float, rate_gain: float,
                     max_run_move: float, amplitudes: np.ndarray, lags: np.ndarray, variance: np.ndarray,
                     residual_power: np.ndarray) -> None:
    """Least-squares path amplitudes and delay-loop updates over a batch (module docstring).

    The columns of ``taps`` may come from several header-correlation windows
    ("views", :meth:`receiver.channel_estimate.ChannelEstimator.view_taps`):
    path i adds ``scale[v, i] a_i g(lag - lambda_i)`` to a column of view v,
    where ``scale`` holds the share of the path's header chips inside that
    view's window (the rest of the window holds body data, noise here) over
    the view's noise standard deviation, by which its columns have been
    divided too (a weighted least-squares fit).

    The frames are fitted in runs with one window offset, each run's pulses
    at the paths' lags in its middle frame; a run ends before its fastest
    path drifts by ``max_run_move`` (a receiver clock tens of ppm off moves
    every path by hundredths of a sample per frame, and a pulse fitted half a
    sample off bends the amplitude's phase). The delay loops are updated every
    ``block_frames`` frames whatever the runs, so their bandwidth per frame
    does not depend on how often the receiver's timing moves the window.

    Parameters
    ----------
    taps : (F, L) complex64
        Raw CIR of each frame; column j is lag ``lag_axis[j]`` of view ``column_view[j]``.
    offsets : (F,) float64
        Each frame's window start on the path-delay grid: path i sits at lag
        ``delay_i - offsets[k]``.
    lag_axis : (L,) float64
        Lag of each column, samples after the frame's window start.
    column_view : (L,) int64
        View of each column (row of ``scale``).
    scale : (V, n) float64
        Scale of path i's pulse in the columns of view v.
    delay, rate : (n,) float64
        Grid delay of each path at the batch's first frame and its drift per
        frame, samples; updated in place to the frame after the batch.
    max_step : (n,) float64
        Largest delay correction per update of each path, samples.
    table, dtable : float64
        :func:`pulse_tables` (period ``(len - 1) / oversampling`` chips).
    block_frames, gain, rate_gain
        Frames per update and the loop gains.
    max_run_move : float
        Largest drift of a path's lag over one run of frames fitted with the same pulses, samples.
    amplitudes : (F, n) complex128, out
        Fitted amplitude of each path in each frame.
    lags : (F, n) float64, out
        Lag of each path in each frame, samples after the window start.
    variance : (F, n) float64, out
        Diagonal of ``(G^T G)^-1``: the amplitude's noise variance in units of the tap noise.
    residual_power : (L,) float64, in/out
        Accumulates, per lag, the power of what neither the paths' pulses nor
        their delay derivatives explain (``y`` minus its projection on
        ``[G, G']``): a slightly mis-delayed strong path leaves no trace there
        that detection could take for a path.
    """
    n_frames, n_lags = taps.shape
    n = delay.shape[0]
    period = (table.shape[0] - 1) // oversampling
    # Pulses and their derivatives, one contiguous row per path: the per-frame sums run along the lags.
    both = np.empty((2 * n, n_lags))
    lam = np.empty(n)
    hess = np.zeros((n, n))
    grad = np.zeros(n)
    y_re = np.empty(n_lags)
    y_im = np.empty(n_lags)
    r_re = np.empty(n_lags)
    r_im = np.empty(n_lags)
    uv_re = np.empty(2 * n)
    uv_im = np.empty(2 * n)
    pending = 0
    start = 0
    while start < n_frames:
        fastest = 0.0
        for i in range(n):
            fastest = max(fastest, abs(rate[i]))
        run_cap = block_frames if fastest * block_frames <= max_run_move else max(1, int(max_run_move / fastest))
        stop = start + 1
        while (stop < n_frames and pending + stop - start < block_frames and stop - start < run_cap
               and offsets[stop] == offsets[start]):
            stop += 1
        count = stop - start
        mid = 0.5 * (count - 1)
        for i in range(n):
            lam[i] = delay[i] + rate[i] * mid - offsets[start]
            for j in range(n_lags):
                x = lag_axis[j] - lam[i]
                c = scale[column_view[j], i]
                both[i, j] = c * _table_at(table, x, period, oversampling)
                both[n + i, j] = c * _table_at(dtable, x, period, oversampling)
        gram2 = both @ both.T
        ridge = 1e-6 * np.trace(gram2[:n, :n]) / max(n, 1)
        for i in range(2 * n):
            gram2[i, i] += ridge
        inverse = np.linalg.inv(gram2[:n, :n].copy())
        cross = gram2[n:, :n].copy()
        q = gram2[n:, n:] - cross @ inverse @ cross.T
        for i in range(n):
            q[i, i] -= ridge
        inverse2 = np.linalg.inv(gram2)
        for k in range(start, stop):
            y = taps[k]
            for j in range(n_lags):
                y_re[j] = y[j].real
                y_im[j] = y[j].imag
            for i in range(2 * n):
                row = both[i]
                acc_re = 0.0
                acc_im = 0.0
                for j in range(n_lags):
                    acc_re += row[j] * y_re[j]
                    acc_im += row[j] * y_im[j]
                uv_re[i] = acc_re
                uv_im[i] = acc_im
            for j in range(n_lags):
                r_re[j] = y_re[j]
                r_im[j] = y_im[j]
            for i in range(2 * n):
                c_re = 0.0
                c_im = 0.0
                for m in range(2 * n):
                    c_re += inverse2[i, m] * uv_re[m]
                    c_im += inverse2[i, m] * uv_im[m]
                row = both[i]
                for j in range(n_lags):
                    r_re[j] -= row[j] * c_re
                    r_im[j] -= row[j] * c_im
            for j in range(n_lags):
                residual_power[j] += r_re[j] * r_re[j] + r_im[j] * r_im[j]
            for i in range(n):
                a_re = 0.0
                a_im = 0.0
                for m in range(n):
                    a_re += inverse[i, m] * uv_re[m]
                    a_im += inverse[i, m] * uv_im[m]
                amplitudes[k, i] = complex(a_re, a_im)
                lags[k, i] = lam[i] + rate[i] * (k - start - mid)
                variance[k, i] = inverse[i, i]
            for i in range(n):
                ca = 0j
                for m in range(n):
                    ca += cross[i, m] * amplitudes[k, m]
                a = amplitudes[k, i]
                # d(model)/d(lambda_i) = -a_i g'_i: gradient term Re(J^H r), r = y - G a orthogonal to G.
                grad[i] += -(np.conj(a) * (complex(uv_re[n + i], uv_im[n + i]) - ca)).real
                for m in range(n):
                    hess[i, m] += q[i, m] * (np.conj(a) * amplitudes[k, m]).real
        for i in range(n):
            delay[i] += rate[i] * count
        pending += count
        if n > 0 and (pending >= block_frames or stop == n_frames):
            for i in range(n):
                hess[i, i] += 1e-9 + 1e-6 * abs(hess[i, i])
            step = np.linalg.solve(hess, grad)
            # A partial block (the batch's end) moves the loop in proportion to its frames.
            weight = gain * pending / block_frames
            for i in range(n):
                correction = min(max(step[i], -max_step[i]), max_step[i])
                delay[i] += weight * correction
                rate[i] += rate_gain * correction / block_frames
                for m in range(n):
                    hess[i, m] = 0.0
                grad[i] = 0.0
            pending = 0
        start = stop


@njit(cache=True, nogil=True, fastmath=True)
def model_residual_kernel(taps: np.ndarray, lag_axis: np.ndarray, column_view: np.ndarray, scale: np.ndarray,
                          amplitudes: np.ndarray, lags: np.ndarray, table: np.ndarray, oversampling: int,
                          block_frames: int, max_run_move: float, residual_power: np.ndarray) -> None:
    """Per column, the power left in ``taps`` once the paths' fitted pulses are taken out, summed over the frames.

    Column j of frame k loses ``scale[column_view[j], i] amplitudes[k, i]
    g(lag_axis[j] - lags[k, i])`` for every path i (the model of
    :func:`fit_views_kernel`, with the amplitudes and lags it fitted on
    other columns); the power left is added to ``residual_power[j]``. As in
    the fit, the pulses are made once per run of at most ``block_frames``
    frames over which no path's lag moves by more than ``max_run_move``, at
    the lags of the run's middle frame.
    """
    n_frames, n_lags = taps.shape
    n = amplitudes.shape[1]
    period = (table.shape[0] - 1) // oversampling
    pulse = np.zeros((n, n_lags))
    start = 0
    while start < n_frames:
        stop = start + 1
        while stop < n_frames and stop - start < block_frames:
            moved = 0.0
            for i in range(n):
                moved = max(moved, abs(lags[stop, i] - lags[start, i]))
            if moved > max_run_move:
                break
            stop += 1
        mid = (start + stop - 1) // 2
        for i in range(n):
            for j in range(n_lags):
                c = scale[column_view[j], i]
                pulse[i, j] = c * _table_at(table, lag_axis[j] - lags[mid, i], period, oversampling) if c != 0.0 else 0.0
        for k in range(start, stop):
            for j in range(n_lags):
                left_re = taps[k, j].real
                left_im = taps[k, j].imag
                for i in range(n):
                    a = amplitudes[k, i]
                    left_re -= a.real * pulse[i, j]
                    left_im -= a.imag * pulse[i, j]
                residual_power[j] += left_re * left_re + left_im * left_im
        start = stop


def fit_paths_reference(taps: np.ndarray, offsets: np.ndarray, lag0: int, delay: np.ndarray, rate: np.ndarray,
                        max_step: np.ndarray, table: np.ndarray, dtable: np.ndarray, oversampling: int,
                        block_frames: int, gain: float, rate_gain: float, max_run_move: float,
                        lag_axis: np.ndarray | None = None, column_view: np.ndarray | None = None,
                        scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Plain-numpy :func:`fit_paths_kernel` (vectorised over the frames of each run).

    With ``lag_axis``, ``column_view`` and ``scale`` given (``lag0`` is then
    unused) it is :func:`fit_views_kernel`'s twin. Returns ``amplitudes,
    lags, variance, residual_power``; ``delay`` and ``rate`` are updated in place.
    """
    n_frames, n_lags = taps.shape
    n = len(delay)
    period = (len(table) - 1) // oversampling
    grid = np.arange(len(table) - 1) / oversampling
    amplitudes = np.zeros((n_frames, n), complex)
    lags = np.zeros((n_frames, n))
    variance = np.zeros((n_frames, n))
    residual_power = np.zeros(n_lags)
    if lag_axis is None:
        lag_axis = lag0 + np.arange(n_lags)
    column_scale = np.ones((n_lags, n)) if scale is None else np.asarray(scale)[column_view]
    hess, grad, pending = np.zeros((n, n)), np.zeros(n), 0
    start = 0
    while start < n_frames:
        fastest = float(np.max(np.abs(rate), initial=0.0))
        run_cap = block_frames if fastest * block_frames <= max_run_move else max(1, int(max_run_move / fastest))
        limit = min(block_frames - pending, n_frames - start, run_cap)
        same = np.flatnonzero(offsets[start:start + limit] != offsets[start])
        stop = start + (same[0] if len(same) else limit)
        count, mid = stop - start, 0.5 * (stop - start - 1)
        lam = delay + rate * mid - offsets[start]
        x = np.mod(lag_axis[:, None] - lam[None, :], period)
        g = np.interp(x, grid, table[:-1], period=period) * column_scale
        dg = np.interp(x, grid, dtable[:-1], period=period) * column_scale
        ridge = 1e-6 * np.trace(g.T @ g) / max(n, 1)
        inverse = np.linalg.inv(g.T @ g + ridge * np.eye(n))
        cross = dg.T @ g
        q = dg.T @ dg - cross @ inverse @ cross.T
        both = np.hstack([g, dg])
        y = taps[start:stop].astype(np.complex128)
        a = (y @ g) @ inverse.T
        c = np.linalg.solve(both.T @ both + ridge * np.eye(2 * n), (y @ both).T).T if n else np.zeros((count, 0))
        residual_power += np.sum(np.abs(y - c @ both.T) ** 2, axis=0)
        amplitudes[start:stop] = a
        lags[start:stop] = lam[None, :] + rate[None, :] * (np.arange(count) - mid)[:, None]
        variance[start:stop] = np.diag(inverse)[None, :]
        grad += -np.real(np.conj(a) * (y @ dg - a @ cross.T)).sum(axis=0)
        hess += q * np.real(np.conj(a).T @ a)
        delay += rate * count
        pending += count
        if n and (pending >= block_frames or stop == n_frames):
            hess += np.diag(1e-9 + 1e-6 * np.abs(np.diag(hess)))
            correction = np.clip(np.linalg.solve(hess, grad), -max_step, max_step)
            delay += gain * pending / block_frames * correction
            rate += rate_gain * correction / block_frames
            hess, grad, pending = np.zeros((n, n)), np.zeros(n), 0
        start = stop
    return amplitudes, lags, variance, residual_power
