"""Receiver front end: anti-alias filter, tuner CFO, the SDR's impairments, thermal noise, AGC and quantisation.

Order (sim.rf applies it to the noise-free multipath signal):

0. **Anti-alias filter.** An SDR low-pass filters the channel before it
   samples it at ``fs``: a capture below the symbol rate (an RTL-SDR at 2.4
   Msps) records the band-limited centre of the channel, not the whole
   7.56 MHz band folded onto itself. The filter passes
   ``|f| <= ANTI_ALIAS_PASSBAND * fs / 2`` and stops ``|f| >= fs / 2`` (by
   ``ANTI_ALIAS_STOPBAND_DB``), a Kaiser-windowed sinc. It is linear and
   time-invariant and the channel changes slowly, so it is applied to the
   transmit pulse (:meth:`FrontEnd.pulse`): every path's shaped signal then
   comes out filtered, at the cost of a longer pulse. The tuner CFO and
   Doppler (tens of kHz at most) shift the signal against the filter by a
   small fraction of its passband, which this leaves out. At the symbol rate
   and above the filter passes the whole channel and the pulse is used as it
   is (at exactly 7.56 Msps the SRRC's 5 % excess band folds onto the band
   edges, which the receiver's model of the body, the whole Nyquist band,
   takes in).
0a. **Off-centre tuning** (``receiver.tuning_offset_hz``, capture centre
   minus channel centre): the channel lies at ``-tuning_offset_hz`` in the
   capture, and the anti-alias filter, centred on the capture, cuts what of
   the shifted channel lies outside the recorded band. The pulse trick of
   step 0 does not apply (the filter is not centred on the channel), so the
   noise-free signal is synthesised on the channel at ``factor * fs``
   (:func:`tuning_factor`, the whole channel and its shift without aliasing),
   multiplied by ``exp(-j 2 pi tuning_offset_hz m / (factor fs))`` (``m`` the
   absolute sample index at that rate: receiver time, so chunking does not
   matter), low-pass filtered (the step-0 filter's passband and stopband, a
   Kaiser-windowed FIR, zero phase) and decimated to ``fs``
   (:func:`tune_kernel`). The LO runs on the receiver's clock, so the shift is
   exact in receiver time and the clock's carrier-phase error is the
   channel's. At 0 none of this runs.
1. **Tuner CFO** ``exp(j 2 pi bulk_cfo_hz t)`` (t true time), a constant
   scenario option separate from the reference-oscillator offset (it is folded
   into the common phase of ``transmitter.multipath_kernel``, see
   :meth:`FrontEnd.tuner_phase_rad`).
2. **LO phase noise** (``receiver.phase_noise_dbc_hz``, the SSB profile
   ``L(f)``, dBc/Hz at offsets f, log-log interpolated and flat outside the
   given points): the signal (tuned and filtered) is multiplied by
   ``exp(j phi(n))``. A PLL-locked LO's phase is stationary and Gaussian, so
   ``phi`` is white noise shaped to the one-sided PSD ``S_phi(f) = 2 *
   10 ** (L(f) / 10)`` rad^2/Hz (two-sided ``10 ** (L / 10)``) by
   :class:`PhaseNoise`: a sum of stages at rates ``fs / 8 ** k``, each a
   Kaiser-windowed FIR designed from the profile over its band (a band of
   about a factor 8 in offset, raised-cosine crossovers an octave wide, the
   last stage down to DC), the slower stages interpolated to ``fs``. Each
   stage's white noise is drawn per fixed block of ``PHASE_DRAW_BLOCK``
   absolute indices at its rate from ``default_rng([seed, stream_id, block,
   2])`` (stage 0; ``[seed, stream_id, block, 2, stage]`` below; the blocks
   of history before sample 0 take the odd numbers, the others the even
   ones) and the phase is computed per fixed block of ``PHASE_BLOCK``
   absolute samples from the draws it needs (its filters' history
   included), so any chunking, order or thread gives the same phase. The
   thermal noise that follows is not rotated.
3. **AWGN** at ``receiver.cn_db``: carrier power of the unobstructed direct
   path over the noise power in the 7.56 MHz signal band. The noise is white at
   the output rate ``fs``, so its total power is ``N * fs / 7.56 MHz``.
   It is drawn per fixed block of ``NOISE_BLOCK`` absolute sample indices from
   ``default_rng([seed, stream_id, block, 1])``, so any chunking gives the
   same noise.
4. **IQ imbalance** (``receiver.iq_gain_db`` ``G``, ``receiver.iq_phase_deg``
   ``phi``): ``y = I + j g (Q cos(phi) - I sin(phi))`` with ``g = 10 ** (G /
   20)``, i.e. ``y = mu z + nu conj(z)``, ``mu = (1 + g exp(-j phi)) / 2``,
   ``nu = (1 - g exp(j phi)) / 2`` (:func:`iq_imbalance`; the receiver's
   estimator uses the same convention).
5. **LO leakage** (``receiver.lo_leakage_dbc``, ``receiver.lo_leakage_phase_deg``):
   a constant at the capture's DC whose power is ``lo_leakage_dbc`` relative
   to the capture's signal power (the direct path after the anti-alias
   filter, :attr:`FrontEnd.signal_power_passed`). The LO's own phase noise
   cancels in the leak (it mixes with itself), so the tone is clean.
6. **IQ conjugation** (``receiver.iq_conjugate``), which flips the sign of
   every frequency (and of the leakage tone's phase).
7. **AGC**: one fixed gain for the whole capture, putting the expected per-rail
   RMS of (direct-path signal after the anti-alias filter + noise)
   ``receiver.agc_backoff_db`` below the quantiser's full scale (+-1 after
   ``dtmbnav_core.iqformat.decode``), times gain steps
   (``receiver.agc_step_db``, ``receiver.agc_steps_per_minute``): at Poisson
   times from the scenario's first sample (receiver clock) the gain steps
   up or down by ``agc_step_db`` (random sign, turned back at
   ``AGC_MAX_STEPS`` steps from nominal), instantaneously at an absolute
   sample index (:func:`agc_schedule`, ``default_rng([seed, stream_id, 4])``).
8. **Quantisation** with clipping to ``cu8``/``ci8``/``ci16``/``cf32``
   (``dtmbnav_core.iqformat.encode``); with ``receiver.adc_bits`` or
   ``receiver.adc_dc_lsb`` an ADC of ``adc_bits`` bits spans the format's
   full scale (``2 ** adc_bits`` levels: a 12-bit ADC in ci16 moves in steps
   of 16 codes, in cf32 of ``2 / 2 ** 12``), its DC ``adc_dc_lsb`` (I, Q; ADC
   LSB) added before rounding, levels about the format's zero code (the
   ``rtl-sdr`` device presets of :mod:`sim.devices` centre their cu8 bytes
   below 128 this way), clipped at full scale (:func:`adc_quantise`).
9. **Dropped samples** (``receiver.drops_per_minute``,
   ``receiver.drop_samples``): runs of samples lost between the ADC and the
   file (USB overflows). At Poisson times from the scenario's first sample
   (each run's gap counted from the end of the one before, so runs never
   overlap) a run of a log-uniform whole number of samples in
   ``drop_samples`` is left out of the file (:func:`drop_schedule`,
   ``default_rng([seed, stream_id, 3])``). Everything above stays indexed by
   the receiver's sample clock; only the written stream omits the runs
   (:meth:`sim.rf.CaptureGenerator.drops`).

With every impairment key at its default (:data:`IMPAIRMENT_DEFAULTS`) steps
2, 4, 5 and 9, the gain steps of step 7 and the ADC of step 8 run no code:
the capture is bit for bit the one the scenario gives without the keys.
:func:`check_impairments` validates the keys.
"""

from __future__ import annotations

import math
import threading
from numbers import Real

import numpy as np
from numba import njit
from scipy import fft as sp_fft
from scipy.signal import firwin, firwin2, kaiserord

from dtmbnav_core import gb20600
from dtmbnav_core.iqformat import IqFormat, encode, get_format, interleave
from sim.frames import FrameConfig
from sim.scenario import FrontEndConfig
from sim.transmitter import PULSE_SPAN, PulseTable, pulse_table

#: Samples per independently seeded noise block.
NOISE_BLOCK = 1 << 16
#: Passband edge of the anti-alias filter, fraction of the output Nyquist frequency fs / 2.
ANTI_ALIAS_PASSBAND = 0.8
#: Attenuation of the anti-alias filter from fs / 2 on, dB.
ANTI_ALIAS_STOPBAND_DB = 60.0

#: The impairment keys of ``[receiver]`` (module steps 2, 4, 5, 7, 8, 9) at their defaults: nothing impaired.
IMPAIRMENT_DEFAULTS = {name: getattr(FrontEndConfig(), name) for name in (
    "lo_leakage_dbc", "lo_leakage_phase_deg", "iq_gain_db", "iq_phase_deg", "adc_bits", "adc_dc_lsb",
    "agc_step_db", "agc_steps_per_minute", "drops_per_minute", "drop_samples", "phase_noise_dbc_hz")}
#: Bits of each format's own ADC (what ``adc_bits`` defaults to; for cf32 the float32 significand).
FORMAT_BITS = {"cu8": 8, "ci8": 8, "ci16": 16, "cf32": 24}
#: Furthest the AGC's gain steps wander from nominal, steps (a step beyond turns back).
AGC_MAX_STEPS = 3
#: Events drawn per call to the generator of the AGC and drop schedules (a fixed size, so that a schedule
#: drawn to a later end begins with the same events).
SCHEDULE_BATCH = 256

#: Samples at fs per block of phase noise computed whole (module step 2).
PHASE_BLOCK = 1 << 16
#: White-noise draws per independently seeded block of one phase-noise stage.
PHASE_DRAW_BLOCK = 1 << 14
#: Rate ratio of successive phase-noise stages (stage k runs at ``fs / PHASE_STAGE_RATIO ** k``).
PHASE_STAGE_RATIO = 8
#: Taps of each stage's shaping FIR (odd: symmetric about the centre tap); it resolves a stage's lowest
#: offset (``rate / PHASE_STAGE_RATIO ** 2``) with about 64 bins.
PHASE_FIR_TAPS = 4095
#: Points of the frequency grid the shaping FIRs are sampled from (several times the taps: little time aliasing).
PHASE_DESIGN_GRID = 1 << 14
#: Kaiser beta of the shaping FIRs' window and of the interpolator (sidelobes over 100 dB down: the images and
#: leakage of a strong close-in stage stay below a profile that falls by tens of dB to the faster stages' bands).
PHASE_KAISER_BETA = 12.0
#: Taps (input samples) of the interpolator from one stage's rate to the next.
PHASE_INTERP_TAPS = 16
#: Most stages below fs; offsets below the last stage's resolution are taken as flat.
PHASE_MAX_STAGES = 10


def anti_alias_pulse(table: PulseTable, sample_rate_hz: float) -> PulseTable:
    """The transmit pulse seen through the front end's anti-alias filter at ``sample_rate_hz`` (module step 0).

    Returns ``table`` itself at the symbol rate and above. Below, the pulse
    convolved with a Kaiser-windowed sinc low-pass (cutoff midway between
    the passband edge and fs / 2, length for the stopband attenuation over
    that transition), tabulated by :func:`sim.transmitter.pulse_table` over a
    span longer by half the filter (its ``lowpass``, which
    :func:`sim.transmitter.pulse_spectrum` also applies, so the block
    synthesis and its exact twin shape with the same filtered pulse).
    """
    rs = gb20600.SYMBOL_RATE_HZ
    if sample_rate_hz >= rs:
        return table
    osr = table.oversampling
    # fs / 2 as a fraction of the table grid's Nyquist frequency (osr / 2 cycles per symbol).
    edge = sample_rate_hz / (rs * osr)
    numtaps, beta = anti_alias_order(edge)
    half = -(-numtaps // (2 * osr))                                      # half length, whole symbols
    # pulse_table's lowpass has unit gain at DC in the table's units: taps summing to osr.
    h = osr * anti_alias_fir(2 * half * osr + 1, beta, edge)
    return pulse_table(table.span, osr, table.rolloff, table.taper, lowpass=h)


def anti_alias_order(edge: float) -> tuple[int, float]:
    """Kaiser length and beta of the anti-alias filter (module step 0) at a rate of ``fs / edge``.

    Parameters
    ----------
    edge : float
        ``fs / 2`` as a fraction of the Nyquist frequency of the rate the filter runs at (at most 1).

    Returns
    -------
    numtaps : int
        Fewest taps for ``ANTI_ALIAS_STOPBAND_DB`` over the transition ``ANTI_ALIAS_PASSBAND * fs / 2 .. fs / 2``
        (:func:`scipy.signal.kaiserord`).
    beta : float
        Kaiser window parameter.
    """
    return kaiserord(ANTI_ALIAS_STOPBAND_DB, (1.0 - ANTI_ALIAS_PASSBAND) * edge)


def anti_alias_fir(numtaps: int, beta: float, edge: float) -> np.ndarray:
    """Taps of the anti-alias filter (module step 0): a Kaiser-windowed sinc cut midway between the passband edge
    and ``fs / 2``, unit gain at DC.

    Parameters
    ----------
    numtaps : int
        Length, odd (:func:`anti_alias_order` gives the least).
    beta : float
        Kaiser window parameter (:func:`anti_alias_order`).
    edge : float
        ``fs / 2`` as a fraction of the filter rate's Nyquist frequency (:func:`anti_alias_order`).

    Returns
    -------
    float64 ndarray
        ``numtaps`` symmetric taps summing to 1 (firwin's ``scale``: unit gain at DC).
    """
    return firwin(numtaps, 0.5 * (1.0 + ANTI_ALIAS_PASSBAND) * edge, window=("kaiser", beta))


def tuning_factor(sample_rate_hz: float, tuning_offset_hz: float) -> int:
    """Integer ``factor`` of the synthesis rate ``factor * fs`` of a capture tuned ``tuning_offset_hz`` off.

    At least 2, and enough that the shifted channel (half-width 4 MHz with
    the SRRC's excess band) wraps, if at all, only into the anti-alias
    filter's stopband, and that the synthesis rate is at least the symbol
    rate (the pulse is then the SRRC itself).
    """
    half_band = 0.5 * gb20600.SYMBOL_RATE_HZ * 1.06
    need = 0.5 * sample_rate_hz + abs(tuning_offset_hz) + half_band
    return max(2, int(np.ceil(need / sample_rate_hz)), int(np.ceil(gb20600.SYMBOL_RATE_HZ / sample_rate_hz)))


def tuning_filter(factor: int) -> np.ndarray:
    """Taps of the off-centre anti-alias filter at ``factor * fs`` (odd length, symmetric, unit DC gain).

    Passband ``ANTI_ALIAS_PASSBAND * fs / 2``, stopband from ``fs / 2`` by
    ``ANTI_ALIAS_STOPBAND_DB`` (frequencies as fractions of the synthesis
    rate's Nyquist frequency: ``1 / factor`` is ``fs / 2``).
    """
    numtaps, beta = anti_alias_order(1.0 / factor)
    return anti_alias_fir(numtaps | 1, beta, 1.0 / factor)


@njit(cache=True, nogil=True)
def tune_kernel(x: np.ndarray, first_index: int, factor: int, taps: np.ndarray, cycles_per_sample: float,
                out: np.ndarray) -> None:
    """Shift, filter and decimate: ``out[i] = sum_k taps[k] y[factor i + k]``, ``y[j] = x[j] exp(-j 2 pi c (first_index + j))``.

    Parameters
    ----------
    x : complex128 ndarray
        Noise-free samples at ``factor * fs``, ``x[j]`` being absolute sample
        ``first_index + j``; ``len(x) >= factor * (len(out) - 1) + len(taps)``.
    first_index : int
        Absolute index (at ``factor * fs``) of ``x[0]``.
    factor : int
        Decimation factor.
    taps : float64 ndarray
        Symmetric FIR (:func:`tuning_filter`).
    cycles_per_sample : float
        ``tuning_offset_hz / (factor * fs)``.
    out : complex128 ndarray
        Output at ``fs``.
    """
    n_in = factor * (out.shape[0] - 1) + taps.shape[0]
    y = np.empty(n_in, dtype=np.complex128)
    for j in range(n_in):
        # Phase from the absolute index alone, reduced to [0, 1) cycles in float64.
        cycles = ((first_index + j) * cycles_per_sample) % 1.0
        y[j] = x[j] * complex(np.cos(2.0 * np.pi * cycles), -np.sin(2.0 * np.pi * cycles))
    for i in range(out.shape[0]):
        acc = 0j
        base = factor * i
        for k in range(taps.shape[0]):
            acc += taps[k] * y[base + k]
        out[i] = acc


def tuned_band_share(sample_rate_hz: float, tuning_offset_hz: float) -> float:
    """Share of the channel's 7.56 MHz band that the off-centre anti-alias filter passes (its cutoff midway)."""
    half = 0.5 * gb20600.SYMBOL_RATE_HZ
    cutoff = 0.25 * (1.0 + ANTI_ALIAS_PASSBAND) * sample_rate_hz
    low, high = max(-tuning_offset_hz - half, -cutoff), min(-tuning_offset_hz + half, cutoff)
    return max(high - low, 0.0) / gb20600.SYMBOL_RATE_HZ


def pulse_energy(table: PulseTable) -> float:
    """Energy of a tabulated pulse (symbols as the time unit); 1 for :func:`sim.transmitter.pulse_table`."""
    return float(np.sum(table.polyphase[:-1] ** 2) / table.oversampling)


def mean_signal_power(config: FrameConfig) -> float:
    """Mean power of the shaped signal of an unobstructed unit-gain path.

    Header symbols have power ``header_power_ratio``; the body is unit-power
    data plus 36 SI symbols at ``si_power_db`` relative to data. With a
    unit-energy pulse the shaped signal has the mean symbol power.
    """
    mode = config.pn_mode.value
    body = (gb20600.DATA_LENGTH + gb20600.SI_LENGTH * 10.0 ** (config.si_power_db / 10.0)) / gb20600.BODY_LENGTH
    return (mode.header_length * mode.header_power_ratio + gb20600.BODY_LENGTH * body) / mode.frame_length


# --------------------------------------------------------------------------------------- impairments


def _finite(value, key: str, what: str = "a finite number") -> float:
    """``value`` as a float, or a ValueError naming ``receiver.<key>``."""
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value):
        raise ValueError(f"scenario receiver.{key} must be {what}, got {value!r}")
    return float(value)


def _whole(value, key: str, what: str) -> int:
    """``value`` as an int when it is a whole number, or a ValueError naming ``receiver.<key>``."""
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value) or value != int(value):
        raise ValueError(f"scenario receiver.{key} must be {what}, got {value!r}")
    return int(value)


def _pair(value, key: str, what: str) -> tuple:
    """The two items of a list, or a ValueError naming ``receiver.<key>``."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise ValueError(f"scenario receiver.{key} must be {what}, got {value!r}")
    return tuple(value)


def phase_noise_profile(rows, key: str = "phase_noise_dbc_hz") -> tuple[np.ndarray, np.ndarray]:
    """Offsets (Hz) and SSB levels (dBc/Hz) of a phase-noise profile ``[[offset_hz, dBc/Hz], ...]``.

    Raises
    ------
    ValueError
        Naming ``receiver.<key>``: no rows, a row that is not two finite
        numbers, offsets not positive and increasing.
    """
    what = "a list of [offset_hz, dBc/Hz] rows with positive, increasing offsets"
    if isinstance(rows, (str, bytes)) or not hasattr(rows, "__len__") or len(rows) == 0:
        raise ValueError(f"scenario receiver.{key} must be {what}, got {rows!r}")
    offsets, levels = [], []
    for i, row in enumerate(rows):
        offset, level = _pair(row, f"{key}[{i}]", "a row [offset_hz, dBc/Hz]")
        offsets.append(_finite(offset, f"{key}[{i}][0]", "a finite offset in Hz"))
        levels.append(_finite(level, f"{key}[{i}][1]", "a finite level in dBc/Hz"))
    offsets_hz = np.array(offsets)
    if offsets_hz[0] <= 0.0 or np.any(np.diff(offsets_hz) <= 0.0):
        raise ValueError(f"scenario receiver.{key} must be {what}; offsets {offsets}")
    return offsets_hz, np.array(levels)


def check_impairments(receiver: FrontEndConfig, sample_format: str | IqFormat) -> None:
    """Validate the impairment keys of ``[receiver]`` (:data:`IMPAIRMENT_DEFAULTS`) for a capture format.

    Raises
    ------
    ValueError
        Naming the key and the value, e.g. ``scenario receiver.adc_bits
        must be 2..16 for ci16, got 20``.
    """
    fmt = sample_format if isinstance(sample_format, IqFormat) else get_format(sample_format)
    if receiver.lo_leakage_dbc is not None:
        _finite(receiver.lo_leakage_dbc, "lo_leakage_dbc", "a finite power in dBc (or left out: no leakage)")
    for key in ("lo_leakage_phase_deg", "iq_gain_db", "agc_step_db"):
        _finite(getattr(receiver, key), key)
    phase = _finite(receiver.iq_phase_deg, "iq_phase_deg", "a finite angle in degrees")
    if not abs(phase) < 90.0:
        raise ValueError(f"scenario receiver.iq_phase_deg must be within (-90, 90) degrees, got {phase!r}")
    width = FORMAT_BITS[fmt.name]
    if receiver.adc_bits is not None:
        what = f"2..{width} for {fmt.name}"
        if _whole(receiver.adc_bits, "adc_bits", what) not in range(2, width + 1):
            raise ValueError(f"scenario receiver.adc_bits must be {what}, got {receiver.adc_bits!r}")
    for i, dc in enumerate(_pair(receiver.adc_dc_lsb, "adc_dc_lsb", "[I, Q] DC in ADC LSB")):
        _finite(dc, f"adc_dc_lsb[{i}]", "a finite DC in ADC LSB")
    for key in ("agc_steps_per_minute", "drops_per_minute"):
        if _finite(getattr(receiver, key), key, "a finite rate per minute") < 0.0:
            raise ValueError(f"scenario receiver.{key} must be >= 0 (events per minute), got {getattr(receiver, key)!r}")
    what = "two positive whole numbers [shortest, longest] of samples"
    low, high = (_whole(n, "drop_samples", what) for n in _pair(receiver.drop_samples, "drop_samples", what))
    if not 0 < low <= high:
        raise ValueError(f"scenario receiver.drop_samples must be {what}, shortest first, got {receiver.drop_samples!r}")
    if receiver.phase_noise_dbc_hz is not None:
        phase_noise_profile(receiver.phase_noise_dbc_hz)


def iq_imbalance(z: np.ndarray, gain_db: float, phase_deg: float) -> np.ndarray:
    """IQ imbalance (module step 4): ``I + j g (Q cos(phi) - I sin(phi))`` of ``z = I + j Q``.

    Parameters
    ----------
    z : complex ndarray
        Ideal samples.
    gain_db : float
        Q rail's gain relative to I, dB (``g = 10 ** (gain_db / 20)``).
    phase_deg : float
        Quadrature error ``phi``, degrees.

    Returns
    -------
    complex128 ndarray
        ``mu z + nu conj(z)``, ``mu = (1 + g exp(-j phi)) / 2``, ``nu = (1 - g exp(j phi)) / 2``.
    """
    g, phi = 10.0 ** (gain_db / 20.0), math.radians(phase_deg)
    out = np.empty(np.shape(z), dtype=np.complex128)
    out.real = z.real
    out.imag = (g * math.cos(phi)) * z.imag - (g * math.sin(phi)) * z.real
    return out


def _poisson_gaps(rng: np.random.Generator, mean_gap: float):
    """Endless (gap, uniform) pairs: exponential gaps of mean ``mean_gap`` and a uniform [0, 1) per event.

    Drawn in batches of fixed size, so a schedule drawn further begins with the same events.
    """
    while True:
        gaps = rng.exponential(mean_gap, SCHEDULE_BATCH)
        uniform = rng.random(SCHEDULE_BATCH)
        yield from zip(gaps.tolist(), uniform.tolist())


def agc_schedule(step_db: float, steps_per_minute: float, sample_rate_hz: float, stop_sample: int,
                 seed: int, stream_id: int) -> tuple[np.ndarray, np.ndarray]:
    """The AGC's gain steps before absolute sample ``stop_sample`` (module step 7).

    Poisson times (mean ``60 / steps_per_minute`` s) from the scenario's
    first sample; each steps up or down with equal chance, a step that would
    leave ``+-AGC_MAX_STEPS`` going the other way. Drawn from
    ``default_rng([seed, stream_id, 4])``, the same events for any
    ``stop_sample`` (a segment sees the full capture's steps).

    Returns
    -------
    sample : int64 ndarray
        Absolute sample index from which each step's gain holds (ascending).
    level : int64 ndarray
        Steps from nominal from that sample on (the gain is ``level * step_db`` dB).
    """
    if step_db == 0.0 or steps_per_minute <= 0.0 or stop_sample <= 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    samples, levels, level, t = [], [], 0, 0.0
    for gap, uniform in _poisson_gaps(np.random.default_rng([seed, stream_id, 4]),
                                      60.0 / steps_per_minute * sample_rate_hz):
        t += gap
        index = math.ceil(t)
        if index >= stop_sample:
            break
        step = 1 if uniform < 0.5 else -1
        if abs(level + step) > AGC_MAX_STEPS:
            step = -step
        level += step
        samples.append(index)
        levels.append(level)
    return np.array(samples, dtype=np.int64), np.array(levels, dtype=np.int64)


def drop_schedule(drops_per_minute: float, drop_samples: tuple[int, int], sample_rate_hz: float,
                  stop_sample: int, seed: int, stream_id: int) -> tuple[np.ndarray, np.ndarray]:
    """Runs of dropped samples starting before absolute sample ``stop_sample`` (module step 9).

    Each run starts an exponential gap (mean ``60 / drops_per_minute`` s)
    after the end of the one before (the first after sample 0) and lasts a
    log-uniform whole number of samples in ``drop_samples``. Drawn from
    ``default_rng([seed, stream_id, 3])``, the same runs for any
    ``stop_sample``.

    Returns
    -------
    first : int64 ndarray
        Absolute index (receiver clock) of each run's first lost sample, ascending.
    count : int64 ndarray
        Samples lost (a run may reach past ``stop_sample``).
    """
    if drops_per_minute <= 0.0 or stop_sample <= 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    low, high = int(drop_samples[0]), int(drop_samples[1])
    log_low, log_span = math.log(low), math.log(high + 1.0) - math.log(low)
    firsts, counts, resume = [], [], 0.0
    for gap, uniform in _poisson_gaps(np.random.default_rng([seed, stream_id, 3]),
                                      60.0 / drops_per_minute * sample_rate_hz):
        first = math.ceil(resume + gap)
        if first >= stop_sample:
            break
        count = min(max(int(math.exp(log_low + uniform * log_span)), low), high)
        firsts.append(first)
        counts.append(count)
        resume = float(first + count)
    return np.array(firsts, dtype=np.int64), np.array(counts, dtype=np.int64)


def adc_quantise(samples: np.ndarray, fmt: str | IqFormat, bits: int | None, dc_lsb) -> np.ndarray:
    """Interleaved rails of an ADC of ``bits`` bits with DC ``dc_lsb`` recorded in format ``fmt`` (module step 8).

    The ADC's ``2 ** bits`` levels span the format's full scale (+-1), one
    LSB being ``2 * scale / 2 ** bits`` codes, centred on the code the format
    gives 0 (``encode`` of 0: 128 in cu8); the DC (I, Q; LSB) is added before
    rounding to the nearest level and clipping to ``-2 ** (bits - 1) ..
    2 ** (bits - 1) - 1`` levels. cf32 without ``bits`` is not rounded (its
    DC in LSB of a ``FORMAT_BITS`` ADC).

    Parameters
    ----------
    samples : complex ndarray
        Full scale 1.
    fmt : str or IqFormat
    bits : int or None
        ADC resolution; None: the format's width (:data:`FORMAT_BITS`).
    dc_lsb : pair of float
        DC of the I and Q rails, ADC LSB.

    Returns
    -------
    numpy.ndarray
        Rails (I, Q, ...) of the format's storage dtype.

    Raises
    ------
    ValueError
        NaN or inf in the input.
    """
    fmt = fmt if isinstance(fmt, IqFormat) else get_format(fmt)
    rails = interleave(samples, fmt)
    levels = 2.0 ** (FORMAT_BITS[fmt.name] if bits is None else int(bits))
    lsb = 2.0 / levels                                   # full scale per LSB
    rails *= 1.0 / lsb                                   # a power of two: exact
    rails[0::2] += float(dc_lsb[0])
    rails[1::2] += float(dc_lsb[1])
    if fmt.is_integer or bits is not None:
        np.clip(np.rint(rails, out=rails), -levels / 2.0, levels / 2.0 - 1.0, out=rails)
    # The format's zero code as encode writes it (its offset: an integer in every integer format).
    return (rails * (lsb * fmt.scale) + fmt.offset).astype(fmt.dtype)


# --------------------------------------------------------------------------------------- phase noise


def _crossover(f_hz: np.ndarray, edge_hz: float) -> np.ndarray:
    """0 below ``edge / sqrt 2``, 1 above ``edge * sqrt 2``, a raised cosine in log frequency between."""
    x = np.clip(np.log2(np.maximum(f_hz, 1e-300) / edge_hz), -0.5, 0.5)
    return 0.5 + 0.5 * np.sin(np.pi * x)


def interpolator_table(ratio: int, taps: int, beta: float) -> np.ndarray:
    """Polyphase taps, ``(ratio, taps)``, of a Kaiser-windowed sinc interpolating by ``ratio``.

    Row ``p`` gives output ``n = ratio m + p`` (time ``m + p / ratio`` in
    input samples) from inputs ``m - taps / 2 + 1 .. m + taps / 2``; each row
    sums to 1 (unit gain at DC). The cutoff is the input's Nyquist frequency.
    """
    # Not firwin: scipy builds no polyphase table, and firwin's window spans its taps' centres, not +-taps / 2.
    p = np.arange(ratio)[:, None] / ratio
    x = np.arange(taps)[None, :] - (taps // 2 - 1) - p                   # input samples from the output instant
    window = np.i0(beta * np.sqrt(np.clip(1.0 - (x / (taps / 2.0)) ** 2, 0.0, None))) / np.i0(beta)
    table = np.sinc(x) * window
    return table / table.sum(axis=1, keepdims=True)


@njit(cache=True, nogil=True)
def interpolate_add_kernel(low: np.ndarray, phase: int, table: np.ndarray, out: np.ndarray) -> None:
    """``out[i] += sum_j table[p, j] low[m_i + j]``: interpolate a slower stage onto ``out`` and add it.

    Parameters
    ----------
    low : float64 ndarray
        The slower stage; ``low[0]`` is the first tap of ``out[0]``.
    phase : int
        Polyphase row ``p`` of ``out[0]``; ``p`` steps by one per output and
        ``m_i`` by one each time ``p`` wraps.
    table : float64 ndarray
        :func:`interpolator_table`.
    out : float64 ndarray
        Faster stage, added to in place.
    """
    ratio, taps = table.shape
    base = 0
    p = phase
    for i in range(out.shape[0]):
        acc = 0.0
        for j in range(taps):
            acc += table[p, j] * low[base + j]
        out[i] += acc
        p += 1
        if p == ratio:
            p = 0
            base += 1


@njit(cache=True, nogil=True)
def rotate_kernel(z: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """``z * exp(j phase)`` (complex128), in one pass."""
    out = np.empty(z.shape[0], dtype=np.complex128)
    for i in range(z.shape[0]):
        out[i] = z[i] * complex(np.cos(phase[i]), np.sin(phase[i]))
    return out


class PhaseNoise:
    """Stationary Gaussian LO phase of an SSB phase-noise profile, random access at fs (module step 2).

    Stage ``k`` runs at ``rates_hz[k] = fs / PHASE_STAGE_RATIO ** k``: unit
    white noise filtered by ``taps[k]`` (PSD ``|H(f)|^2 / rate``), shaped to
    the profile times the stage's weight (:meth:`stage_weight`; the weights
    add to 1). The deepest stage is interpolated to the next stage's rate and
    added to it, and so on up to fs. The last stage is the first whose lowest
    resolved offset (``rate / PHASE_STAGE_RATIO ** 2``) reaches the
    profile's first offset.

    Parameters
    ----------
    profile : list of [offset_hz, dBc/Hz]
        SSB profile ``L(f)`` (:func:`phase_noise_profile`).
    sample_rate_hz : float
        fs, Hz.
    seed, stream_id : int
        Random streams (module docstring).
    """

    def __init__(self, profile, sample_rate_hz: float, seed: int, stream_id: int) -> None:
        #: Profile offsets, Hz, and SSB levels, dBc/Hz.
        self.offsets_hz, self.levels_dbc_hz = phase_noise_profile(profile)
        self.sample_rate_hz = float(sample_rate_hz)
        self.seed, self.stream_id = int(seed), int(stream_id)
        ratio = PHASE_STAGE_RATIO
        stages = 0
        while stages < PHASE_MAX_STAGES and self.sample_rate_hz / ratio ** (stages + 2) > self.offsets_hz[0]:
            stages += 1
        #: Stage rates, Hz (stage 0 at fs).
        self.rates_hz = self.sample_rate_hz / float(ratio) ** np.arange(stages + 1)
        #: Shaping FIR of each stage (odd, symmetric; unit-variance white input).
        self.taps = [self._design(k) for k in range(stages + 1)]
        #: Polyphase interpolator from one stage's rate to the next faster one.
        self.interpolator = interpolator_table(ratio, PHASE_INTERP_TAPS, PHASE_KAISER_BETA)
        # Spectra of the taps by (stage, FFT size): every block of a stage uses the same size.
        self._spectra: dict[tuple[int, int], np.ndarray] = {}
        # Each thread's last draws (consecutive blocks share the history of every stage).
        self._local = threading.local()

    def psd_rad2_hz(self, f_hz: np.ndarray) -> np.ndarray:
        """Two-sided PSD of the phase, ``10 ** (L(|f|) / 10)`` rad^2/Hz (the one-sided ``S_phi`` is twice it)."""
        log_f = np.log10(np.maximum(np.abs(np.asarray(f_hz, dtype=np.float64)), 1e-300))
        return 10.0 ** (np.interp(log_f, np.log10(self.offsets_hz), self.levels_dbc_hz) / 10.0)

    def stage_weight(self, stage: int, f_hz: np.ndarray) -> np.ndarray:
        """Share of the PSD at ``f_hz`` that stage ``stage`` carries (crossovers at ``rate / PHASE_STAGE_RATIO``)."""
        f_hz = np.abs(np.asarray(f_hz, dtype=np.float64))
        weight = np.ones_like(f_hz)
        if stage > 0:
            weight *= 1.0 - _crossover(f_hz, self.rates_hz[stage] / PHASE_STAGE_RATIO)
        if stage < len(self.rates_hz) - 1:
            weight *= _crossover(f_hz, self.rates_hz[stage + 1] / PHASE_STAGE_RATIO)
        return weight

    def _design(self, stage: int) -> np.ndarray:
        """Stage FIR by frequency sampling: ``|H| = sqrt(PSD * weight * rate)``, Kaiser-windowed, centred.

        :func:`scipy.signal.firwin2` given the ``PHASE_DESIGN_GRID`` grid itself, so its interpolation changes nothing.
        """
        rate = self.rates_hz[stage]
        f_hz = np.arange(PHASE_DESIGN_GRID // 2 + 1) * rate / PHASE_DESIGN_GRID
        amplitude = np.sqrt(self.psd_rad2_hz(f_hz) * self.stage_weight(stage, f_hz) * rate)
        return firwin2(PHASE_FIR_TAPS, f_hz, amplitude, nfreqs=len(f_hz), window=("kaiser", PHASE_KAISER_BETA),
                       fs=rate)

    def _white(self, stage: int, first: int, count: int) -> np.ndarray:
        """Unit white noise (float32) of one stage at its absolute indices ``first .. first + count - 1`` (any sign)."""
        draws = getattr(self._local, "draws", None)
        if draws is None:
            draws = self._local.draws = {}
        out = np.empty(count, dtype=np.float32)
        pos, stop = first, first + count
        while pos < stop:
            block, offset = divmod(pos, PHASE_DRAW_BLOCK)
            take = min(PHASE_DRAW_BLOCK - offset, stop - pos)
            values = draws.get((stage, block))
            if values is None:
                key = 2 * block if block >= 0 else -2 * block - 1      # seed sequences take no negative entries
                rng = np.random.default_rng([self.seed, self.stream_id, key, 2] + ([stage] if stage else []))
                values = draws[(stage, block)] = rng.standard_normal(PHASE_DRAW_BLOCK, dtype=np.float32)
                if len(draws) > 4 * len(self.taps) + 8:
                    del draws[next(iter(draws))]
            out[pos - first: pos - first + take] = values[offset: offset + take]
            pos += take
        return out

    def _stage(self, stage: int, first: int, count: int) -> np.ndarray:
        """Phase of stages ``stage..`` at stage ``stage``'s rate, its absolute indices ``first ..``, rad."""
        taps = self.taps[stage]
        n_taps = len(taps)
        n_in = count + n_taps - 1
        size = sp_fft.next_fast_len(n_in, real=True)
        spectrum = self._spectra.get((stage, size))
        if spectrum is None:
            spectrum = self._spectra[(stage, size)] = sp_fft.rfft(taps, size).astype(np.complex64)
        # FIR by FFT (the sizes depend on the block alone, so the rounding does too): the outputs that see
        # n_taps inputs, phase[i] = sum_j taps[j] white[first + i + centre - j]. Single precision: its
        # rounding lies far below any profile's floor, at half the cost.
        white = self._white(stage, first + n_taps // 2 - n_taps + 1, n_in)
        phase = sp_fft.irfft(sp_fft.rfft(white, size) * spectrum, size)[n_taps - 1: n_in].astype(np.float64)
        if stage + 1 < len(self.taps):
            ratio, width = self.interpolator.shape
            low_first = first // ratio - width // 2 + 1
            low_count = (first + count - 1) // ratio + width // 2 + 1 - low_first
            interpolate_add_kernel(self._stage(stage + 1, low_first, low_count), first % ratio, self.interpolator,
                                   phase)
        return phase

    def block(self, index: int) -> np.ndarray:
        """Phase of samples ``index * PHASE_BLOCK ..`` (one block, computed whole), rad."""
        return self._stage(0, index * PHASE_BLOCK, PHASE_BLOCK)


class FrontEnd:
    """The receiver front end of a scenario at one output rate.

    Parameters
    ----------
    receiver : FrontEndConfig
        ``cn_db``, ``bulk_cfo_hz``, ``iq_conjugate``, ``agc_backoff_db``,
        ``sample_format``.
    signal_power : float
        Mean power of the unobstructed direct path's signal
        (:func:`mean_signal_power`).
    sample_rate_hz : float
        Output rate, samples/s.
    sample_format : str
        Quantiser format.
    seed, stream_id : int
        Seed of the random streams: noise, phase noise, AGC steps, drops (module docstring).
    pulse_span : int
        Half-length of the transmit pulse before the anti-alias filter, symbols.
    stop_sample : int
        Absolute index after the capture's last sample (receiver clock): the
        AGC steps and drops are drawn from sample 0 up to it.

    With ``receiver.tuning_offset_hz`` non-zero the signal is synthesised at
    ``tuning_factor * fs`` and brought to ``fs`` by :meth:`tune` (module step 0a).
    The impairment keys (:data:`IMPAIRMENT_DEFAULTS`) are checked by
    :func:`check_impairments`; at their defaults none of their code runs.
    """

    def __init__(self, receiver: FrontEndConfig, signal_power: float, sample_rate_hz: float, sample_format: str,
                 seed: int, stream_id: int, pulse_span: int = PULSE_SPAN, stop_sample: int = 0) -> None:
        self.receiver = receiver
        self.format = get_format(sample_format)
        check_impairments(receiver, self.format)
        self.seed = seed
        self.stream_id = stream_id
        self.tuning_offset_hz = float(receiver.tuning_offset_hz)
        if not np.isfinite(self.tuning_offset_hz):
            raise ValueError(f"receiver.tuning_offset_hz must be a finite frequency, got {receiver.tuning_offset_hz!r}")
        self.sample_rate_hz = float(sample_rate_hz)
        band_noise = signal_power / 10.0 ** (receiver.cn_db / 10.0)
        #: Complex noise power per output sample (total over fs).
        self.noise_power = band_noise * sample_rate_hz / gb20600.SYMBOL_RATE_HZ
        if self.tuning_offset_hz == 0.0:
            #: The transmit pulse through the anti-alias filter (module step 0).
            self.pulse = anti_alias_pulse(pulse_table(pulse_span), sample_rate_hz)
            # The filter passes a share of the signal power: the pulse energy (1 unfiltered).
            passed = pulse_energy(self.pulse)
        else:
            # Off-centre (step 0a): the pulse is the SRRC, filtered after the shift.
            self.pulse = pulse_table(pulse_span)
            #: Synthesis rate over fs, and the anti-alias filter at that rate (step 0a).
            self.tuning_factor = tuning_factor(sample_rate_hz, self.tuning_offset_hz)
            self.tuning_taps = tuning_filter(self.tuning_factor)
            passed = tuned_band_share(sample_rate_hz, self.tuning_offset_hz)
        per_rail_rms = np.sqrt((signal_power * passed + self.noise_power) / 2.0)
        #: Fixed AGC gain (normalised full scale 1).
        self.agc_gain = 10.0 ** (-receiver.agc_backoff_db / 20.0) / per_rail_rms
        # Last noise block drawn: consecutive small chunks share a block.
        self._block: tuple[int, np.ndarray] = (-1, np.zeros(0))
        #: Mean power of the capture's signal (the direct path after the anti-alias filter), before the AGC.
        self.signal_power_passed = float(signal_power * passed)

        #: The LO's phase noise (module step 2); None without a profile.
        self.phase_noise = None
        if receiver.phase_noise_dbc_hz is not None:
            self.phase_noise = PhaseNoise(receiver.phase_noise_dbc_hz, sample_rate_hz, seed, stream_id)
        # Last phase-noise block computed (tuples are replaced whole: a thread's copy never sees another's).
        self._phase: tuple[int, np.ndarray] = (-1, np.zeros(0))
        #: IQ imbalance (module step 4): Q gain (dB) and quadrature error (deg); None when balanced.
        self.iq_imbalance = None
        if receiver.iq_gain_db != 0.0 or receiver.iq_phase_deg != 0.0:
            self.iq_imbalance = (float(receiver.iq_gain_db), float(receiver.iq_phase_deg))
        #: LO leakage (module step 5), complex amplitude before the AGC; None without.
        self.leakage = None
        if receiver.lo_leakage_dbc is not None:
            self.leakage = complex(np.sqrt(self.signal_power_passed * 10.0 ** (receiver.lo_leakage_dbc / 10.0))
                                   * np.exp(1j * np.radians(receiver.lo_leakage_phase_deg)))
        #: AGC gain steps (module step 7): absolute sample index from which each holds, and its level in steps.
        self.agc_steps = agc_schedule(float(receiver.agc_step_db), float(receiver.agc_steps_per_minute),
                                      self.sample_rate_hz, stop_sample, seed, stream_id)
        #: Dropped runs (module step 9): absolute index of each run's first lost sample, and its length.
        self.drop_runs = drop_schedule(float(receiver.drops_per_minute), tuple(receiver.drop_samples),
                                       self.sample_rate_hz, stop_sample, seed, stream_id)
        #: The ADC (module step 8): bits (None: the format's) and [I, Q] DC in LSB; None: ``encode`` as it is.
        self.adc = None
        if receiver.adc_bits is not None or any(dc != 0.0 for dc in receiver.adc_dc_lsb):
            self.adc = (None if receiver.adc_bits is None else int(receiver.adc_bits),
                        tuple(float(dc) for dc in receiver.adc_dc_lsb))

    def tuner_phase_rad(self, true_time_s: np.ndarray) -> np.ndarray:
        """Phase of the tuner's constant CFO at true times, ``2 pi bulk_cfo_hz t``, rad."""
        return 2.0 * np.pi * self.receiver.bulk_cfo_hz * np.asarray(true_time_s, dtype=np.float64)

    def tune(self, wide_samples, first_sample: int, count: int) -> np.ndarray:
        """Noise-free samples at fs of a capture tuned off the channel (module step 0a).

        Parameters
        ----------
        wide_samples : callable
            ``wide_samples(first, count)``: noise-free samples on the channel
            at ``tuning_factor * fs`` for absolute indices at that rate.
        first_sample, count : int
            Absolute output samples (at fs).
        """
        factor, taps = self.tuning_factor, self.tuning_taps
        first_wide = factor * first_sample - (len(taps) - 1) // 2
        need = factor * (count - 1) + len(taps)
        # The scenario has no signal before its first sample: the filter's first outputs see zeros there.
        lead = min(max(-first_wide, 0), need)
        x = np.zeros(need, dtype=np.complex128)
        if need > lead:
            x[lead:] = wide_samples(first_wide + lead, need - lead)
        out = np.empty(count, dtype=np.complex128)
        tune_kernel(x, first_wide, factor, taps, self.tuning_offset_hz / (factor * self.sample_rate_hz), out)
        return out

    def noise(self, first_sample: int, count: int) -> np.ndarray:
        """Complex AWGN for absolute samples ``first_sample .. first_sample + count - 1``."""
        out = np.empty(count, dtype=np.complex128)
        sigma = np.sqrt(self.noise_power / 2.0)
        pos = first_sample
        stop = first_sample + count
        while pos < stop:
            block, offset = divmod(pos, NOISE_BLOCK)
            take = min(NOISE_BLOCK - offset, stop - pos)
            rails = self._noise_block(block)[2 * offset: 2 * (offset + take)]
            out[pos - first_sample: pos - first_sample + take] = sigma * rails.view(np.complex128)
            pos += take
        return out

    def _noise_block(self, block: int) -> np.ndarray:
        """Unit-variance rails (I, Q, ...) of one noise block."""
        if self._block[0] != block:
            rng = np.random.default_rng([self.seed, self.stream_id, block, 1])
            self._block = (block, rng.standard_normal(2 * NOISE_BLOCK))
        return self._block[1]

    def phase_noise_rad(self, first_sample: int, count: int) -> np.ndarray:
        """The LO's phase (module step 2) at absolute samples ``first_sample ..``, rad (zeros without a profile)."""
        if self.phase_noise is None:
            return np.zeros(count)
        out = np.empty(count, dtype=np.float64)
        pos, stop = first_sample, first_sample + count
        while pos < stop:
            block, offset = divmod(pos, PHASE_BLOCK)
            take = min(PHASE_BLOCK - offset, stop - pos)
            if self._phase[0] != block:
                self._phase = (block, self.phase_noise.block(block))
            out[pos - first_sample: pos - first_sample + take] = self._phase[1][offset: offset + take]
            pos += take
        return out

    def gain(self, first_sample: int, count: int) -> float | np.ndarray:
        """AGC gain (module step 7) at absolute samples ``first_sample ..``: a float where no step falls inside."""
        steps, levels = self.agc_steps
        if len(steps) == 0:
            return self.agc_gain
        lo, hi = np.searchsorted(steps, [first_sample, first_sample + count], side="right")
        # Level of each stretch: the one before the chunk, then one per step inside it.
        stretch_levels = np.concatenate([levels[lo - 1: lo] if lo else [0], levels[lo: hi]])
        gains = self.agc_gain * 10.0 ** (self.receiver.agc_step_db * stretch_levels / 20.0)
        if hi == lo:
            return float(gains[0])
        edges = np.concatenate([[0], steps[lo: hi] - first_sample, [count]])
        return np.repeat(gains, np.diff(edges))

    def apply(self, clean: np.ndarray, first_sample: int) -> np.ndarray:
        """Module steps 2 to 7 on noise-free samples: complex64 at full scale 1."""
        z = clean
        if self.phase_noise is not None:
            z = rotate_kernel(np.ascontiguousarray(z, dtype=np.complex128), self.phase_noise_rad(first_sample, len(z)))
        z = z + self.noise(first_sample, len(clean)) if self.receiver.cn_db < np.inf else z
        if self.iq_imbalance is not None:
            z = iq_imbalance(z, *self.iq_imbalance)
        if self.leakage is not None:
            z = z + self.leakage
        if self.receiver.iq_conjugate:
            z = np.conj(z)
        return (z * self.gain(first_sample, len(clean))).astype(np.complex64)

    def quantise(self, samples: np.ndarray) -> np.ndarray:
        """Interleaved rails of the capture's format (``.tobytes()`` is the file content; module step 8)."""
        if self.adc is None:
            return encode(samples, self.format)
        return adc_quantise(samples, self.format, *self.adc)
