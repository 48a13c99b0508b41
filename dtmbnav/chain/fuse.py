"""``dtmbnav fuse``'s work: the receiver's range and the PDR of a walk's files fused into ``/fusion/<filter>``.

A capture made by ``dtmbnav simulate`` records where it starts in the sensors file (``/truth/frames``
attribute ``capture_start_s``); other captures are placed on the IMU log's clock from the two files' UTC
start times, refined from the motion, unless ``time_offset_s`` says where. The libraries do the work; this
module reads, converts and writes (atomically, ``dtmbnav_core.h5io``), so a failure leaves nothing behind.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import h5py
import numpy as np

from dtmbnav.chain.errors import NoResult
from dtmbnav.chain.inputs import (
    check_same_walk,
    read_checked_imu,
    read_other_towers,
    read_receiver_frames,
    read_receiver_paths,
    read_transmit_delays,
)
from dtmbnav.chain.pdr import resolve_pdr_config, write_pdr
from dtmbnav.field.sensors_import import iso_utc
from dtmbnav_core import schema
from dtmbnav_core.geodetic import GeodeticPoint, read_origin, to_geodetic
from dtmbnav_core.h5io import atomic_h5, open_h5, read_attrs, read_columns, write_columns
from dtmbnav_core.records import Track
from dtmbnav_core.sensors import read_capture_start_s, read_gnss, read_tower
from fusion.model import Geometry
from fusion.pdr import PdrConfig, PdrResult, run_pdr
from fusion.run import FusionConfig, FusionResult, fuse
from fusion.time_alignment import AlignmentConfig, TimeAlignment, align_range_to_pdr, coarse_offset_s
from fusion.transmit_delays import TransmitDelays
from receiver.observables import observations_from_receiver, paths_from_frames, ranges_from_frames


def write_fusion(h5: h5py.File, result: FusionResult) -> None:
    """Write ``/fusion/<filter>`` for every filter (its track and stated error), with the initial heading used,
    and its smoothed track as ``/fusion/<filter>/smoothed`` where the result has one."""
    heading = result.heading
    for name, track in result.tracks.items():
        write_columns(h5, schema.fusion_group(name), track, {
            schema.INITIAL_HEADING_ATTR: heading.heading_rad, "initial_heading_confidence": heading.confidence,
            "initial_heading_sigma_rad": heading.sigma_rad, "initial_heading_uncertain": heading.uncertain(),
            **dict(zip(schema.FUSION_START_ATTRS, result.start_xy_m)),
            "initial_heading_minima_rad": heading.minima_rad, "initial_heading_costs_m": heading.costs_m})
        if name in result.smoothed:
            write_columns(h5, schema.fusion_group(name, smoothed=True), result.smoothed[name])


def write_geodetic(h5: h5py.File, sensors_path: str | os.PathLike, origin: GeodeticPoint,
                   towers: tuple[tuple[float, float, float], ...]) -> None:
    """What a map of the results needs, for a sensors file with a geodetic origin (``docs/schema.md``).

    Copies the sensors file's ``/gnss`` (its fixes, and the origin as its attributes), adds
    ``lat_deg`` and ``lon_deg`` to every ``/fusion/<filter>`` and its smoothed track (up 0 m: at the origin's
    height), and
    records ``towers`` (east, north and height above the receiver's antenna, m) with their latitude
    and longitude on ``/fusion``.
    """
    write_columns(h5, schema.GNSS, read_columns(sensors_path, schema.GNSS), read_attrs(sensors_path, schema.GNSS))
    fusion = h5[schema.FUSION]
    groups = [g for filtered in fusion.values() for g in (filtered, filtered.get(schema.SMOOTHED)) if g is not None]
    for group in groups:
        lat, lon = to_geodetic(group["x_m"][()], group["y_m"][()], 0.0, origin)
        for name, values in zip(schema.FUSION_GEODETIC_COLUMNS, (lat, lon)):
            group.create_dataset(name, data=values)
    sites = np.array(towers, dtype=np.float64).reshape(-1, 3)
    lat, lon = to_geodetic(sites[:, 0], sites[:, 1], sites[:, 2], origin)
    for name, values in zip((*schema.FUSION_TOWER_ATTRS, *schema.FUSION_TOWER_GEODETIC_ATTRS),
                            (*sites.T, lat, lon)):
        fusion.attrs[name] = values


def fuse_files(receiver_path: str | os.PathLike, sensors_path: str | os.PathLike, out_path: str | os.PathLike,
               filters: tuple[str, ...], pdr_config: PdrConfig, tower_xy_m: tuple[float, float] | None = None,
               start_xy_m: tuple[float, float] | None = None,
               config: FusionConfig = FusionConfig(), tower_height_m: float = 0.0,
               other_towers: tuple[tuple[float, float, float], ...] = (),
               transmit_delays: TransmitDelays | None = None, time_offset_s: float | None = None,
               alignment_config: AlignmentConfig = AlignmentConfig()) -> tuple[FusionResult, TimeAlignment]:
    """``dtmbnav fuse``: receiver range + PDR of the sensors file -> ``/pdr`` and ``/fusion/*``.

    ``config`` carries the receiver's clock model, the range eq. 15 is solved on, where the
    filters take the SI-carrier range and every filter setting (:class:`fusion.run.FusionConfig`).
    ``tower_height_m`` is the height of a given tower (``tower_xy_m``) above the receiver's antenna, m;
    ``other_towers`` the further towers of its network (x, y and height above the receiver's antenna,
    m) and ``transmit_delays`` their transmit delay offsets as a network plan gives them (``fuse --towers``;
    None: estimated at the start fix, :mod:`fusion.transmit_delays`). Without ``tower_xy_m`` all three come
    from a simulation's truth record (:func:`read_transmit_delays`).

    Every input is read and checked first, including that both files are of
    one walk (:func:`check_same_walk`). A sensors file with a geodetic origin
    (``dtmbnav sensors``) also gets the tracks and towers on WGS84 (:func:`write_geodetic`).
    """
    walk = read_aligned_walk(receiver_path, sensors_path, pdr_config, time_offset_s, alignment_config)
    frames, rx_attrs, pdr, alignment = walk.frames, walk.rx_attrs, walk.pdr, walk.alignment
    origin = read_origin(sensors_path)
    start_sigma_m = None   # a start given by hand states no sigma: the filters' default spread
    if start_xy_m is None:
        fix = read_gnss(sensors_path)[1]
        start_xy_m, start_sigma_m = (fix.x_m, fix.y_m), fix.sigma_m
    height_m = tower_height_m
    if tower_xy_m is None:
        with open_h5(sensors_path) as f:
            if schema.TRUTH_TRAJECTORY not in f:
                raise ValueError(f"{sensors_path}: no tower position (no /{schema.TRUTH_TRAJECTORY} group); give "
                                 "--tower X,Y")
        *tower_xy, height_m = read_tower(sensors_path)
        tower_xy_m = (tower_xy[0], tower_xy[1])
        other_towers = read_other_towers(sensors_path)
        transmit_delays = read_transmit_delays(sensors_path)
    geometry = Geometry(start_xy_m[0], start_xy_m[1], tower_xy_m[0], tower_xy_m[1], height_m, other_towers)
    observed = observations_from_receiver(
        frames, read_receiver_paths(receiver_path), rx_attrs, geometry.n_towers, alignment.offset_s,
        None if transmit_delays is None else transmit_delays.delays_s, geometry.start_ranges_m())
    # A results file is a recording's: it always holds the smoothed tracks beside the filtered ones.
    result = fuse(pdr.steps, observed.ranges, start_xy_m, tower_xy_m, filters, tower_height_m=height_m,
                  other_towers=other_towers, paths=observed.paths, transmit_delays=transmit_delays,
                  start_sigma_m=start_sigma_m, config=dataclasses.replace(config, smooth=True))
    with atomic_h5(out_path) as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, frames, rx_attrs)
        write_pdr(h5, pdr, walk.pdr_config)
        write_fusion(h5, result)
        h5.require_group(schema.FUSION).attrs.update(alignment_attrs(alignment))
        if result.code_offsets is not None and len(result.code_offsets.source):
            h5[schema.FUSION].attrs.update(result.code_offsets.attrs())
        if origin is not None:
            write_geodetic(h5, sensors_path, origin, ((*tower_xy_m, height_m), *other_towers))
    return result, alignment


@dataclasses.dataclass(frozen=True)
class AlignedWalk:
    """A walk's receiver and sensors files read, checked to be of one walk, and put on one clock.

    Attributes
    ----------
    frames : dict of str -> ndarray
        The receiver's ``/receiver/frames`` columns.
    rx_attrs : dict
        Their attributes.
    pdr : PdrResult
        The PDR of the sensors file's IMU (:func:`fusion.pdr.run_pdr`).
    pdr_config : PdrConfig
        The PDR settings it ran with (:func:`dtmbnav.chain.pdr.resolve_pdr_config`).
    alignment : TimeAlignment
        Where the capture starts on the IMU log's clock.
    """

    frames: dict[str, np.ndarray]
    rx_attrs: dict[str, Any]
    pdr: PdrResult
    pdr_config: PdrConfig
    alignment: TimeAlignment


def read_aligned_walk(receiver_path: str | os.PathLike, sensors_path: str | os.PathLike, pdr_config: PdrConfig,
                      time_offset_s: float | None = None,
                      alignment_config: AlignmentConfig = AlignmentConfig()) -> AlignedWalk:
    """Read a walk's receiver frames and IMU, run the PDR and place the capture on the IMU's clock: given
    (``time_offset_s``), recorded by a simulation, or from the files' start times refined from the motion.

    Raises
    ------
    ValueError
        A bad file, or files not of one walk (:func:`dtmbnav.chain.inputs.check_same_walk`).
    NoResult
        The PDR found no steps.
    """
    frames, rx_attrs = read_receiver_frames(receiver_path)
    imu = read_checked_imu(sensors_path)
    alignment = recorded_time_offset(sensors_path, time_offset_s)
    coarse = alignment or coarse_time_offset(rx_attrs, sensors_path, alignment_config)
    try:
        check_same_walk(receiver_path, rx_attrs, frames["t_s"], sensors_path, imu.t_s, coarse.offset_s)
    except ValueError as exc:
        if coarse.source != "coarse":
            raise
        raise ValueError(f"{exc}: the capture starts at {iso_utc(int(rx_attrs[schema.START_UTC_NS_ATTR]))} and the "
                         f"phone log at {iso_utc(int(read_attrs(sensors_path, schema.IMU)[schema.START_UTC_NS_ATTR]))}"
                         f" ({coarse.offset_s:+.1f} s apart): a log of another walk or day? If a clock was wrong, "
                         "give --time-offset") from None
    pdr_config = resolve_pdr_config(pdr_config, sensors_path)
    pdr = run_pdr(imu, pdr_config)
    if len(pdr.steps) == 0:
        raise NoResult(f"{sensors_path}: /{schema.IMU}: the PDR found no steps; nothing to fuse")
    if alignment is None:
        alignment = fine_time_offset(frames, pdr.track, coarse, alignment_config, read_receiver_paths(receiver_path))
        check_same_walk(receiver_path, rx_attrs, frames["t_s"], sensors_path, imu.t_s, alignment.offset_s)
    return AlignedWalk(frames, rx_attrs, pdr, pdr_config, alignment)


def recorded_time_offset(sensors_path: str | os.PathLike, given_s: float | None) -> TimeAlignment | None:
    """The capture's start on the IMU clock where it is known exactly: given (``--time-offset``), or recorded
    by ``dtmbnav simulate`` in the sensors file; None where it must be estimated."""
    if given_s is not None:
        return TimeAlignment(float(given_s), 0.0, "given")
    with open_h5(sensors_path) as f:
        recorded = schema.TRUTH_FRAMES in f and schema.CAPTURE_START_ATTR in f[schema.TRUTH_FRAMES].attrs
    return TimeAlignment(read_capture_start_s(sensors_path), 0.0, "simulation record") if recorded else None


def coarse_time_offset(rx_attrs: dict[str, Any], sensors_path: str | os.PathLike,
                       config: AlignmentConfig) -> TimeAlignment:
    """The capture's start on the IMU clock from the capture's start time and the phone log's (their UTC
    stamps); 0 s, of unknown uncertainty, where either file has none (the two assumed to start together)."""
    imu_utc_ns = read_attrs(sensors_path, schema.IMU).get(schema.START_UTC_NS_ATTR)
    capture_utc_ns = rx_attrs.get(schema.START_UTC_NS_ATTR)
    if imu_utc_ns is None or capture_utc_ns is None:
        return TimeAlignment(0.0, float("inf"), "assumed")
    offset = coarse_offset_s(int(capture_utc_ns), int(imu_utc_ns))
    return TimeAlignment(offset, config.coarse_sigma_s, "coarse", coarse_offset_s=offset,
                         coarse_sigma_s=config.coarse_sigma_s)


def fine_time_offset(frames: dict[str, np.ndarray], pdr_track: Track, coarse: TimeAlignment,
                     config: AlignmentConfig, path_rows: dict[str, np.ndarray] | None = None) -> TimeAlignment:
    """Refine ``coarse`` from the motion (:func:`fusion.time_alignment.align_range_to_pdr`), on tower 0's
    first-path range where the receiver tracked one (``path_rows``: its ``/receiver/paths``, for the slips);
    ``coarse`` itself where the two records do not overlap enough, the best offset lies at the edge of the
    search, or the motion's offset is no more certain than ``coarse``'s. A fine offset less certain than
    :attr:`AlignmentConfig.useful_sigma_s` is marked as too little to align on."""
    paths = paths_from_frames(frames, path_rows, 1)
    first_path = None if paths is None else paths.first_path.get(0)
    try:
        offset, sigma = align_range_to_pdr(ranges_from_frames(frames), pdr_track, coarse.offset_s, config, first_path)
    except ValueError:
        return coarse
    if not np.isfinite(sigma):
        return coarse
    fine = dataclasses.replace(coarse, fine_offset_s=offset, fine_sigma_s=sigma,
                               too_little=sigma > config.useful_sigma_s)
    if sigma >= coarse.sigma_s:   # the UTC stamps say more than the motion: keep them
        return fine
    return dataclasses.replace(fine, offset_s=offset, sigma_s=sigma, source="fine")


def alignment_attrs(alignment: TimeAlignment) -> dict[str, Any]:
    """``/fusion`` attributes of the capture-to-IMU time offset used (:class:`fusion.time_alignment.TimeAlignment`)."""
    return {f"time_offset_{key}" if key != "offset_s" else "time_offset_s": value
            for key, value in dataclasses.asdict(alignment).items()}


#: Share of the IMU log the receiver's frames must span before ``run`` fuses.
MIN_FUSION_COVERAGE = 0.5


def range_coverage_s(receiver_path: str | os.PathLike, sensors_path: str | os.PathLike) -> tuple[float, float]:
    """Seconds of the IMU log covered by receiver frames, and the log's length, s."""
    frames = read_columns(receiver_path, schema.RECEIVER_FRAMES)
    imu_t = read_columns(sensors_path, schema.IMU)["t_s"]
    if len(frames["t_s"]) == 0:
        return 0.0, float(imu_t[-1] - imu_t[0])
    t = frames["t_s"] + read_capture_start_s(sensors_path)
    covered = max(0.0, min(t[-1], imu_t[-1]) - max(t[0], imu_t[0]))
    return covered, float(imu_t[-1] - imu_t[0])
