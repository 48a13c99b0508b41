"""The scenario's towers as a station list gives them: ``towers.csv``, latitude, longitude and height.

One row per transmitter (every site of a single-frequency network, tower 0 first), columns
:data:`dtmbnav_core.schema.TOWERS_CSV_COLUMNS`: the name ``tower<i>``, the site's WGS84 latitude and
longitude (deg) and its antenna's height above the ellipsoid (m), all from its ENU position about the
scenario's ``[origin]`` (its ``height_m`` is the up coordinate: the walker's plane is the origin's
height), the channel's centre (``[tower] carrier_hz``, Hz), the site's transmit delay offset as the network
plan has it (s) and the plan's error (``[network] plan_error_s``, s) as its sigma. Numbers
are written as the shortest text that reads back to the same float, so the ENU position comes back
to within rounding of the conversion.
"""

from __future__ import annotations

import csv
from pathlib import Path

from dtmbnav_core import schema
from dtmbnav_core.geodetic import to_lat_lon_height
from dtmbnav_core.h5io import atomic_path
from sim.scenario import Scenario

#: File name of the towers file in a simulation's output folder.
TOWERS_CSV = "towers.csv"


def tower_rows(scenario: Scenario) -> list[tuple[str, float, float, float, float, float, float]]:
    """The rows of the towers file (:data:`dtmbnav_core.schema.TOWERS_CSV_COLUMNS`), tower 0 first: each
    tower's transmit delay offset as the network plan has it, with the plan's error as its sigma."""
    sites = scenario.sites
    lat, lon, height = to_lat_lon_height([s.x_m for s in sites], [s.y_m for s in sites],
                                         [s.height_m for s in sites], scenario.origin.point)
    return [(f"tower{i}", float(lat[i]), float(lon[i]), float(height[i]), float(scenario.tower.carrier_hz),
             float(site.transmit_delay_s), float(scenario.network.plan_error_s)) for i, site in enumerate(sites)]


def write_towers_csv(out_dir: str | Path, scenario: Scenario) -> Path:
    """Write ``towers.csv`` into ``out_dir`` (atomically) and return its path."""
    path = Path(out_dir) / TOWERS_CSV
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(schema.TOWERS_CSV_COLUMNS)
        for name, *values in tower_rows(scenario):
            writer.writerow([name, *(repr(v) for v in values)])
    return path
