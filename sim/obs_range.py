"""Observation-level DTMB range: what the receiver's integrated range would be, without IQ.

For Monte Carlo studies of the fusion filters (docs/scenarios.md allows it), this
module produces a :class:`dtmbnav_core.records.RangeSeries` straight from the truth
track, with the errors the IQ receiver actually makes (docs/method.md §1-2). It
uses the *same* channel (:class:`sim.channel.Channel`) and receiver clock
(:func:`sim.oscillator.scenario_oscillator`) as the IQ simulation, drawn from
the same random streams (``sim.rf.STREAM_CHANNEL``, ``STREAM_CLOCK``), so for a
given scenario seed both levels see the same multipath and the same clock
wander. What it leaves out is the waveform: it simulates the receiver's 36 SI
carriers per frame, not the samples they come from.

- **SI carriers per frame.** The receiver's eq. 8 works on the SI carriers of
  each signal frame, ``Y_m(k) = H_m(k) X(k) + W_m(k)``, with the composite
  channel ``H_m(k) = sum_p c_p(t_m) exp(-j 2 pi f_k tau_p(t_m))`` (``c_p`` the
  path coefficient at the carrier, ``f_k`` the SI carrier's baseband
  frequency) and white noise (amplitudes relative to the unobstructed
  direct path). The scenario's C/N is that of the whole signal, whose mean
  power the boosted PN headers raise above the body's
  (:func:`sim.frontend.mean_signal_power`), so the noise on a carrier is that
  mean power over the C/N, as in the IQ front end; the SI carriers have
  ``tower.si_power_db`` relative to data, less the receiver's implementation
  loss (``implementation_loss_db``). The SI symbols
  ``X(k)`` repeat frame to frame and have unit modulus, so they cancel in
  everything below and are left out. In line of sight the composite phase
  ripples by centimetres around the direct path's; where buildings attenuate
  the direct path and a reflection dominates, the range follows the
  reflection's length: the NLOS bias.
- **Phase steps (eq. 8).** Per frame, the SI phase against a running reference of the
  frames before it, differenced, as the receiver computes it (``receiver/cfo.py``, "Telescoping"): on a strong link the noise telescopes
  (docs/method.md §2); in a deep flat fade of the SI slice the per-frame angle
  is noisy and non-linear, and its errors (up to half a wavelength a frame)
  no longer cancel, which is where the receiver's integrated range picks up
  its random jumps.
- **Oscillator and coarse CFO.** The clock's time error ``x(t)`` puts
  ``-2 pi fc x(t)`` on the carrier phase, common to the 36 carriers. The
  receiver derotates by its acquisition's coarse CFO before eq. 8 and adds it
  back afterwards (``receiver/cfo.py``), so eq. 8 measures the *residual*
  rotation per frame, wrapped to +-pi about zero: the coarse estimate's error
  plus the Doppler and the clock's wander. Where a deep fade makes the
  per-frame angle random, each such frame reads about zero and loses that
  residual rotation, so the range error of a fade has a sign, set by the
  coarse error. The coarse estimate here is the clock's offset at the first
  frame plus a Gaussian error with the standard deviation of the
  acquisition's lag-P estimator (:func:`coarse_cfo_sigma_hz`) at the
  header SNR of the first frame. (The tuner's constant offset is removed
  by the coarse estimate as it is added, so it is left out.) Like the
  receiver (eq. 9-10), f_s is the mean frequency over the start-still window
  (minus a guard before the walker moves) and is removed; what remains is
  the f_s estimation error times time plus the wander since the calibration.
- **SI SNR (the link quality the fusion watches).** The receiver's estimate
  (``receiver/ofdm.py::si_snr_db``): the mean ``|Y_m(k)|^2`` over the 36 SI
  carriers over its noise-power estimate, minus 1, floored at 1e-30. The
  carrier power follows a non-central chi-square with 72 degrees of freedom
  around the true SNR, and the noise power comes from the ``noise_bins``
  correlation bins of the PN header outside the channel's taps (a chi-square
  with ``2 noise_bins`` degrees of freedom around the true noise power): the
  per-frame spread the fusion's fading (Rician K) rule sees on the real
  receiver, not the exact channel power.
- **Validity.** The receiver flags a frame whose header peak metric
  ``S / (S + N)`` (header signal over received power) is below its track
  threshold; here the header SNR is the header symbols' power times the
  summed power of the paths over the noise, and frames below
  ``min_header_snr_db`` are invalid.

Every frame is simulated (1800 frames/s for PN420) in blocks of
:data:`BLOCK_FRAMES`; one sample every ``decimation`` frames is returned
(default 8: 225 Hz), each the value of that frame (its range, its own
per-frame SNR estimate). The noise is drawn frame by frame from streams of
their own, so the output does not depend on the block length (beyond the
last-bit rounding of numpy's vector and scalar paths).

The speed of light and the building-blockage geometry live in
:mod:`sim.channel`, the clock presets in :mod:`sim.oscillator`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SI_REFERENCE_GAIN, SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import PnMode
from dtmbnav_core.records import RangeSeries, Track
from sim.channel import Channel
from sim.frames import FrameConfig
from sim.frontend import mean_signal_power
from sim.oscillator import scenario_oscillator
from sim.rf import STREAM_CHANNEL, STREAM_CLOCK
from sim.scenario import Scenario

#: Stream ids mixed into the seed so this module's draws never repeat another module's:
#: the SI carriers' noise, the receiver's noise-power estimate and its coarse CFO error.
_STREAM_CARRIER_NOISE = 0x0B5
_STREAM_NOISE_ESTIMATE = 0x0B6
_STREAM_COARSE_CFO = 0x0B7

#: Frames simulated per block (memory stays flat over a long walk).
BLOCK_FRAMES = 8192

#: Smallest linear SNR estimate, as the receiver floors it (``receiver/ofdm.py::si_snr_db``).
SNR_FLOOR = 1e-30


@dataclass(frozen=True)
class ObsRangeConfig:
    """Parameters of the observation-level range model (module docstring).

    Attributes
    ----------
    decimation : int
        Output one sample every ``decimation`` signal frames.
    min_header_snr_db : float
        Header SNR below which a frame is invalid, dB: the receiver's
        track threshold of 0.15 on the header peak metric ``S / (S + N)``
        (``receiver.pipeline.ReceiverConfig.track_threshold``) is an SNR of
        ``10 log10(0.15 / 0.85)``.
    noise_bins : int
        PN-correlation bins the receiver's noise-power estimate averages: the
        255 of a PN420 m-sequence period minus the 64 taps of the channel
        estimate (``receiver/channel_estimate.py``).
    acquisition_frames : int
        Frames the receiver's acquisition folds for its coarse CFO
        (``receiver.pipeline.ReceiverConfig.acquisition_frames``).
    implementation_loss_db : float
        How far the receiver's SI carriers fall below the channel's power,
        dB: the IQ receiver's per-frame phase steps are as noisy as a channel
        this much weaker would make them (the calibration against the IQ
        receiver, ``dtmbnav/evaluation/obs_vs_iq.py``).
    calibration_guard_s : float
        End the f_s calibration this long before the walker starts, s.
    noise_draw : int
        Which draw of the receiver's noise (the carriers' noise, its
        noise-power estimate, its coarse CFO error): other draws over the same
        walk, channel and clock show the spread the receiver's noise alone
        causes.
    """

    decimation: int = 8
    min_header_snr_db: float = -7.5
    noise_bins: int = 191
    acquisition_frames: int = 16
    implementation_loss_db: float = 0.1
    calibration_guard_s: float = 1.0
    noise_draw: int = 0


def coarse_cfo_sigma_hz(header_snr: float, mode: PnMode, acquisition_frames: int) -> float:
    """Standard deviation of the acquisition's coarse CFO, Hz (``receiver/acquisition.py`` step 1).

    The estimate is the angle of ``sum conj(r[n]) r[n + P]`` over the
    ``header - P`` cyclic chips of each of ``acquisition_frames`` headers,
    divided by ``2 pi P T``. Each product of two samples at SNR ``s`` has a
    phase variance ``(1 + 1 / (2 s)) / s`` (both carry noise), so over N
    products the angle's variance is ``(1 + 1 / (2 s)) / (N s)``.

    Parameters
    ----------
    header_snr : float
        SNR of the header samples (linear) during acquisition.
    mode : PnMode
        Header mode (its length and m-sequence period P).
    acquisition_frames : int
    """
    period = mode.value.period
    products = mode.value.cyclic_length * acquisition_frames
    if products <= 0:
        raise ValueError(f"{mode.name}: the header has no cyclic part for a lag-P coarse CFO")
    phase_sigma = np.sqrt((1.0 + 1.0 / (2.0 * header_snr)) / (products * header_snr))
    return float(phase_sigma * gb20600.SYMBOL_RATE_HZ / (2.0 * np.pi * period))


@njit(cache=True)
def si_frames_kernel(coef: np.ndarray, delay_s: np.ndarray, common_rad: np.ndarray, first_hz: float,
                     spacing_hz: float, count: int, noise: np.ndarray, reference: np.ndarray, phase: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 8 frame by frame on noisy SI carriers, as the receiver measures it: the phase steps and the mean power.

    Each frame's phase is taken against a reference, the exponential average (gain
    :data:`~dtmbnav_core.constants.SI_REFERENCE_GAIN`) of the frames before it, each turned back by its own
    phase, and its step is the difference of two such phases (``receiver/cfo.py``, "Telescoping").

    Parameters
    ----------
    coef : ndarray of complex, shape (P, M)
        Path coefficients at the carrier (gain times ``exp(-j 2 pi fc tau)``), M frames.
    delay_s : ndarray, shape (P, M)
        Path delays, s.
    common_rad : ndarray, shape (M,)
        Phase common to every carrier (clock, less the coarse CFO), rad.
    first_hz, spacing_hz : float
        The SI carriers are ``first_hz + i spacing_hz``, i < ``count``, Hz.
    count : int
        Number of SI carriers K.
    noise : ndarray of complex, shape (M, K)
        Noise added to each carrier (same units as ``coef``).
    reference : ndarray of complex, shape (K,)
        The SI reference before the first frame (all 0 at the start: the first step is 0); updated in place.
    phase : ndarray, shape (1,)
        Phase of the frame before the first against the reference, rad; updated in place.

    Returns
    -------
    steps : ndarray, shape (M,)
        Phase advance into frame m, rad, in (-pi, pi].
    power : ndarray, shape (M,)
        Mean ``|Y_m(k)|^2`` over the carriers.
    """
    p_count, m_count = coef.shape
    y = np.zeros(count, dtype=np.complex128)
    steps = np.zeros(m_count)
    power = np.zeros(m_count)
    for m in range(m_count):
        for k in range(count):
            y[k] = noise[m, k]
        rotation = np.exp(1j * common_rad[m])
        for p in range(p_count):
            # exp(-j 2 pi f_k tau) for equally spaced carriers: one phasor and its ratio per path.
            z = coef[p, m] * rotation * np.exp(-2j * np.pi * first_hz * delay_s[p, m])
            ratio = np.exp(-2j * np.pi * spacing_hz * delay_s[p, m])
            for k in range(count):
                y[k] += z
                z *= ratio
        projection = 0j
        acc = 0.0
        for k in range(count):
            projection += np.conj(reference[k]) * y[k]
            acc += y[k].real * y[k].real + y[k].imag * y[k].imag
        steps[m] = np.angle(projection * np.exp(-1j * phase[0]))
        phase[0] = np.angle(projection)
        turn = SI_REFERENCE_GAIN * np.exp(-1j * phase[0])
        for k in range(count):
            reference[k] = (1.0 - SI_REFERENCE_GAIN) * reference[k] + turn * y[k]
        power[m] = acc / count
    return steps, power


def si_frames_reference(coef: np.ndarray, delay_s: np.ndarray, common_rad: np.ndarray, first_hz: float,
                        spacing_hz: float, count: int, noise: np.ndarray, reference: np.ndarray, phase: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Plain-numpy twin of :func:`si_frames_kernel` (one complex exponential per carrier and path)."""
    baseband_hz = first_hz + spacing_hz * np.arange(count)
    h = np.einsum("pm,pmk->mk", coef, np.exp(-2j * np.pi * baseband_hz[None, None, :] * delay_s[:, :, None]))
    y = h * np.exp(1j * common_rad)[:, None] + noise
    phases = np.empty(len(y) + 1)
    phases[0] = phase[0]
    for m, carriers in enumerate(y):     # each frame's phase needs the reference the frames before it made
        phases[m + 1] = np.angle(np.vdot(reference, carriers))
        reference[:] = (1.0 - SI_REFERENCE_GAIN) * reference + SI_REFERENCE_GAIN * np.exp(-1j * phases[m + 1]) * carriers
    phase[0] = phases[-1]
    return np.angle(np.exp(1j * np.diff(phases))), np.mean(np.abs(y) ** 2, axis=1)


def si_carrier_grid_hz() -> tuple[float, float, int]:
    """Baseband frequencies of the SI carriers as (first, spacing, count), Hz: they are consecutive carriers."""
    baseband = np.sort(gb20600.bin_frequency_hz(gb20600.si_bins()).astype(np.float64))
    spacing = np.diff(baseband)
    if not np.allclose(spacing, spacing[0]):
        raise ValueError("SI carriers are not equally spaced")
    return float(baseband[0]), float(spacing[0]), len(baseband)


def noise_variance(scenario: Scenario) -> float:
    """Receiver noise per sample relative to a unit-power data symbol through the unobstructed path.

    The scenario's C/N is that of the whole signal, whose mean power the
    boosted PN headers raise above the body's (:func:`sim.frontend.mean_signal_power`).
    """
    tower = scenario.tower
    return (mean_signal_power(FrameConfig(pn_mode=PnMode.parse(tower.pn_mode), si_power_db=tower.si_power_db))
            / 10.0 ** (scenario.receiver.cn_db / 10.0))


def observation_times_s(scenario: Scenario, truth: Track, decimation: int) -> np.ndarray:
    """The observation level's output grid: every ``decimation``-th signal frame over the truth track, s."""
    frame_s = PnMode.parse(scenario.tower.pn_mode).value.frame_duration_s
    return np.arange(truth.t_s[0], truth.t_s[-1], frame_s)[::decimation]


def simulate_obs_range(scenario: Scenario, truth: Track, config: ObsRangeConfig = ObsRangeConfig(),
                       block_frames: int = BLOCK_FRAMES) -> RangeSeries:
    """The receiver's integrated range for a truth track, from the model of the module.

    Parameters
    ----------
    scenario : Scenario
        Tower, receiver (C/N, clock), channel and walk (start-still time); its
        ``seed`` seeds every random draw.
    truth : Track
        True trajectory (e.g. ``simulate_walk(scenario).track``), starting at
        the capture start with the walker standing at P0.
    config : ObsRangeConfig
    block_frames : int
        Frames simulated at a time (memory only: the output does not depend on it beyond rounding).

    Returns
    -------
    RangeSeries
        One row per output sample (every ``config.decimation`` frames):
        range change since the first frame, the frame's SI SNR estimate and
        validity.
    """
    if config.decimation < 1:
        raise ValueError(f"ObsRangeConfig.decimation must be >= 1, got {config.decimation}")
    if block_frames < 1:
        raise ValueError(f"block_frames must be >= 1, got {block_frames}")
    tower = scenario.tower
    mode = PnMode.parse(tower.pn_mode)
    frame_s = mode.value.frame_duration_s
    t_s = np.arange(truth.t_s[0], truth.t_s[-1], frame_s)
    # f_s calibration window (eq. 9): the start-still time minus a guard before the walker moves.
    cal_end = max(scenario.walk.start_still_s - config.calibration_guard_s, 10 * frame_s * config.decimation)
    cal = int(np.searchsorted(t_s, truth.t_s[0] + cal_end))
    if cal >= len(t_s):
        raise ValueError(f"simulate_obs_range: truth track ({truth.t_s[-1] - truth.t_s[0]:.1f} s) is shorter than "
                         f"the f_s calibration window ({cal_end:.1f} s of walk.start_still_s)")
    channel = Channel(scenario, truth, np.random.default_rng([scenario.seed, STREAM_CHANNEL, 0, 1]))
    first_hz, spacing_hz, count = si_carrier_grid_hz()
    carrier_rng = np.random.default_rng([scenario.seed, _STREAM_CARRIER_NOISE, config.noise_draw])
    estimate_rng = np.random.default_rng([scenario.seed, _STREAM_NOISE_ESTIMATE, config.noise_draw])
    # Noise per sample (and per carrier) relative to a unit-power data symbol through the unobstructed path.
    noise_var = noise_variance(scenario)
    si_amplitude = 10.0 ** ((tower.si_power_db - config.implementation_loss_db) / 20.0)

    # The coarse CFO: the clock's offset when the receiver acquires, plus the estimator's error.
    fc = tower.carrier_hz
    oscillator = scenario_oscillator(scenario, float(truth.t_s[-1]) + 1.0, scenario.seed, STREAM_CLOCK)
    t0 = t_s[:1]
    header_snr = mode.value.header_power_ratio * float(np.sum(np.abs(channel.state(t0).coef) ** 2)) / noise_var
    coarse_sigma = coarse_cfo_sigma_hz(header_snr, mode, config.acquisition_frames)
    coarse_rng = np.random.default_rng([scenario.seed, _STREAM_COARSE_CFO, config.noise_draw])
    coarse_hz = float(oscillator.clock_offset_hz(t0, fc)[0]) + coarse_sigma * coarse_rng.standard_normal()

    steps = np.empty(len(t_s))
    snr_est = np.empty(len(t_s))
    header_power = np.empty(len(t_s))
    reference, last_phase = np.zeros(count, dtype=np.complex128), np.zeros(1)
    for lo in range(0, len(t_s), block_frames):
        hi = min(lo + block_frames, len(t_s))
        state = channel.state(t_s[lo:hi])
        noise = carrier_rng.standard_normal((hi - lo, count, 2)).view(np.complex128)[..., 0]
        # Clock phase less the coarse derotation, in cycles first (both are thousands of cycles over a walk).
        cycles = fc * oscillator.time_error_s(t_s[lo:hi]) + coarse_hz * (t_s[lo:hi] - t0)
        common = -2.0 * np.pi * (cycles - np.floor(cycles))
        steps[lo:hi], power = si_frames_kernel(state.coef * si_amplitude, state.delay_s, common, first_hz,
                                               spacing_hz, count, noise * np.sqrt(noise_var / 2.0), reference,
                                               last_phase)
        # The receiver's noise-power estimate: mean power of 2 * noise_bins real Gaussian components.
        dof = 2 * config.noise_bins
        noise_estimate = noise_var * estimate_rng.chisquare(dof, hi - lo) / dof
        snr_est[lo:hi] = np.maximum(power / noise_estimate - 1.0, SNR_FLOOR)
        header_power[lo:hi] = np.sum(np.abs(state.coef) ** 2, axis=0)
    steps[0] = 0.0

    # The receiver's CFO is the coarse estimate plus eq. 8's residual.
    phase = np.cumsum(steps) + 2.0 * np.pi * coarse_hz * (t_s - t0)
    # f_s (eq. 9): the mean frequency over the calibration window, removed from the whole series.
    f_s_hz = (phase[cal] - phase[0]) / (2.0 * np.pi * (t_s[cal] - t_s[0]))
    corrected = phase - phase[0] - 2.0 * np.pi * f_s_hz * (t_s - t_s[0])
    wavelength_m = SPEED_OF_LIGHT_MPS / fc
    out = slice(None, None, config.decimation)
    header_snr_db = 10.0 * np.log10(mode.value.header_power_ratio * header_power[out] / noise_var)
    return RangeSeries(t_s=t_s[out], range_change_m=-wavelength_m * corrected[out] / (2.0 * np.pi),
                       snr_db=10.0 * np.log10(snr_est[out]), valid=header_snr_db >= config.min_header_snr_db)


#: SNR of every row of :func:`exact_range`, dB: above any "good link" threshold of the fusion, so the
#: filters weigh it with their floor sigma, as they would a clean line-of-sight range.
EXACT_RANGE_SNR_DB = 30.0


def exact_range(scenario: Scenario, truth: Track, config: ObsRangeConfig = ObsRangeConfig()) -> RangeSeries:
    """The direct path's true range change, on :func:`simulate_obs_range`'s output grid: no error at all.

    No noise, no multipath, no clock, no gap: what the fusion could do with
    a perfect receiver, which separates what the filters and the single-tower
    geometry cannot do from what the range's errors cost
    (``dtmbnav evaluate --level exact``). Every row is valid, with SNR
    :data:`EXACT_RANGE_SNR_DB`.

    Parameters
    ----------
    scenario : Scenario
        Tower 0 and the receiver antenna height.
    truth : Track
        True trajectory, as for :func:`simulate_obs_range`.
    config : ObsRangeConfig
        Only ``decimation`` is used (the output grid).

    Returns
    -------
    RangeSeries
        3-D range to tower 0's antenna minus its value at the first row, m.
    """
    t_s = observation_times_s(scenario, truth, config.decimation)
    # The channel's seed does not matter: only its deterministic direct-path geometry is read.
    range_m = Channel(scenario, truth, np.random.default_rng(0)).direct(t_s).range_m
    return RangeSeries(t_s=t_s, range_change_m=range_m - range_m[0], snr_db=np.full(len(t_s), EXACT_RANGE_SNR_DB),
                       valid=np.ones(len(t_s), dtype=bool))
