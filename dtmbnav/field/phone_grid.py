"""The common part of the live phone sources (:mod:`dtmbnav.field.phone_stream`): their chunks, their counts,
and the resampling of samples arriving in pieces onto the file importer's grid.

:class:`Resampler` makes, from samples given a piece at a time, the grid samples that
:func:`dtmbnav.field.sensors_import.build_sensors` makes from the whole log: the grid starts at the
latest first sample of the sensors present (``common_grid``), its times are k / rate after it
(``uniform_grid``), each sensor is linearly interpolated at them (``resampling.interpolate``) from the
same two neighbouring samples, so the values are the same floats. A grid time is given out once every
sensor has a sample at or after it. What differs is said in :mod:`dtmbnav.field.phone_stream`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from dtmbnav.field.sensors_import import DEFAULT_RATE_HZ, Gap
from dtmbnav_core import phone_formats as fmt
from dtmbnav_core.records import ColumnRecord, GeodeticFixes, ImuLog
from dtmbnav_core.resampling import interpolate

#: Longest stretch without samples of a sensor that the grid interpolates across, s: the phone's usual
#: dropped runs are tens of ms; a step takes ~0.5 s, so a longer stretch would be a step invented.
MAX_BRIDGE_S = 0.5
#: How long (sample time) the grid waits for a magnetometer after the accelerometer and gyroscope begin, s;
#: without one by then, ``mag_ut`` is zeros (``has_magnetometer`` False), as the importer writes a log without.
MAGNETOMETER_WAIT_S = 1.0
#: Most samples one sensor holds waiting for the others (a minute at 500 Hz); past that the oldest go, counted.
MAX_HELD_SAMPLES = 30_000
#: Fix batches held until the grid starts (fixes come ~1 Hz: only a grid that never starts piles them up).
MAX_HELD_FIXES = 256


@dataclass(frozen=True)
class PhoneChunk:
    """What settled since the last poll.

    Attributes
    ----------
    imu : ImuLog
        Grid samples (possibly none), t_s s since the stream's ``t0_utc_ns``.
    fixes : GeodeticFixes
    gaps : tuple of Gap
        Stretches longer than :data:`MAX_BRIDGE_S` without a sensor's samples, s on the stream's clock.
    notes : tuple of str
        Errors and warnings (rejected batches, late samples dropped, lost messages, ...).
    """

    imu: ImuLog
    fixes: GeodeticFixes
    gaps: tuple[Gap, ...] = ()
    notes: tuple[str, ...] = ()


@dataclass
class StreamStats:
    """Counts over the stream's life (what was taken, and every loss, by cause)."""

    batches: int = 0
    samples: int = 0
    fixes: int = 0
    rejected_batches: int = 0
    overflow_batches: int = 0
    lost_messages: int = 0
    late_samples: int = 0
    repeated_samples: int = 0
    bad_rows: int = 0
    gaps: int = 0


class PhoneStream(Protocol):
    """A live phone source: chunks on the stream's own clock."""

    @property
    def t0_utc_ns(self) -> int | None:
        """UTC of the grid's first sample, ns since the Unix epoch; None before the grid starts."""

    @property
    def stats(self) -> StreamStats: ...

    def idle_s(self) -> float:
        """Wall-clock seconds since data last arrived (a stalled phone: the caller flags the gap)."""

    def poll(self) -> PhoneChunk | None: ...

    def close(self) -> PhoneChunk | None: ...


def _empty_imu() -> ImuLog:
    return ImuLog(t_s=np.zeros(0), acc_mps2=np.zeros((0, 3)), gyro_radps=np.zeros((0, 3)), mag_ut=np.zeros((0, 3)))


class _Series:
    """One sensor's settled samples, from the one just before the next grid time on: times (log clock, ns)."""

    def __init__(self) -> None:
        self.t_ns = np.zeros(0, dtype=np.int64)
        self.values = np.zeros((0, 3))
        self.first_ns: int | None = None


class Resampler:
    """Sensor samples in arrival order -> grid samples, as :func:`~dtmbnav.field.sensors_import.build_sensors`
    makes them (module docstring); ``stats`` counts what it drops."""

    def __init__(self, stats: StreamStats, rate_hz: float = DEFAULT_RATE_HZ) -> None:
        self.rate_hz = rate_hz
        self.stats = stats
        self.series = {sensor: _Series() for sensor in fmt.SENSORS}
        self.t0_ns: int | None = None
        self.has_magnetometer: bool | None = None
        self.next_k = 0
        self.gaps: list[Gap] = []
        self.notes: list[str] = []
        self._gaps_ns: list[tuple[str, int, int]] = []

    def add(self, sensor: str, t_ns: np.ndarray, values: np.ndarray) -> None:
        """Append samples (sorted here): a time not after the last one taken is dropped and counted."""
        s = self.series[sensor]
        order = np.argsort(t_ns, kind="stable")
        t_ns, values = np.asarray(t_ns, dtype=np.int64)[order], np.asarray(values, dtype=np.float64)[order]
        last = s.t_ns[-1] if len(s.t_ns) else np.iinfo(np.int64).min
        before = np.maximum.accumulate(np.concatenate(([last], t_ns)))[:-1]  # the latest time taken before each
        keep, late = t_ns > before, t_ns < before
        self.stats.repeated_samples += int((t_ns == before).sum())
        if late.any():
            self.stats.late_samples += int(late.sum())
            self.notes.append(f"{sensor}: {int(late.sum())} sample(s) came after later ones were taken: dropped")
        t_ns, values = t_ns[keep], values[keep]
        if not len(t_ns):
            return
        if s.first_ns is None:
            s.first_ns = int(t_ns[0])
        joined = np.concatenate(([last], t_ns)) if len(s.t_ns) else t_ns
        for i in np.flatnonzero(np.diff(joined) > MAX_BRIDGE_S * 1e9):
            self._gaps_ns.append((sensor, int(joined[i]), int(joined[i + 1])))
        s.t_ns, s.values = np.concatenate((s.t_ns, t_ns)), np.concatenate((s.values, values))
        self.stats.samples += len(t_ns)
        if len(s.t_ns) > MAX_HELD_SAMPLES:
            drop = len(s.t_ns) - MAX_HELD_SAMPLES
            self.stats.late_samples += drop
            self.notes.append(f"{sensor}: {drop} sample(s) dropped waiting for the other sensors (one silent?)")
            s.t_ns, s.values = s.t_ns[drop:], s.values[drop:]

    def _start(self, final: bool) -> bool:
        """Fix the grid's first sample once every sensor present has begun (module docstring)."""
        if self.t0_ns is not None:
            return True
        acc, gyro, mag = (self.series[name] for name in fmt.SENSORS)
        if acc.first_ns is None or gyro.first_ns is None:
            return False
        if mag.first_ns is None:
            newest = min(int(acc.t_ns[-1]), int(gyro.t_ns[-1]))
            if not final and newest - max(acc.first_ns, gyro.first_ns) < MAGNETOMETER_WAIT_S * 1e9:
                return False
            self.has_magnetometer = False
            self.notes.append("no magnetometer: mag_ut holds zeros (has_magnetometer False)")
        else:
            self.has_magnetometer = True
        self.t0_ns = max(s.first_ns for s in self._used())
        return True

    def _used(self) -> list[_Series]:
        return [self.series[name] for name in fmt.SENSORS if name != "magnetometer" or self.has_magnetometer]

    def emit(self, final: bool = False) -> ImuLog:
        """The grid samples whose neighbours have arrived (``final``: the stream ended; start without waiting)."""
        if not self._start(final) or any(not len(s.t_ns) for s in self._used()):
            return _empty_imu()
        t0 = self.t0_ns
        for sensor, a, b in self._gaps_ns:
            if b > t0:
                self.gaps.append(Gap(sensor, (a - t0) / 1e9, (b - t0) / 1e9))
                self.stats.gaps += 1
        self._gaps_ns.clear()
        end_ns = min(int(s.t_ns[-1]) for s in self._used())
        if end_ns < t0:
            return _empty_imu()
        n = int(np.floor(((end_ns - t0) / 1e9) * self.rate_hz)) + 1  # sensors_import.common_grid's grid
        t_s = np.arange(self.next_k, n) / self.rate_hz
        if not len(t_s):
            return _empty_imu()
        keep = np.ones(len(t_s), dtype=bool)
        out = {}
        for name in fmt.SENSORS:
            s = self.series[name]
            if name == "magnetometer" and not self.has_magnetometer:
                continue
            xp = (s.t_ns - t0) / 1e9
            j = np.clip(np.searchsorted(xp, t_s, side="right") - 1, 0, max(len(xp) - 2, 0))
            if len(xp) > 1:
                keep &= ~((xp[j + 1] - xp[j] > MAX_BRIDGE_S) & (t_s > xp[j]) & (t_s < xp[j + 1]))
            out[name] = interpolate(xp, s.values, t_s)
            # keep the sample just before the next grid time: the left neighbour of what comes next
            cut = max(int(np.searchsorted(xp, n / self.rate_hz, side="right")) - 1, 0)
            s.t_ns, s.values = s.t_ns[cut:], s.values[cut:]
        self.next_k = n
        mag = out["magnetometer"][keep] if self.has_magnetometer else np.zeros((int(keep.sum()), 3))
        return ImuLog(t_s=t_s[keep], acc_mps2=out["accelerometer"][keep], gyro_radps=out["gyroscope"][keep],
                      mag_ut=mag)


class Collector:
    """What a source gathers between polls: resampled IMU, fixes (held until the grid starts), notes."""

    def __init__(self, rate_hz: float) -> None:
        self.stats = StreamStats()
        self.grid = Resampler(self.stats, rate_hz)
        self.utc_offset_ns: int | None = None
        self._fixes: list[tuple[np.ndarray, ...]] = []  # (t_ns, lat, lon, height, accuracy, cn0)
        self.notes: list[str] = []
        self.last_data = time.monotonic()

    @property
    def t0_utc_ns(self) -> int | None:
        if self.grid.t0_ns is None or self.utc_offset_ns is None:
            return None
        return self.grid.t0_ns + self.utc_offset_ns

    def add_fixes(self, t_ns, lat, lon, height, accuracy, cn0) -> None:
        self._fixes.append(tuple(np.asarray(a) for a in (t_ns, lat, lon, height, accuracy, cn0)))
        self.stats.fixes += len(t_ns)
        if len(self._fixes) > MAX_HELD_FIXES:  # fixes come ~1 Hz; only a grid that never starts piles them up
            self.notes.append(f"{len(self._fixes[0][0])} fix(es) dropped: the motion sensors never began")
            del self._fixes[0]

    def chunk(self, final: bool = False) -> PhoneChunk | None:
        imu = self.grid.emit(final)
        fixes = GeodeticFixes.empty()
        if self.grid.t0_ns is not None and self._fixes:
            columns = [np.concatenate(c) for c in zip(*self._fixes)]
            order = np.argsort(columns[0], kind="stable")
            t_s = (columns[0][order] - self.grid.t0_ns) / 1e9
            fixes = GeodeticFixes(t_s, *(c[order].astype(np.float64) for c in columns[1:]))
            self._fixes.clear()
        notes = tuple(self.notes + self.grid.notes)
        gaps = tuple(self.grid.gaps)
        self.notes.clear()
        self.grid.notes.clear()
        self.grid.gaps.clear()
        if not len(imu.t_s) and not len(fixes.t_s) and not gaps and not notes:
            return None
        return PhoneChunk(imu, fixes, gaps, notes)
