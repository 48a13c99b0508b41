"""Write and read the walk's groups of a truth file: /truth/trajectory, /truth/steps, /imu, /gnss.

The layout is the project's one schema (``conventions.md``): equal-length
columns per group, parameters as attributes. The start fix P0 is stored as
attributes ``start_fix_t_s``, ``start_fix_x_m``, ``start_fix_y_m`` and
``start_fix_sigma_m`` on both /truth/trajectory and /gnss (the fusion side
reads it from /gnss, an evaluation from the truth).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import h5py
import numpy as np

from fusion.records import GnssLog, ImuLog, StartFix, Track
from receiver.h5io import read_attrs, read_columns, write_columns
from sim.calibration import CALIBRATION_WALK_M, calibration_walk_k_m
from sim.gnss import simulate_start_fix
from sim.imu import PRESETS
from sim.scenario import Scenario, scenario_to_toml
from sim.walk import Walk

#: Sensor-frame definitions written with /imu (see sim.imu).
FRAME_DEFINITIONS = {
    "hand": "phone frame: x right, y forward (top of the phone), z out of the screen; "
            "acc is specific force (reads +g up at rest)",
    "foot": "foot frame: x right, y forward along the foot, z up out of the instep; "
            "acc is specific force (reads +g up at rest)",
}


@dataclass(frozen=True)
class WalkTruth:
    """The walk's truth as read back from a file.

    Attributes
    ----------
    track : Track
        Truth trajectory.
    step_t_s, step_length_m : ndarray
        Heel-strike times (s) and truth step lengths (m).
    walk_start_t_s : float
        When the walker sets off, s.
    start_fix : StartFix
        The GNSS start fix P0.
    """

    track: Track
    step_t_s: np.ndarray
    step_length_m: np.ndarray
    walk_start_t_s: float
    start_fix: StartFix


def _start_fix_attrs(fix: StartFix) -> dict[str, float]:
    return {"start_fix_t_s": fix.t_s, "start_fix_x_m": fix.x_m, "start_fix_y_m": fix.y_m,
            "start_fix_sigma_m": fix.sigma_m}


def _start_fix_from(attrs: dict, where: str) -> StartFix:
    try:
        return StartFix(t_s=float(attrs["start_fix_t_s"]), x_m=float(attrs["start_fix_x_m"]),
                        y_m=float(attrs["start_fix_y_m"]), sigma_m=float(attrs["start_fix_sigma_m"]))
    except KeyError as exc:
        raise ValueError(f"{where}: no start-fix attribute {exc}") from exc


def write_walk_groups(h5file: h5py.File, scenario: Scenario, walk: Walk, imu: ImuLog, gnss: GnssLog) -> None:
    """Write /truth/trajectory, /truth/steps, /imu and /gnss into an open (atomic) HDF5 file.

    Parameters
    ----------
    h5file : h5py.File
        Open for writing (e.g. by :func:`receiver.h5io.atomic_h5`); groups of
        the same names are replaced.
    scenario : Scenario
        Stored as TOML text; its seed, tower and presets become attributes.
    walk, imu, gnss
        Outputs of :func:`sim.walk.simulate_walk`, :func:`sim.imu.simulate_imu`,
        :func:`sim.gnss.simulate_gnss` for this scenario.
    """
    fix = simulate_start_fix(scenario, walk)
    write_columns(h5file, "truth/trajectory", walk.track, attrs={
        "tower_x_m": scenario.tower.x_m, "tower_y_m": scenario.tower.y_m,
        "tower_height_above_receiver_m": scenario.tower.height_m - scenario.channel.antenna_height_m,
        "carrier_hz": scenario.tower.carrier_hz, "seed": scenario.seed,
        "scenario": scenario_to_toml(scenario), "rate_hz": walk.rate_hz,
        "walk_start_t_s": walk.walk_start_t_s, "walk_end_t_s": walk.walk_end_t_s,
        **_start_fix_attrs(fix)})
    write_columns(h5file, "truth/steps", {"t_s": walk.step_t_s, "step_length_m": walk.step_length_m},
                  attrs={"definition": "heel strike ending each step; length = path distance from the previous one"})
    mount = PRESETS[scenario.imu.preset].mount
    write_columns(h5file, "imu", imu, attrs={
        "rate_hz": scenario.imu.rate_hz, "preset": scenario.imu.preset, "frame": FRAME_DEFINITIONS[mount],
        "units": "acc_mps2 m/s^2, gyro_radps rad/s, mag_ut uT",
        # What the user's own calibration walk gave (not the simulator's true K).
        "weinberg_k_m": calibration_walk_k_m(scenario),
        "weinberg_k_source": f"{CALIBRATION_WALK_M:g} m straight calibration walk by the same walker and device"})
    write_columns(h5file, "gnss", gnss, attrs={"rate_hz": scenario.gnss.rate_hz, **_start_fix_attrs(fix)})


def _need(columns: dict[str, np.ndarray], names: tuple[str, ...], where: str) -> None:
    missing = [n for n in names if n not in columns]
    if missing:
        raise ValueError(f"{where}: missing column(s) {missing}")


def read_walk_truth(path: str | os.PathLike) -> WalkTruth:
    """Read /truth/trajectory and /truth/steps of a truth file.

    Raises
    ------
    ValueError
        Missing file, group, column or attribute (the message names it).
    """
    traj = read_columns(path, "truth/trajectory")
    _need(traj, ("t_s", "x_m", "y_m", "heading_rad", "speed_mps"), f"{path}: /truth/trajectory")
    steps = read_columns(path, "truth/steps")
    _need(steps, ("t_s", "step_length_m"), f"{path}: /truth/steps")
    attrs = read_attrs(path, "truth/trajectory")
    if "walk_start_t_s" not in attrs:
        raise ValueError(f"{path}: /truth/trajectory has no walk_start_t_s attribute")
    return WalkTruth(track=Track(**{k: traj[k] for k in ("t_s", "x_m", "y_m", "heading_rad", "speed_mps")}),
                     step_t_s=steps["t_s"], step_length_m=steps["step_length_m"],
                     walk_start_t_s=float(attrs["walk_start_t_s"]),
                     start_fix=_start_fix_from(attrs, f"{path}: /truth/trajectory"))


def read_imu(path: str | os.PathLike) -> ImuLog:
    """Read /imu of a file as an :class:`ImuLog` (ValueError naming what is missing or malformed)."""
    cols = read_columns(path, "imu")
    names = ("t_s", "acc_mps2", "gyro_radps", "mag_ut")
    _need(cols, names, f"{path}: /imu")
    for name in names[1:]:
        if cols[name].ndim != 2 or cols[name].shape[1] != 3:
            raise ValueError(f"{path}: /imu/{name} must be N x 3, got shape {cols[name].shape}")
    return ImuLog(**{k: cols[k] for k in names})


def read_gnss(path: str | os.PathLike) -> tuple[GnssLog, StartFix]:
    """Read /gnss of a file: the per-epoch fixes and the start fix P0."""
    cols = read_columns(path, "gnss")
    names = ("t_s", "x_m", "y_m", "cn0_dbhz")
    _need(cols, names, f"{path}: /gnss")
    return GnssLog(**{k: cols[k] for k in names}), _start_fix_from(read_attrs(path, "gnss"), f"{path}: /gnss")
