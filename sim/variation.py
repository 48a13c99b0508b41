"""Per-seed variation of a scenario's geometry, so that no setting is fitted to one layout.

:func:`vary_scenario` draws, from the seed alone, a new layout of the same
walk (``docs/scenarios.md``, "Geometry variation"):

1. **Scene orientation.** The whole scene turns about the start P0 (the first
   waypoint) by an angle drawn uniformly in ``rotation_deg``: the waypoints,
   the walls, the building footprints and the point scatterers together, so
   the streets keep their shape around the walk and every blockage and
   reflection is still computed from the geometry. The tower turns with them.
2. **Tower bearing.** The tower's bearing from P0 is then moved by an offset
   drawn uniformly in ``[-spread, +spread]``: ``open_bearing_spread_deg`` for
   a scene without buildings (180: any bearing), ``shadowed_bearing_spread_deg``
   for a scene with buildings, whose buildings stand where they do to shadow
   the walk from its tower; a sector keeps that shadow while still moving it.
3. **Tower distance.** The tower's horizontal distance from P0 is drawn
   uniformly in ``tower_distance_m``; its height is kept.

A single-frequency network (``[[towers]]``) turns with the scene as a whole:
every tower keeps its distance, so the delays between towers stay those of
the file (a drawn bearing and distance could move a tower out of the guard
interval). The bearing and distance draws are still made (the stream stays
the same) but not applied.

The draws use ``default_rng([seed, STREAM_VARIATION])`` in that order, so the
layout is a pure function of (scenario, seed) and the scenario's other random
streams are untouched. The scenario's own ``seed`` is not changed. Amplitudes
are relative to the direct path (:mod:`sim.channel`), so the tower's distance
changes the geometry (bearing, elevation), not the C/N.

Each positional field of a scenario is listed once in :func:`vary_scenario`;
a new one (another tower, another kind of scene object) is one more line
there.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sim.scenario import Scenario

#: Random stream id of the geometry draws (second element of the seed sequence).
STREAM_VARIATION = 0x6E0


@dataclass(frozen=True)
class VariationConfig:
    """Ranges of the per-seed geometry draws (module docstring).

    Attributes
    ----------
    rotation_deg : (float, float)
        Scene rotation about the start, clockwise, degrees (uniform).
    open_bearing_spread_deg : float
        Half-width of the tower-bearing offset in a scene without buildings, degrees.
    shadowed_bearing_spread_deg : float
        Half-width of the tower-bearing offset in a scene with buildings, degrees.
    tower_distance_m : (float, float)
        Horizontal tower distance from the start, m (uniform).
    """

    rotation_deg: tuple[float, float] = (0.0, 360.0)
    open_bearing_spread_deg: float = 180.0
    shadowed_bearing_spread_deg: float = 30.0
    tower_distance_m: tuple[float, float] = (2000.0, 10000.0)


@dataclass(frozen=True)
class Layout:
    """One draw of :func:`draw_layout`.

    Attributes
    ----------
    rotation_rad : float
        Scene rotation about the start, clockwise, rad.
    bearing_offset_rad : float
        Tower bearing offset after the rotation, clockwise, rad.
    tower_distance_m : float
        Horizontal tower distance from the start, m.
    """

    rotation_rad: float
    bearing_offset_rad: float
    tower_distance_m: float


def draw_layout(scenario: Scenario, seed: int, config: VariationConfig = VariationConfig()) -> Layout:
    """The rotation, tower-bearing offset and tower distance of ``seed`` (module docstring)."""
    rng = np.random.default_rng([int(seed), STREAM_VARIATION])
    rotation = rng.uniform(*config.rotation_deg)
    spread = config.shadowed_bearing_spread_deg if scenario.channel.buildings else config.open_bearing_spread_deg
    offset = rng.uniform(-spread, spread)
    distance = rng.uniform(*config.tower_distance_m)
    return Layout(float(np.deg2rad(rotation)), float(np.deg2rad(offset)), float(distance))


def rotate_xy(points_m: np.ndarray, centre_m: np.ndarray, angle_rad: float) -> np.ndarray:
    """Points (..., 2) turned clockwise (the heading sense, docs/conventions.md) about ``centre_m``, m."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    d = np.asarray(points_m, dtype=np.float64) - centre_m
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1) + centre_m


def vary_scenario(scenario: Scenario, seed: int, config: VariationConfig = VariationConfig()) -> Scenario:
    """The scenario with the layout of ``seed``: scene rotated about the start, tower re-placed.

    Parameters
    ----------
    scenario : Scenario
        The reference layout.
    seed : int
        Draws the layout (:func:`draw_layout`); the scenario's own seed is kept.
    config : VariationConfig

    Returns
    -------
    Scenario
        A new scenario; ``scenario`` is not changed.
    """
    layout = draw_layout(scenario, seed, config)
    start = np.asarray(scenario.walk.waypoints_m[0], dtype=np.float64)

    def turn(point) -> list[float]:
        return rotate_xy(np.asarray(point, dtype=np.float64), start, layout.rotation_rad).tolist()

    channel = scenario.channel
    if scenario.towers:
        moved = {"towers": [dataclasses.replace(site, **dict(zip(("x_m", "y_m"), turn([site.x_m, site.y_m]))))
                            for site in scenario.towers]}
    else:
        tower = scenario.tower
        bearing = (np.arctan2(tower.x_m - start[0], tower.y_m - start[1]) + layout.rotation_rad
                   + layout.bearing_offset_rad)
        tower_xy = start + layout.tower_distance_m * np.array([np.sin(bearing), np.cos(bearing)])
        moved = {"tower": dataclasses.replace(tower, x_m=float(tower_xy[0]), y_m=float(tower_xy[1]))}
    return dataclasses.replace(
        scenario,
        **moved,
        walk=dataclasses.replace(scenario.walk, waypoints_m=[turn(p) for p in scenario.walk.waypoints_m]),
        channel=dataclasses.replace(
            channel,
            scatterers=[dataclasses.replace(s, **dict(zip(("x_m", "y_m"), turn([s.x_m, s.y_m]))))
                        for s in channel.scatterers],
            walls=[dataclasses.replace(w, start_m=turn(w.start_m), end_m=turn(w.end_m)) for w in channel.walls],
            buildings=[dataclasses.replace(b, polygon_m=[turn(p) for p in b.polygon_m]) for b in channel.buildings]))
