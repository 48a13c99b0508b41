"""A walk's input files read and checked for the chain: the receiver's frames and paths, the sensors file's IMU,
the towers and transmit delays a simulation recorded, and the check that the files are of one walk.

Time bases: the receiver's ``t_s`` counts from the capture's first sample, the IMU's from the start of its
log. Every input is read and checked before any work, so bad input fails fast with a ``ValueError`` naming
the file.
"""

from __future__ import annotations

import os
import tomllib
from typing import Any

import numpy as np

from dtmbnav_core import schema
from dtmbnav_core.constants import TRANSMIT_DELAY_KNOWLEDGE
from dtmbnav_core.h5io import open_h5, read_attrs, read_columns
from dtmbnav_core.records import ImuLog
from dtmbnav_core.sensors import read_imu, read_tower
from fusion.transmit_delays import TransmitDelays, given_transmit_delays

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
