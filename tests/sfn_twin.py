"""An independent DTMB single-frequency-network transmitter and channel, for the receiver's tests.

The receiver's other end-to-end tests hear ``sim/``'s transmitter; this one shares nothing
with it but ``dtmbnav_core.gb20600``'s tables of the standard (header m-sequences and phases,
SI words, carrier placement, constellations), which ``tests/test_gb20600.py`` pins to the
standard's appendix. Every step is done another way than ``sim/`` does it:

- **Frames.** Each frame's body is the unitary 3780-point IDFT of its carriers (the SI
  symbols, random data of the SI word's constellation, one generator per frame), made by
  ``numpy.fft`` frame by frame as needed.
- **Pulse and delay.** The symbol stream is shaped by the square-root raised-cosine
  filter in the frequency domain, on blocks of receiver samples, with each tower's
  delay at the block's centre applied as a linear phase; the filter is the exact
  response of the continuous pulse sampled once per chip (its roll-off folded at the
  band edges), so no pulse is truncated.
- **Towers, walk and clock.** Each tower's direct path has the delay and the carrier
  phase ``-2 pi f_c tau`` of the receiver's distance at every sample (no multipath); the
  receiver's oscillator (a TCXO whose offset drifts linearly) makes both the sample clock
  and the carrier offset.

The receiver's output is judged against :meth:`TwinCapture.range_m` and
:meth:`TwinCapture.delay_s`, the geometry's own truth.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache

import numpy as np

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import SRRC_ROLLOFF, SYMBOL_RATE_HZ, PnMode

#: Receiver samples per synthesis block (the delay is taken at the block's centre: a drift of at most
#: the clock's offset times half a block, 0.005 chips, within it).
BLOCK = 1 << 15
#: Symbols of margin on each side of a block (the pulse's tails beyond it wrap around the FFT, far below
#: the noise).
MARGIN = 1024


@dataclass(frozen=True)
class TwinTower:
    """One transmitter of the network.

    Attributes
    ----------
    x_m, y_m, height_m : float
        Position, m (the walk is at height 0).
    gain_db : float
        Received power relative to the unit-power body of the reference tower, dB.
    transmit_delay_s : float
        Transmit-delay offset of the tower, s.
    """

    x_m: float
    y_m: float
    height_m: float
    gain_db: float = 0.0
    transmit_delay_s: float = 0.0


@dataclass(frozen=True)
class TwinCapture:
    """A capture of a receiver that stands, then walks along +x, hearing every tower's direct path.

    Attributes
    ----------
    towers : tuple of TwinTower
    pn_mode : PnMode
    seconds : float
        Length of the capture, s (of the receiver's clock).
    still_s : float
        Time the receiver stands before it walks, s.
    speed_mps : float
        Walking speed, reached with a time constant of ``ramp_s``.
    ramp_s : float
    snr_db : float
        Body SNR of a 0 dB tower, dB.
    carrier_hz : float
    clock_ppm, clock_drift_ppm_per_s : float
        The receiver oscillator's offset at the start and its linear drift.
    si_index : int
    start_symbol : int
        Transmitted symbol (of superframe-aligned frame 0) at the capture's start.
    seed : int
    """

    towers: tuple[TwinTower, ...]
    pn_mode: PnMode = PnMode.PN420
    seconds: float = 5.0
    still_s: float = 1.0
    speed_mps: float = 1.4
    ramp_s: float = 0.3
    snr_db: float = 15.0
    carrier_hz: float = 666e6
    clock_ppm: float = 0.4
    clock_drift_ppm_per_s: float = 0.005
    si_index: int = 15
    start_symbol: int = 1_234_567
    seed: int = 0

    @classmethod
    def two_towers(cls, apart_us: float, pn_mode: PnMode = PnMode.PN420, **kwargs) -> TwinCapture:
        """Tower A and a tower B 3 dB weaker whose direct path arrives ``apart_us`` later at the walk's start.

        The walk leads away from A and towards B, so the tower difference changes by about 2.5 m/s.
        """
        a = TwinTower(-3000.0, 1200.0, 150.0)
        b = TwinTower(4200.0, -1800.0, 120.0, gain_db=-3.0)
        extra_s = (_distance(b, 0.0) - _distance(a, 0.0)) / SPEED_OF_LIGHT_MPS
        b = TwinTower(b.x_m, b.y_m, b.height_m, b.gain_db, apart_us * 1e-6 - extra_s)
        return cls((a, b), pn_mode, **kwargs)

    @property
    def sample_rate_hz(self) -> float:
        return SYMBOL_RATE_HZ

    @property
    def samples(self) -> int:
        return int(self.seconds * SYMBOL_RATE_HZ)

    def position_m(self, t_s: np.ndarray) -> np.ndarray:
        """The receiver's x at true time ``t_s``, m (y = 0)."""
        w = np.maximum(np.asarray(t_s, dtype=np.float64) - self.still_s, 0.0)
        return self.speed_mps * (w - self.ramp_s * (1.0 - np.exp(-w / self.ramp_s)))

    def range_m(self, tower: int, t_s: np.ndarray) -> np.ndarray:
        """Distance of tower ``tower`` from the receiver at time ``t_s``, m."""
        return _distance(self.towers[tower], self.position_m(t_s))

    def delay_s(self, tower: int, t_s: np.ndarray) -> np.ndarray:
        """Arrival delay of tower ``tower``'s direct path at time ``t_s`` (transmit delay included), s."""
        return self.range_m(tower, t_s) / SPEED_OF_LIGHT_MPS + self.towers[tower].transmit_delay_s

    def true_time_s(self, n: np.ndarray) -> np.ndarray:
        """True time of receiver sample ``n``: the sample clock runs ``1 + offset(t)`` fast (second order dropped)."""
        t = np.asarray(n, dtype=np.float64) / SYMBOL_RATE_HZ
        return t * (1.0 - 1e-6 * (self.clock_ppm + 0.5 * self.clock_drift_ppm_per_s * t))

    def chunks(self) -> Iterator[np.ndarray]:
        """The capture, complex64, one block after the other."""
        source = _Frames(self.pn_mode, self.si_index, self.seed)
        rng = np.random.default_rng([self.seed, 58])
        sigma = np.sqrt(10.0 ** (-self.snr_db / 10.0) / 2.0)
        for first in range(0, self.samples, BLOCK):
            n = np.arange(first, min(first + BLOCK, self.samples))
            t = self.true_time_s(n)
            centre = t[len(t) // 2]
            x = np.zeros(len(n), np.complex128)
            for k, tower in enumerate(self.towers):
                tau = self.delay_s(k, t)
                # Symbol time of the block's first sample with the centre's delay; the block steps one chip a
                # sample (the clock's and the walk's compression, ppm, left out within a block).
                u0 = self.start_symbol + (centre - self.delay_s(k, centre)) * SYMBOL_RATE_HZ - len(n) // 2
                shaped = _shaped(source, u0, len(n))
                x += 10.0 ** (tower.gain_db / 20.0) * shaped * np.exp(-2j * np.pi * self.carrier_hz * tau)
            clock_cycles = self.carrier_hz * 1e-6 * (self.clock_ppm * t + 0.5 * self.clock_drift_ppm_per_s * t ** 2)
            x *= np.exp(-2j * np.pi * clock_cycles)
            x += sigma * (rng.standard_normal(len(n)) + 1j * rng.standard_normal(len(n)))
            yield x.astype(np.complex64)


def _distance(tower: TwinTower, x_m: np.ndarray | float) -> np.ndarray:
    return np.sqrt((tower.x_m - x_m) ** 2 + tower.y_m ** 2 + tower.height_m ** 2)


class _Frames:
    """The transmitted symbol stream: frame ``j`` (of superframe-aligned frame 0) at symbols ``j L .. j L + L - 1``."""

    def __init__(self, mode: PnMode, si_index: int, seed: int) -> None:
        self.mode, self.seed = mode, seed
        self.points = gb20600.constellation(gb20600.si_constellation(si_index))
        self.template = np.zeros(gb20600.BODY_LENGTH, np.complex128)
        self.template[gb20600.si_bins()] = gb20600.si_symbols(si_index)
        self.data = gb20600.data_bins()
        self.cache: dict[int, np.ndarray] = {}

    def frame(self, j: int) -> np.ndarray:
        if j not in self.cache:
            if len(self.cache) > 64:
                self.cache.clear()
            m = self.mode.value
            rng = np.random.default_rng([self.seed, j])
            carriers = self.template.copy()
            carriers[self.data] = self.points[rng.integers(0, len(self.points), len(self.data))]
            phase = gb20600.header_phase(self.mode, j % m.frames_per_superframe)
            self.cache[j] = np.concatenate([gb20600.header_symbols(self.mode, int(phase)),
                                            np.fft.ifft(carriers, norm="ortho")])
        return self.cache[j]

    def symbols(self, start: int, stop: int) -> np.ndarray:
        length = self.mode.value.frame_length
        frames = range(start // length, (stop - 1) // length + 1)
        stream = np.concatenate([self.frame(j) for j in frames])
        return stream[start - frames[0] * length: stop - frames[0] * length]


def _srrc_response(nu: np.ndarray) -> np.ndarray:
    """The square-root raised-cosine spectrum at ``nu`` cycles per chip (1 at DC)."""
    a = np.abs(nu)
    edge = (1.0 - SRRC_ROLLOFF) / 2.0
    roll = np.cos(np.pi / (2.0 * SRRC_ROLLOFF) * np.clip(a - edge, 0.0, SRRC_ROLLOFF))
    return np.where(a <= edge, 1.0, np.where(a <= edge + SRRC_ROLLOFF, roll, 0.0))


def _shaped(source: _Frames, u0: float, count: int) -> np.ndarray:
    """The pulse-shaped stream at symbol times ``u0, u0 + 1, ..., u0 + count - 1``.

    ``s(m + f) = sum_i d_i p(m + f - i)``: the chip-rate samples of the continuous pulse advanced by
    ``f`` have the spectrum ``sum_k P(nu - k) exp(j 2 pi (nu - k) f)`` (the roll-off folds at +-1/2).
    """
    whole = int(np.floor(u0))
    frac = u0 - whole
    symbols = source.symbols(whole - MARGIN, whole + count + MARGIN)
    nu, folds = _folds(len(symbols))
    response = np.exp(2j * np.pi * nu * frac) * (folds[0] + folds[1] * np.exp(2j * np.pi * frac)
                                                 + folds[2] * np.exp(-2j * np.pi * frac))
    return np.fft.ifft(np.fft.fft(symbols) * response)[MARGIN: MARGIN + count]


@cache
def _folds(size: int) -> tuple[np.ndarray, np.ndarray]:
    """FFT frequencies of ``size`` points, cycles per chip, and the pulse spectrum at ``nu``, ``nu + 1``, ``nu - 1``."""
    nu = np.fft.fftfreq(size)
    return nu, np.stack([_srrc_response(nu + k) for k in (0, 1, -1)])
