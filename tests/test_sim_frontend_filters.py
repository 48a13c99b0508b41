"""The simulator front end's anti-alias filter (``sim.frontend`` step 0) meets its specification at every rate it runs at.

One design serves the transmit pulse below the symbol rate (on the pulse
table's grid) and the off-centre tuning filter (at ``factor * fs``); both must
pass ``ANTI_ALIAS_PASSBAND * fs / 2`` flat and stop ``fs / 2`` on by
``ANTI_ALIAS_STOPBAND_DB``, with unit gain at DC.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.frontend import ANTI_ALIAS_PASSBAND, ANTI_ALIAS_STOPBAND_DB, anti_alias_fir, anti_alias_order, tuning_filter

#: How far the stopband may come above ANTI_ALIAS_STOPBAND_DB, dB: kaiserord's length formula is an approximation
#: that leaves the first sidelobe, at fs / 2, up to about a dB short.
KAISER_SLACK_DB = 1.0


def response_db(taps: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Gain, dB, over the passband and over the stopband; frequencies as fractions of ``fs / 2`` at ``edge``."""
    n = 1 << max(16, int(np.ceil(np.log2(len(taps)))) + 4)
    nyquist_fraction = np.arange(n // 2 + 1) / (n // 2) / edge         # f over fs / 2
    gain = 20 * np.log10(np.abs(np.fft.rfft(taps, n)) + 1e-300)
    return gain[nyquist_fraction <= ANTI_ALIAS_PASSBAND], gain[nyquist_fraction >= 1.0]


@pytest.mark.parametrize("edge", [1 / 2, 1 / 3, 1 / 7, 2.4e6 / 7.56e6 / 8, 1e6 / 7.56e6 / 64])
def test_the_anti_alias_fir_passes_flat_and_stops_from_half_the_rate(edge):
    numtaps, beta = anti_alias_order(edge)
    taps = anti_alias_fir(numtaps | 1, beta, edge)
    assert len(taps) % 2 == 1 and np.allclose(taps, taps[::-1], rtol=0, atol=1e-15)
    assert np.sum(taps) == pytest.approx(1.0, abs=1e-12)
    passband, stopband = response_db(taps, edge)
    # A Kaiser design for 60 dB ripples by about 10 ** (-60 / 20) in amplitude, 0.009 dB: under 0.02 dB.
    assert np.max(np.abs(passband)) < 0.02
    assert np.max(stopband) < -ANTI_ALIAS_STOPBAND_DB + KAISER_SLACK_DB


def test_the_tuning_filter_is_the_anti_alias_fir_at_the_synthesis_rate():
    for factor in (2, 3, 5, 11):
        taps = tuning_filter(factor)
        numtaps, _ = anti_alias_order(1.0 / factor)
        assert len(taps) == numtaps | 1
        passband, stopband = response_db(taps, 1.0 / factor)
        assert np.max(np.abs(passband)) < 0.02 and np.max(stopband) < -ANTI_ALIAS_STOPBAND_DB + KAISER_SLACK_DB
