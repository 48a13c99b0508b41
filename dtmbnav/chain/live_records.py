"""What ``dtmbnav live`` is given, says as it goes and gives back (:mod:`dtmbnav.chain.live`), and where its files go."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from dtmbnav.field.towers import Tower
from dtmbnav_core.geodetic import GeodeticPoint
from dtmbnav_core.start_fix import CombinedFix
from fusion.pdr import PdrConfig
from fusion.run import FusionConfig, FusionResult

#: File names in the live command's output folder.
RECEIVER_NAME = "receiver.h5"
LIVE_NAME = "live.h5"
CSV_NAME = "live.csv"
GEOJSON_NAME = "live.geojsonl"
#: Receiver frames kept for the fusion before it can start (no start fix or clock offset yet), s: the
#: fusion needs none from before the walk's first steps, and memory stays bounded however long one waits.
PRE_START_FRAMES_S = 60.0
#: Stages of a live position, as the line formats and the page name them.
STAGE_HEADING, STAGE_FILTERED, STAGE_NOWCAST = "heading", "filtered", "nowcast"


@dataclass(frozen=True)
class LiveSetup:
    """What a live walk is fused with.

    Attributes
    ----------
    towers : tuple of Tower
        The towers used, the ranging tower first (:func:`dtmbnav.field.towers.choose_towers`).
    filters : tuple of str
        Streaming filters (:data:`fusion.streaming.STREAMING_FILTERS`); the first is the live one.
    fusion : FusionConfig
    pdr : PdrConfig
    time_offset_s : float or None
        Where the capture starts on the phone's clock, s; None: from the two streams' UTC stamps.
    start : GeodeticPoint or None
        The start position when given (the walk's frame is then about it and its sigma the filters'
        default); None: from the phone's fixes.
    start_window_s : float or None
        Only the standstill's last seconds make the start fix (``dtmbnav sensors --start-window``).
    tick_s : float
        How often the fusion thread polls and writes, s.
    """

    towers: tuple[Tower, ...]
    filters: tuple[str, ...] = ("pf",)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    pdr: PdrConfig = field(default_factory=PdrConfig)
    time_offset_s: float | None = None
    start: GeodeticPoint | None = None
    start_window_s: float | None = None
    tick_s: float = 0.5


@dataclass
class LiveStatus:
    """What the status line and the page say, updated as the streams come.

    Attributes
    ----------
    frames, gaps : int
        Receiver frames, and those flagged as the first after a loss of lock.
    snr_db : float
        The newest batch's median SI-carrier SNR, dB.
    clock_offset_hz : float
        The receiver's oscillator offset f_s, Hz (NaN until measured in the standstill).
    capture_s : float
        Receiver time of the newest frame, s.
    walk_s : float
        Phone time of the newest IMU sample, s.
    steps, provisional_steps : int
        Settled and provisional PDR steps.
    positions : int
        Positions written.
    stage : str
        The newest position's stage.
    position : str
        The newest position, latitude and longitude (deg) and its 95 % radius (m), as the status line says it.
    lag_s : float
        The newest phone sample's time minus the newest position's, s of walk (a held position,
        :func:`fusion.streaming.hold_position`, is at the newest sample).
    step_lag_s : float
        The newest phone sample's time minus the newest PDR step's (settled or provisional), s of walk:
        how far the motion the position holds trails the samples while walking (it grows in a standstill).
    longest_silence_s : float
        The longest wait between two writes of positions since the initial heading became confident,
        s of the host's clock.
    """

    frames: int = 0
    gaps: int = 0
    snr_db: float = math.nan
    clock_offset_hz: float = math.nan
    capture_s: float = math.nan
    walk_s: float = math.nan
    steps: int = 0
    provisional_steps: int = 0
    positions: int = 0
    stage: str = "waiting"
    position: str = "-"
    lag_s: float = math.nan
    step_lag_s: float = math.nan
    longest_silence_s: float = 0.0

    def line(self) -> str:
        """One line for the terminal."""
        lock = "no lock" if not self.frames else (f"{self.frames} frames, SNR {self.snr_db:.1f} dB, "
                                                  f"f_s {self.clock_offset_hz:+.1f} Hz, {self.gaps} gap(s)")
        return (f"{lock} | walk {self.walk_s:.1f} s, {self.steps} steps (+{self.provisional_steps}) | "
                f"{self.position} ({self.stage}, {self.lag_s:.1f} s behind)")


@dataclass
class LiveResult:
    """What a live walk gave.

    Attributes
    ----------
    fusion : FusionResult or None
        The final tracks (None where the walk never got a start fix or two steps).
    status : LiveStatus
    notes : list of str
        What the user should know (no start fix, phone gaps, ...).
    start_fix : CombinedFix or None
    origin : GeodeticPoint or None
    time_offset_s : float or None
        The capture's start on the phone's clock used, s.
    cpu_s : dict of str to float
        CPU time of the receiver's thread (``receiver``), the fusion thread (``fusion``), the whole
        process (``process``) and the process from its first frame on (``after_first_frame``: its
        start-up left out), s: where a live walk's processor goes.
    """

    fusion: FusionResult | None
    status: LiveStatus
    notes: list[str]
    start_fix: CombinedFix | None
    origin: GeodeticPoint | None
    time_offset_s: float | None
    cpu_s: dict[str, float] = field(default_factory=dict)


def output_paths(folder: str | os.PathLike) -> dict[str, Path]:
    """The files ``dtmbnav live`` writes in ``folder``."""
    folder = Path(folder)
    return {"receiver": folder / RECEIVER_NAME, "live": folder / LIVE_NAME, "csv": folder / CSV_NAME,
            "geojson": folder / GEOJSON_NAME}
