"""Observables: the receiver's output rows turned into the range observations fusion consumes.

The receiver writes one row per frame (``/receiver/frames``) and one per
frame and tracked path (``/receiver/paths``); this stage reads those columns
and gives the typed :class:`~dtmbnav_core.records.Observations`:

- the SI-carrier range change (:func:`ranges_from_frames`, eq. 9-11), with
  the frames flagged as a gap or low quality marked invalid;
- per tower, the first path's carrier range change and its code range
  (:func:`first_path_code_range_m`), and each tower's clock-free range
  difference to tower 0 with its code range difference
  (:func:`range_difference_code_m`), each broken into runs at a cycle slip
  or a change of first path (:func:`paths_from_frames`, docs/paths.md);
- the receiver's towers matched to the tower table by their first paths'
  delays (:func:`receiver_tower_order`).

It works on the column arrays as they come from a file or from the
receiver's batches (``FrameBatch.columns()``), so ``dtmbnav fuse`` and the
IQ-level evaluation read the receiver the same way. Older files that lack
a column (no SI SNR, no lock segment, no path tracker) are read with the
documented fall-back.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import FrameFlag, Observations, PathFlag, PathRanges, PathRangeSeries, RangeSeries

#: Frame flags that make a frame's range unusable for ranging.
UNUSABLE_FLAGS = FrameFlag.GAP | FrameFlag.LOW_QUALITY


def ranges_from_frames(columns: dict[str, np.ndarray], time_offset_s: float = 0.0) -> RangeSeries:
    """Receiver frame columns -> the :class:`RangeSeries` fusion consumes.

    Frames flagged as a gap or low quality, and frames without a range
    (NaN), are marked invalid; ``time_offset_s`` moves the receiver's times
    onto the IMU's time base. The SNR handed on is the SI-carrier SNR (the
    slice of the band the range is measured on, whose fading the fusion
    watches for multipath); files from receivers that did not write it give
    the header SNR instead. The lock segment goes with them (the fusion takes
    a new segment as a new range origin); files from receivers that did not
    write it are one segment.
    """
    rng = columns["range_change_m"]
    valid = np.isfinite(rng) & ((columns["flags"].astype(np.int64) & int(UNUSABLE_FLAGS)) == 0)
    segment = columns.get("segment_id", np.zeros(len(rng), dtype=np.int32)).astype(np.int32)
    return RangeSeries(t_s=columns["t_s"] + time_offset_s, range_change_m=np.where(np.isfinite(rng), rng, 0.0),
                       snr_db=columns.get("si_snr_db", columns["snr_db"]).astype(np.float64), valid=valid,
                       segment_id=segment)


#: ``/receiver/frames`` columns of the path tracker's tower differences (tower k minus tower 0, k = 1, 2).
RANGE_DIFFERENCE_COLUMNS = {1: "range_difference_change_1_m", 2: "range_difference_change_2_m"}


def tower_first_paths(frames: dict[str, np.ndarray], rows: dict[str, np.ndarray] | None,
                       tower: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: the id, SNR (dB), cycle-slip flag and delay (s) of a tower's first path in ``/receiver/paths``.

    Frames where the tower has none get id -1, NaN, False and NaN (and so
    does every frame's delay where the rows have no ``delay_s``). Tower 0's
    id, SNR and delay are the frame columns' (``first_path_id``,
    ``first_path_snr_db``, ``first_path_delay_s``); without the group no slip
    is known.
    """
    n = len(frames["t_s"])
    ids, snr, slip, delay = np.full(n, -1, np.int64), np.full(n, np.nan), np.zeros(n, bool), np.full(n, np.nan)
    if tower == 0:
        ids, snr = frames["first_path_id"].astype(np.int64), frames["first_path_snr_db"].astype(np.float64)
        delay = np.asarray(frames.get("first_path_delay_s", delay), dtype=np.float64)
    if rows is None:
        return ids, snr, slip, delay
    flags = rows["flags"].astype(np.int64)
    sel = np.flatnonzero(((flags & int(PathFlag.FIRST_PATH)) != 0) & (rows["tower_id"] == tower))
    # Join on frame_index (increasing in both groups); rows of frames not in /receiver/frames are left out.
    at = np.minimum(np.searchsorted(frames["frame_index"], rows["frame_index"][sel]), n - 1)
    found = frames["frame_index"][at] == rows["frame_index"][sel]
    sel, at = sel[found], at[found]
    ids[at] = rows["path_id"][sel]
    snr[at] = rows["snr_db"][sel]
    slip[at] = (flags[sel] & int(PathFlag.CYCLE_SLIP)) != 0
    if "delay_s" in rows:
        delay[at] = rows["delay_s"][sel]
    return ids, snr, slip, delay


def first_path_code_range_m(frames: dict[str, np.ndarray], attrs: dict[str, Any]) -> np.ndarray | None:
    """Per frame, the code range of tower 0's first path, m (docs/paths.md, "The first path's code range").

    ``c (t_s + first_path_delay_s - frame_index T_frame)``: the path's
    arrival time on the receiver's clock less the frame's transmit time (up
    to a constant), plus ``lambda f_s t_s``, which takes out the clock's drift
    as the first-path carrier range's f_s does (a receiver clock that runs
    fast by ``eps`` counts ``eps t`` more time and sees the carrier
    ``f_s = -eps f_c`` low). The receiver's frame counter keeps counting
    across gaps; should it slip by whole frames there, the value is taken
    modulo ``c T_frame`` (166 km in PN420) next to the first frame's.
    None without the attributes it needs (``pn_mode``, ``carrier_hz``,
    ``first_path_clock_offset_hz``: a file from a receiver without the path
    tracker, or that found no signal); NaN where no first path is tracked.
    """
    try:
        period_s = gb20600.PnMode.parse(str(attrs["pn_mode"])).value.frame_duration_s
        wavelength_m = SPEED_OF_LIGHT_MPS / float(attrs["carrier_hz"])
        f_s_hz = float(attrs["first_path_clock_offset_hz"])
    except (KeyError, ValueError):
        return None
    if not np.isfinite(f_s_hz):
        return None
    t_s = np.asarray(frames["t_s"], dtype=np.float64)
    # The transmit time in the frame's own period (the t_s and frame counter's common part cancels).
    frames_since = frames["frame_index"] - frames["frame_index"][0]
    arrival_s = (t_s - t_s[0]) + frames["first_path_delay_s"] - frames_since * period_s
    ambiguity_m = SPEED_OF_LIGHT_MPS * period_s
    code_m = SPEED_OF_LIGHT_MPS * arrival_s + wavelength_m * f_s_hz * (t_s - t_s[0])
    known = np.isfinite(code_m)
    if not known.any():
        return code_m
    start = code_m[np.argmax(known)]
    return start + (code_m - start + ambiguity_m / 2.0) % ambiguity_m - ambiguity_m / 2.0


def expected_tower_delays_s(start_ranges_m: Sequence[float],
                            transmit_delays_s: Sequence[float] | None = None) -> np.ndarray:
    """Arrival delay of each tower's direct path at the start P0, relative to tower 0's, s.

    Parameters
    ----------
    start_ranges_m : sequence of float
        Distance from P0 (the GNSS fix) to each tower, in the tower table's order, m.
    transmit_delays_s : sequence of float, optional
        Each tower's transmit delay offset, s (none: 0).
    """
    distance_m = np.asarray(start_ranges_m, dtype=np.float64)
    delay_s = distance_m / SPEED_OF_LIGHT_MPS + (0.0 if transmit_delays_s is None else
                                                np.asarray(transmit_delays_s, dtype=np.float64)[:len(distance_m)])
    return delay_s - delay_s[0]


def receiver_tower_order(first_path_delays_s: Sequence[np.ndarray], expected_delays_s: np.ndarray) -> np.ndarray:
    """Which receiver tower is geometry tower k (entry k), matched on their first paths' delays.

    The receiver numbers the towers of a single-frequency network in the
    order it finds them (``/receiver/paths`` ``tower_id``; the strongest
    first, as a rule), the geometry in the order of the tower table. Tower 0
    is taken as the same in both (it carries the SI carriers' range); the
    others are matched by the median delay of their first paths after
    receiver tower 0's, against the delays the tower table predicts at the
    start (:func:`expected_tower_delays_s`): towers tens of chips apart, a
    fix metres off. A receiver tower never seen keeps its number.

    Parameters
    ----------
    first_path_delays_s : sequence of ndarray
        Per receiver tower, the per-frame delay of its first path, s (NaN: none).
    expected_delays_s : ndarray
        Per geometry tower, its expected arrival delay after tower 0, s.
    """
    from scipy.optimize import linear_sum_assignment

    n = len(expected_delays_s)
    after_tower_0 = [first_path_delays_s[r] - first_path_delays_s[0] for r in range(1, n)]
    measured = np.array([np.nanmedian(d) if np.isfinite(d).any() else np.nan for d in after_tower_0])
    seen = np.flatnonzero(np.isfinite(measured)) + 1
    if not len(seen):
        return np.arange(n)
    cost = np.abs(measured[seen - 1][:, None] - np.asarray(expected_delays_s, dtype=np.float64)[None, 1:])
    receiver, geometry = linear_sum_assignment(cost)
    order = np.full(n, -1)
    order[0] = 0
    order[geometry + 1] = seen[receiver]
    # Geometry towers left without a seen receiver tower take the unseen ones, in order.
    order[order < 0] = np.setdiff1d(np.arange(1, n), seen)
    return order


def paths_from_frames(frames: dict[str, np.ndarray], rows: dict[str, np.ndarray] | None, n_towers: int,
                      time_offset_s: float = 0.0, attrs: dict[str, Any] | None = None,
                      expected_delays_s: np.ndarray | None = None) -> PathRanges | None:
    """The path tracker's output of a receiver file -> the :class:`PathRanges` fusion consumes (docs/paths.md).

    Tower 0's first-path range is the ``first_path_range_change_m`` column;
    the difference of tower k's and tower 0's ranges (k < ``n_towers``) the
    ``range_difference_change_k_m`` column. The receiver numbers towers in the
    order it finds them, which is taken as the geometry's order. An origin
    break (``slip``) is a cycle slip of a first path (``/receiver/paths``
    ``CYCLE_SLIP``) or a change of first path: the path age restarts there,
    and for a difference also where it starts again after a gap. Frames
    flagged as a gap or low quality are invalid. Tower 0's first path
    carries its code range (:func:`first_path_code_range_m`) when the
    receiver's ``attrs`` are given; a difference, with the ``/receiver/paths``
    rows, its code range difference (:func:`range_difference_code_m`), the
    towers' transmit delay offsets still in it (the fusion takes them out).
    With the towers' expected delays (``expected_delays_s``,
    :func:`expected_tower_delays_s`) the receiver's further towers are put in
    the geometry's order (:func:`receiver_tower_order`; without, the
    receiver's order is taken). Returns None for a file without the
    first-path columns (path tracker off).
    """
    if "first_path_range_change_m" not in frames:
        return None
    t = frames["t_s"] + time_offset_s
    usable = (frames["flags"].astype(np.int64) & int(UNUSABLE_FLAGS)) == 0
    towers = [tower_first_paths(frames, rows, k) for k in range(n_towers)]
    order = (np.arange(n_towers) if expected_delays_s is None or rows is None else
             receiver_tower_order([tower[3] for tower in towers], expected_delays_s))

    ids0, snr0, slip0, delay0 = towers[0]
    rng0 = frames["first_path_range_change_m"]
    code0 = None if attrs is None else first_path_code_range_m(frames, attrs)
    first = {0: PathRangeSeries.from_runs(t, rng0, ids0, (ids0 >= 0) & np.isfinite(rng0), usable, snr0, slip0,
                                          code0)}
    differences = {}
    for k in range(1, n_towers):
        name = RANGE_DIFFERENCE_COLUMNS.get(int(order[k]))   # the receiver's column of geometry tower k
        if name is None or name not in frames:
            continue
        ids_k, snr_k, slip_k, delay_k = towers[order[k]]
        diff = frames[name]
        # A pair key: the difference restarts when either tower's first path changes.
        key = ids0 * (1 << 32) + ids_k if rows is not None else np.zeros(len(t), np.int64)
        code = None if rows is None else range_difference_code_m(delay0, delay_k)
        differences[k] = PathRangeSeries.from_runs(t, diff, key, np.isfinite(diff), usable, np.fmin(snr0, snr_k),
                                                  slip0 | slip_k, code)
    return PathRanges(first_path=first, differences=differences)


def range_difference_code_m(delay_0_s: np.ndarray, delay_k_s: np.ndarray) -> np.ndarray:
    """Per frame, the code range difference of tower k's first path and tower 0's, m (docs/paths.md).

    ``c (delay_k - delay_0)``: both delays are read in the same frame on the
    same receiver clock, so its offset and drift cancel; what is left is the
    difference of the distances plus that of the towers' transmit delay
    offsets, ``c (tx_k - tx_0)``, which the fusion takes out as far as it
    knows them (:mod:`fusion.transmit_delays`). NaN where either tower has
    no first path.
    """
    return SPEED_OF_LIGHT_MPS * (np.asarray(delay_k_s, dtype=np.float64) - np.asarray(delay_0_s, dtype=np.float64))


def observations_from_receiver(frames: dict[str, np.ndarray], rows: dict[str, np.ndarray] | None,
                               attrs: dict[str, Any] | None, n_towers: int = 1, time_offset_s: float = 0.0,
                               transmit_delays_s: Sequence[float] | None = None,
                               start_ranges_m: Sequence[float] | None = None) -> Observations:
    """Everything the fusion takes from one recording's receiver output.

    Parameters
    ----------
    frames : dict of str -> ndarray
        ``/receiver/frames`` columns.
    rows : dict of str -> ndarray or None
        ``/receiver/paths`` columns (only the first paths' rows are read);
        None without the path tracker.
    attrs : dict or None
        ``/receiver/frames`` attributes (``pn_mode``, ``carrier_hz``,
        ``first_path_clock_offset_hz``: the first path's code range needs them).
    n_towers : int
        Towers of the tower table.
    time_offset_s : float
        Moves the receiver's times onto the IMU's time base, s.
    transmit_delays_s : sequence of float, optional
        The towers' transmit delay offsets as the network plan gives them, s
        (none: 0), to match the receiver's towers to the table.
    start_ranges_m : sequence of float, optional
        Distance from the start fix to each tower of the table, m: with it
        the receiver's towers are matched to the table
        (:func:`expected_tower_delays_s`, :func:`receiver_tower_order`).
    """
    expected = None if start_ranges_m is None else expected_tower_delays_s(start_ranges_m, transmit_delays_s)
    return Observations(ranges_from_frames(frames, time_offset_s),
                        paths_from_frames(frames, rows, n_towers, time_offset_s, attrs, expected))
