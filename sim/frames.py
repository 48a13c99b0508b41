"""Symbol-rate TDS-OFDM signal frames (GB 20600, C=3780).

A :class:`FrameSource` produces the transmitted symbol stream at the symbol rate
(7.56 Msym/s, before pulse shaping): for every signal frame, the PN header of
the frame's place in the superframe followed by a 3780-point IDFT body that
carries the 36 SI symbols on their fixed carriers and random data of the
constellation the SI word announces.

The stream is a pure function of (configuration, seed, symbol index): frames
are made in groups of ``FRAMES_PER_GROUP`` consecutive frames (group ``g``
holds frames ``g G .. g G + G - 1``), each group's data drawn by its own
generator seeded with ``(seed, g)`` and its bodies transformed in one batched
FFT, so any slice of the stream can be produced on its own, in any order, and
is identical bytes whatever the chunking.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from dtmbnav_core import gb20600
from dtmbnav_core.gb20600 import PnMode
from sim.fft import fftw_plan

#: Frames made together (one random generator, one batched FFT).
FRAMES_PER_GROUP = 32


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


@njit(cache=True, nogil=True)
def carriers_kernel(draws: np.ndarray, points: np.ndarray, bin_data: np.ndarray, template: np.ndarray,
                    out: np.ndarray) -> None:
    """Carrier vectors of frame bodies: the SI carriers of the template and a drawn point on every data bin.

    Parameters
    ----------
    draws : (F, D) uint8
        Random bytes; ``draws & (len(points) - 1)`` picks the point (the number
        of points is a power of two, so every point is equally likely).
    points : (Q,) complex128
        Constellation.
    bin_data : (3780,) int64
        Data symbol carried by each FFT bin, -1 on the SI bins.
    template : (3780,) complex128
        Carriers with the SI symbols (zero elsewhere).
    out : (F, 3780) complex
    """
    mask = points.shape[0] - 1
    for f in range(draws.shape[0]):
        for k in range(bin_data.shape[0]):
            d = bin_data[k]
            out[f, k] = points[draws[f, d] & mask] if d >= 0 else template[k]


def carriers_reference(draws: np.ndarray, points: np.ndarray, bin_data: np.ndarray,
                       template: np.ndarray) -> np.ndarray:
    """Plain-numpy reference of :func:`carriers_kernel`; returns ``out`` (complex128)."""
    out = np.tile(template, (draws.shape[0], 1))
    data = bin_data >= 0
    out[:, data] = points[draws[:, bin_data[data]] & (len(points) - 1)]
    return out


class FrameSource:
    """Random-access generator of the transmitted symbol stream.

    Not shared between threads (the FFT plan's buffers are its own); each
    thread makes its own, which gives the same symbols.

    Parameters
    ----------
    config : FrameConfig
        Transmitter settings.
    cache_groups : int
        Number of recently built frame groups kept (streams read overlapping slices).
    """

    def __init__(self, config: FrameConfig, cache_groups: int = 3) -> None:
        self.config = config
        name = config.constellation or gb20600.si_constellation(config.si_index)
        self._points = gb20600.constellation(name)
        if len(self._points) & (len(self._points) - 1):
            raise ValueError(f"constellation {name}: {len(self._points)} points is not a power of two")
        si = gb20600.si_symbols(config.si_index, polarity=config.si_polarity, power_db=config.si_power_db)
        self._carriers_template = np.zeros(gb20600.BODY_LENGTH, dtype=np.complex128)
        self._carriers_template[gb20600.si_bins()] = si
        self._bin_data = np.full(gb20600.BODY_LENGTH, -1, dtype=np.int64)
        self._bin_data[gb20600.data_bins()] = np.arange(gb20600.DATA_LENGTH)
        self._headers: dict[int, np.ndarray] = {}
        self._position_headers: dict[int, np.ndarray] = {}
        self._ifft = None
        self._group = lru_cache(maxsize=cache_groups)(self._build_group)

    def header(self, phase: int) -> np.ndarray:
        """Header symbols for a cyclic phase (cached)."""
        if phase not in self._headers:
            self._headers[phase] = gb20600.header_symbols(self.config.pn_mode, phase)
        return self._headers[phase]

    def _frame_header(self, frame_number: int) -> np.ndarray:
        """Header symbols of absolute frame ``frame_number`` (the schedule repeats every superframe)."""
        position = frame_number % self.config.pn_mode.value.frames_per_superframe
        if position not in self._position_headers:
            self._position_headers[position] = self.header(self.config.header_phase(position))
        return self._position_headers[position]

    def _group_carriers(self, group: int, out: np.ndarray | None = None) -> np.ndarray:
        """Physical carrier vectors X[k] (FFT-bin order) of a group's frame bodies, shape (G, 3780)."""
        rng = np.random.default_rng([self.config.seed, group])
        draws = np.frombuffer(rng.bytes(FRAMES_PER_GROUP * gb20600.DATA_LENGTH), dtype=np.uint8)
        if out is None:
            out = np.empty((FRAMES_PER_GROUP, gb20600.BODY_LENGTH), dtype=np.complex128)
        carriers_kernel(draws.reshape(FRAMES_PER_GROUP, gb20600.DATA_LENGTH), self._points, self._bin_data,
                        self._carriers_template, out)
        return out

    def carriers(self, frame_number: int) -> np.ndarray:
        """Physical carrier vector X[k] (FFT-bin order) of a frame's body."""
        group, row = divmod(frame_number, FRAMES_PER_GROUP)
        return self._group_carriers(group)[row]

    def _build_group(self, group: int) -> np.ndarray:
        """Header + body symbols of a group's frames, one after the other (complex64, read-only).

        Single precision: its rounding is about -140 dB of the symbol power.
        """
        if group < 0:
            raise ValueError("frame numbers start at 0")
        if self._ifft is None:
            self._ifft = fftw_plan(FRAMES_PER_GROUP, gb20600.BODY_LENGTH, "FFTW_BACKWARD", np.complex64)
        self._group_carriers(group, self._ifft.input_array)
        self._ifft.execute()
        header_length = self.config.pn_mode.value.header_length
        frames = np.empty((FRAMES_PER_GROUP, self.config.frame_length), dtype=np.complex64)
        for row in range(FRAMES_PER_GROUP):
            frames[row, :header_length] = self._frame_header(group * FRAMES_PER_GROUP + row)
        # Unitary IDFT: x[t] = (1/sqrt(N)) sum_k X[k] exp(+j 2 pi k t / N)  (docs/dtmb.md §3.3)
        scale = np.float32(1.0 / np.sqrt(gb20600.BODY_LENGTH))
        np.multiply(self._ifft.output_array, scale, out=frames[:, header_length:])
        frames = frames.reshape(-1)
        frames.flags.writeable = False
        return frames

    def frame_symbols(self, frame_number: int) -> np.ndarray:
        """Header + body symbols of one frame (complex128)."""
        if frame_number < 0:
            raise ValueError("frame numbers start at 0")
        flen = self.config.frame_length
        return self.symbols(frame_number * flen, (frame_number + 1) * flen)

    def symbols(self, start: int, stop: int, out: np.ndarray | None = None) -> np.ndarray:
        """Transmitted symbols with absolute indices ``start <= n < stop``.

        Symbol 0 is the first symbol of frame 0, the first frame of a superframe.
        ``out`` (length ``stop - start``, any complex dtype) receives them
        instead of a new complex128 array.
        """
        if start < 0 or stop < start:
            raise ValueError(f"bad symbol range [{start}, {stop})")
        size = self.config.frame_length * FRAMES_PER_GROUP
        if out is None:
            out = np.empty(stop - start, dtype=np.complex128)
        pos = start
        while pos < stop:
            group, offset = divmod(pos, size)
            take = min(size - offset, stop - pos)
            out[pos - start: pos - start + take] = self._group(group)[offset: offset + take]
            pos += take
        return out
