"""``dtmbnav pdr``'s work: a sensors file's ``/imu`` in, ``/pdr`` and ``/pdr/track`` out (atomically); or, with
``--calibrate``, the walker's Weinberg gain fitted to a walk of known length, out as a walker profile."""

from __future__ import annotations

import dataclasses
import os

import h5py
import numpy as np

from dtmbnav.chain.inputs import read_checked_imu
from dtmbnav.field.walker import WalkerProfile, calibration_date, read_walker_profile, write_walker_profile
from dtmbnav_core import schema
from dtmbnav_core.h5io import atomic_h5, write_columns
from dtmbnav_core.sensors import read_has_magnetometer, read_weinberg_k_m
from fusion.pdr import PdrConfig, PdrResult, calibrate_weinberg_k_from_walk, run_pdr
from fusion.pdr.pipeline import weinberg_gain
from receiver.writer import write_csv


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
    attrs = {"step_model": config.step_model, "weinberg_k_m": weinberg_gain(config, result.carriage) or np.nan,
             "frame": "PDR frame: starts at (0, 0), heading relative to the initial one",
             "carriage": result.carriage, "carriage_changes": result.carriage_changes,
             "heading_from": "walking direction" if result.walking_used else "phone yaw"}
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


def calibrate_walker(sensors_path: str | os.PathLike, distance_m: float, out_path: str | os.PathLike,
                     config: PdrConfig) -> tuple[WalkerProfile, PdrResult]:
    """``dtmbnav pdr --calibrate``: the Weinberg gain that makes the steps of the walk in ``/imu`` add up to
    ``distance_m`` (m; every step detected is taken to belong to it), written as a walker profile to
    ``out_path``; and the PDR of the walk with that gain, whose steps then add up to the distance.

    ``config``'s step detector is the one the gain is fitted with (:func:`calibrate_weinberg_k_from_walk`),
    so the gain matches the steps a later ``pdr --walker`` detects with it. The gain is also kept for the
    carriage the walk was made in (:data:`fusion.pdr.pipeline.CARRIAGE_CLASSES`); where ``out_path`` is a
    walker profile already, the gains it holds for other carriages are kept, so that calibrating once per
    carriage builds one profile.

    Raises
    ------
    ValueError
        A missing or malformed ``/imu``, no steps detected, or an ``out_path`` that exists and is not a
        walker profile (the file named); nothing is written.
    """
    earlier = read_walker_profile(out_path).k_by_carriage_m if os.path.exists(out_path) else {}
    imu = read_checked_imu(sensors_path)
    config = resolve_pdr_config(dataclasses.replace(config, step_model="weinberg", weinberg_k_m=1.0), sensors_path)
    try:
        k_m = calibrate_weinberg_k_from_walk(imu, distance_m, config)
    except ValueError as exc:
        raise ValueError(f"{sensors_path}: /{schema.IMU}: {exc}; walk the distance with the phone as it will be "
                         "carried") from None
    result = run_pdr(imu, dataclasses.replace(config, weinberg_k_m=k_m))
    profile = WalkerProfile(weinberg_k_m=k_m, distance_m=float(distance_m), steps=len(result.steps),
                            source=str(sensors_path), date=calibration_date(),
                            k_by_carriage_m={**earlier, result.carriage: k_m})
    write_walker_profile(out_path, profile)
    return profile, result
