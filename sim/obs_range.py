"""Observation-level DTMB range: what the receiver's integrated range would be, without IQ.

For Monte Carlo studies of the fusion filters (docs/scenarios.md allows it), this
module produces a :class:`dtmbnav.core.records.RangeSeries` straight from the truth
track, with the errors the IQ receiver actually makes (docs/method.md §1-2). It
uses the *same* channel (:class:`sim.channel.Channel`) and receiver clock
(:func:`sim.oscillator.scenario_oscillator`) as the IQ simulation, drawn from
the same random streams (``sim.rf.STREAM_CHANNEL``, ``STREAM_CLOCK``), so for a
given scenario seed both levels see the same multipath and the same clock
wander; what this module leaves out is the receiver's signal processing.

- **Channel phase on the SI carriers.** The receiver's eq. 8 sums
  ``conj(Y_{m+1}(k)) Y_m(k)`` over the 36 SI carriers, so its range follows
  the phase of the *composite* channel at those carriers,
  ``H_m(k) = sum_p c_p(t_m) exp(-j 2 pi f_k tau_p(t_m))`` (``c_p`` the path
  coefficient at the carrier, ``f_k`` the SI carrier's baseband frequency).
  In line of sight the composite phase ripples by centimetres around the
  direct path's; where buildings attenuate the direct path and a reflection
  dominates, the range follows the reflection's length: the NLOS bias.
- **Oscillator.** The clock's time error ``x(t)`` puts ``-2 pi fc x(t)`` on
  the carrier phase. Like the receiver (eq. 9-10), f_s is the mean frequency
  over the start-still window (minus a guard before the walker moves) and is
  removed; what remains is the f_s estimation error times time plus the
  wander since the calibration.
- **Noise.** The integrated phase's noise telescopes (docs/method.md §2), so it is
  white per output sample, with the phase standard deviation of the SI sum,
  ``1 / sqrt(2 * sum_k snr_k)``.
- **Quality.** ``snr_db`` is the SI-carrier SNR (C/N times the composite
  channel power relative to the unobstructed direct path); samples below
  ``quality_snr_db`` are flagged invalid, as the receiver's low-quality flag.
  Cycle slips in deep fades are not modelled (those samples are flagged).

The channel is evaluated every ``decimation`` signal frames (default 8:
225 Hz for PN420), which keeps the phase step between samples below 0.2 rad at
walking speed, so the unwrapped phase is the one the per-frame receiver would
integrate.

The speed of light and the building-blockage geometry live in
:mod:`sim.channel`, the clock presets in :mod:`sim.oscillator`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from dtmbnav.core import gb20600
from dtmbnav.core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav.core.gb20600 import PnMode
from dtmbnav.core.records import RangeSeries, Track
from sim.channel import Channel
from sim.oscillator import scenario_oscillator
from sim.rf import STREAM_CHANNEL, STREAM_CLOCK
from sim.scenario import Scenario

#: Stream id mixed into the seed so this module's draws never repeat another module's.
_STREAM_ID = 0x0B5


@dataclass(frozen=True)
class ObsRangeConfig:
    """Parameters of the observation-level range model (module docstring).

    Attributes
    ----------
    decimation : int
        Output one sample every ``decimation`` signal frames.
    quality_snr_db : float
        SI SNR below which a sample is flagged invalid, dB.
    calibration_guard_s : float
        End the f_s calibration this long before the walker starts, s.
    """

    decimation: int = 8
    quality_snr_db: float = 3.0
    calibration_guard_s: float = 1.0


@njit(cache=True)
def si_phase_steps_kernel(coef: np.ndarray, delay_s: np.ndarray, baseband_hz: np.ndarray,
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 8 on a noise-free channel: phase step of the SI sum, and the channel power.

    Parameters
    ----------
    coef : ndarray of complex, shape (P, M)
        Path coefficients at the carrier (gain times ``exp(-j 2 pi fc tau)``).
    delay_s : ndarray, shape (P, M)
        Path delays, s.
    baseband_hz : ndarray, shape (K,)
        Baseband frequencies of the SI carriers, Hz.

    Returns
    -------
    steps : ndarray, shape (M - 1,)
        ``angle(sum_k H_{m+1}(k) conj(H_m(k)))``: the phase advance from
        sample m to m+1, rad.
    power : ndarray, shape (M,)
        Mean ``|H_m(k)|^2`` over the SI carriers.
    """
    p_count, m_count = coef.shape
    k_count = baseband_hz.shape[0]
    h_prev = np.zeros(k_count, dtype=np.complex128)
    h_cur = np.zeros(k_count, dtype=np.complex128)
    steps = np.zeros(max(m_count - 1, 0))
    power = np.zeros(m_count)
    for m in range(m_count):
        acc = 0.0
        for k in range(k_count):
            h = 0j
            for p in range(p_count):
                h += coef[p, m] * np.exp(-2j * np.pi * baseband_hz[k] * delay_s[p, m])
            h_cur[k] = h
            acc += h.real * h.real + h.imag * h.imag
        power[m] = acc / k_count
        if m > 0:
            theta = 0j
            for k in range(k_count):
                theta += h_cur[k] * np.conj(h_prev[k])
            steps[m - 1] = np.angle(theta)
        h_prev[:] = h_cur
    return steps, power


def si_phase_steps_reference(coef: np.ndarray, delay_s: np.ndarray, baseband_hz: np.ndarray,
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Plain-numpy twin of :func:`si_phase_steps_kernel`."""
    h = np.einsum("pm,pmk->mk", coef, np.exp(-2j * np.pi * baseband_hz[None, None, :] * delay_s[:, :, None]))
    return np.angle(np.sum(h[1:] * np.conj(h[:-1]), axis=1)), np.mean(np.abs(h) ** 2, axis=1)


def simulate_obs_range(scenario: Scenario, truth: Track, config: ObsRangeConfig = ObsRangeConfig()) -> RangeSeries:
    """The receiver's integrated range for a truth track, from the error model of the module.

    Parameters
    ----------
    scenario : Scenario
        Tower, receiver (C/N, clock), channel and walk (start-still time); its
        ``seed`` seeds every random draw.
    truth : Track
        True trajectory (e.g. ``simulate_walk(scenario).track``), starting at
        the capture start with the walker standing at P0.
    config : ObsRangeConfig

    Returns
    -------
    RangeSeries
        One row per output sample (every ``config.decimation`` frames):
        range change since the first sample, SNR and validity.
    """
    if config.decimation < 1:
        raise ValueError(f"ObsRangeConfig.decimation must be >= 1, got {config.decimation}")
    frame_s = PnMode.parse(scenario.tower.pn_mode).value.frame_duration_s
    t_s = np.arange(truth.t_s[0], truth.t_s[-1], frame_s * config.decimation)
    # f_s calibration window (eq. 9): the start-still time minus a guard before the walker moves.
    cal_end = max(scenario.walk.start_still_s - config.calibration_guard_s, 10 * frame_s * config.decimation)
    cal = int(np.searchsorted(t_s, truth.t_s[0] + cal_end))
    if cal >= len(t_s):
        raise ValueError(f"simulate_obs_range: truth track ({truth.t_s[-1] - truth.t_s[0]:.1f} s) is shorter than "
                         f"the f_s calibration window ({cal_end:.1f} s of walk.start_still_s)")
    channel = Channel(scenario, truth, np.random.default_rng([scenario.seed, STREAM_CHANNEL, 0, 1]))
    state = channel.state(t_s)
    steps, power = si_phase_steps_kernel(state.coef, state.delay_s,
                                         gb20600.bin_frequency_hz(gb20600.si_bins()).astype(np.float64))

    fc = scenario.tower.carrier_hz
    oscillator = scenario_oscillator(scenario, float(truth.t_s[-1]) + 1.0, scenario.seed, STREAM_CLOCK)
    snr_lin = 10.0 ** (scenario.receiver.cn_db / 10.0) * power
    rng = np.random.default_rng([scenario.seed, _STREAM_ID])
    phase = (np.concatenate([[0.0], np.cumsum(steps)]) - 2.0 * np.pi * fc * oscillator.time_error_s(t_s)
             + rng.standard_normal(len(t_s)) / np.sqrt(2.0 * gb20600.SI_LENGTH * snr_lin))

    # f_s (eq. 9): the mean frequency over the calibration window, removed from the whole series.
    f_s_hz = (phase[cal] - phase[0]) / (2.0 * np.pi * (t_s[cal] - t_s[0]))
    corrected = phase - phase[0] - 2.0 * np.pi * f_s_hz * (t_s - t_s[0])
    wavelength_m = SPEED_OF_LIGHT_MPS / fc
    snr_db = 10.0 * np.log10(snr_lin)
    return RangeSeries(t_s=t_s, range_change_m=-wavelength_m * corrected / (2.0 * np.pi),
                       snr_db=snr_db, valid=snr_db >= config.quality_snr_db)
