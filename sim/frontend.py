"""Receiver front end: anti-alias filter, tuner CFO, thermal noise, IQ swap, AGC and quantisation.

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
2. **AWGN** at ``receiver.cn_db``: carrier power of the unobstructed direct
   path over the noise power in the 7.56 MHz signal band. The noise is white at
   the output rate ``fs``, so its total power is ``N * fs / 7.56 MHz``.
   It is drawn per fixed block of ``NOISE_BLOCK`` absolute sample indices from
   ``default_rng([seed, stream_id, block, 1])``, so any chunking gives the
   same noise.
3. **IQ conjugation** (``receiver.iq_conjugate``), which flips the sign of
   every frequency.
4. **AGC**: one fixed gain for the whole capture, putting the expected per-rail
   RMS of (direct-path signal after the anti-alias filter + noise)
   ``receiver.agc_backoff_db`` below the quantiser's full scale (+-1 after
   ``dtmbnav_core.iqformat.decode``).
5. **Quantisation** with clipping to ``cu8``/``ci8``/``ci16``/``cf32``
   (``dtmbnav_core.iqformat.encode``).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.signal import firwin, kaiserord

from dtmbnav_core import gb20600
from dtmbnav_core.iqformat import encode, get_format
from sim.frames import FrameConfig
from sim.scenario import FrontEndConfig
from sim.transmitter import PULSE_SPAN, PulseTable, pulse_table

#: Samples per independently seeded noise block.
NOISE_BLOCK = 1 << 16
#: Passband edge of the anti-alias filter, fraction of the output Nyquist frequency fs / 2.
ANTI_ALIAS_PASSBAND = 0.8
#: Attenuation of the anti-alias filter from fs / 2 on, dB.
ANTI_ALIAS_STOPBAND_DB = 60.0


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
    nyquist = sample_rate_hz / 2.0
    cutoff = 0.5 * (1.0 + ANTI_ALIAS_PASSBAND) * nyquist / rs          # cycles per symbol
    # Transition width as a fraction of the table grid's Nyquist frequency (osr / 2 cycles per symbol).
    numtaps, beta = kaiserord(ANTI_ALIAS_STOPBAND_DB, (1.0 - ANTI_ALIAS_PASSBAND) * nyquist / rs / (osr / 2.0))
    half = -(-numtaps // (2 * osr))                                      # half length, whole symbols
    x = np.arange(-half * osr, half * osr + 1) / osr
    h = 2.0 * cutoff * np.sinc(2.0 * cutoff * x) * np.kaiser(len(x), beta)
    h /= np.sum(h) / osr                                                 # unit gain at DC
    return pulse_table(table.span, osr, table.rolloff, table.taper, lowpass=h)


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
    numtaps, beta = kaiserord(ANTI_ALIAS_STOPBAND_DB, (1.0 - ANTI_ALIAS_PASSBAND) / factor)
    numtaps |= 1
    return firwin(numtaps, 0.5 * (1.0 + ANTI_ALIAS_PASSBAND) / factor, window=("kaiser", beta))


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
        Noise seed (module docstring).
    pulse_span : int
        Half-length of the transmit pulse before the anti-alias filter, symbols.

    With ``receiver.tuning_offset_hz`` non-zero the signal is synthesised at
    ``tuning_factor * fs`` and brought to ``fs`` by :meth:`tune` (module step 0a).
    """

    def __init__(self, receiver: FrontEndConfig, signal_power: float, sample_rate_hz: float, sample_format: str,
                 seed: int, stream_id: int, pulse_span: int = PULSE_SPAN) -> None:
        self.receiver = receiver
        self.format = get_format(sample_format)
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

    def apply(self, clean: np.ndarray, first_sample: int) -> np.ndarray:
        """Noise, conjugation and AGC gain on noise-free samples; complex64 at full scale 1."""
        z = clean + self.noise(first_sample, len(clean)) if self.receiver.cn_db < np.inf else clean
        if self.receiver.iq_conjugate:
            z = np.conj(z)
        return (z * self.agc_gain).astype(np.complex64)

    def quantise(self, samples: np.ndarray) -> np.ndarray:
        """Interleaved rails of the capture's format (``.tobytes()`` is the file content)."""
        return encode(samples, self.format)
