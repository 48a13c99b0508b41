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
from scipy.signal import kaiserord

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
    """

    def __init__(self, receiver: FrontEndConfig, signal_power: float, sample_rate_hz: float, sample_format: str,
                 seed: int, stream_id: int, pulse_span: int = PULSE_SPAN) -> None:
        self.receiver = receiver
        self.format = get_format(sample_format)
        self.seed = seed
        self.stream_id = stream_id
        #: The transmit pulse through the anti-alias filter (module step 0).
        self.pulse = anti_alias_pulse(pulse_table(pulse_span), sample_rate_hz)
        band_noise = signal_power / 10.0 ** (receiver.cn_db / 10.0)
        #: Complex noise power per output sample (total over fs).
        self.noise_power = band_noise * sample_rate_hz / gb20600.SYMBOL_RATE_HZ
        # The filter passes a share of the signal power: the pulse energy (1 unfiltered).
        per_rail_rms = np.sqrt((signal_power * pulse_energy(self.pulse) + self.noise_power) / 2.0)
        #: Fixed AGC gain (normalised full scale 1).
        self.agc_gain = 10.0 ** (-receiver.agc_backoff_db / 20.0) / per_rail_rms
        # Last noise block drawn: consecutive small chunks share a block.
        self._block: tuple[int, np.ndarray] = (-1, np.zeros(0))

    def tuner_phase_rad(self, true_time_s: np.ndarray) -> np.ndarray:
        """Phase of the tuner's constant CFO at true times, ``2 pi bulk_cfo_hz t``, rad."""
        return 2.0 * np.pi * self.receiver.bulk_cfo_hz * np.asarray(true_time_s, dtype=np.float64)

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
