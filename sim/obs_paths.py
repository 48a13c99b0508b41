"""Observation-level path tracker: the first-path ranges and tower differences the IQ receiver gives, without IQ.

:mod:`sim.obs_range` models the receiver's SI-carrier range; the IQ receiver
also tracks the paths of the PN header's channel estimate
(``receiver/paths/``, ``docs/paths.md``) and gives, per frame, tower 0's
first-path range change and the change of each further tower's first-path
range minus tower 0's. The fusion uses these wherever they exist, so an
evaluation without them measures another receiver. This module gives them from
the truth track, with the same channel (:class:`sim.channel.Channel`, the same
random stream, so the same multipath as the IQ level and as
:mod:`sim.obs_range`) and the same receiver clock:

- **What the tracker can separate.** The receiver fits the known pulse to
  the channel estimate, so two paths of a tower more than
  ``min_separation_chips`` apart are tracked apart, however strong each is
  (its ``PathConfig.min_separation``), unless one is more than
  ``weak_power_db`` weaker than a later one within ``weak_separation_chips``:
  the strong path's fitting error then swamps the weak one, which is
  *swallowed*: a diffracted direct path far under a wall reflection a
  fraction of a chip later is not separated, one whose reflection trails it
  by more is, and two paths of comparable power are (docs/paths.md). The two
  settings are fitted to what the IQ tracker separates at a street corner of
  the tuning walks, a wall reflection far above the direct path and a
  diffuse tap a few dB above it (docs/decisions.md, D34). A path counts only
  while its tap SNR (the
  sample SNR times the header's correlation gain, averaged over
  ``power_time_s`` as the tracker keeps or drops paths batch by batch)
  holds ``survival_snr_db``, the receiver's own survival threshold.
- **The first path** of a tower is held while it is tracked, as the
  tracker keeps a path it has, unless a path at least
  ``min_separation_chips`` earlier appears that is not swallowed (a new
  first path). Without one it is the earliest tracked path, or the path
  that swallows it. Its amplitude is the sum of the coefficients of the
  paths it cannot be separated from, each weighted by the pulse (``g``, the
  SRRC of GB 20600 the header correlation sees, 1 at no offset) at its delay
  from the anchor: the first path itself, or while it is swallowed the path
  that swallows it, whose phase the first path then follows (the street's
  corner hand-over).
- **Carrier phase.** Its range change is the integral of its phase steps
  (eq. 9-11: the receiver integrates the path's frequency), each step
  wrapped to +-pi as the receiver's per-frame phase difference is, plus the
  receiver clock's term ``c x(t)`` (``x`` the clock's time error), minus f_s
  times time: f_s is the clock's mean frequency over the standstill, which is
  what the receiver measures on its steadiest path there. The phase noise of
  a frame, ``1 / sqrt(2 SNR_tap)`` rad, is added at each output sample; it is
  millimetres on any path the tracker keeps.
- **Origin breaks.** Where the first path changes (it fades below the
  threshold, a new one appears before it) or a swallowed first path is
  separated again, the sample is an origin break (``slip``): the range
  continues from an unknown new origin; its step is left out and the path
  age restarts.
- **Confirmation.** The receiver reports a first path only after the path
  has been confirmed and has lived ``first_path_batches`` batches: nothing
  is output before ``confirm_s`` after the capture start.

Tower differences are the difference of the towers' first-path ranges, the
clock cancelling, valid where both are, with an origin break where either has
one (``receiver.observables.paths_from_frames`` reads the IQ receiver's the same way).
Each carries its code range difference: the two first paths' delays less the
towers' transmit delay offsets (known, as the simulated network plan is), each
with its own code error, the clock cancelling here too.
The model is checked against the IQ receiver on the same walks by
``dtmbnav/evaluation/obs_vs_iq.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.signal import lfilter

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import PnMode
from dtmbnav_core.records import PathRangeSeries, Track
from sim.channel import Channel
from sim.obs_range import ObsRangeConfig, noise_variance, observation_times_s
from sim.oscillator import scenario_oscillator
from sim.rf import STREAM_CHANNEL, STREAM_CLOCK
from sim.scenario import Scenario
from sim.transmitter import srrc_pulse

#: Stream ids mixed into the seed for the paths' phase noise and code-range error (no other module draws from them).
_STREAM_PATH_NOISE = 0x0B8
_STREAM_CODE_NOISE = 0x0B9


@dataclass(frozen=True)
class ObsPathConfig:
    """Parameters of the observation-level path model (module docstring).

    Attributes
    ----------
    decimation : int
        Output one sample every ``decimation`` signal frames (as :class:`sim.obs_range.ObsRangeConfig`).
    min_separation_chips : float
        Paths closer than this are one path to the tracker, chips (``PathConfig.min_separation``).
    weak_separation_chips, weak_power_db : float
        A path more than ``weak_power_db`` (dB) weaker than a later path
        within ``weak_separation_chips`` (chips) is swallowed by it (module
        docstring; fitted on the tuning walks, docs/decisions.md, D34).
    survival_snr_db : float
        Per-frame tap SNR below which a path is not tracked, dB (``PathConfig.survival_snr_db``).
    power_time_s : float
        Time constant of the path power the tracker's decisions see, s: it
        keeps or drops a path after ``lost_batches`` batches of 128 frames
        (0.2 s), so a diffuse tap's fast fading does not make and break paths.
    confirm_s : float
        Time from the capture start to the first reported first path, s.
    calibration_guard_s : float
        The f_s window ends this long before the walker starts, s (as the SI-carrier model).
    code_noise_m, code_noise_snr_db, code_noise_time_s : float
        The code range's error: ``code_noise_m`` (m, RMS) on a path of
        sample SNR ``code_noise_snr_db`` (dB), growing as 1/amplitude below
        it and shrinking above, correlated over ``code_noise_time_s`` (s; a
        first-order Gauss-Markov process). Calibrated on the IQ receiver's
        code error on a street's diffracted direct path (docs/paths.md;
        docs/decisions.md, D34).
    noise_draw : int
        Which draw of the receiver's phase noise and code-range error.
    """

    decimation: int = ObsRangeConfig.decimation
    min_separation_chips: float = 0.35
    weak_separation_chips: float = 0.7
    weak_power_db: float = 15.0
    survival_snr_db: float = 6.0
    power_time_s: float = 0.2
    confirm_s: float = 0.9
    calibration_guard_s: float = ObsRangeConfig.calibration_guard_s
    code_noise_m: float = 0.65
    code_noise_snr_db: float = -7.5
    code_noise_time_s: float = 0.25
    noise_draw: int = 0


@dataclass(frozen=True)
class ObsPaths:
    """The model's path observations: tower 0's first path and each further tower's difference to it.

    Attributes
    ----------
    first_path : PathRangeSeries
        Tower 0's first-path range change, m.
    differences : dict of int -> PathRangeSeries
        Tower k's first-path range minus tower 0's (k >= 1), change since both were first tracked, m.
    """

    first_path: PathRangeSeries
    differences: dict[int, PathRangeSeries]


#: Points per chip of the pulse table the kernel interpolates, and its half-width, chips.
PULSE_TABLE_OVERSAMPLING = 256
PULSE_TABLE_SPAN_CHIPS = 4.0


def pulse_gain_table() -> np.ndarray:
    """The header correlation's pulse (the SRRC) relative to its peak, at ``-SPAN + i / OVERSAMPLING`` chips."""
    x = np.arange(-PULSE_TABLE_SPAN_CHIPS, PULSE_TABLE_SPAN_CHIPS + 0.5 / PULSE_TABLE_OVERSAMPLING,
                  1.0 / PULSE_TABLE_OVERSAMPLING)
    return srrc_pulse(x) / srrc_pulse(np.zeros(1))[0]


@njit(cache=True)
def _swallower(p: int, m: int, delay_chips: np.ndarray, tap_snr: np.ndarray, weak: float,
               weak_separation: float) -> int:
    """The strongest later path within ``weak_separation`` that path ``p`` is weak next to at time ``m``, or -1."""
    best = -1
    for q in range(delay_chips.shape[0]):
        later = delay_chips[q, m] - delay_chips[p, m]
        if (0.0 < later < weak_separation and tap_snr[p, m] < weak * tap_snr[q, m]
                and (best < 0 or tap_snr[q, m] > tap_snr[best, m])):
            best = q
    return best


@njit(cache=True)
def first_path_kernel(coef: np.ndarray, delay_chips: np.ndarray, tap_snr: np.ndarray, survival: float,
                      weak: float, min_separation: float, weak_separation: float, pulse: np.ndarray,
                      held: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each time's first path of one tower: which path it is, its merged amplitude, origin breaks and anchor.

    Parameters
    ----------
    coef : ndarray of complex, shape (P, M)
        The tower's path coefficients at the carrier.
    delay_chips : ndarray, shape (P, M)
        Their delays, chips.
    tap_snr : ndarray, shape (P, M)
        Their per-frame tap SNR (linear) as the tracker sees it over its
        batches: which paths are tracked, and which is weak next to which,
        is decided on it.
    survival : float
        Tap SNR (linear) a path needs to be tracked.
    weak : float
        Power ratio under which a path is weak next to another (linear, < 1).
    min_separation, weak_separation : float
        :class:`ObsPathConfig`'s separations, chips.
    pulse : ndarray
        :func:`pulse_gain_table`.
    held : ndarray of int, shape (2,)
        The first path before the first time (-1: none) and whether it was
        swallowed (1) then; updated to the last time's.

    Returns
    -------
    identity : ndarray of int, shape (M,)
        Index of the first path (-1: no path tracked). A tracked first path
        is held (the tracker keeps a path it has) unless a path at least
        ``min_separation`` earlier is tracked and not weak next to a later
        path within ``weak_separation`` (a new first path is found); without
        one the first path is the earliest tracked path or, where that is
        weak next to a later path, the strongest such path (the fit finds
        that one).
    amplitude : ndarray of complex, shape (M,)
        Around an anchor, the first path or, while it is weak next to a later
        path within ``weak_separation`` (swallowed), the strongest such path:
        the sum over the paths closer to the anchor than ``min_separation``,
        or weak next to it and earlier by less than ``weak_separation``, of
        their coefficients times the pulse at their offset from it. A weak
        path after a strong one is left out: it is separated (or leaves the
        strong path's fit alone).
    broken : ndarray of bool, shape (M,)
        Where a held first path stops being swallowed: the tracker separates
        it again and its phase restarts from a new origin.
    anchor : ndarray of int, shape (M,)
        The path whose delay the tracker's fit finds for the first path
        (``amplitude``'s anchor: the first path, or the path swallowing it;
        -1: no path tracked).
    """
    n_paths, n_times = coef.shape
    identity = np.full(n_times, -1, dtype=np.int64)
    amplitude = np.zeros(n_times, dtype=np.complex128)
    broken = np.zeros(n_times, dtype=np.bool_)
    anchors = np.full(n_times, -1, dtype=np.int64)
    centre = (pulse.shape[0] - 1) / 2.0
    per_chip = centre / PULSE_TABLE_SPAN_CHIPS
    first, swallowed = held[0], held[1] == 1
    for m in range(n_times):
        if first >= 0 and tap_snr[first, m] >= survival:
            found = -1
            for p in range(n_paths):
                if (tap_snr[p, m] >= survival and delay_chips[p, m] <= delay_chips[first, m] - min_separation
                        and (found < 0 or delay_chips[p, m] < delay_chips[found, m])
                        and _swallower(p, m, delay_chips, tap_snr, weak, weak_separation) < 0):
                    found = p
            if found >= 0:
                first, swallowed = found, False
        else:
            first, swallowed = -1, False
            for p in range(n_paths):
                if tap_snr[p, m] >= survival and (first < 0 or delay_chips[p, m] < delay_chips[first, m]):
                    first = p
            if first < 0:
                continue
            swallower = _swallower(first, m, delay_chips, tap_snr, weak, weak_separation)
            if swallower >= 0:
                first = swallower
        anchor = _swallower(first, m, delay_chips, tap_snr, weak, weak_separation)
        broken[m] = swallowed and anchor < 0
        swallowed = anchor >= 0
        if anchor < 0:
            anchor = first
        total = 0j
        for q in range(n_paths):
            offset = delay_chips[q, m] - delay_chips[anchor, m]
            if abs(offset) < min_separation or (-weak_separation < offset < 0.0
                                                 and tap_snr[q, m] < weak * tap_snr[anchor, m]):
                position = centre + offset * per_chip
                i = min(max(int(position), 0), pulse.shape[0] - 2)
                frac = position - i
                total += coef[q, m] * (pulse[i] * (1.0 - frac) + pulse[i + 1] * frac)
        identity[m] = first
        amplitude[m] = total
        anchors[m] = anchor
    held[0], held[1] = first, 1 if swallowed else 0
    return identity, amplitude, broken, anchors


def first_path_reference(coef: np.ndarray, delay_chips: np.ndarray, tap_snr: np.ndarray, survival: float,
                         weak: float, min_separation: float, weak_separation: float, pulse: np.ndarray,
                         held: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Plain-numpy twin of :func:`first_path_kernel` (vectorised over the paths, the pulse from the table)."""
    n_paths, n_times = coef.shape
    identity = np.full(n_times, -1, dtype=np.int64)
    amplitude = np.zeros(n_times, dtype=np.complex128)
    broken = np.zeros(n_times, dtype=bool)
    anchors = np.full(n_times, -1, dtype=np.int64)
    x = np.arange(pulse.shape[0]) / ((pulse.shape[0] - 1) / 2.0 / PULSE_TABLE_SPAN_CHIPS) - PULSE_TABLE_SPAN_CHIPS
    first, swallowed = int(held[0]), bool(held[1])
    for m in range(n_times):
        delay, snr = delay_chips[:, m], tap_snr[:, m]
        tracked = snr >= survival
        later = delay[None, :] - delay[:, None]  # [p, q]: how much later q is than p
        weak_next_to = (later > 0.0) & (later < weak_separation) & (snr[:, None] < weak * snr[None, :])

        def swallower(p: int) -> int:
            return int(np.flatnonzero(weak_next_to[p])[np.argmax(snr[weak_next_to[p]])]) if weak_next_to[p].any() \
                else -1

        if first >= 0 and tracked[first]:
            found = np.flatnonzero(tracked & (delay <= delay[first] - min_separation) & ~weak_next_to.any(axis=1))
            if len(found):
                first, swallowed = int(found[np.argmin(delay[found])]), False
        elif tracked.any():
            first, swallowed = int(np.flatnonzero(tracked)[np.argmin(delay[tracked])]), False
            if swallower(first) >= 0:
                first = swallower(first)
        else:
            first, swallowed = -1, False
            continue
        anchor = swallower(first)
        broken[m] = swallowed and anchor < 0
        swallowed = anchor >= 0
        anchor = first if anchor < 0 else anchor
        offset = delay - delay[anchor]
        merged = (np.abs(offset) < min_separation) | ((offset > -weak_separation) & (offset < 0.0)
                                                      & (snr < weak * snr[anchor]))
        identity[m] = first
        amplitude[m] = np.sum(coef[merged, m] * np.interp(offset[merged], x, pulse))
        anchors[m] = anchor
    held[0], held[1] = first, int(swallowed)
    return identity, amplitude, broken, anchors


def _wrapped(phase_rad: np.ndarray) -> np.ndarray:
    """``phase_rad`` wrapped to [-pi, pi)."""
    return (phase_rad + np.pi) % (2.0 * np.pi) - np.pi


def code_error_m(t_s: np.ndarray, snr_db: np.ndarray, config: ObsPathConfig, rng: np.random.Generator) -> np.ndarray:
    """The code range's error at times ``t_s`` (s) on a path of sample SNR ``snr_db`` (dB), m (``ObsPathConfig``)."""
    dt_s = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
    keep = np.exp(-dt_s / config.code_noise_time_s)
    start = keep * rng.standard_normal(1)   # a stationary start: unit variance from the first sample on
    unit = lfilter([np.sqrt(1.0 - keep * keep)], [1.0, -keep], rng.standard_normal(len(t_s)), zi=start)[0]
    with np.errstate(over="ignore"):
        return config.code_noise_m * 10.0 ** ((config.code_noise_snr_db - snr_db) / 20.0) * unit


def simulate_obs_paths(scenario: Scenario, truth: Track, config: ObsPathConfig = ObsPathConfig(),
                       block_samples: int = 8192) -> ObsPaths:
    """The path tracker's first-path range and tower differences for a truth track (module docstring).

    Parameters
    ----------
    scenario : Scenario
        Towers (``sites``), channel, receiver (C/N, clock) and walk (start-still time); its ``seed`` seeds
        the channel and the clock as at every other level.
    truth : Track
        True trajectory, starting at the capture start with the walker standing at P0.
    config : ObsPathConfig
    block_samples : int
        Output samples computed at a time (memory only: the output does not depend on it).

    Returns
    -------
    ObsPaths
        On the grid of :func:`sim.obs_range.simulate_obs_range` with the same ``decimation``.
    """
    if config.decimation < 1 or block_samples < 1:
        raise ValueError(f"decimation and block_samples must be >= 1, got {config.decimation}, {block_samples}")
    tower = scenario.tower
    mode = PnMode.parse(tower.pn_mode)
    t_s = observation_times_s(scenario, truth, config.decimation)
    cal_end = truth.t_s[0] + max(scenario.walk.start_still_s - config.calibration_guard_s, 0.0)
    cal = int(np.searchsorted(t_s, cal_end))
    if cal < 2 or cal >= len(t_s):
        raise ValueError(f"simulate_obs_paths: the f_s window ({cal_end - truth.t_s[0]:.1f} s) must lie inside the "
                         f"track ({truth.t_s[-1] - truth.t_s[0]:.1f} s)")
    channel = Channel(scenario, truth, np.random.default_rng([scenario.seed, STREAM_CHANNEL, 0, 1]))
    # Per-sample SNR of a path (signal relative to a unit-power data symbol through the unobstructed path, as
    # sim.obs_range), and the header correlation's gain to the per-frame tap SNR the tracker's threshold sees.
    noise_var = noise_variance(scenario)
    header_gain = mode.value.header_power_ratio * mode.value.period
    pulse = pulse_gain_table()
    survival = 10.0 ** (config.survival_snr_db / 10.0)
    weak = 10.0 ** (-config.weak_power_db / 10.0)
    n_towers = channel.num_towers
    identity = np.full((n_towers, len(t_s)), -1, dtype=np.int64)
    amplitude = np.zeros((n_towers, len(t_s)), dtype=np.complex128)
    # The tracker's view of each path's tap SNR: an exponential average over power_time_s, carried across blocks.
    alpha = min(1.0, (t_s[1] - t_s[0]) / config.power_time_s)
    smoothing = None
    held = np.tile(np.array([-1, 0], dtype=np.int64), (n_towers, 1))
    broken = np.zeros((n_towers, len(t_s)), dtype=bool)
    # c x the delay of each tower's first path as the fit finds it, the tower's transmit delay offset included
    # (a receiver sees no other; the fusion takes the offsets out, fusion.transmit_delays).
    path_delay_m = np.full((n_towers, len(t_s)), np.nan)
    for lo in range(0, len(t_s), block_samples):
        hi = min(lo + block_samples, len(t_s))
        state = channel.state(t_s[lo:hi])
        instant = np.abs(state.coef) ** 2 * header_gain / noise_var
        if smoothing is None:
            smoothing = instant[:, :1] * (1.0 - alpha)
        seen, smoothing = lfilter([alpha], [1.0, alpha - 1.0], instant, axis=1, zi=smoothing)
        for k in range(n_towers):
            rows = channel.path_tower == k
            identity[k, lo:hi], amplitude[k, lo:hi], broken[k, lo:hi], anchor = first_path_kernel(
                state.coef[rows], state.delay_s[rows] * gb20600.SYMBOL_RATE_HZ, seen[rows], survival, weak,
                config.min_separation_chips, config.weak_separation_chips, pulse, held[k])
            found = anchor >= 0
            path_delay_m[k, lo:hi][found] = SPEED_OF_LIGHT_MPS * state.delay_s[rows][anchor[found],
                                                                                     np.flatnonzero(found)]

    # Each tower's first-path range: its phase steps integrated where the first path stays the same path.
    wavelength_m = SPEED_OF_LIGHT_MPS / tower.carrier_hz
    reported = (identity >= 0) & (t_s >= truth.t_s[0] + config.confirm_s)
    same = np.concatenate([np.zeros((n_towers, 1), bool), reported[:, 1:] & reported[:, :-1]
                           & (identity[:, 1:] == identity[:, :-1])], axis=1) & ~broken
    steps = np.zeros(amplitude.shape)
    steps[:, 1:] = _wrapped(np.angle(amplitude[:, 1:]) - np.angle(amplitude[:, :-1]))
    geometric_m = -wavelength_m / (2.0 * np.pi) * np.cumsum(np.where(same, steps, 0.0), axis=1)
    tap_snr = np.maximum(np.abs(amplitude) ** 2 * header_gain / noise_var, 1e-30)
    noise_rng = np.random.default_rng([scenario.seed, _STREAM_PATH_NOISE, config.noise_draw])
    phase_noise_m = (wavelength_m / (2.0 * np.pi) * noise_rng.standard_normal(amplitude.shape)
                     / np.sqrt(2.0 * tap_snr))
    # The receiver clock (c x(t), common to every path) less f_s, its mean rate over the standstill.
    oscillator = scenario_oscillator(scenario, float(truth.t_s[-1]) + 1.0, scenario.seed, STREAM_CLOCK)
    clock_m = SPEED_OF_LIGHT_MPS * (oscillator.time_error_s(t_s) - oscillator.time_error_s(t_s[:1]))
    clock_m -= clock_m[cal] / (t_s[cal] - t_s[0]) * (t_s - t_s[0])
    snr_db = 10.0 * np.log10(tap_snr / header_gain)
    # Each tower's code error; tower 0's stream is keyed without a tower index, as with a single tower.
    code_error = np.stack([code_error_m(t_s, snr_db[k], config, np.random.default_rng(
        [scenario.seed, _STREAM_CODE_NOISE, config.noise_draw, *([k] if k else [])])) for k in range(n_towers)])
    code_m = path_delay_m[0] + clock_m + code_error[0]

    usable = np.ones(len(t_s), dtype=bool)
    first = PathRangeSeries.from_runs(t_s, geometric_m[0] + phase_noise_m[0] + clock_m, identity[0], reported[0],
                                      usable, snr_db[0], broken[0], code_m)
    differences = {}
    for k in range(1, n_towers):
        both = reported[0] & reported[k]
        start = int(np.argmax(both)) if both.any() else 0
        difference_m = geometric_m[k] - geometric_m[0] + phase_noise_m[k] - phase_noise_m[0]
        pair = identity[0] * channel.num_paths + identity[k]
        code_difference_m = path_delay_m[k] + code_error[k] - path_delay_m[0] - code_error[0]
        differences[k] = PathRangeSeries.from_runs(t_s, difference_m - difference_m[start], pair, both, usable,
                                                   np.fmin(snr_db[0], snr_db[k]), broken[0] | broken[k],
                                                   code_difference_m)
    return ObsPaths(first_path=first, differences=differences)
