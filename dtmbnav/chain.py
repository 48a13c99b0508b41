"""The processing chain behind ``pdr``, ``fuse`` and ``run`` (``receive`` is :mod:`dtmbnav.receive`).

Files in, files out: the receiver's ``/receiver/frames``, the sensors file's
``/imu`` and ``/gnss`` (a simulation's ``truth.h5`` is one), and the results
file with ``/receiver``, ``/pdr`` and ``/fusion/<filter>`` groups. The
libraries do the work; this module only reads, converts and writes.

Time bases: the receiver's ``t_s`` counts from the capture's first sample,
the IMU's from the start of its log. A capture made by ``dtmbnav simulate``
records where it starts in the sensors file (``/truth/frames`` attribute
``capture_start_s``); other captures are assumed to start with the IMU log
unless ``time_offset_s`` says otherwise.

Every input is read and checked before any work, and every output is
written atomically (``dtmbnav_core.h5io``), so bad input fails fast with a
``ValueError`` naming the file and leaves nothing behind.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from dtmbnav_core import schema
from dtmbnav_core.constants import TRANSMIT_DELAY_KNOWLEDGE
from dtmbnav_core.h5io import atomic_folder, atomic_h5, open_h5, read_attrs, read_columns, write_columns
from dtmbnav_core.records import ImuLog, Track
from dtmbnav_core.sensors import (read_capture_start_s, read_gnss, read_has_magnetometer, read_imu, read_tower,
                                  read_walk_truth, read_weinberg_k_m)
from dtmbnav.errors import NoResult
from dtmbnav.sensors_import import iso_utc
from dtmbnav.geodetic import GeodeticPoint, read_origin, to_geodetic
from dtmbnav.receive import receive_capture
from fusion.model import Geometry
from fusion.pdr import PdrConfig, PdrResult, run_pdr
from fusion.run import FusionConfig, FusionResult, fuse
from fusion.transmit_delays import TransmitDelays, given_transmit_delays
from fusion.time_alignment import AlignmentConfig, TimeAlignment, align_range_to_pdr, coarse_offset_s
from receiver.capture import open_capture
from receiver.observables import observations_from_receiver, ranges_from_frames
from receiver.pipeline import ReceiverConfig
from receiver.writer import write_csv

#: The ``/receiver/frames`` columns that ``fuse`` needs.
FUSE_FRAME_COLUMNS = ("t_s", "range_change_m", "snr_db", "flags")


def _check_columns(columns: dict[str, np.ndarray], needed: tuple[str, ...], where: str) -> None:
    """Needed columns present, 1-D numeric (first axis for vectors) and of one length, else ValueError."""
    missing = [name for name in needed if name not in columns]
    if missing:
        raise ValueError(f"{where}: missing column(s) {missing}")
    for name, values in columns.items():
        if values.ndim == 0 or not (np.issubdtype(values.dtype, np.number) or values.dtype == np.bool_):
            raise ValueError(f"{where}/{name}: expected a numeric column, got {values.dtype} of shape {values.shape}")
    lengths = {name: len(values) for name, values in columns.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{where}: columns differ in length: {lengths}")


def read_receiver_frames(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The checked ``/receiver/frames`` columns and attributes of a receiver (or results) file.

    Raises
    ------
    ValueError
        Missing, incomplete or foreign file, missing group or column, columns
        of different lengths, or no frames at all.
    """
    where = f"{path}: /{schema.RECEIVER_FRAMES}"
    frames = read_columns(path, schema.RECEIVER_FRAMES)
    _check_columns(frames, FUSE_FRAME_COLUMNS, where)
    if len(frames["t_s"]) == 0:
        raise ValueError(f"{where}: no frames (the receiver found no DTMB signal in that capture)")
    if not np.all(np.isfinite(frames["t_s"])) or np.any(np.diff(frames["t_s"]) <= 0):
        raise ValueError(f"{where}/t_s: frame times must be finite and increasing")
    return frames, read_attrs(path, schema.RECEIVER_FRAMES)


def read_checked_imu(path: str | os.PathLike) -> ImuLog:
    """``/imu`` of a sensors file with finite values and increasing times (ValueError naming the file)."""
    imu = read_imu(path)
    where = f"{path}: /{schema.IMU}"
    if len(imu.t_s) < 2:
        raise ValueError(f"{where}: {len(imu.t_s)} sample(s); an IMU log needs at least two")
    for name, values in imu.columns().items():
        if not np.issubdtype(values.dtype, np.number) or not np.all(np.isfinite(values)):
            raise ValueError(f"{where}/{name}: NaN, inf or non-numeric values")
    if np.any(np.diff(imu.t_s) <= 0):
        raise ValueError(f"{where}/t_s: sample times must be increasing")
    return imu


def _walk_of_sensors(path: str | os.PathLike) -> tuple[str | None, int | None]:
    """Scenario name and seed of a simulated sensors file (``/truth/frames``), None where not recorded."""
    with open_h5(path) as f:
        if schema.TRUTH_FRAMES not in f:
            return None, None
        attrs = f[schema.TRUTH_FRAMES].attrs
        seed = attrs.get("seed")
        text = attrs.get("scenario")
    try:  # a record that cannot be read proves nothing: the time check still applies
        name = tomllib.loads(str(text)).get("name") if text is not None else None
    except tomllib.TOMLDecodeError:
        name = None
    try:
        seed = int(seed) if seed is not None else None
    except (TypeError, ValueError):
        seed = None
    return (str(name) if name is not None else None), seed


def check_same_walk(receiver_path: str | os.PathLike, rx_attrs: dict[str, Any], rx_t_s: np.ndarray,
                    sensors_path: str | os.PathLike, imu_t_s: np.ndarray, capture_start_s: float) -> None:
    """Refuse a receiver file and a sensors file that cannot be of one walk.

    Two checks: where both files record which simulated walk they are of
    (scenario name and seed), those must agree; and the receiver's frames,
    moved onto the sensors' clock, must overlap the IMU log in time.

    Raises
    ------
    ValueError
        Naming both files and what differs.
    """
    rx_walk = (rx_attrs.get(schema.CAPTURE_SCENARIO_ATTR), rx_attrs.get(schema.CAPTURE_SEED_ATTR))
    sensors_walk = _walk_of_sensors(sensors_path)
    for what, mine, theirs in zip(("scenario", "seed"), rx_walk, sensors_walk):
        if mine is not None and theirs is not None and str(mine) != str(theirs):
            raise ValueError(f"{receiver_path} and {sensors_path} are of different walks: the capture's {what} is "
                             f"{mine}, the sensors file's is {theirs}")
    t0, t1 = float(rx_t_s[0]) + capture_start_s, float(rx_t_s[-1]) + capture_start_s
    if min(t1, float(imu_t_s[-1])) <= max(t0, float(imu_t_s[0])):
        raise ValueError(f"{receiver_path} and {sensors_path} do not overlap in time: the frames span "
                         f"{t0:.1f}-{t1:.1f} s, the IMU log {float(imu_t_s[0]):.1f}-{float(imu_t_s[-1]):.1f} s "
                         "(on the sensors' clock); files of different walks?")


def read_receiver_paths(path: str | os.PathLike) -> dict[str, np.ndarray] | None:
    """The ``/receiver/paths`` columns of a receiver file (None when it has none: tracker off, older file)."""
    with open_h5(path) as f:
        if schema.RECEIVER_PATHS not in f:
            return None
    return read_columns(path, schema.RECEIVER_PATHS)


def _recorded_scenario(sensors_path: str | os.PathLike) -> dict[str, Any]:
    """The scenario recorded in ``/truth/frames``, parsed (empty without a record)."""
    with open_h5(sensors_path) as f:
        text = f[schema.TRUTH_FRAMES].attrs.get("scenario") if schema.TRUTH_FRAMES in f else None
    if text is None:
        return {}
    try:
        return tomllib.loads(str(text))
    except tomllib.TOMLDecodeError:
        raise ValueError(f"{sensors_path}: /{schema.TRUTH_FRAMES}: unreadable scenario record; give --tower X,Y") \
            from None


def _recorded_towers(sensors_path: str | os.PathLike, record: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The ``[[towers]]`` of the scenario recorded in ``/truth/frames`` (empty without a record or with one tower);
    ``record``: that scenario already read (:func:`_recorded_scenario`)."""
    sites = (_recorded_scenario(sensors_path) if record is None else record).get("towers", [])
    if not isinstance(sites, list) or not all(isinstance(s, dict) for s in sites):
        raise ValueError(f"{sensors_path}: /{schema.TRUTH_FRAMES}: unreadable [[towers]] in the scenario record; "
                         "give --tower X,Y")
    return sites if len(sites) >= 2 else []


def read_other_towers(sensors_path: str | os.PathLike) -> tuple[tuple[float, float, float], ...]:
    """Further towers of a simulated single-frequency network: ``[[towers]]`` after the first, from the
    scenario recorded in ``/truth/frames`` (x, y, m, and height above the receiver's antenna, m, like
    the first tower's in ``/truth/trajectory``); empty when there are none."""
    sites = _recorded_towers(sensors_path)
    if not sites:
        return ()
    try:
        # The record holds the towers' heights above the ground; the first tower's above the antenna is known.
        antenna_m = float(sites[0]["height_m"]) - read_tower(sensors_path)[2]
        return tuple((float(s["x_m"]), float(s["y_m"]), float(s["height_m"]) - antenna_m) for s in sites[1:])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{sensors_path}: /{schema.TRUTH_FRAMES}: unreadable [[towers]] in the scenario record; "
                         "give --tower X,Y") from None


def read_transmit_delays(sensors_path: str | os.PathLike) -> TransmitDelays | None:
    """What a simulated single-frequency network's user is taken to know of its towers' transmit delay offsets
    (the recorded scenario's ``[network] known``): None where nothing (the fusion estimates them at the start
    fix), or with one tower; the network plan's (``[[towers]] transmit_delay_s``, sigma ``[network]
    plan_error_s``); or the walk's true offsets (``/truth/paths`` ``towers_transmit_delay_s``)."""
    record = _recorded_scenario(sensors_path)
    sites = _recorded_towers(sensors_path, record)
    network = record.get("network", {})
    known = network.get("known", "unknown") if isinstance(network, dict) else None
    if not sites:
        return None
    if known not in TRANSMIT_DELAY_KNOWLEDGE:
        raise ValueError(f"{sensors_path}: /{schema.TRUTH_FRAMES}: the scenario record's [network] known must be "
                         f"one of {', '.join(TRANSMIT_DELAY_KNOWLEDGE)}; got {known!r}")
    try:
        plan_s = [float(site.get("transmit_delay_s", 0.0)) for site in sites]
        plan_error_s = float(network.get("plan_error_s", 0.0))
    except (TypeError, ValueError):
        raise ValueError(f"{sensors_path}: /{schema.TRUTH_FRAMES}: unreadable transmit delays in the scenario "
                         "record") from None

    def true_s() -> list[float]:
        true = read_attrs(sensors_path, schema.TRUTH_PATHS).get("towers_transmit_delay_s")
        if true is None or len(true) != len(sites):
            raise ValueError(f"{sensors_path}: [network] known = \"exact\" but /{schema.TRUTH_PATHS} has no "
                             "towers_transmit_delay_s for every tower")
        return list(true)

    return given_transmit_delays(known, plan_s, plan_error_s, true_s)


def resolve_pdr_config(config: PdrConfig, sensors_path: str | os.PathLike) -> PdrConfig:
    """The PDR settings a sensors file needs: its Weinberg gain, and no magnetometer where it has none.

    A file without a calibrated gain falls back to the linear step-frequency
    model, which needs no calibration (docs/method.md §3), when the user gave
    no gain. A file whose log had no magnetometer (``has_magnetometer``
    False) gets the attitude from the gyro and accelerometer alone, whatever
    the settings say: the zeros that stand in for the magnetometer would
    otherwise be taken for a field.
    """
    if not read_has_magnetometer(sensors_path) and config.attitude.use_magnetometer:
        config = dataclasses.replace(config, attitude=dataclasses.replace(config.attitude, use_magnetometer=False))
    if config.step_model != "weinberg" or config.weinberg_k_m is not None:
        return config
    k_m = read_weinberg_k_m(sensors_path)
    if k_m is None:
        return dataclasses.replace(config, step_model="frequency")
    return dataclasses.replace(config, weinberg_k_m=k_m)


def write_pdr(h5: h5py.File, result: PdrResult, config: PdrConfig) -> None:
    """Write ``/pdr`` (per step) and ``/pdr/track`` (resampled)."""
    attrs = {"step_model": config.step_model, "weinberg_k_m": config.weinberg_k_m or np.nan,
             "frame": "PDR frame: starts at (0, 0), heading relative to the initial one"}
    write_columns(h5, schema.PDR, result.steps, attrs)
    write_columns(h5, schema.PDR_TRACK, result.track, {"rate_hz": config.output_rate_hz})


def run_pdr_file(sensors_path: str | os.PathLike, out_path: str | os.PathLike, config: PdrConfig,
                 csv_path: str | None = None) -> PdrResult:
    """``dtmbnav pdr``: PDR on the ``/imu`` of a file, written to ``out_path`` (and the steps to ``csv_path``)."""
    imu = read_checked_imu(sensors_path)
    config = resolve_pdr_config(config, sensors_path)
    result = run_pdr(imu, config)
    with atomic_h5(out_path) as h5:
        write_pdr(h5, result, config)
        if csv_path is not None:  # inside: a failing CSV leaves no HDF5 file either
            write_csv(csv_path, result.steps.columns())
    return result


def write_fusion(h5: h5py.File, result: FusionResult) -> None:
    """Write ``/fusion/<filter>`` for every filter, with the initial heading used."""
    heading = result.heading
    for name, track in result.tracks.items():
        write_columns(h5, schema.fusion_group(name), track, {
            schema.INITIAL_HEADING_ATTR: heading.heading_rad, "initial_heading_confidence": heading.confidence,
            "initial_heading_sigma_rad": heading.sigma_rad, "initial_heading_uncertain": heading.uncertain(),
            **dict(zip(schema.FUSION_START_ATTRS, result.start_xy_m)),
            "initial_heading_minima_rad": heading.minima_rad, "initial_heading_costs_m": heading.costs_m})


def write_geodetic(h5: h5py.File, sensors_path: str | os.PathLike, origin: GeodeticPoint,
                   towers: tuple[tuple[float, float, float], ...]) -> None:
    """What a map of the results needs, for a sensors file with a geodetic origin (``docs/schema.md``).

    Copies the sensors file's ``/gnss`` (its fixes, and the origin as its attributes), adds
    ``lat_deg`` and ``lon_deg`` to every ``/fusion/<filter>`` (up 0 m: at the origin's height), and
    records ``towers`` (east, north and height above the receiver's antenna, m) with their latitude
    and longitude on ``/fusion``.
    """
    write_columns(h5, schema.GNSS, read_columns(sensors_path, schema.GNSS), read_attrs(sensors_path, schema.GNSS))
    fusion = h5[schema.FUSION]
    for group in fusion.values():
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
    frames, rx_attrs = read_receiver_frames(receiver_path)
    imu = read_checked_imu(sensors_path)
    origin = read_origin(sensors_path)
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
    if start_xy_m is None:
        fix = read_gnss(sensors_path)[1]
        start_xy_m = (fix.x_m, fix.y_m)
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
    pdr = run_pdr(imu, pdr_config)
    if len(pdr.steps) == 0:
        raise NoResult(f"{sensors_path}: /{schema.IMU}: the PDR found no steps; nothing to fuse")
    if alignment is None:
        alignment = fine_time_offset(frames, pdr.track, coarse, alignment_config)
        check_same_walk(receiver_path, rx_attrs, frames["t_s"], sensors_path, imu.t_s, alignment.offset_s)
    observed = observations_from_receiver(
        frames, read_receiver_paths(receiver_path), rx_attrs, geometry.n_towers, alignment.offset_s,
        None if transmit_delays is None else transmit_delays.delays_s, geometry.start_ranges_m())
    result = fuse(pdr.steps, observed.ranges, start_xy_m, tower_xy_m, filters, tower_height_m=height_m,
                  other_towers=other_towers, paths=observed.paths, transmit_delays=transmit_delays, config=config)
    with atomic_h5(out_path) as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, frames, rx_attrs)
        write_pdr(h5, pdr, pdr_config)
        write_fusion(h5, result)
        h5.require_group(schema.FUSION).attrs.update(alignment_attrs(alignment))
        if result.code_offsets is not None and len(result.code_offsets.source):
            h5[schema.FUSION].attrs.update(result.code_offsets.attrs())
        if origin is not None:
            write_geodetic(h5, sensors_path, origin, ((*tower_xy_m, height_m), *other_towers))
    return result, alignment


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
                     config: AlignmentConfig) -> TimeAlignment:
    """Refine ``coarse`` from the motion (:func:`fusion.time_alignment.align_range_to_pdr`); ``coarse`` itself
    where the two records do not overlap enough or the best offset lies at the edge of the search."""
    try:
        offset, sigma = align_range_to_pdr(ranges_from_frames(frames), pdr_track, coarse.offset_s, config)
    except ValueError:
        return coarse
    if not np.isfinite(sigma):
        return coarse
    return dataclasses.replace(coarse, offset_s=offset, sigma_s=sigma, source="fine", fine_offset_s=offset,
                               fine_sigma_s=sigma)


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


def check_report_inputs(results_path: str | os.PathLike, truth_path: str | os.PathLike | None,
                        receiver_only: bool = False) -> None:
    """The groups a report reads are there (ValueError naming the file and what is missing)."""
    if receiver_only:
        read_receiver_frames(results_path)
    else:
        with open_h5(results_path) as f:
            if schema.FUSION not in f or not len(f[schema.FUSION]):
                raise ValueError(f"{results_path}: no /{schema.FUSION} group (run 'dtmbnav fuse' or 'dtmbnav run' "
                                 "first)")
            for name in (schema.PDR, schema.RECEIVER_FRAMES):
                if name not in f:
                    raise ValueError(f"{results_path}: no /{name} group (not a results file of 'dtmbnav fuse')")
    if truth_path is not None:
        read_walk_truth(truth_path)
        read_columns(truth_path, schema.TRUTH_FRAMES)
        if not receiver_only:
            read_tower(truth_path)


def write_report_folder(results_path: str | os.PathLike, out_dir: str | os.PathLike,
                        truth_path: str | os.PathLike | None = None, receiver_only: bool = False,
                        origin: GeodeticPoint | None = None) -> Path:
    """``dtmbnav report``: the report of a results file (or of a receiver file alone) into ``out_dir``.

    ``origin`` places the results' ENU frame on WGS84 for the map files (``report --origin``), in place
    of the origin the results file holds.

    Written into a temporary folder and moved into ``out_dir`` only when
    complete (:func:`dtmbnav_core.h5io.atomic_folder`): a bad input leaves no
    half-written report.
    """
    from dtmbnav.report import write_receiver_report, write_report

    check_report_inputs(results_path, truth_path, receiver_only)
    with atomic_folder(out_dir) as tmp:
        if receiver_only:
            write_receiver_report(results_path, tmp, truth_path=truth_path)
        else:
            write_report(results_path, tmp, truth_path=truth_path, origin=origin)
    return Path(out_dir)


@dataclass(frozen=True)
class RunOutcome:
    """Files written by :func:`run_directory` and a summary for the user."""

    receiver_path: Path
    results_path: Path | None
    report_path: Path | None
    summary: str
    found: bool = True


def find_capture_set(directory: str | os.PathLike) -> tuple[Path, Path]:
    """The capture and the sensors file of a capture-set folder.

    The folder holds one capture (``*.sigmf-meta``, or a raw file with a
    ``.json`` sidecar) and one HDF5 file with ``/imu`` and ``/gnss``
    (``truth.h5`` as written by ``dtmbnav simulate``, or ``sensors.h5``).
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    captures = sorted(folder.glob("*.sigmf-meta")) or sorted(
        p.with_suffix("") for p in folder.glob("*.json") if p.with_suffix("").is_file())
    sensors = [p for p in (folder / "truth.h5", folder / "sensors.h5") if p.is_file()]
    if len(captures) != 1:
        raise ValueError(f"{folder}: expected exactly one capture (*.sigmf-meta or raw + .json), found "
                         f"{len(captures)}")
    if not sensors:
        raise ValueError(f"{folder}: no sensors file (truth.h5 or sensors.h5 with /imu and /gnss)")
    return captures[0], sensors[0]


def run_directory(directory: str | os.PathLike, output: str | os.PathLike, filters: tuple[str, ...],
                  progress: bool = True) -> RunOutcome:
    """``dtmbnav run``: receive the folder's capture, then PDR, fusion and the report.

    Both inputs are opened and checked before any work. Fusion needs the
    receiver's range over the walk: when the capture spans less than
    :data:`MIN_FUSION_COVERAGE` of the IMU log (the bundled capture is a few
    seconds), the run stops after the receiver, says so, and reports the
    receiver against the truth.
    """
    capture_path, sensors_path = find_capture_set(directory)
    source = open_capture(capture_path)
    read_checked_imu(sensors_path)
    with open_h5(sensors_path) as f:
        has_truth = schema.TRUTH_TRAJECTORY in f
    truth_path = sensors_path if has_truth else None
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    rx_path = out / "receiver.h5"
    summary = receive_capture(source, rx_path, ReceiverConfig(), progress=progress)
    lines = [f"capture  {capture_path}", f"receiver {summary.describe()}"]
    if not summary.frames:
        return RunOutcome(rx_path, None, None, "\n".join(lines), found=False)
    covered_s, walk_s = range_coverage_s(rx_path, sensors_path)
    report = out / "report"
    if covered_s < MIN_FUSION_COVERAGE * walk_s:
        lines.append(f"fusion   skipped: the capture covers {covered_s:.1f} s of the {walk_s:.1f} s IMU log; the "
                     "filters need the DTMB range over the walk (try 'dtmbnav demo', which streams a whole walk)")
        write_report_folder(rx_path, report, truth_path=truth_path, receiver_only=True)
        lines.append((report / "summary.md").read_text())
        lines.append(f"report   {report}")
        return RunOutcome(rx_path, None, report, "\n".join(lines))
    results_path = out / "results.h5"
    result, _ = fuse_files(rx_path, sensors_path, results_path, filters, PdrConfig())
    ranged = int(np.count_nonzero(np.isfinite(result.epochs.range_change_m)))
    lines.append(f"fusion   {len(result.epochs)} PDR steps, {ranged} with a DTMB range; initial heading "
                 f"{result.heading.describe()}")
    write_report_folder(results_path, report, truth_path=truth_path)
    if (report / "summary.md").is_file():
        lines.append((report / "summary.md").read_text())
    lines.append(f"report   {report}")
    return RunOutcome(rx_path, results_path, report, "\n".join(lines))
