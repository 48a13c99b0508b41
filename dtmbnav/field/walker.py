"""A walker profile: one walker's (and phone's) calibrated Weinberg gain, for ``--walker`` (pdr, fuse).

``dtmbnav pdr SENSORS.h5 --calibrate --distance D -o walker.toml`` writes it from a walk of a measured
length; the PDR then takes its gain. The file is TOML:

==========================  ========  =====================================================================
field                       unit      what
==========================  ========  =====================================================================
``weinberg_k_m``            m         the Weinberg gain K: step length = K (a_max - a_min)^(1/4); > 0
``[calibration]``                     how K was found (read for the record, not used):
``distance_m``              m         the walk's measured length
``steps``                             the steps detected on it
``source``                  text      the sensors file calibrated on
``date``                    text      when, ISO 8601 UTC
``[weinberg_k_m_by_carriage]``        optional: K per carriage class the PDR tells apart (``steady = 0.47``,
                                      ``swinging = 0.52``), m, > 0; a walk in that carriage takes its own
==========================  ========  =====================================================================

Every value is checked as it is read; an error names the file and the field.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dtmbnav_core.h5io import atomic_path

K_FIELD = "weinberg_k_m"
CALIBRATION_TABLE = "calibration"
BY_CARRIAGE_TABLE = "weinberg_k_m_by_carriage"


@dataclass(frozen=True)
class WalkerProfile:
    """A walker profile (module docstring).

    Attributes
    ----------
    weinberg_k_m : float
        The Weinberg gain, m.
    distance_m : float
        The calibration walk's measured length, m (NaN where the file does not say).
    steps : int
        Steps detected on it (0 where the file does not say).
    source : str
        The sensors file calibrated on.
    date : str
        When, ISO 8601 UTC.
    k_by_carriage_m : dict of str -> float
        The Weinberg gain per carriage class, m (empty where none is calibrated).
    """

    weinberg_k_m: float
    distance_m: float = math.nan
    steps: int = 0
    source: str = ""
    date: str = ""
    k_by_carriage_m: Mapping[str, float] = field(default_factory=dict)


def _gain(value: Any, where: str) -> float:
    """A Weinberg gain from a TOML value: a positive finite number, else a ValueError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{where} must be a positive number of metres, got {value!r}")
    return float(value)


def read_walker_profile(path: str | os.PathLike) -> WalkerProfile:
    """Read and check a walker profile.

    Raises
    ------
    ValueError
        A missing or unreadable file, malformed TOML (its line), no ``weinberg_k_m``, or a field of the wrong
        kind; the message names the file and the field.
    """
    where = str(path)
    try:
        doc = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ValueError(f"{where}: no such walker profile (write one with 'dtmbnav pdr SENSORS.h5 --calibrate "
                         "--distance M -o walker.toml')") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{where}: cannot read the walker profile: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{where}: not a TOML walker profile: {exc}") from None
    if K_FIELD not in doc:
        raise ValueError(f"{where}: no {K_FIELD} (the Weinberg gain, m): not a walker profile")
    k_m = _gain(doc[K_FIELD], f"{where}: {K_FIELD}")
    calibration, by_carriage = (doc.get(name, {}) for name in (CALIBRATION_TABLE, BY_CARRIAGE_TABLE))
    for name, table in ((CALIBRATION_TABLE, calibration), (BY_CARRIAGE_TABLE, by_carriage)):
        if not isinstance(table, dict):
            raise ValueError(f"{where}: {name} must be a table ([{name}]), got {table!r}")
    distance, steps = calibration.get("distance_m", math.nan), calibration.get("steps", 0)
    if isinstance(distance, bool) or not isinstance(distance, (int, float)):
        raise ValueError(f"{where}: {CALIBRATION_TABLE}.distance_m must be a number of metres, got {distance!r}")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"{where}: {CALIBRATION_TABLE}.steps must be a whole number >= 0, got {steps!r}")
    return WalkerProfile(weinberg_k_m=k_m, distance_m=float(distance), steps=steps,
                         source=str(calibration.get("source", "")), date=str(calibration.get("date", "")),
                         k_by_carriage_m={str(carriage): _gain(k, f"{where}: {BY_CARRIAGE_TABLE}.{carriage}")
                                          for carriage, k in by_carriage.items()})


def _toml_string(text: str) -> str:
    """A TOML basic string: JSON's escapes are TOML's (``\\"``, ``\\\\``, ``\\uXXXX``, ...)."""
    return json.dumps(text)


def write_walker_profile(path: str | os.PathLike, profile: WalkerProfile) -> None:
    """Write ``profile`` as TOML (atomically: the whole file or none)."""
    lines = ["# dtmbnav walker profile: the Weinberg gain of one walker and phone (dtmbnav pdr --calibrate)",
             f"{K_FIELD} = {profile.weinberg_k_m!r}", "", f"[{CALIBRATION_TABLE}]",
             f"distance_m = {profile.distance_m!r}", f"steps = {profile.steps}",
             f"source = {_toml_string(profile.source)}", f"date = {_toml_string(profile.date)}"]
    if profile.k_by_carriage_m:
        lines += ["", f"[{BY_CARRIAGE_TABLE}]",
                  *(f"{_toml_string(carriage)} = {k!r}" for carriage, k in profile.k_by_carriage_m.items())]
    with atomic_path(Path(path)) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def calibration_date() -> str:
    """Now, ISO 8601 UTC to the second, for a profile's ``date``."""
    return datetime.datetime.now(tz=datetime.UTC).isoformat(timespec="seconds")
