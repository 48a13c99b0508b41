"""The towers file of ``fuse --towers`` (``dtmbnav.field.towers``): reading it, choosing towers, placing them.

TOML and CSV forms of one table read to the same records; any valid table written as CSV reads back
equal (a property test); ``fuse --towers`` hands the chosen towers, in the sensors file's ENU frame,
and their transmit delays to the fusion, leaves out towers on another channel than the capture's,
and on the tiny walk gives the tracks the truth's own tower gives.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import h5py
import numpy as np
import pymap3d
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_OK, main
from dtmbnav.field.towers import HEIGHT_RANGE_M, MAX_TRANSMIT_DELAY_S, Tower, choose_towers, read_towers
from dtmbnav_core import schema
from dtmbnav_core.h5io import read_attrs, read_columns
from dtmbnav_core.sensors import read_tower
from fusion.transmit_delays import DEFAULT_PLAN_SIGMA_S, TransmitDelays

ORIGIN = (30.52, 114.36, 24.0)

TOML = """\
[[towers]]
name = "Guishan"
lat_deg = 30.5508
lon_deg = 114.2763
height_m = 420.0
channel_hz = 666e6
transmit_delay_s = 0.0
transmit_delay_sigma_s = 1e-7

[[towers]]
name = "Hongshan"
lat_deg = 30.5071
lon_deg = 114.3382
height_m = 96.5
channel_hz = 666e6
transmit_delay_s = 2.5e-6

[[towers]]
name = "Hankou"
lat_deg = 30.6
lon_deg = 114.3
height_m = 80
"""

#: The same towers as a CSV, with the header the simulator writes and an extra column for the sigma.
CSV = """\
name,lat_deg,lon_deg,height_m,channel_hz,transmit_delay_s,transmit_delay_sigma_s
Guishan,30.5508,114.2763,420.0,666e6,0.0,1e-7
Hongshan,30.5071,114.3382,96.5,666e6,2.5e-6,
Hankou,30.6,114.3,80,,,
"""

EXPECTED = (Tower("Guishan", 30.5508, 114.2763, 420.0, 666e6, 0.0, 1e-7),
            Tower("Hongshan", 30.5071, 114.3382, 96.5, 666e6, 2.5e-6),
            Tower("Hankou", 30.6, 114.3, 80.0))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_toml_and_csv_read_to_the_same_records(tmp_path):
    assert read_towers(_write(tmp_path / "towers.toml", TOML)) == EXPECTED
    assert read_towers(_write(tmp_path / "towers.csv", CSV)) == EXPECTED


def test_the_simulators_header_reads_with_empty_cells_as_not_given(tmp_path):
    text = "name,lat_deg,lon_deg,height_m,channel_hz,transmit_delay_s\nA,1.5,2.5,30,,\nB,-1.5,-2.5,40,7e8,1e-5\n"
    assert read_towers(_write(tmp_path / "towers.csv", text)) == (Tower("A", 1.5, 2.5, 30.0),
                                                                   Tower("B", -1.5, -2.5, 40.0, 7e8, 1e-5))


def _finite(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


_NAME = st.text(st.characters(whitelist_categories=("L", "N", "Pd", "Zs"), whitelist_characters="\"'_."),
                min_size=1, max_size=12).filter(lambda name: name == name.strip() and name.isprintable())


@st.composite
def _tower(draw, name: str) -> Tower:
    delay = draw(st.none() | _finite(-MAX_TRANSMIT_DELAY_S, MAX_TRANSMIT_DELAY_S))
    return Tower(name, draw(_finite(-90.0, 90.0)), draw(_finite(-180.0, 180.0)), draw(_finite(*HEIGHT_RANGE_M)),
                 draw(st.none() | _finite(1.0, 1e10)), delay,
                 None if delay is None else draw(st.none() | _finite(0.0, MAX_TRANSMIT_DELAY_S)))


_TABLES = st.lists(_NAME, min_size=1, max_size=6, unique=True).flatmap(
    lambda names: st.tuples(*(_tower(name) for name in names)))


@given(_TABLES)
def test_any_valid_table_written_as_csv_reads_back_equal(tmp_path_factory, towers):
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(schema.TOWERS_CSV_COLUMNS)
    for tower in towers:
        writer.writerow([tower.name, *("" if v is None else repr(v) for v in
                                       (getattr(tower, field) for field in schema.TOWERS_CSV_COLUMNS[1:]))])
    path = _write(tmp_path_factory.mktemp("csv") / "towers.csv", out.getvalue())
    assert read_towers(path) == towers


_BAD_CSV = [
    ("name,lat_deg,lon_deg,height_m\nA,1,2,3,4\n", ["line 2", "more cells"]),
    ("name,lat_deg,lon_deg,height_m\nA,1,2\n", ["line 2", "missing height_m"]),
    ("name,lat_deg,lon_deg,height_m,power_kw\nA,1,2,3,10\n", ["line 2", "unknown field", "power_kw"]),
    ("name,lat_deg,lon_deg,height_m\nA,1,2,inf\n", ["line 2", "height_m", "finite"]),
    ("name,lat_deg,lon_deg,height_m,channel_hz\nA,1,2,3,-5\n", ["line 2", "channel_hz", "positive"]),
    ("name,lat_deg,lon_deg,height_m,transmit_delay_s\nA,1,2,3,5\n", ["line 2", "transmit_delay_s", "out of range"]),
    ("name,lat_deg,lon_deg,height_m,transmit_delay_sigma_s\nA,1,2,3,1e-6\n", ["line 2", "without transmit_delay_s"]),
    ('name,lat_deg,lon_deg,height_m\n"A,B",1,2,3\n', ["line 2", "comma"]),
    ("name,lat_deg,lon_deg,height_m\n,1,2,3\n", ["line 2", "missing name"]),
    ("name,lat_deg,lat_deg,lon_deg,height_m\nA,1,1,2,3\n", ["line 1", "lat_deg", "more than once"]),
    ("name,lat_deg,lon_deg,height_m\n", ["no towers"]),
]
_BAD_TOML = [
    ('[[towers]]\nname = "A"\nlat_deg = 1\nlon_deg = 2\nheight_m = true\n', ["entry 1", "height_m", "number"]),
    ('[[towers]]\nname = 5\nlat_deg = 1\nlon_deg = 2\nheight_m = 3\n', ["entry 1", "name"]),
    ('[[towers]]\nname = "A"\nlat_deg = 1\nlon_deg = 2\nheight_m = 3\n[[towers]]\nname = "B"\nlat_deg = 1\n',
     ["entry 2", "missing lon_deg, height_m"]),
    ("towers = 3\n", ["[[towers]] tables"]),
    ("[[towers\n", ["not valid TOML"]),
]


@pytest.mark.parametrize("name, text, words", [("towers.csv", *c) for c in _BAD_CSV]
                         + [("towers.toml", *c) for c in _BAD_TOML])
def test_a_bad_file_is_refused_naming_the_line_or_entry(tmp_path, name, text, words):
    path = _write(tmp_path / name, text)
    with pytest.raises(ValueError) as exc:
        read_towers(path)
    for word in [str(path), *words]:
        assert word in str(exc.value)


def test_a_file_of_another_kind_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"\.toml .* or \.csv"):
        read_towers(_write(tmp_path / "towers.txt", CSV))


def test_names_choose_the_towers_and_the_ranging_one(tmp_path):
    chosen, note = choose_towers(EXPECTED, "t.csv", ("Hankou", "Guishan"))
    assert [t.name for t in chosen] == ["Hankou", "Guishan"] and note is None
    with pytest.raises(ValueError, match="no tower named 'Wuchang'"):
        choose_towers(EXPECTED, "t.csv", ("Guishan", "Wuchang"))


def test_towers_on_another_channel_are_left_out_and_said(tmp_path):
    chosen, note = choose_towers(EXPECTED, "t.csv", carrier_hz=674e6)
    # The two on 666 MHz go; the one without a channel stays.
    assert [t.name for t in chosen] == ["Hankou"]
    assert "Guishan" in note and "Hongshan" in note and "6.74e+08 Hz" in note
    assert choose_towers(EXPECTED, "t.csv", carrier_hz=666.2e6) == (EXPECTED, None)
    with pytest.raises(ValueError, match="another channel"):
        choose_towers(EXPECTED, "t.csv", ("Guishan",), carrier_hz=674e6)


def _sensors_with_origin(path: Path) -> Path:
    with h5py.File(path, "w") as f:
        f.create_group(schema.GNSS).attrs.update(dict(zip(schema.ORIGIN_ATTRS, ORIGIN)))
        f.create_group(schema.IMU).attrs[schema.WEINBERG_K_ATTR] = 0.5
    return path


def _receiver_on(path: Path, carrier_hz: float) -> Path:
    with h5py.File(path, "w") as f:
        f.create_group(schema.RECEIVER_FRAMES).attrs["carrier_hz"] = carrier_hz
    return path


def _fuse_arguments(tmp_path, monkeypatch, capsys, *extra: str, carrier_hz: float = 666e6) -> tuple[dict, str]:
    """What ``fuse`` hands ``fuse_files`` (which stops there), and its stderr."""
    seen = {}

    def fake_fuse(receiver, sensors_path, out, **kwargs):
        seen.update(kwargs)
        raise ValueError("stop here")

    monkeypatch.setattr("dtmbnav.chain.fuse.fuse_files", fake_fuse)
    sensors = _sensors_with_origin(tmp_path / "sensors.h5")
    rx = _receiver_on(tmp_path / "rx.h5", carrier_hz)
    # The sensors file holds an origin but no fixes, so the start fix is given.
    code = main(["-q", "fuse", "--receiver", str(rx), "--sensors", str(sensors), "-o", str(tmp_path / "f.h5"),
                 "--towers", str(_write(tmp_path / "towers.toml", TOML)), "--start", "0,0", *extra])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and "stop here" in err
    return seen, err


def _enu(tower: Tower) -> tuple[float, float, float]:
    return tuple(float(v) for v in pymap3d.geodetic2enu(tower.lat_deg, tower.lon_deg, tower.height_m, *ORIGIN))


def test_fuse_towers_hands_the_network_in_the_sensors_frame(tmp_path, monkeypatch, capsys):
    seen, err = _fuse_arguments(tmp_path, monkeypatch, capsys)
    first, *others = (_enu(t) for t in EXPECTED)
    assert seen["tower_xy_m"] == pytest.approx(first[:2], abs=1e-6)
    assert seen["tower_height_m"] == pytest.approx(first[2], abs=1e-6)
    assert np.allclose(seen["other_towers"], others, atol=1e-6)
    # A tower without an offset is taken at 0, one without a sigma at the default sigma.
    assert seen["transmit_delays"] == TransmitDelays((0.0, 2.5e-6, 0.0), (1e-7, DEFAULT_PLAN_SIGMA_S,
                                                                         DEFAULT_PLAN_SIGMA_S), "plan")
    assert "towers: Guishan, Hongshan, Hankou (ranging on Guishan)" in err


def test_fuse_tower_name_picks_the_ranging_tower_and_a_channel_leaves_towers_out(tmp_path, monkeypatch, capsys):
    seen, _ = _fuse_arguments(tmp_path, monkeypatch, capsys, "--tower-name", "Hongshan")
    assert seen["tower_xy_m"] == pytest.approx(_enu(EXPECTED[1])[:2], abs=1e-6)
    assert seen["other_towers"] == () and seen["transmit_delays"].delays_s == (2.5e-6,)
    seen, err = _fuse_arguments(tmp_path, monkeypatch, capsys, carrier_hz=674e6)
    assert seen["tower_xy_m"] == pytest.approx(_enu(EXPECTED[2])[:2], abs=1e-6)
    assert seen["other_towers"] == () and seen["transmit_delays"] is None
    assert "warning" in err and "left out" in err and "Guishan" in err


def test_fuse_towers_on_the_tiny_walk_gives_the_truth_towers_tracks(tiny_results, tiny_walk_truth, tmp_path):
    """The truth's tower, written to a towers file about an origin given to the truth, fuses as the truth's."""
    sensors = tmp_path / "sensors.h5"
    sensors.write_bytes(tiny_walk_truth.read_bytes())
    with h5py.File(sensors, "a") as f:
        f[schema.GNSS].attrs.update(dict(zip(schema.ORIGIN_ATTRS, ORIGIN)))
    x, y, up = read_tower(tiny_walk_truth)
    lat, lon, height = (float(v) for v in pymap3d.enu2geodetic(x, y, up, *ORIGIN))
    towers = _write(tmp_path / "towers.csv", f"name,lat_deg,lon_deg,height_m\nT,{lat!r},{lon!r},{height!r}\n")
    rx = tiny_results.parent / "exact-receiver.h5"
    common = ["-q", "fuse", "--receiver", str(rx), "--filters", "ukf"]
    assert main([*common, "--sensors", str(tiny_walk_truth), "-o", str(tmp_path / "truth-tower.h5")]) == EXIT_OK
    assert main([*common, "--sensors", str(sensors), "-o", str(tmp_path / "file-tower.h5"),
                 "--towers", str(towers)]) == EXIT_OK
    ukf = schema.fusion_group("ukf")
    a, b = (read_columns(tmp_path / name, ukf) for name in ("truth-tower.h5", "file-tower.h5"))
    assert np.hypot(a["x_m"] - b["x_m"], a["y_m"] - b["y_m"]).max() < 1e-3
    fusion = read_attrs(tmp_path / "file-tower.h5", schema.FUSION)
    assert math.isclose(fusion["towers_lat_deg"][0], lat, abs_tol=1e-9)
    assert math.isclose(fusion["towers_lon_deg"][0], lon, abs_tol=1e-9)

