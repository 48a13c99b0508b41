"""Write a simulated walk's groups of a truth file: /truth/trajectory, /truth/steps, /imu, /gnss.

The layout and the typed writers are :mod:`dtmbnav_core.sensors`; this module
only gathers what the simulator knows about the walk (tower, presets, sensor
frames, the start fix) into their attributes.
"""

from __future__ import annotations

import h5py

from dtmbnav_core import schema
from dtmbnav_core.records import GnssLog, ImuLog
from dtmbnav_core.sensors import write_gnss, write_imu, write_truth_trajectory
from sim.calibration import CALIBRATION_WALK_M
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


def write_walk_groups(h5file: h5py.File, scenario: Scenario, walk: Walk, imu: ImuLog, gnss: GnssLog,
                      weinberg_k_m: float | None = None) -> None:
    """Write /truth/trajectory, /truth/steps, /imu and /gnss into an open (atomic) HDF5 file.

    Parameters
    ----------
    h5file : h5py.File
        Open for writing (e.g. by :func:`dtmbnav_core.h5io.atomic_h5`); groups of
        the same names are replaced.
    scenario : Scenario
        Stored as TOML text; its seed, tower and presets become attributes.
    walk, imu, gnss
        Outputs of :func:`sim.walk.simulate_walk`, :func:`sim.imu.simulate_imu`,
        :func:`sim.gnss.simulate_gnss` for this scenario; the start fix is made of ``gnss``'s
        fixes over the standstill (:func:`sim.gnss.simulate_start_fix`).
    weinberg_k_m : float, optional
        The Weinberg gain the user's own calibration walk gave (not the
        simulator's true K), stored as the ``/imu`` attribute the PDR reads;
        None leaves it out (the PDR then uses the frequency model).
    """
    fix = simulate_start_fix(scenario, walk, gnss)
    write_truth_trajectory(h5file, walk.track, walk.step_t_s, walk.step_length_m, fix, attrs={
        schema.TOWER_X_ATTR: scenario.tower.x_m, schema.TOWER_Y_ATTR: scenario.tower.y_m,
        schema.TOWER_HEIGHT_ATTR: scenario.tower.height_m - scenario.channel.antenna_height_m,
        "carrier_hz": scenario.tower.carrier_hz, "seed": scenario.seed,
        "scenario": scenario_to_toml(scenario), "rate_hz": walk.rate_hz,
        schema.WALK_START_ATTR: walk.walk_start_t_s, schema.WALK_END_ATTR: walk.walk_end_t_s})
    mount = PRESETS[scenario.imu.preset].mount
    imu_attrs = {"rate_hz": scenario.imu.rate_hz, "preset": scenario.imu.preset, "frame": FRAME_DEFINITIONS[mount],
                 "units": "acc_mps2 m/s^2, gyro_radps rad/s, mag_ut uT"}
    if not scenario.imu.magnetometer:  # as an imported log without one: zeros, and said
        imu_attrs[schema.HAS_MAGNETOMETER_ATTR] = False
    if weinberg_k_m is not None:
        imu_attrs[schema.WEINBERG_K_ATTR] = weinberg_k_m
        imu_attrs["weinberg_k_source"] = (f"{CALIBRATION_WALK_M:g} m straight calibration walk by the same "
                                          "walker and device")
    write_imu(h5file, imu, imu_attrs)
    write_gnss(h5file, gnss, fix, attrs={"rate_hz": scenario.gnss.rate_hz})
