"""The HDF5 file schema: group, column and attribute names, defined once.

Every file the project writes follows one layout (``docs/schema.md``): one
group per stage holding equal-length columns (N x 3 for vector sensors), with
parameters, units and versions as attributes. Writers and readers take the
names from here, so a rename happens in one place.
"""

from __future__ import annotations

#: Version of this layout, written on every file's root group. Bumped when a
#: group or column changes meaning; readers accept files without it (written
#: before the attribute existed, same layout as version 1).
SCHEMA_VERSION = 1
SCHEMA_VERSION_ATTR = "dtmbnav_schema_version"
#: Root attribute set to True only once a file is complete (atomic writing).
COMPLETE_ATTR = "dtmbnav_complete"
#: Root attribute holding the package version that wrote the file.
PACKAGE_VERSION_ATTR = "dtmbnav_version"

# --- groups ----------------------------------------------------------------------------------
TRUTH_TRAJECTORY = "truth/trajectory"
TRUTH_FRAMES = "truth/frames"
TRUTH_STEPS = "truth/steps"
TRUTH_PATHS = "truth/paths"
#: Runs of samples a simulated front end dropped from the capture (written when the scenario drops any).
TRUTH_DROPS = "truth/drops"
IMU = "imu"
GNSS = "gnss"
RECEIVER_FRAMES = "receiver/frames"
RECEIVER_PATHS = "receiver/paths"
PDR = "pdr"
PDR_TRACK = "pdr/track"
FUSION = "fusion"


#: Subgroup of ``fusion/<filter>`` holding the filter's smoothed track (the whole recording's data at every row).
SMOOTHED = "smoothed"


def fusion_group(filter_name: str, smoothed: bool = False) -> str:
    """Group of one filter's fused track, ``fusion/<filter name>``, or of its smoothed track,
    ``fusion/<filter name>/smoothed``."""
    return f"{FUSION}/{filter_name}/{SMOOTHED}" if smoothed else f"{FUSION}/{filter_name}"


# --- columns ---------------------------------------------------------------------------------
TRACK_COLUMNS = ("t_s", "x_m", "y_m", "heading_rad", "speed_mps")
#: Further /fusion/<filter> (and .../smoothed) columns: the stated east/north position covariance, m^2
#: (``dtmbnav_core.records.FusedTrack``). Files written before them have none; they read as NaN (no stated error).
FUSION_COVARIANCE_COLUMNS = ("var_x_m2", "var_y_m2", "cov_xy_m2")
STEP_COLUMNS = ("t_s", "step_length_m")
IMU_COLUMNS = ("t_s", "acc_mps2", "gyro_radps", "mag_ut")
GNSS_COLUMNS = ("t_s", "x_m", "y_m", "cn0_dbhz")
#: /truth/drops (int64): the first lost sample on the receiver's clock and the file index of the first sample
#: after the gap (both samples since the capture's first), and the samples lost.
DROP_COLUMNS = ("receiver_sample", "capture_sample", "samples")
#: Columns of a towers file as CSV (``towers.csv``, one row per transmitter of the network, header first; the
#: fields of its TOML form too): those every tower needs, the tower's name, WGS84 latitude and longitude (deg)
#: and its antenna's height above the ellipsoid (m); and those it may leave out (an empty cell), the DTMB
#: channel's centre (Hz), the tower's fixed transmit delay of the network plan (s) and that delay's standard
#: deviation (s).
TOWERS_CSV_REQUIRED = ("name", "lat_deg", "lon_deg", "height_m")
TOWERS_CSV_OPTIONAL = ("channel_hz", "transmit_delay_s", "transmit_delay_sigma_s")
TOWERS_CSV_COLUMNS = TOWERS_CSV_REQUIRED + TOWERS_CSV_OPTIONAL
#: Further /gnss columns of an imported phone log: up (m) in the ENU frame, the stated horizontal accuracy
#: (m), and the fix as logged (WGS84 latitude and longitude, deg; height above the ellipsoid, m).
GNSS_GEODETIC_COLUMNS = ("z_m", "accuracy_m", "lat_deg", "lon_deg", "height_m")

# --- attributes ------------------------------------------------------------------------------
#: On /truth/trajectory: tower position (ENU, m), its height above the receiver antenna (m).
TOWER_X_ATTR = "tower_x_m"
TOWER_Y_ATTR = "tower_y_m"
TOWER_HEIGHT_ATTR = "tower_height_above_receiver_m"
#: On /truth/trajectory: when the walker sets off and stops, s.
WALK_START_ATTR = "walk_start_t_s"
WALK_END_ATTR = "walk_end_t_s"
#: On /truth/trajectory and /gnss: the GNSS start fix P0 (time s, position m, 1-sigma m).
START_FIX_ATTRS = ("start_fix_t_s", "start_fix_x_m", "start_fix_y_m", "start_fix_sigma_m")
#: On /truth/frames: where a simulated capture starts on the sensors' clock, s.
CAPTURE_START_ATTR = "capture_start_s"
#: On /imu: the Weinberg gain K calibrated for the walker and device, m.
WEINBERG_K_ATTR = "weinberg_k_m"
#: On /imu of an imported phone log: the UTC time of t_s = 0, as ISO 8601 text and as ns since the Unix epoch.
START_UTC_ATTR = "start_utc"
START_UTC_NS_ATTR = "start_utc_unix_ns"
#: On /imu of an imported phone log: False when the log had no magnetometer (``mag_ut`` then holds zeros).
HAS_MAGNETOMETER_ATTR = "has_magnetometer"
#: On /gnss of an imported phone log, and of a results file fused from one (``fuse`` copies that /gnss): the
#: geodetic origin of the ENU frame (WGS84 latitude and longitude, deg; height above the ellipsoid, m).
ORIGIN_ATTRS = ("origin_lat_deg", "origin_lon_deg", "origin_height_m")
#: Further /fusion/<filter> columns where the ENU frame has a geodetic origin: the fused track as WGS84 latitude
#: and longitude, deg (``pymap3d.enu2geodetic`` of x_m, y_m with up 0 m, i.e. at the origin's height).
FUSION_GEODETIC_COLUMNS = ("lat_deg", "lon_deg")
#: On /fusion where the ENU frame has a geodetic origin: every tower the filters used, tower 0 first (as
#: arrays): east and north, m, and the antenna's height above the receiver's antenna, m.
FUSION_TOWER_ATTRS = ("towers_x_m", "towers_y_m", "towers_height_m")
#: On /fusion with :data:`FUSION_TOWER_ATTRS`: the towers' WGS84 latitude and longitude, deg (up = their height
#: above the receiver's antenna about the origin).
FUSION_TOWER_GEODETIC_ATTRS = ("towers_lat_deg", "towers_lon_deg")
#: On /fusion/<filter>: the initial heading used and how it was chosen.
INITIAL_HEADING_ATTR = "initial_heading_rad"
#: On /fusion/<filter>: the start fix P0 every filter started from (x, y), m.
FUSION_START_ATTRS = ("start_x_m", "start_y_m")
#: On /receiver/frames: why the input ended before its end (interrupted, a stream cut inside an IQ pair,
#: a read error); absent when the whole input was received.
ENDED_EARLY_ATTR = "ended_early"
#: On /receiver/frames: the scenario name and seed of a simulated capture (from its metadata), so that
#: ``fuse`` can tell a receiver file and a sensors file of different walks apart.
CAPTURE_SCENARIO_ATTR = "capture_scenario"
CAPTURE_SEED_ATTR = "capture_seed"
