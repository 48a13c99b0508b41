"""Clock-offset calibration and Doppler ranging (docs/method.md §2, eq. 9-11).

``df_m = f_s + f_d,m + noise`` (eq. 9): f_s, the constant part of the carrier
offset (oscillator mismatch plus the tuner's bulk offset), is measured while
the receiver stands still at the start (``static_window_s``, default :data:`receiver.DEFAULT_STATIC_WINDOW_S`) or
given by the user. Then per frame

- ``doppler_hz = cfo_hz - f_s``,
- ``velocity_mps = doppler_hz * c / fc`` (eq. 10; positive when closing),
- ``range_change_m = -(c / fc) * sum (cfo_hz - f_s) * dt`` (eq. 11 with the
  sign of docs/conventions.md: range shrinks when closing), with dt the time
  between the frame and the one before it.

The f_s of the static window is the time-weighted mean of the CFO over it,
i.e. the total SI phase advance over the window divided by its duration (the
per-frame phase differences telescope). The sum is kept in float64 and is
continuous across batches. The first frame of a lock has no CFO pair and
adds nothing, so across a gap (a loss of lock and a re-acquisition) the range
is held flat: nothing is known of the motion during the gap, and inventing
some (the last velocity times the gap) would put a jump in the range. A drop
(samples the front end lost, flagged DROP) is different: its length is
measured to a sample and is tens of milliseconds at most, so the median
Doppler of the last trusted frames bridges it. After a
gap ``range_change_m`` is therefore the range change since the first frame of
the new segment (``segment_id``) plus the last value of the segment before
it; the receiver flags that frame GAP, and the fusion takes the new segment as
a new range origin.

The same eq. 9-11 apply to one propagation path's carrier frequency
(``docs/paths.md``): a second integrator works on the first path's columns
(:data:`FIRST_PATH_COLUMNS`), with its own f_s from the same static window
(the first path's own mean frequency there; the SI carriers' f_s when the
first path had no valid frame in it), and :class:`PathRanging` applies that
f_s to every tracked path's rows.

At a standstill every path has zero Doppler, so any path's mean frequency
over the static window is f_s; what differs is how much the scatter around a
path disturbs its phase. In a street whose direct path is blocked, the
first path is 20 dB down and merges with diffuse scatter (which moves while
the walker stands: environmental motion), so its mean frequency over a few
seconds can be off by tenths of a hertz, and that error grows the range by
tens of metres over a walk; a wall reflection there may hold its phase.
:meth:`PathRanging.steadiest_path_offset_hz` measures f_s on the path whose
phase stays closest to a straight line over the window instead
(``PathConfig.clock_path``): power does not tell a clean path from a
composite whose parts beat, phase linearity does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import FrameBatch, FrameFlag, PathBatch, PathFlag
from receiver import DEFAULT_STATIC_WINDOW_S


#: Trusted frames whose median Doppler bridges a drop (a few tens of milliseconds of PN420 frames).
BRIDGE_FRAMES = 32


@dataclass(frozen=True)
class RangeColumns:
    """The :class:`FrameBatch` columns one integrator reads and writes (None: not written)."""

    cfo: str
    range: str
    doppler: str | None = None
    velocity: str | None = None


#: The SI-carrier columns (eq. 5-11).
SI_COLUMNS = RangeColumns("cfo_hz", "range_change_m", "doppler_hz", "velocity_mps")
#: The first path's columns (docs/paths.md).
FIRST_PATH_COLUMNS = RangeColumns("first_path_cfo_hz", "first_path_range_change_m")


def mean_frequency_hz(cfo_hz: np.ndarray, dt_s: np.ndarray) -> float:
    """Time-weighted mean of per-frame frequencies: the phase advance over the frames divided by their duration.

    The f_s of a static window (eq. 9), for the SI carriers' or one path's frequencies alike.
    """
    return float(np.sum(cfo_hz * dt_s) / np.sum(dt_s))


def held_doppler(doppler_hz: np.ndarray, last_hz: float) -> np.ndarray:
    """``doppler_hz`` with each NaN replaced by the last finite value before it (``last_hz`` before the first)."""
    missing = ~np.isfinite(doppler_hz)
    if not missing.any():
        return doppler_hz
    idx = np.where(~missing, np.arange(len(doppler_hz)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, doppler_hz[np.maximum(idx, 0)], last_hz)


class RangeIntegrator:
    """Turns CFO rows into Doppler, velocity and integrated range.

    Parameters
    ----------
    carrier_hz : float
        RF carrier of the tower, Hz.
    clock_offset_hz : float or None
        f_s given by the user; None to measure it over the static window.
    static_window_s : float
        Length of the static window at the start of the first lock, s.
    columns : RangeColumns
        What to integrate: the SI carriers' CFO (default) or the first path's.
    fallback : RangeIntegrator, optional
        Whose f_s to use when the static window holds no usable frame of
        ``columns.cfo`` (instead of an error); it must have calibrated first.
    calibration : callable, optional
        ``calibration(t_from_s, t_to_s)`` measures f_s over the static window
        elsewhere (e.g. :meth:`PathRanging.steadiest_path_offset_hz`); where it
        returns None, f_s comes from ``columns.cfo`` as without it.
    """

    def __init__(self, carrier_hz: float, clock_offset_hz: float | None = None,
                 static_window_s: float = DEFAULT_STATIC_WINDOW_S, columns: RangeColumns = SI_COLUMNS,
                 fallback: "RangeIntegrator | None" = None,
                 calibration: Callable[[float, float], float | None] | None = None) -> None:
        if not np.isfinite(carrier_hz) or carrier_hz <= 0:
            raise ValueError(f"carrier_hz must be a positive frequency, got {carrier_hz!r}")
        if clock_offset_hz is None and static_window_s <= 0:
            raise ValueError("static_window_s must be positive when no clock_offset_hz is given")
        self.carrier_hz = carrier_hz
        self.wavelength_m = SPEED_OF_LIGHT_MPS / carrier_hz
        self.clock_offset_hz = clock_offset_hz
        self.static_window_s = static_window_s
        self.columns = columns
        self.fallback = fallback
        self.calibration = calibration
        self._pending: list[FrameBatch] = []
        self._t_first: float | None = None
        self._range_m = 0.0
        self._last_t_s: float | None = None
        self._recent_doppler_hz = np.zeros(0)     # the last trusted Dopplers, for bridging a drop

    def push(self, batch: FrameBatch) -> list[FrameBatch]:
        """Add receiver rows; return the rows whose range is now known."""
        if len(batch) == 0:
            return []
        if self._t_first is None:
            self._t_first = float(batch.t_s[0])
        if self.clock_offset_hz is not None:
            return [self._integrate(batch)]
        self._pending.append(batch)
        if float(batch.t_s[-1]) < self._t_first + self.static_window_s:
            return []
        return self._calibrate()

    def flush(self) -> list[FrameBatch]:
        """End of stream: calibrate on what arrived if the window never filled."""
        return self._calibrate() if self._pending else []

    def _calibrate(self) -> list[FrameBatch]:
        rows = FrameBatch.concatenate(self._pending)
        self._pending = []
        in_window = rows.t_s < self._t_first + self.static_window_s
        dt = np.diff(rows.t_s, prepend=np.nan)
        cfo = getattr(rows, self.columns.cfo)
        usable = in_window & np.isfinite(cfo) & ((rows.flags & FrameFlag.LOW_QUALITY) == 0)
        measured = (None if self.calibration is None
                    else self.calibration(self._t_first, self._t_first + self.static_window_s))
        if measured is not None:
            self.clock_offset_hz = measured
        elif np.any(usable):
            self.clock_offset_hz = mean_frequency_hz(cfo[usable], dt[usable])
        elif self.fallback is not None and self.fallback.clock_offset_hz is not None:
            self.clock_offset_hz = self.fallback.clock_offset_hz
        else:
            raise ValueError("no valid frame in the static window: cannot estimate the clock offset f_s "
                             "(give clock_offset_hz or a longer static_window_s)")
        rows.flags[in_window] |= np.uint8(FrameFlag.CALIBRATION)
        return [self._integrate(rows)]

    def _remember(self, doppler: np.ndarray, flags: np.ndarray) -> None:
        """Keep the last :data:`BRIDGE_FRAMES` trusted Dopplers (finite, not LOW_QUALITY)."""
        trusted = doppler[np.isfinite(doppler) & ((flags & FrameFlag.LOW_QUALITY) == 0)]
        if len(trusted):
            self._recent_doppler_hz = np.concatenate([self._recent_doppler_hz, trusted[-BRIDGE_FRAMES:]])[
                -BRIDGE_FRAMES:]

    def _integrate(self, batch: FrameBatch) -> FrameBatch:
        assert self.clock_offset_hz is not None
        doppler = getattr(batch, self.columns.cfo) - self.clock_offset_hz
        t_prev = np.concatenate([[self._last_t_s if self._last_t_s is not None else batch.t_s[0]], batch.t_s[:-1]])
        # A frame without a CFO pair (a lock's first) adds nothing: the range is held across a gap. Across a
        # drop the time lost is known to a sample and short: the recent Doppler bridges it (the median of the
        # last trusted frames: the frame the drop cut through carries a wild CFO).
        bridge = ~np.isfinite(doppler) & ((batch.flags & FrameFlag.DROP) != 0)
        rate = doppler
        done = 0   # frames of the batch remembered so far
        if bridge.any():
            rate = doppler.copy()
            for k in np.flatnonzero(bridge):
                self._remember(doppler[done:k], batch.flags[done:k])
                done = k
                rate[k] = np.median(self._recent_doppler_hz) if len(self._recent_doppler_hz) else 0.0
        self._remember(doppler[done:], batch.flags[done:])
        cycles = np.cumsum(np.where(np.isfinite(rate), rate * (batch.t_s - t_prev), 0.0))
        range_m = self._range_m - self.wavelength_m * cycles
        self._range_m = float(range_m[-1])
        self._last_t_s = float(batch.t_s[-1])
        out = {self.columns.range: range_m}
        if self.columns.doppler is not None:
            out[self.columns.doppler] = doppler
        if self.columns.velocity is not None:
            out[self.columns.velocity] = doppler * self.wavelength_m
        return replace(batch, **out)


class PathRanging:
    """Eq. 9-11 per tracked path: ``doppler_hz`` and ``range_change_m`` of ``/receiver/paths`` rows.

    Rows wait until the f_s they need is known (the first-path integrator's,
    after the static window), then every path's Doppler ``cfo_hz - f_s`` is
    integrated from the path's first row (range change 0 there), holding the
    last Doppler where ``cfo_hz`` is NaN, exactly as :class:`RangeIntegrator`.

    Parameters
    ----------
    carrier_hz : float
        RF carrier, Hz.
    """

    def __init__(self, carrier_hz: float) -> None:
        self.wavelength_m = SPEED_OF_LIGHT_MPS / carrier_hz
        self._pending: list[PathBatch] = []
        #: path id -> (range change, last Doppler, time of its last row)
        self._state: dict[int, tuple[float, float, float]] = {}

    def push(self, rows: PathBatch) -> None:
        """Queue rows (in frame order)."""
        if len(rows):
            self._pending.append(rows)

    def steadiest_path_offset_hz(self, t_from_s: float, t_to_s: float, min_coverage: float = 0.25) -> float | None:
        """f_s measured on the steadiest path tracked through a static window (module docstring), Hz.

        Every queued path (every tower's: the towers of an SFN share the
        carrier) whose rows cover at least ``min_coverage`` of the window
        without a cycle slip is a candidate. Standing still, each one's phase
        advances at f_s; scatter merged with a path, or a second path not yet
        resolved from it, bends its phase away from that straight line. The
        score of a path is the RMS of its integrated phase about a fitted
        line, in cycles, divided by the time its rows cover, s: the frequency
        error its wander allows, Hz. The lowest score gives its
        :func:`mean_frequency_hz` over the window (as :class:`RangeIntegrator`
        measures the first path's). None when no path qualifies (the caller
        then measures f_s as it would without this). The window is
        ``[t_from_s, t_to_s)`` from the first path row in it on (a path is
        confirmed a few hundred frames after the lock, some only seconds later).
        """
        rows = PathBatch.concatenate(self._pending)
        rows = rows.select((rows.t_s >= t_from_s) & (rows.t_s < t_to_s))
        if len(rows) == 0:
            return None
        window_s = t_to_s - float(rows.t_s.min())
        best: tuple[float, float] | None = None          # (score, f_s)
        for path_id in np.unique(rows.path_id):
            path = rows.select(rows.path_id == path_id)
            dt = np.diff(path.t_s, prepend=np.nan)
            ok = np.isfinite(path.cfo_hz) & np.isfinite(dt)
            covered_s = float(np.sum(dt[ok]))
            if np.any(path.flags & PathFlag.CYCLE_SLIP) or ok.sum() < 3 or covered_s < min_coverage * window_s:
                continue
            f_s = mean_frequency_hz(path.cfo_hz[ok], dt[ok])
            t = path.t_s[ok] - float(np.mean(path.t_s[ok]))
            phase_cycles = np.cumsum((path.cfo_hz[ok] - f_s) * dt[ok])
            slope, offset = np.polyfit(t, phase_cycles, 1)
            score = float(np.sqrt(np.mean((phase_cycles - slope * t - offset) ** 2))) / covered_s
            if best is None or score < best[0]:
                best = (score, f_s)
        return None if best is None else best[1]

    def release(self, clock_offset_hz: float | None, until_t_s: float) -> PathBatch:
        """The queued rows up to ``until_t_s`` with their range, once ``clock_offset_hz`` is known."""
        if clock_offset_hz is None or not self._pending:
            return PathBatch.concatenate([])
        rows = self._pending[0] if len(self._pending) == 1 else PathBatch.concatenate(self._pending)
        done = rows.t_s <= until_t_s
        if done.all():
            self._pending = []
        else:
            self._pending = [rows.select(~done)]
            rows = rows.select(done)
        if len(rows) == 0:
            return rows
        doppler = rows.cfo_hz - clock_offset_hz
        # Group the rows by path (in time order within each) and integrate every group at once.
        order = np.lexsort((rows.t_s, rows.path_id))
        ids, t, dop = rows.path_id[order], rows.t_s[order], doppler[order]
        first = np.r_[True, ids[1:] != ids[:-1]]
        group = np.cumsum(first) - 1
        starts = np.flatnonzero(first)
        carried = [self._state.get(int(pid)) for pid in ids[starts]]
        born = (rows.flags[order][starts] & PathFlag.BORN) > 0
        fresh = np.array([c is None or b for c, b in zip(carried, born)])
        range0 = np.array([0.0 if f else c[0] for f, c in zip(fresh, carried)])
        last_doppler = np.array([0.0 if f else c[1] for f, c in zip(fresh, carried)])
        last_t = np.array([t[s] if f else c[2] for f, c, s in zip(fresh, carried, starts)])
        # Held Doppler: the last finite value in the group, else the path's last one.
        finite = np.isfinite(dop)
        idx = np.where(finite, np.arange(len(dop)), -1)
        np.maximum.accumulate(idx, out=idx)
        inside = idx >= starts[group]
        held = np.where(inside, dop[np.maximum(idx, 0)], last_doppler[group])
        dt = np.diff(np.r_[0.0, t])
        dt[starts] = t[starts] - last_t
        steps = held * dt
        total = np.cumsum(steps)
        before = np.r_[0.0, total][starts]            # cumulative sum before each group
        path_range = range0[group] - self.wavelength_m * (total - before[group])
        range_m = np.empty(len(rows))
        range_m[order] = path_range
        ends = np.r_[starts[1:], len(ids)] - 1
        self._state = {int(ids[e]): (float(path_range[e]), float(held[e]), float(t[e])) for e in ends}
        return replace(rows, doppler_hz=doppler, range_change_m=range_m)
