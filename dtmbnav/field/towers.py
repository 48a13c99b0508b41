"""A towers file: a network's transmitters by latitude, longitude and height, for ``fuse --towers``.

The file is TOML (one ``[[towers]]`` table a tower) or CSV (a header row, then one row a tower),
told apart by its suffix (``.toml`` or ``.csv``). Its fields:

==========================  ========  =====================================================================
field                       unit      what
==========================  ========  =====================================================================
``name``                    text      unique; no comma (``--tower-name`` separates names with commas)
``lat_deg``, ``lon_deg``    deg       WGS84 latitude (-90..90) and longitude (-180..180)
``height_m``                m         the antenna's height above the WGS84 ellipsoid (-500..9000)
``channel_hz``              Hz        optional: centre of the DTMB channel the tower transmits on
``transmit_delay_s``        s         optional: the tower's transmit delay offset in the network plan
``transmit_delay_sigma_s``  s         optional, with ``transmit_delay_s``: its standard deviation (100 ns without)
==========================  ========  =====================================================================

An empty CSV cell is a field not given. Every value is checked as it is read, and an error names the
file and the CSV line or the ``[[towers]]`` entry (counted from 1). :func:`towers_for_fuse` picks the
towers a fusion uses and puts them into a sensors file's ENU frame (:func:`towers_about`: about any origin);
:func:`write_towers_csv` writes a towers file back (``dtmbnav towers calibrate``'s surveyed one).
"""

from __future__ import annotations

import csv
import io
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dtmbnav_core import schema
from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from dtmbnav_core.geodetic import GeodeticPoint, required_origin, tower_in_frame
from dtmbnav_core.h5io import atomic_path, read_attrs
from dtmbnav_core.schema import TOWERS_CSV_COLUMNS, TOWERS_CSV_OPTIONAL, TOWERS_CSV_REQUIRED
from fusion.transmit_delays import DEFAULT_PLAN_SIGMA_S, TransmitDelays

#: Antenna heights above the WGS84 ellipsoid a towers file may give, m: below it or above it is a unit slip.
HEIGHT_RANGE_M = (-500.0, 9000.0)
#: Largest transmit delay offset taken, s: a network plan's offsets are far shorter.
MAX_TRANSMIT_DELAY_S = 1.0
#: A tower whose ``channel_hz`` is within this of the capture's carrier is on its channel, Hz: half the
#: signal's bandwidth (GB 20600's 7.56 Msps), well short of the next channel's centre.
SAME_CHANNEL_HZ = SYMBOL_RATE_HZ / 2


@dataclass(frozen=True)
class Tower:
    """One transmitter of a towers file.

    Attributes
    ----------
    name : str
        The tower's name, unique in its file.
    lat_deg, lon_deg : float
        WGS84 latitude and longitude, deg.
    height_m : float
        The antenna's height above the WGS84 ellipsoid, m.
    channel_hz : float or None
        Centre of the DTMB channel it transmits on, Hz; None where not given.
    transmit_delay_s : float or None
        Its transmit delay offset in the network plan, s; None where not given.
    transmit_delay_sigma_s : float or None
        Standard deviation of that offset, s; None where not given.
    """

    name: str
    lat_deg: float
    lon_deg: float
    height_m: float
    channel_hz: float | None = None
    transmit_delay_s: float | None = None
    transmit_delay_sigma_s: float | None = None

    def point(self) -> GeodeticPoint:
        """The antenna's place on WGS84 (deg, deg, m above the ellipsoid)."""
        return GeodeticPoint(self.lat_deg, self.lon_deg, self.height_m)


def _number(value: Any, field: str, where: str) -> float:
    """A finite number from a CSV cell (text) or a TOML value, else ValueError naming ``where`` and the field."""
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise ValueError(f"{where}: {field} must be a number, got {value!r}")
    try:
        number = float(value)
    except ValueError:
        raise ValueError(f"{where}: {field} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{where}: {field} must be a finite number, got {value!r}")
    return number


def _within(number: float, field: str, where: str, low: float, high: float, unit: str) -> None:
    """ValueError naming ``where`` and the field where ``number`` (in ``unit``) is outside ``low..high``."""
    if not low <= number <= high:
        raise ValueError(f"{where}: {field} {number:g} {unit} is out of range ({low:g}..{high:g} {unit})")


def _tower(entry: Mapping[str, Any], where: str) -> Tower:
    """A checked :class:`Tower` from one table or row (absent or None: a field not given)."""
    unknown = sorted(str(key) for key in entry if key not in TOWERS_CSV_COLUMNS)
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; a tower's fields are {', '.join(TOWERS_CSV_COLUMNS)}")
    missing = [field for field in TOWERS_CSV_REQUIRED if entry.get(field) is None]
    if missing:
        raise ValueError(f"{where}: missing {', '.join(missing)}")
    name = entry["name"]
    if not isinstance(name, str) or not name.strip() or not name.isprintable():
        raise ValueError(f"{where}: name must be non-empty printable text, got {name!r}")
    if "," in name:
        raise ValueError(f"{where}: name {name!r} holds a comma (--tower-name separates names with commas)")
    values = {field: _number(entry[field], field, where) for field in TOWERS_CSV_COLUMNS[1:]
              if entry.get(field) is not None}
    _within(values["lat_deg"], "lat_deg", where, -90.0, 90.0, "deg")
    _within(values["lon_deg"], "lon_deg", where, -180.0, 180.0, "deg")
    _within(values["height_m"], "height_m", where, *HEIGHT_RANGE_M, "m")
    if values.get("channel_hz", 1.0) <= 0:
        raise ValueError(f"{where}: channel_hz must be positive, got {values['channel_hz']:g} Hz")
    if "transmit_delay_s" in values:
        _within(values["transmit_delay_s"], "transmit_delay_s", where, -MAX_TRANSMIT_DELAY_S, MAX_TRANSMIT_DELAY_S,
                "s")
    if "transmit_delay_sigma_s" in values:
        if "transmit_delay_s" not in values:
            raise ValueError(f"{where}: transmit_delay_sigma_s without transmit_delay_s")
        _within(values["transmit_delay_sigma_s"], "transmit_delay_sigma_s", where, 0.0, MAX_TRANSMIT_DELAY_S, "s")
    return Tower(name=name.strip(), **values)


def _csv_rows(path: Path, text: str) -> list[Tower]:
    reader = csv.DictReader(io.StringIO(text, newline=""), skipinitialspace=True)
    header = [str(field).strip() for field in reader.fieldnames or ()]
    if not header:
        raise ValueError(f"{path}: empty; a towers CSV starts with a header row ({', '.join(TOWERS_CSV_REQUIRED)}; "
                         f"optional {', '.join(TOWERS_CSV_OPTIONAL)})")
    reader.fieldnames = header
    missing = [field for field in TOWERS_CSV_REQUIRED if field not in header]
    if missing:
        raise ValueError(f"{path}: line 1: the header has no column(s) {', '.join(missing)} "
                         f"(it has {', '.join(header)})")
    repeated = sorted({field for field in header if header.count(field) > 1})
    if repeated:
        raise ValueError(f"{path}: line 1: column(s) {', '.join(repeated)} appear more than once")
    towers = []
    for row in reader:
        where = f"{path}: line {reader.line_num}"
        if None in row:
            raise ValueError(f"{where}: more cells than the header's {len(header)} columns")
        cells = {key: value.strip() for key, value in row.items() if value is not None and value.strip()}
        towers.append(_tower(cells, where))
    return towers


def _toml_tables(path: Path, text: str) -> list[Tower]:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    tables = doc.get("towers")
    if tables is None:
        raise ValueError(f"{path}: no [[towers]] table; give one [[towers]] table a tower "
                         f"(fields {', '.join(TOWERS_CSV_COLUMNS)})")
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ValueError(f"{path}: towers must be [[towers]] tables, one a tower")
    return [_tower(table, f"{path}: [[towers]] entry {i}") for i, table in enumerate(tables, start=1)]


def read_towers(path: str | os.PathLike) -> tuple[Tower, ...]:
    """Every tower of a towers file (module docstring), in the file's order.

    Raises
    ------
    ValueError
        Missing or unreadable file, unknown suffix, no towers, a missing field or column, a value
        that is not a finite number or is out of range, or a name given twice: the message names the
        file and the CSV line or ``[[towers]]`` entry.
    """
    path = Path(path)
    readers = {".csv": _csv_rows, ".toml": _toml_tables}
    if path.suffix.lower() not in readers:
        raise ValueError(f"{path}: a towers file is .toml ([[towers]] tables) or .csv (a header row), "
                         f"not {path.suffix or 'a file without a suffix'}")
    if not path.is_file():
        raise ValueError(f"{path}: {'no such file' if not path.exists() else 'not a file'}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    towers = readers[path.suffix.lower()](path, text)
    if not towers:
        raise ValueError(f"{path}: no towers")
    names = [t.name for t in towers]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"{path}: tower name(s) {', '.join(map(repr, repeated))} given more than once")
    return tuple(towers)


def write_towers_csv(path: str | os.PathLike, towers: tuple[Tower, ...]) -> Path:
    """Write ``towers`` as a towers CSV (every column of :data:`~dtmbnav_core.schema.TOWERS_CSV_COLUMNS`, an
    empty cell for a field not given; numbers as the shortest text that reads back to the same float),
    atomically; its path."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(TOWERS_CSV_COLUMNS)
        for tower in towers:
            writer.writerow([tower.name, *("" if (v := getattr(tower, field)) is None else repr(float(v))
                                           for field in TOWERS_CSV_COLUMNS[1:])])
    return path


def choose_towers(towers: tuple[Tower, ...], path: str | os.PathLike, names: tuple[str, ...] | None = None,
                  carrier_hz: float | None = None) -> tuple[tuple[Tower, ...], str | None]:
    """The towers a fusion uses, the ranging tower first, and a note on those left out for their channel.

    Parameters
    ----------
    towers : tuple of Tower
        A towers file's towers (:func:`read_towers`).
    path : str or path
        That file, for the messages.
    names : tuple of str, optional
        The towers to use, the ranging tower first; default: every tower of the file, its first the
        ranging one.
    carrier_hz : float, optional
        The capture's channel centre, Hz: towers with a ``channel_hz`` elsewhere are left out
        (named ones are an error).

    Raises
    ------
    ValueError
        A name the file does not hold, a named tower on another channel, or none left.
    """
    by_name = {t.name: t for t in towers}
    unknown = [name for name in names or () if name not in by_name]
    if unknown:
        raise ValueError(f"{path}: no tower named {', '.join(map(repr, unknown))} (the file has "
                         f"{', '.join(map(repr, by_name))})")
    chosen = tuple(by_name[name] for name in names) if names else towers
    if carrier_hz is None:
        return chosen, None
    elsewhere = [t for t in chosen if t.channel_hz is not None and abs(t.channel_hz - carrier_hz) > SAME_CHANNEL_HZ]
    if not elsewhere:
        return chosen, None
    listed = ", ".join(f"{t.name!r} ({t.channel_hz:g} Hz)" for t in elsewhere)
    if names:
        raise ValueError(f"{path}: tower(s) {listed} transmit on another channel than the capture's "
                         f"{carrier_hz:g} Hz")
    kept = tuple(t for t in chosen if t not in elsewhere)
    if not kept:
        raise ValueError(f"{path}: no tower on the capture's channel {carrier_hz:g} Hz (the file's: {listed})")
    return kept, (f"{path}: left out the tower(s) on another channel than the capture's {carrier_hz:g} Hz: "
                  f"{listed}")


@dataclass(frozen=True)
class TowerLayout:
    """The towers of a fusion in a sensors file's ENU frame, as :func:`dtmbnav.chain.fuse.fuse_files` takes them.

    Attributes
    ----------
    names : tuple of str
        The towers used, the ranging tower (tower 0) first.
    tower_xy_m : (float, float)
        Tower 0's east and north, m.
    tower_height_m : float
        Tower 0's antenna height above the receiver's antenna, m.
    other_towers : tuple of (x_m, y_m, height_m)
        The network's other towers, same units.
    transmit_delays : TransmitDelays or None
        Each tower's transmit delay offset in the network plan and its sigma, s (0 where the file
        gives no offset; :data:`fusion.transmit_delays.DEFAULT_PLAN_SIGMA_S` where it gives no
        sigma); None where no tower used has an offset (the fusion then estimates them).
    note : str or None
        Which towers were left out for their channel, to tell the user; None where none.
    """

    names: tuple[str, ...]
    tower_xy_m: tuple[float, float]
    tower_height_m: float
    other_towers: tuple[tuple[float, float, float], ...]
    transmit_delays: TransmitDelays | None
    note: str | None


def _recorded_carrier_hz(receiver_path: str | os.PathLike) -> float | None:
    """The channel centre a receiver file's ``/receiver/frames`` records (``carrier_hz``), Hz; None without."""
    value = read_attrs(receiver_path, schema.RECEIVER_FRAMES).get("carrier_hz")
    try:
        carrier = float(value)
    except (TypeError, ValueError):
        return None
    return carrier if math.isfinite(carrier) and carrier > 0 else None


def towers_for_fuse(towers_path: str | os.PathLike, names: tuple[str, ...] | None,
                    receiver_path: str | os.PathLike, sensors_path: str | os.PathLike) -> TowerLayout:
    """``fuse --towers``: the towers of a towers file a fusion uses, in the sensors file's ENU frame.

    The towers are those ``names`` gives, or all the file's, the first the ranging tower; where
    a tower states its channel, the receiver file's is read and towers on other channels are left out
    (:func:`choose_towers`).

    Raises
    ------
    ValueError
        A bad towers file (:func:`read_towers`, :func:`choose_towers`), an unreadable receiver file
        where a channel is to be checked, or a sensors file without a geodetic origin.
    """
    towers = read_towers(towers_path)
    carrier_hz = None
    if any(t.channel_hz is not None for t in towers):
        carrier_hz = _recorded_carrier_hz(receiver_path)
    chosen, note = choose_towers(towers, towers_path, names, carrier_hz)
    return towers_about(chosen, required_origin(sensors_path), note)


def towers_about(chosen: tuple[Tower, ...], origin: GeodeticPoint, note: str | None = None) -> TowerLayout:
    """The towers ``chosen`` (the ranging tower first) as a :class:`TowerLayout` in the ENU frame about ``origin``."""
    sites = [tower_in_frame(origin, t.point()) for t in chosen]
    delays = None
    if any(t.transmit_delay_s is not None for t in chosen):
        delays = TransmitDelays(
            tuple(t.transmit_delay_s or 0.0 for t in chosen),
            tuple(DEFAULT_PLAN_SIGMA_S if t.transmit_delay_sigma_s is None else t.transmit_delay_sigma_s
                  for t in chosen), "plan")
    return TowerLayout(names=tuple(t.name for t in chosen), tower_xy_m=sites[0][:2], tower_height_m=sites[0][2],
                       other_towers=tuple(sites[1:]), transmit_delays=delays, note=note)
