"""Symbol-rate TDS-OFDM signal frames (GB 20600, C=3780).

A :class:`FrameSource` produces the transmitted symbol stream at the symbol rate
(7.56 Msym/s, before pulse shaping): for every signal frame, the PN header of
the frame's place in the superframe followed by a 3780-point IDFT body that
carries the 36 SI symbols on their fixed carriers and random data of the
constellation the SI word announces.

The stream is a pure function of (configuration, seed, symbol index): each
frame's data comes from its own generator seeded with ``(seed, frame_number)``,
so any slice of the stream can be produced on its own, in any order, and is
identical bytes whatever the chunking.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from dtmbnav.core import gb20600
from dtmbnav.core.gb20600 import PnMode


@dataclass(frozen=True)
class FrameConfig:
    """What the transmitter sends.

    Attributes
    ----------
    pn_mode : PnMode
        Header mode.
    rotating_phase : bool
        Variable header phase (PN420, PN945); PN595 is always constant.
    constant_phase : int
        Header phase used when the phase does not rotate.
    si_index : int
        SI word (1..24) sent in every frame.
    si_polarity : int
        SI chip polarity convention (+1 default, see ``gb20600.si_symbols``).
    si_power_db : float
        SI power relative to data, dB.
    constellation : str or None
        Data constellation; None takes the one the SI word announces.
    seed : int
        Seed of the random data.
    """

    pn_mode: PnMode = PnMode.PN420
    rotating_phase: bool = True
    constant_phase: int = 0
    si_index: int = 15
    si_polarity: int = 1
    si_power_db: float = 0.0
    constellation: str | None = None
    seed: int = 0

    @property
    def frame_length(self) -> int:
        """Signal-frame length, symbols."""
        return self.pn_mode.value.frame_length

    def header_phase(self, frame_number: int) -> int:
        """Header phase of absolute frame ``frame_number`` (frame 0 starts a superframe)."""
        if self.rotating_phase and self.pn_mode.value.rotates:
            return int(gb20600.header_phase(self.pn_mode, frame_number))
        return self.constant_phase


class FrameSource:
    """Random-access generator of the transmitted symbol stream.

    Parameters
    ----------
    config : FrameConfig
        Transmitter settings.
    cache_frames : int
        Number of recently built frames kept (streams read overlapping slices).
    """

    def __init__(self, config: FrameConfig, cache_frames: int = 8) -> None:
        self.config = config
        name = config.constellation or gb20600.si_constellation(config.si_index)
        self._points = gb20600.constellation(name)
        si = gb20600.si_symbols(config.si_index, polarity=config.si_polarity, power_db=config.si_power_db)
        self._carriers_template = np.zeros(gb20600.BODY_LENGTH, dtype=np.complex128)
        self._carriers_template[gb20600.si_bins()] = si
        self._data_bins = gb20600.data_bins()
        self._headers: dict[int, np.ndarray] = {}
        self.frame_symbols = lru_cache(maxsize=cache_frames)(self._build_frame)

    def header(self, phase: int) -> np.ndarray:
        """Header symbols for a cyclic phase (cached)."""
        if phase not in self._headers:
            self._headers[phase] = gb20600.header_symbols(self.config.pn_mode, phase)
        return self._headers[phase]

    def carriers(self, frame_number: int) -> np.ndarray:
        """Physical carrier vector X[k] (FFT-bin order) of a frame's body."""
        rng = np.random.default_rng([self.config.seed, frame_number])
        x = self._carriers_template.copy()
        x[self._data_bins] = self._points[rng.integers(0, len(self._points), gb20600.DATA_LENGTH)]
        return x

    def _build_frame(self, frame_number: int) -> np.ndarray:
        """Header + body symbols of one frame (complex128, read-only)."""
        if frame_number < 0:
            raise ValueError("frame numbers start at 0")
        # Unitary IDFT: x[t] = (1/sqrt(N)) sum_k X[k] exp(+j 2 pi k t / N)  (docs/dtmb.md §3.3)
        body = np.fft.ifft(self.carriers(frame_number), norm="ortho")
        frame = np.concatenate([self.header(self.config.header_phase(frame_number)), body])
        frame.flags.writeable = False
        return frame

    def symbols(self, start: int, stop: int) -> np.ndarray:
        """Transmitted symbols with absolute indices ``start <= n < stop``.

        Symbol 0 is the first symbol of frame 0, the first frame of a superframe.
        """
        if start < 0 or stop < start:
            raise ValueError(f"bad symbol range [{start}, {stop})")
        flen = self.config.frame_length
        out = np.empty(stop - start, dtype=np.complex128)
        pos = start
        while pos < stop:
            frame, offset = divmod(pos, flen)
            take = min(flen - offset, stop - pos)
            out[pos - start: pos - start + take] = self.frame_symbols(frame)[offset: offset + take]
            pos += take
        return out
