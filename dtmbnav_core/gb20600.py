"""GB 20600-2006 (DTMB) definitions shared by the receiver and the simulator.

Everything the standard fixes and both ends need lives here once: symbol rate,
frame-header modes and their PN generators, the variable-phase header schedule,
the system-information (SI / TPS) words and their mapping, the C=3780 carrier
placement (frequency interleaver) and the data constellations.

Facts follow ``docs/dtmb.md``; where the spec marks a fact uncertain
(SI polarity, SI power) it is a keyword option, never a hidden constant.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from functools import cache

import numpy as np

#: Symbol rate, symbols/s (docs/dtmb.md §1).
SYMBOL_RATE_HZ = 7.56e6
#: Number of carriers / frame-body length in symbols (C=3780 mode).
BODY_LENGTH = 3780
#: Carrier spacing, Hz.
CARRIER_SPACING_HZ = SYMBOL_RATE_HZ / BODY_LENGTH
#: Number of system-information symbols per frame body.
SI_LENGTH = 36
#: Number of data symbols per frame body.
DATA_LENGTH = BODY_LENGTH - SI_LENGTH
#: Superframe duration, s (every mode).
SUPERFRAME_S = 0.125
#: Square-root raised-cosine roll-off of the transmit filter.
SRRC_ROLLOFF = 0.05


@dataclass(frozen=True)
class HeaderMode:
    """One frame-header mode (PN420, PN595 or PN945).

    Attributes
    ----------
    name : str
        ``"PN420"``, ``"PN595"`` or ``"PN945"``.
    header_length : int
        Header length, symbols.
    period : int
        Period of the PN core m-sequence, chips (255, 1023, 511).
    preamble : int
        Cyclic preamble length, chips (0 for PN595).
    postamble : int
        Cyclic postamble length, chips (0 for PN595).
    frames_per_superframe : int
        Signal frames in one 125 ms superframe.
    header_power_ratio : float
        Header symbol power relative to the unit-power body.
    rotates : bool
        Whether the standard allows a frame-to-frame rotating header phase.
    """

    name: str
    header_length: int
    period: int
    preamble: int
    postamble: int
    frames_per_superframe: int
    header_power_ratio: float
    rotates: bool
    _degree: int
    _seed: str
    _taps: tuple[int, ...]

    @property
    def frame_length(self) -> int:
        """Signal-frame length, symbols (header + body)."""
        return self.header_length + BODY_LENGTH

    @property
    def frame_duration_s(self) -> float:
        """Signal-frame duration, s."""
        return self.frame_length / SYMBOL_RATE_HZ

    @property
    def header_amplitude(self) -> float:
        """Per-rail amplitude A of a header symbol ``chip * (1 + j) * A``."""
        return float(np.sqrt(self.header_power_ratio / 2.0))

    @property
    def cyclic_length(self) -> int:
        """Number of header chips that repeat one core period later.

        ``h[n] == h[n + period]`` for ``0 <= n < cyclic_length``; zero for PN595.
        """
        return max(self.header_length - self.period, 0)


class PnMode(Enum):
    """The three header modes of GB 20600 (docs/dtmb.md §2, §2.1)."""

    PN420 = HeaderMode("PN420", 420, 255, 82, 83, 225, 2.0, True, 8, "10110000", (0, 2, 3, 7))
    PN595 = HeaderMode("PN595", 595, 1023, 0, 0, 216, 1.0, False, 10, "0000000001", (0, 7))
    PN945 = HeaderMode("PN945", 945, 511, 217, 217, 200, 2.0, True, 9, "111110111", (0, 1, 2, 7))

    @classmethod
    def parse(cls, name: str | "PnMode") -> "PnMode":
        """Return the mode for ``"PN420"``, ``"pn420"``, ``"420"`` and the like."""
        if isinstance(name, PnMode):
            return name
        key = str(name).upper()
        key = key if key.startswith("PN") else "PN" + key
        try:
            return cls[key]
        except KeyError:
            raise ValueError(f"unknown header mode {name!r}; expected one of PN420, PN595, PN945") from None


def lfsr_sequence(degree: int, seed: str, taps: tuple[int, ...], length: int) -> np.ndarray:
    """Run the PN recurrence ``b[n+d] = XOR_{t in taps} b[n+t]``.

    Parameters
    ----------
    degree : int
        Register length d; the first d outputs are the seed.
    seed : str
        The first d chips, left to right, as ``'0'``/``'1'`` characters.
    taps : tuple of int
        Offsets t of the recurrence.
    length : int
        Number of chips to produce.

    Returns
    -------
    numpy.ndarray of uint8
        Chips 0/1.
    """
    if len(seed) != degree:
        raise ValueError("seed length must equal the register degree")
    out = np.zeros(max(length, degree), dtype=np.uint8)
    out[:degree] = [int(c) for c in seed]
    for n in range(length - degree):
        acc = 0
        for t in taps:
            acc ^= out[n + t]
        out[n + degree] = acc
    return out[:length]


@cache
def pn_core(mode: PnMode) -> np.ndarray:
    """Phase-0 recurrence output over one period (chips 0/1, read-only).

    For PN595 this is the first 1023 chips of the 10-stage m-sequence.
    """
    m = mode.value
    seq = lfsr_sequence(m._degree, m._seed, m._taps, m.period)
    seq.flags.writeable = False
    return seq


def header_phase(mode: PnMode, frame_in_superframe: int | np.ndarray) -> int | np.ndarray:
    """Cyclic phase of the header of a frame under the variable-phase schedule.

    Parameters
    ----------
    mode : PnMode
        PN420 or PN945 (PN595 has a constant header; its phase is always 0).
    frame_in_superframe : int or array of int
        Frame index i; taken modulo the frames per superframe.

    Returns
    -------
    int or ndarray
        The phase: 0, +1, -1, +2, -2, ... then back (docs/dtmb.md §2.3).
    """
    m = mode.value
    i = np.asarray(frame_in_superframe) % m.frames_per_superframe
    if not m.rotates:
        return np.zeros_like(i) if i.ndim else 0
    turn = m.frames_per_superframe // 2
    i = np.where(i > turn, 2 * turn - i, i)
    phase = np.where(i % 2 == 1, (i + 1) // 2, -(i // 2))
    return phase if phase.ndim else int(phase)


def header_chips(mode: PnMode, phase: int = 0) -> np.ndarray:
    """Header chips ``h[n] = c[(n + phase) mod P]`` for one frame (0/1)."""
    m = mode.value
    n = np.arange(m.header_length)
    return pn_core(mode)[(n + phase) % m.period]


def chips_to_symbols(chips: np.ndarray, amplitude: float) -> np.ndarray:
    """Map chips to BPSK on the I = Q diagonal: 0 -> +(1+j)A, 1 -> -(1+j)A."""
    return ((1.0 - 2.0 * chips.astype(np.float64)) * amplitude * (1.0 + 1.0j)).astype(np.complex128)


def header_symbols(mode: PnMode, phase: int = 0) -> np.ndarray:
    """Complex header symbols of one frame at the standard header power."""
    return chips_to_symbols(header_chips(mode, phase), mode.value.header_amplitude)


# --- System information (docs/dtmb.md §3.1, §3.2) -------------------------------------------

#: SI code words 1..24 (32 chips each, first chip on the left).
SI_WORDS: dict[int, str] = {
    1: "00011110101011100100100010110011",
    2: "11100001010100011011011101001100",
    3: "01111000110010000010111011010101",
    4: "10000111001101111101000100101010",
    5: "01110111110001110010000111011010",
    6: "10001000001110001101111000100101",
    7: "00100010100100100111010010001111",
    8: "11011101011011011000101101110000",
    9: "01001011111110110001110111100110",
    10: "10110100000001001110001000011001",
    11: "00010001101000010100011110111100",
    12: "11101110010111101011100001000011",
    13: "01111000001101110010111000101010",
    14: "10000111110010001101000111010101",
    15: "00101101100111010111101110000000",
    16: "11010010011000101000010001111111",
    17: "01110111001110000010000100100101",
    18: "10001000110001111101111011011010",
    19: "00100010011011010111010001110000",
    20: "11011101100100101000101110001111",
    21: "01000100000010110001001000010110",
    22: "10111011111101001110110111101001",
    23: "00010001010111100100011101000011",
    24: "11101110101000011011100010111100",
}

#: What each SI word announces (constellation, code rate, interleaver mode).
SI_DESCRIPTIONS: dict[int, str] = {
    1: "first-frame indication, odd superframe",
    2: "first-frame indication, even superframe",
    3: "4QAM-NR 0.8 mode 1", 4: "4QAM-NR 0.8 mode 2",
    5: "4QAM 0.4 mode 1", 6: "4QAM 0.4 mode 2", 7: "4QAM 0.6 mode 1", 8: "4QAM 0.6 mode 2",
    9: "4QAM 0.8 mode 1", 10: "4QAM 0.8 mode 2",
    11: "16QAM 0.4 mode 1", 12: "16QAM 0.4 mode 2", 13: "16QAM 0.6 mode 1", 14: "16QAM 0.6 mode 2",
    15: "16QAM 0.8 mode 1", 16: "16QAM 0.8 mode 2",
    17: "32QAM 0.8 mode 1", 18: "32QAM 0.8 mode 2",
    19: "64QAM 0.4 mode 1", 20: "64QAM 0.4 mode 2", 21: "64QAM 0.6 mode 1", 22: "64QAM 0.6 mode 2",
    23: "64QAM 0.8 mode 1", 24: "64QAM 0.8 mode 2",
}

#: Number of carrier-mode flag symbols that precede the SI code word.
SI_MODE_SYMBOLS = 4


def si_word_chips(index: int) -> np.ndarray:
    """The 32 chips (0/1) of SI word ``index`` (1..24)."""
    try:
        word = SI_WORDS[index]
    except KeyError:
        raise ValueError(f"unknown SI word {index}; known words are 1..24") from None
    return np.frombuffer(word.encode(), dtype=np.uint8) - ord("0")


def si_symbols(index: int, *, polarity: int = +1, power_db: float = 0.0) -> np.ndarray:
    """The 36 SI symbols of one frame body, in transmission order.

    Parameters
    ----------
    index : int
        SI word number (1..24), e.g. 15 for 16QAM 0.8 mode 1.
    polarity : {+1, -1}
        +1 (default, validated on air): chip 0 -> +(1+j)a; -1: chip 0 -> -(1+j)a.
        The four C=3780 mode symbols are -(1+j)a either way (docs/dtmb.md §3.2).
    power_db : float
        SI symbol power relative to the unit-power data, dB (0 = equal power).

    Returns
    -------
    numpy.ndarray of complex128, shape (36,)
    """
    if polarity not in (+1, -1):
        raise ValueError("SI polarity must be +1 or -1")
    a = np.sqrt(10.0 ** (power_db / 10.0) / 2.0)
    mode_flags = np.full(SI_MODE_SYMBOLS, -(1.0 + 1.0j) * a)
    word = polarity * chips_to_symbols(si_word_chips(index), a)
    return np.concatenate([mode_flags, word])


# --- C=3780 carrier placement (docs/dtmb.md §3.3) ---------------------------------------------

#: Logical positions of the 36 SI symbols in the 3780-vector, in SI order.
SI_LOGICAL_POSITIONS = (np.array([0, 140, 279, 419])[None, :] + 420 * np.arange(9)[:, None]).ravel()


@cache
def logical_to_physical() -> np.ndarray:
    """Map logical carrier index -> physical FFT bin (mixed-radix digit reversal).

    Returns
    -------
    numpy.ndarray of int64, shape (3780,), read-only
    """
    table = np.empty(BODY_LENGTH, dtype=np.int64)
    i, j, k, l, m, n, o = np.meshgrid(
        np.arange(3), np.arange(3), np.arange(3), np.arange(2), np.arange(2), np.arange(5), np.arange(7),
        indexing="ij",
    )
    logical = i * 1260 + j * 420 + k * 140 + l * 70 + m * 35 + n * 7 + o
    physical = o * 540 + n * 108 + m * 54 + l * 27 + k * 9 + j * 3 + i
    table[logical.ravel()] = physical.ravel()
    table.flags.writeable = False
    return table


@cache
def data_logical_positions() -> np.ndarray:
    """Logical positions of the 3744 data symbols, increasing (read-only)."""
    mask = np.ones(BODY_LENGTH, dtype=bool)
    mask[SI_LOGICAL_POSITIONS] = False
    pos = np.flatnonzero(mask)
    pos.flags.writeable = False
    return pos


@cache
def si_bins() -> np.ndarray:
    """FFT bins (physical carriers) of the 36 SI symbols, in SI order (read-only)."""
    bins = logical_to_physical()[SI_LOGICAL_POSITIONS]
    bins.flags.writeable = False
    return bins


@cache
def data_bins() -> np.ndarray:
    """FFT bins of the 3744 data symbols, in data order (read-only)."""
    bins = logical_to_physical()[data_logical_positions()]
    bins.flags.writeable = False
    return bins


def bin_frequency_hz(bins: np.ndarray) -> np.ndarray:
    """Baseband frequency of FFT bins, Hz (bins >= 1890 are negative)."""
    k = np.asarray(bins)
    return np.where(k < BODY_LENGTH // 2, k, k - BODY_LENGTH) * CARRIER_SPACING_HZ


# --- Constellations (docs/dtmb.md §4) -------------------------------------------------------

def _square_levels(levels: list[float]) -> np.ndarray:
    lv = np.array(levels, dtype=np.float64)
    return (lv[:, None] + 1j * lv[None, :]).ravel()


def _cross32() -> np.ndarray:
    pts = _square_levels([-7.5, -4.5, -1.5, 1.5, 4.5, 7.5])
    corner = (np.abs(pts.real) == 7.5) & (np.abs(pts.imag) == 7.5)
    return pts[~corner]


_CONSTELLATION_POINTS = {
    "4QAM": _square_levels([-4.5, 4.5]),
    "4QAM-NR": _square_levels([-4.5, 4.5]),
    "16QAM": _square_levels([-6, -2, 2, 6]),
    "32QAM": _cross32(),
    "64QAM": _square_levels([-7, -5, -3, -1, 1, 3, 5, 7]),
}


def constellation(name: str) -> np.ndarray:
    """Unit-average-power constellation points of ``name`` (e.g. ``"16QAM"``)."""
    try:
        pts = _CONSTELLATION_POINTS[name.upper()]
    except KeyError:
        raise ValueError(f"unknown constellation {name!r}; expected one of {sorted(_CONSTELLATION_POINTS)}") from None
    return pts / np.sqrt(np.mean(np.abs(pts) ** 2))


def si_constellation(index: int) -> str:
    """Constellation name announced by SI word ``index`` (4QAM for words 1, 2)."""
    desc = SI_DESCRIPTIONS[index]
    name = desc.split()[0]
    return name if name in _CONSTELLATION_POINTS else "4QAM"
