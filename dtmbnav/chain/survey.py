"""``dtmbnav towers calibrate``: a network's transmit delay offsets surveyed on a walk with GNSS, into its towers file.

A single-frequency network's towers send with fixed transmit delay offsets
that their operator sets and seldom publishes; without them a tower
difference's code gives no absolute position (``docs/paths.md``, "Surveying a
network"). One walk where GNSS works measures them: at each of its fixes the
code of each tower difference minus the geometric difference at the fix is
the offset, to the fix's error seen along the difference
(:func:`fusion.transmit_delays.survey_code_offsets`). The result is the towers
file again, each tower's ``transmit_delay_s`` and ``transmit_delay_sigma_s``
the survey's, relative to the first tower used (exact, sigma 0), which later
walks give to ``fuse --towers``.

The walk's files are read and aligned as ``fuse`` reads them
(:func:`dtmbnav.chain.fuse.read_aligned_walk`), the towers placed as
``fuse --towers`` places them (:func:`dtmbnav.field.towers.towers_for_fuse`),
and only fixes that state their accuracy are used (per-axis sigma ``accuracy /``
:data:`~dtmbnav_core.phone.ACCURACY_RADIUS_SIGMAS`).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import numpy as np

from dtmbnav.chain.errors import NoResult
from dtmbnav.chain.fuse import read_aligned_walk
from dtmbnav.chain.inputs import read_receiver_paths
from dtmbnav.field.towers import Tower, read_towers, towers_for_fuse
from dtmbnav_core import schema
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.h5io import read_columns
from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS
from dtmbnav_core.sensors import read_fix_count
from fusion.model import Geometry
from fusion.pdr import PdrConfig
from fusion.time_alignment import TimeAlignment
from fusion.transmit_delays import CodeOffsetSurvey, SurveyFixes, survey_code_offsets
from receiver.observables import observations_from_receiver


@dataclass(frozen=True)
class TowerSurvey:
    """What ``dtmbnav towers calibrate`` found.

    Attributes
    ----------
    towers : tuple of Tower
        The towers file's towers in its order, the surveyed ones with their
        offsets and sigmas, the reference tower (the first used) at its
        file's offset (0 without one) and sigma 0; the others as given.
    names : tuple of str
        The towers surveyed against, the reference first.
    survey : CodeOffsetSurvey
        Each difference's ``c (tx_k - tx_0)``, m.
    alignment : TimeAlignment
        Where the capture started on the IMU log's clock.
    notes : tuple of str
        What the user should know: towers left out for their channel, towers
        not measured (kept as the file gives them).
    """

    towers: tuple[Tower, ...]
    names: tuple[str, ...]
    survey: CodeOffsetSurvey
    alignment: TimeAlignment
    notes: tuple[str, ...]

    def describe(self) -> str:
        """One line per difference, e.g. ``B - A: +150.31 m = +501.4 +- 6.3 ns (412 fixes, 3.1 independent)``."""
        lines = []
        for k, name in enumerate(self.names[1:]):
            offset, sigma = self.survey.offset_m[k], self.survey.sigma_m[k]
            head = f"{name} - {self.names[0]}: "
            if not np.isfinite(offset):
                lines.append(head + "not measured (no code difference at a fix with a stated accuracy)")
                continue
            lines.append(head + f"{offset:+.2f} +- {sigma:.2f} m = {offset / SPEED_OF_LIGHT_MPS * 1e9:+.1f} +- "
                                f"{sigma / SPEED_OF_LIGHT_MPS * 1e9:.1f} ns ({self.survey.fixes[k]} fixes, "
                                f"{self.survey.effective_fixes[k]:.1f} independent)")
        return "\n".join(lines)


def survey_fixes(sensors_path: str | os.PathLike) -> SurveyFixes:
    """The sensors file's GNSS fixes that state their accuracy, each with its per-axis sigma.

    Raises
    ------
    ValueError
        No fixes, or none stating its horizontal accuracy (naming the file).
    """
    where = f"{sensors_path}: /{schema.GNSS}"
    if read_fix_count(sensors_path) == 0:
        raise ValueError(f"{where}: no GNSS fixes; a survey needs a walk with GNSS fixes (the standstill at the start "
                         "and any along the walk)")
    gnss = read_columns(sensors_path, schema.GNSS)
    accuracy = np.asarray(gnss.get("accuracy_m", np.full(len(gnss["t_s"]), np.nan)), dtype=np.float64)
    stated = np.isfinite(accuracy) & (accuracy > 0)
    if not stated.any():
        raise ValueError(f"{where}: no fix states its horizontal accuracy (accuracy_m, 'dtmbnav sensors'); the "
                         "survey weighs each fix by it")
    try:
        return SurveyFixes(gnss["t_s"][stated], gnss["x_m"][stated], gnss["y_m"][stated],
                           accuracy[stated] / ACCURACY_RADIUS_SIGMAS)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def survey_towers(receiver_path: str | os.PathLike, sensors_path: str | os.PathLike,
                  towers_path: str | os.PathLike, names: tuple[str, ...] | None = None,
                  time_offset_s: float | None = None) -> TowerSurvey:
    """Survey the transmit delay offsets of a towers file's network on one walk (module docstring).

    Parameters
    ----------
    receiver_path, sensors_path : path
        The walk's receiver file (with ``/receiver/paths``) and sensors file
        (an imported phone log: a geodetic origin and fixes with their accuracy).
    towers_path : path
        The network's towers file (:mod:`dtmbnav.field.towers`).
    names : tuple of str, optional
        The towers to survey, the reference first (default: the file's, on the capture's channel).
    time_offset_s : float, optional
        Where the capture starts on the IMU log's clock, s (default as ``fuse``).

    Raises
    ------
    ValueError
        Bad or mismatched input: fewer than two towers, no fixes with an
        accuracy, no path tracker output, files of different walks.
    NoResult
        No tower difference at any usable fix.
    """
    layout = towers_for_fuse(towers_path, names, receiver_path, sensors_path)
    if len(layout.names) < 2:
        raise ValueError(f"{towers_path}: a survey measures the towers of a single-frequency network against one "
                         f"another and needs two or more on the capture's channel; it has only {layout.names[0]!r}")
    fixes = survey_fixes(sensors_path)
    rows = read_receiver_paths(receiver_path)
    if rows is None:
        raise ValueError(f"{receiver_path}: no /{schema.RECEIVER_PATHS} (the path tracker was off): a survey needs "
                         "the tower differences' codes; receive the capture again without --no-paths")
    walk = read_aligned_walk(receiver_path, sensors_path, PdrConfig(), time_offset_s)
    geometry = Geometry(float(fixes.x_m[0]), float(fixes.y_m[0]), *layout.tower_xy_m, layout.tower_height_m,
                        layout.other_towers)
    plan = None if layout.transmit_delays is None else layout.transmit_delays.delays_s
    paths = observations_from_receiver(walk.frames, rows, walk.rx_attrs, geometry.n_towers, walk.alignment.offset_s,
                                       plan, geometry.start_ranges_m()).paths
    survey = survey_code_offsets(paths, geometry, fixes)
    if not np.isfinite(survey.offset_m).any():
        raise NoResult(f"{receiver_path}: no tower difference was tracked at a GNSS fix of {sensors_path}; nothing "
                       "surveyed")
    by_name = {t.name: t for t in read_towers(towers_path)}
    reference = by_name[layout.names[0]]
    base_s = reference.transmit_delay_s or 0.0
    surveyed = {reference.name: dataclasses.replace(reference, transmit_delay_s=base_s, transmit_delay_sigma_s=0.0)}
    missing = []
    for k, name in enumerate(layout.names[1:]):
        if np.isfinite(survey.offset_m[k]):
            surveyed[name] = dataclasses.replace(
                by_name[name], transmit_delay_s=base_s + float(survey.offset_m[k]) / SPEED_OF_LIGHT_MPS,
                transmit_delay_sigma_s=float(survey.sigma_m[k]) / SPEED_OF_LIGHT_MPS)
        else:
            missing.append(name)
    notes = [layout.note] if layout.note else []
    if missing:
        notes.append(f"not measured, kept as {towers_path} gives them: {', '.join(map(repr, missing))}")
    return TowerSurvey(tuple(surveyed.get(name, tower) for name, tower in by_name.items()), layout.names, survey,
                       walk.alignment, tuple(notes))
