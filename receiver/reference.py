"""The per-frame receiver pipeline in plain numpy, one frame at a time.

The same arithmetic as :class:`receiver.pipeline.Receiver` after acquisition
(channel estimate, timing loop, body recovery, FFT, SI and PN CFO), written
with ``np.fft`` and the ``*_reference`` functions of each stage and a Python
loop over frames. It exists for two reasons: the tests check that the
batched numba/pyfftw pipeline gives the same per-frame CFO, and the benchmark
compares their speed. It works on an in-memory 7.56 Msps signal.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SI_REFERENCE_GAIN
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from receiver.acquisition import Acquisition
from receiver.body import recover_bodies_reference
from receiver.cfo import cfo_from_advance, cfo_from_theta, pn_theta_reference, si_phase_reference
from receiver.channel_estimate import TAP_THRESHOLD, TAPS_AFTER, TAPS_BEFORE, ChannelEstimator
from receiver.derotate import derotate_segments_reference
from receiver.ofdm import si_carrier_numbers, si_carriers_reference
from receiver.tracking import timing_loop_reference


@dataclass
class ReferenceFrames:
    """Per-frame outputs of the reference pipeline."""

    window_start: np.ndarray
    cfo_hz: np.ndarray
    cfo_pn_hz: np.ndarray
    snr_db: np.ndarray


def receive_reference(r: np.ndarray, acq: Acquisition, n_frames: int, *, taps_before: int = TAPS_BEFORE,
                      taps_after: int = TAPS_AFTER, tap_threshold: float = TAP_THRESHOLD, loop_alpha: float = 0.05,
                      loop_beta: float = 0.001, batch_frames: int = 128,
                      first_frame_index: int | None = None,
                      stage_seconds: dict[str, float] | None = None) -> ReferenceFrames:
    """Process ``n_frames`` frames of ``r`` (stream index 0 = ``r[0]``) after acquisition ``acq``.

    As in the streaming receiver, the FFT windows of each group of
    ``batch_frames`` frames are placed from the loop state at the group's
    start, and the first frame has no CFO (NaN). ``stage_seconds``, when
    given, accumulates the time spent per stage under the names of
    :data:`receiver.pipeline.STAGES` (channel = header-window derotation +
    estimate, sync = timing loop, as in the streaming receiver).
    """
    mode = acq.mode
    m = mode.value
    ng = m.header_length
    est = ChannelEstimator(mode, 1, taps_before, taps_after, tap_threshold)
    cycles = acq.coarse_cfo_hz / SYMBOL_RATE_HZ
    k = si_carrier_numbers().astype(np.float64)
    index0 = acq.frame_in_superframe if first_frame_index is None else first_frame_index
    tau, period = float(acq.frame_start), float(m.frame_length)
    out = ReferenceFrames(*(np.full(n_frames, np.nan) for _ in range(4)))
    prev = None
    si_reference, si_phase = np.zeros(gb20600.SI_LENGTH, dtype=np.complex128), 0.0
    for i in range(n_frames):
        if i % batch_frames == 0:
            batch_tau, batch_period = tau, period
        start = int(np.rint(batch_tau + (i % batch_frames) * batch_period))
        index = index0 + i
        phase_now, phase_next = (
            (int(gb20600.header_phase(mode, index)), int(gb20600.header_phase(mode, index + 1)))
            if acq.rotating else (acq.constant_phase, acq.constant_phase))
        t0 = time.perf_counter()
        windows = derotate_segments_reference(r, 0, np.array([start + est.window_offset]), est.window_length, cycles)
        ch = est.estimate_reference(windows, np.array([phase_now]))
        t2 = time.perf_counter()
        smoothed, periods, tau, period = timing_loop_reference(np.array([start + ch.centroid[0]]),
                                                      np.array([ch.peak_metric[0] >= 0.15]), tau, period,
                                                      loop_alpha, loop_beta)
        t3 = time.perf_counter()
        body = recover_bodies_reference(r, 0, np.array([start]), ng, cycles, ch.taps, taps_before,
                                        gb20600.header_symbols(mode, phase_now)[None, :],
                                        gb20600.header_symbols(mode, phase_next)[None, :])
        t4 = time.perf_counter()
        si = si_carriers_reference(body)[0]
        t5 = time.perf_counter()
        delta = start - smoothed[0]
        out.window_start[i], out.snr_db[i] = start, ch.snr_db[0]
        prev_si, prev_taps, prev_start, prev_delta = (si, ch.raw_taps[0], start, delta) if prev is None else prev
        # The first frame has no CFO but starts the SI reference.
        advance, _, si_phase = si_phase_reference(prev_si, si[None, :], k, prev_delta, np.array([delta]), si_reference,
                                                  si_phase, SI_REFERENCE_GAIN)
        if prev is not None:
            step = np.array([start - prev_start])
            eta = periods[0] / m.frame_length - 1.0
            out.cfo_hz[i] = cfo_from_advance(advance, step, eta, acq.coarse_cfo_hz)[0]
            shift = step - np.rint(periods).astype(np.int64)
            out.cfo_pn_hz[i] = cfo_from_theta(pn_theta_reference(prev_taps, ch.raw_taps, shift), step, eta,
                                              acq.coarse_cfo_hz)[0]
        prev = (si, ch.raw_taps[0], start, delta)
        if stage_seconds is not None:
            for stage, spent in (("sync", t3 - t2), ("channel", t2 - t0), ("body", t4 - t3),
                                 ("fft", t5 - t4), ("estimators", time.perf_counter() - t5)):
                stage_seconds[stage] = stage_seconds.get(stage, 0.0) + spent
    return out
