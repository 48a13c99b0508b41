"""GB 20600 definitions pinned to the standard's appendix vectors and derived facts."""

import numpy as np
import pytest

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import PnMode

PN420_HEX = (
    "B0A5E9FEA1CF0D9A3DC7407C4A22D5C8C938109BCCEFCB2B6906358AA60BAFB7614BD3FD439E1B347B8E80F89445AB91927021379"
)
PN945_HEX = (
    "FB946DFF3259AD7E9A7C9CDC081A82531A292661E8F1233A432F2D8055BABDE0EBA16959060BE1BD4B9EDAA88E44D953B15C5DA03FB3F1884F38EEF"
    "AC28708B1F728DBFE64B35AFD34F939B8103504A634524CC3D1E24674865E5B00AB757BC1D742D2B20C17C37A973DB5511C89B2A762B8BB407F678"
)
PN595_FIRST40 = "0000000001001001001101001101011111001100"

SI_BIN_TABLE = [0, 9, 3762, 3771, 3, 12, 3765, 3774, 6, 15, 3768, 3777, 1, 10, 3763, 3772, 4, 13, 3766, 3775,
                7, 16, 3769, 3778, 2, 11, 3764, 3773, 5, 14, 3767, 3776, 8, 17, 3770, 3779]


def hex_to_bits(text: str, n: int) -> np.ndarray:
    bits = np.unpackbits(np.frombuffer(bytes.fromhex(text + "0" * (len(text) % 2)), dtype=np.uint8))
    return bits[:n]


def test_pn420_phase0_matches_appendix():
    assert np.array_equal(gb20600.header_chips(PnMode.PN420, 0), hex_to_bits(PN420_HEX, 420))


def test_pn945_phase0_matches_appendix():
    assert np.array_equal(gb20600.header_chips(PnMode.PN945, 0), hex_to_bits(PN945_HEX, 945))


def test_pn595_first_chips():
    chips = "".join(map(str, gb20600.header_chips(PnMode.PN595)[:40]))
    assert chips == PN595_FIRST40


@pytest.mark.parametrize("mode", list(PnMode))
def test_cores_are_m_sequences(mode):
    core = gb20600.pn_core(mode).astype(float)
    p = mode.value.period
    assert len(core) == p
    # Ideal two-valued periodic autocorrelation: -1 at every non-zero lag.
    s = 1 - 2 * core
    acf = np.real(np.fft.ifft(np.abs(np.fft.fft(s)) ** 2))
    assert acf[0] == pytest.approx(p)
    assert np.allclose(acf[1:], -1)


@pytest.mark.parametrize("mode", [PnMode.PN420, PnMode.PN945])
def test_pre_and_postamble_are_cyclic_copies(mode):
    m = mode.value
    for phase in (0, 5, -17):
        h = gb20600.header_chips(mode, phase)
        assert np.array_equal(h[: m.cyclic_length], h[m.period: m.period + m.cyclic_length])
        core = h[m.preamble: m.preamble + m.period]
        assert np.array_equal(h[: m.preamble], core[-m.preamble:])
        assert np.array_equal(h[m.preamble + m.period:], core[: m.postamble])


@pytest.mark.parametrize("mode, frames, distinct, peak", [(PnMode.PN420, 225, 113, 56), (PnMode.PN945, 200, 101, 50)])
def test_variable_phase_schedule(mode, frames, distinct, peak):
    phases = gb20600.header_phase(mode, np.arange(frames))
    assert len(set(phases.tolist())) == distinct
    assert phases[0] == 0 and list(phases[1:5]) == [1, -1, 2, -2]
    assert phases.max() == peak and phases.min() == -peak
    # The step between adjacent headers (+1, -2, +3, ...) identifies the frame number.
    steps = np.diff(phases[: frames // 2 + 1])
    assert list(steps[:4]) == [1, -2, 3, -4]
    # Schedule repeats every superframe.
    assert np.array_equal(gb20600.header_phase(mode, np.arange(frames) + frames), phases)


def test_frame_timing_facts():
    for mode, dur in [(PnMode.PN420, 555.6e-6), (PnMode.PN595, 578.7e-6), (PnMode.PN945, 625e-6)]:
        m = mode.value
        assert m.frame_duration_s == pytest.approx(dur, abs=0.1e-6)
        assert m.frames_per_superframe * m.frame_duration_s == pytest.approx(gb20600.SUPERFRAME_S)


def test_header_power():
    assert np.mean(np.abs(gb20600.header_symbols(PnMode.PN420)) ** 2) == pytest.approx(2.0)
    assert np.mean(np.abs(gb20600.header_symbols(PnMode.PN945)) ** 2) == pytest.approx(2.0)
    assert np.mean(np.abs(gb20600.header_symbols(PnMode.PN595)) ** 2) == pytest.approx(1.0)
    # I = Q, chip 0 -> +(1+j).
    h = gb20600.header_symbols(PnMode.PN420)
    assert np.allclose(h.real, h.imag)
    assert h[0] == pytest.approx(-1 - 1j)  # first chip of PN420 phase 0 is 1 (hex B = 1011)


def test_si_on_36_carriers_nearest_dc():
    bins = gb20600.si_bins()
    assert list(bins) == SI_BIN_TABLE
    freqs = gb20600.bin_frequency_hz(bins)
    assert sorted(freqs / gb20600.CARRIER_SPACING_HZ) == list(range(-18, 18))


def test_interleaver_is_a_permutation_and_data_fills_the_rest():
    table = gb20600.logical_to_physical()
    assert sorted(table) == list(range(3780))
    assert len(gb20600.data_bins()) == 3744
    assert set(gb20600.data_bins()).isdisjoint(gb20600.si_bins())


def test_si_words_even_complements_odd():
    for k in range(1, 24, 2):
        assert np.array_equal(gb20600.si_word_chips(k), 1 - gb20600.si_word_chips(k + 1))


def test_si_symbol_mapping_and_options():
    s = gb20600.si_symbols(15)
    assert len(s) == 36
    assert np.allclose(s[:4], -(1 + 1j) / np.sqrt(2))
    chips = gb20600.si_word_chips(15).astype(int)
    assert np.allclose(s[4:], (1 - 2 * chips) * (1 + 1j) / np.sqrt(2))
    flipped = gb20600.si_symbols(15, polarity=-1)
    assert np.allclose(flipped[:4], s[:4]) and np.allclose(flipped[4:], -s[4:])
    quiet = gb20600.si_symbols(15, power_db=-13)
    assert np.mean(np.abs(quiet) ** 2) == pytest.approx(10 ** -1.3)
    with pytest.raises(ValueError):
        gb20600.si_symbols(99)


@pytest.mark.parametrize("name, size, raw_power", [("4QAM", 4, 40.5), ("16QAM", 16, 40), ("32QAM", 32, 45), ("64QAM", 64, 42)])
def test_constellations(name, size, raw_power):
    pts = gb20600.constellation(name)
    assert len(set(np.round(pts, 9))) == size
    assert np.mean(np.abs(pts) ** 2) == pytest.approx(1.0)
    raw = gb20600._CONSTELLATION_POINTS[name]
    assert np.mean(np.abs(raw) ** 2) == pytest.approx(raw_power)


def test_mode_parse():
    assert gb20600.PnMode.parse("pn945") is PnMode.PN945
    assert gb20600.PnMode.parse("420") is PnMode.PN420
    with pytest.raises(ValueError):
        gb20600.PnMode.parse("PN111")
