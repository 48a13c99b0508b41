"""The walker: a time-stamped truth path with step events (scenario ``[walk]``).

The path is the scenario's polyline with every interior corner replaced by a
circular arc of ``corner_radius_m`` (people cut corners), so heading and
velocity are continuous. Each piece of the path is a constant-curvature curve
(a line is curvature 0), which keeps position and heading analytic in the
distance walked.

Speed is a function of the distance walked: the scheduled pace (``speed_mps``
and its ``pace_changes``, blended over a few metres) capped near every stop
(start, pauses, end) by a constant-acceleration ramp ``v = sqrt(2 a d)``, so
the velocity is continuous through stops too (the acceleration jumps, as it
does when a person sets off). Time follows from ``dt = ds / v``; pauses insert
standing time at their waypoint. The standing periods before and after the
walk are part of the track.

Steps are heel strikes placed along the walked distance: nominal step length
``speed / cadence`` of the current pace, shortened while speeding up or
slowing down, with ``step_length_jitter`` relative scatter, and rescaled per
leg (stop to stop) so that the steps cover the leg exactly. A step's truth
length is therefore the path distance between consecutive heel strikes.

Everything random comes from ``numpy.random.default_rng([seed, WALK_STREAM])``:
the same scenario and seed give the same walk, and the IMU and GNSS simulators
draw from their own streams so that they never shift it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtmbnav_core.records import Track
from sim.scenario import Scenario, WalkConfig

#: Random stream of the walk (the IMU and GNSS use other stream ids).
WALK_STREAM = 1
#: Acceleration used when setting off and stopping, m/s^2 (about 1.5 s to full pace).
START_STOP_ACCEL_MPS2 = 0.8
#: Distance over which a pace change blends into the new pace, m.
PACE_BLEND_M = 3.0
#: Step length at standstill relative to the cruise step (the first and last steps are short).
MIN_STEP_FRACTION = 0.6
#: Resolution of the distance grid on which time is integrated, m.
DISTANCE_GRID_M = 0.005


@dataclass(frozen=True)
class PathPieces:
    """A path made of constant-curvature pieces, parametrised by distance walked.

    Attributes
    ----------
    s0_m : ndarray
        Distance at the start of each piece, m (the last entry of ``length_m``
        ends the path).
    x0_m, y0_m : ndarray
        Start point of each piece, m.
    heading0_rad : ndarray
        Heading at the start of each piece, clockwise from north, rad.
    curvature_per_m : ndarray
        Signed curvature, 1/m; positive turns clockwise (right), 0 for a line.
    length_m : ndarray
        Length of each piece, m.
    waypoint_s_m : ndarray
        Distance at which the walker passes closest to each scenario waypoint
        (the middle of its corner arc), m.
    """

    s0_m: np.ndarray
    x0_m: np.ndarray
    y0_m: np.ndarray
    heading0_rad: np.ndarray
    curvature_per_m: np.ndarray
    length_m: np.ndarray
    waypoint_s_m: np.ndarray

    @property
    def total_m(self) -> float:
        """Total path length, m."""
        return float(self.s0_m[-1] + self.length_m[-1])

    def evaluate(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position and heading at distances ``s_m`` along the path.

        Returns
        -------
        x_m, y_m, heading_rad : ndarray
            East, north (m) and heading in [0, 2 pi) (rad).
        """
        s_m = np.clip(np.asarray(s_m, dtype=np.float64), 0.0, self.total_m)
        i = np.clip(np.searchsorted(self.s0_m, s_m, side="right") - 1, 0, len(self.s0_m) - 1)
        u = s_m - self.s0_m[i]
        k = self.curvature_per_m[i]
        h0 = self.heading0_rad[i]
        heading = h0 + k * u
        # Integral of (sin h, cos h) ds with h = h0 + k u; the line (k = 0) is its limit.
        straight = np.abs(k) < 1e-12
        k_safe = np.where(straight, 1.0, k)
        dx = np.where(straight, u * np.sin(h0), (np.cos(h0) - np.cos(heading)) / k_safe)
        dy = np.where(straight, u * np.cos(h0), (np.sin(heading) - np.sin(h0)) / k_safe)
        return self.x0_m[i] + dx, self.y0_m[i] + dy, np.mod(heading, 2.0 * np.pi)


@dataclass(frozen=True)
class Walk:
    """A simulated walk: the truth track and the step events.

    Attributes
    ----------
    track : Track
        Truth at ``rate_hz`` from t = 0 (start of the scenario), standing
        periods included.
    step_t_s : ndarray
        Heel-strike time ending each step, s.
    step_start_t_s : ndarray
        Time each step began (the previous heel strike, or setting off), s.
    step_length_m : ndarray
        Truth length of each step (path distance between heel strikes), m.
    first_of_leg : ndarray of bool
        True for a step taken from a standstill (the first after a stop).
    rate_hz : float
        Sample rate of ``track``, Hz.
    walk_start_t_s, walk_end_t_s : float
        When the walker sets off and finally stops, s.
    path : PathPieces
        The rounded path (for geometry queries, e.g. foot placement).
    distance_m : ndarray
        Distance walked at each track sample, m.
    """

    track: Track
    step_t_s: np.ndarray
    step_start_t_s: np.ndarray
    step_length_m: np.ndarray
    first_of_leg: np.ndarray
    rate_hz: float
    walk_start_t_s: float
    walk_end_t_s: float
    path: PathPieces
    distance_m: np.ndarray

    def step_phase(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which step is in progress at times ``t_s`` and how far through it.

        Returns
        -------
        step_index : ndarray of int
            Index into the step arrays, -1 while standing.
        phase : ndarray
            Fraction of the step elapsed, in [0, 1) (0 at the step's start,
            0 while standing).
        """
        t_s = np.asarray(t_s, dtype=np.float64)
        i = np.searchsorted(self.step_t_s, t_s, side="right")
        inside = i < len(self.step_t_s)
        i_safe = np.where(inside, i, 0)
        start = self.step_start_t_s[i_safe]
        walking = inside & (t_s >= start)
        phase = (t_s - start) / (self.step_t_s[i_safe] - start)
        return np.where(walking, i, -1), np.where(walking, phase, 0.0)


def _wrap(angle_rad: np.ndarray | float) -> np.ndarray | float:
    """Wrap to (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle_rad, 2.0 * np.pi)


def build_path(waypoints_m: list[list[float]], closed: bool, corner_radius_m: float) -> PathPieces:
    """Round the corners of a polyline into a sequence of lines and arcs.

    Each interior corner turning by ``delta`` becomes an arc tangent to both
    segments at ``r tan(|delta|/2)`` from the corner; the radius shrinks where
    a segment is too short for it (at most half of each adjacent segment is
    used). The start and end points (the same point for a closed loop) stay
    sharp: the walker stands still there.

    Raises
    ------
    ValueError
        Fewer than two waypoints, repeated consecutive waypoints, or a
        negative radius.
    """
    pts = np.asarray(waypoints_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError(f"walk.waypoints_m: need at least two [x, y] points, got shape {pts.shape}")
    if corner_radius_m < 0:
        raise ValueError(f"walk.corner_radius_m must be >= 0, got {corner_radius_m}")
    if closed:
        pts = np.vstack([pts, pts[:1]])
    seg = np.diff(pts, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    if np.any(seg_len < 1e-6):
        raise ValueError("walk.waypoints_m: consecutive waypoints coincide")
    seg_heading = np.arctan2(seg[:, 0], seg[:, 1])
    n_corners = len(seg) - 1
    turn = np.array([_wrap(seg_heading[i + 1] - seg_heading[i]) for i in range(n_corners)])
    tan_half = np.tan(np.abs(turn) / 2.0)
    # Tangent distance from each corner, limited to half of either adjacent segment.
    cut = np.minimum(corner_radius_m * tan_half, 0.5 * np.minimum(seg_len[:-1], seg_len[1:]))
    # No arc for a straight-through corner, nor for a cut so small that 1 / radius would overflow.
    cut = np.where((np.abs(turn) > 1e-9) & (cut > 1e-9), cut, 0.0)
    cut_in = np.concatenate([[0.0], cut])   # trimmed from each segment's start
    cut_out = np.concatenate([cut, [0.0]])  # trimmed from each segment's end

    pieces: list[tuple[float, float, float, float, float]] = []  # x0, y0, heading0, curvature, length
    waypoint_s = [0.0]
    s = 0.0
    for i in range(len(seg)):
        direction = seg[i] / seg_len[i]
        start = pts[i] + direction * cut_in[i]
        line_len = seg_len[i] - cut_in[i] - cut_out[i]
        pieces.append((start[0], start[1], seg_heading[i], 0.0, line_len))
        s += line_len
        if i < n_corners:
            if cut[i] > 0.0:
                radius = cut[i] / tan_half[i]
                arc_len = radius * abs(turn[i])
                corner_start = pts[i + 1] - direction * cut[i]
                pieces.append((corner_start[0], corner_start[1], seg_heading[i],
                               np.sign(turn[i]) / radius, arc_len))
                waypoint_s.append(s + arc_len / 2.0)
                s += arc_len
            else:
                waypoint_s.append(s)
    waypoint_s.append(s)
    arr = np.array(pieces)
    lengths = arr[:, 4]
    return PathPieces(s0_m=np.concatenate([[0.0], np.cumsum(lengths)[:-1]]), x0_m=arr[:, 0], y0_m=arr[:, 1],
                      heading0_rad=arr[:, 2], curvature_per_m=arr[:, 3], length_m=lengths,
                      waypoint_s_m=np.array(waypoint_s[: len(waypoints_m)]))


def _smoothstep(u: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero slope at both ends, for u in [0, 1] (clipped outside)."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def scheduled_pace(cfg: WalkConfig, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cruise speed (m/s) and cadence (steps/s) at distances ``s_m``, pace changes blended in."""
    speed = np.full_like(s_m, cfg.speed_mps, dtype=np.float64)
    cadence = np.full_like(s_m, cfg.step_frequency_hz, dtype=np.float64)
    for change in sorted(cfg.pace_changes, key=lambda c: c.after_m):
        if change.speed_mps <= 0 or change.step_frequency_hz <= 0:
            raise ValueError(f"walk.pace_changes: speed and cadence must be > 0, got {change}")
        w = _smoothstep((s_m - change.after_m) / PACE_BLEND_M + 0.5)
        speed = (1.0 - w) * speed + w * change.speed_mps
        cadence = (1.0 - w) * cadence + w * change.step_frequency_hz
    return speed, cadence


def _stop_distances(cfg: WalkConfig, path: PathPieces) -> tuple[np.ndarray, np.ndarray]:
    """Distances where the walker stands still (start, pauses, end) and the standing times, s."""
    n_wp = len(cfg.waypoints_m)
    last_interior = n_wp - 1 if cfg.closed else n_wp - 2
    stops = {0.0: cfg.start_still_s, path.total_m: cfg.end_still_s}
    for pause in cfg.pauses:
        if not 1 <= pause.at_waypoint <= last_interior:
            raise ValueError(f"walk.pauses: at_waypoint must be an interior waypoint 1..{last_interior} "
                             f"(use start_still_s / end_still_s for the ends), got {pause.at_waypoint}")
        if pause.duration_s < 0:
            raise ValueError(f"walk.pauses: duration_s must be >= 0, got {pause.duration_s}")
        s = float(path.waypoint_s_m[pause.at_waypoint])
        stops[s] = stops.get(s, 0.0) + pause.duration_s
    s_stop = np.array(sorted(stops))
    return s_stop, np.array([stops[s] for s in s_stop])


def _speed_profile(cfg: WalkConfig, s_m: np.ndarray, s_stop_m: np.ndarray) -> np.ndarray:
    """Speed at distances ``s_m``: the scheduled pace, capped by set-off / stopping ramps, m/s."""
    cruise, _ = scheduled_pace(cfg, s_m)
    k = np.clip(np.searchsorted(s_stop_m, s_m, side="right") - 1, 0, len(s_stop_m) - 2)
    to_prev = np.maximum(s_m - s_stop_m[k], 0.0)
    to_next = np.maximum(s_stop_m[k + 1] - s_m, 0.0)
    ramp = np.sqrt(2.0 * START_STOP_ACCEL_MPS2 * np.minimum(to_prev, to_next))
    return np.minimum(cruise, ramp)


def _time_of_distance(cfg: WalkConfig, path: PathPieces, s_stop_m: np.ndarray,
                      stand_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (t_s, s_m) of the monotone map from time to distance walked, standing included.

    Each stop appears twice (arrival and departure) so that linear
    interpolation holds the walker still while standing.
    """
    # Near a stop the ramp v = sqrt(2 a d) is steep in distance: refine the grid there so that
    # the interpolated position has no visible kinks while the walker is slow.
    near_stop = np.concatenate([np.geomspace(1e-7, 1e-3, 40), np.arange(1e-3, 0.5, 5e-4)])
    refined = (s_stop_m[:, None] + np.concatenate([-near_stop, near_stop])[None, :]).ravel()
    grid = np.union1d(np.arange(0.0, path.total_m, DISTANCE_GRID_M), s_stop_m)
    grid = np.union1d(grid, refined[(refined > 0.0) & (refined < path.total_m)])
    speed = _speed_profile(cfg, grid, s_stop_m)
    # Mean speed over a cell is exact for the constant-acceleration ramps (and for cruising).
    dt = 2.0 * np.diff(grid) / (speed[1:] + speed[:-1])
    t = np.concatenate([[0.0], np.cumsum(dt)])
    # Shift everything after each stop by the standing time accumulated up to it.
    stop_idx = np.searchsorted(grid, s_stop_m)
    shift = np.zeros_like(t)
    for idx, stand in zip(stop_idx, stand_s):
        shift[idx:] += stand
    arrive_t = t[stop_idx] + shift[stop_idx] - stand_s
    t_nodes = np.concatenate([t + shift, arrive_t])
    s_nodes = np.concatenate([grid, s_stop_m])
    order = np.argsort(t_nodes, kind="stable")
    return t_nodes[order], s_nodes[order]


def _place_steps(cfg: WalkConfig, s_stop_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Heel-strike distances for every leg between stops, m (one array for the whole walk)."""
    strikes: list[float] = []
    for leg_start, leg_end in zip(s_stop_m[:-1], s_stop_m[1:]):
        lengths: list[float] = []
        s = leg_start
        while s < leg_end:
            here = np.array([s])
            cruise, cadence = scheduled_pace(cfg, here)
            nominal = cruise[0] / cadence[0]
            # Shorter steps while the speed ramps up or down (about v/cruise of a full step).
            relative_speed = _speed_profile(cfg, here + 0.5 * nominal, s_stop_m)[0] / cruise[0]
            factor = MIN_STEP_FRACTION + (1.0 - MIN_STEP_FRACTION) * relative_speed
            length = nominal * factor * (1.0 + cfg.step_length_jitter * rng.standard_normal())
            lengths.append(max(length, 0.2 * nominal))
            s += lengths[-1]
        # Round to a whole number of steps and stretch them to cover the leg exactly.
        n = max(1, len(lengths) - 1 if (s - leg_end) > 0.5 * lengths[-1] else len(lengths))
        chosen = np.array(lengths[:n])
        chosen *= (leg_end - leg_start) / chosen.sum()
        leg_strikes = leg_start + np.cumsum(chosen)
        leg_strikes[-1] = leg_end  # exactly at the stop, free of rounding
        strikes.extend(leg_strikes)
    return np.array(strikes)


def _time_at(s_m: np.ndarray, t_nodes: np.ndarray, s_nodes: np.ndarray, depart: bool = False) -> np.ndarray:
    """Invert the time->distance map at distances ``s_m``, s.

    At a stop the map is flat; ``depart=False`` returns the arrival time there,
    ``depart=True`` the departure time.
    """
    last = len(s_nodes) - 1
    if depart:
        j = np.clip(np.searchsorted(s_nodes, s_m, side="right") - 1, 0, last - 1)
        lo, hi = j, j + 1
    else:
        j = np.clip(np.searchsorted(s_nodes, s_m, side="left"), 1, last)
        lo, hi = j - 1, j
    ds = s_nodes[hi] - s_nodes[lo]
    frac = np.where(ds > 0, (s_m - s_nodes[lo]) / np.where(ds > 0, ds, 1.0), 0.0 if depart else 1.0)
    return t_nodes[lo] + frac * (t_nodes[hi] - t_nodes[lo])


def simulate_walk(scenario: Scenario, rate_hz: float = 100.0) -> Walk:
    """Simulate the scenario's walker.

    Parameters
    ----------
    scenario : Scenario
        Uses ``scenario.walk`` and ``scenario.seed``.
    rate_hz : float
        Sample rate of the truth track, Hz.

    Returns
    -------
    Walk
        Truth track from t = 0 (start of the standing period) to the end of
        the final standing period, and the step events.

    Raises
    ------
    ValueError
        Invalid walk parameters (the message names the field).
    """
    cfg = scenario.walk
    if rate_hz <= 0:
        raise ValueError(f"simulate_walk: rate_hz must be > 0, got {rate_hz}")
    if cfg.speed_mps <= 0 or cfg.step_frequency_hz <= 0:
        raise ValueError(f"walk.speed_mps and walk.step_frequency_hz must be > 0, got "
                         f"{cfg.speed_mps}, {cfg.step_frequency_hz}")
    if cfg.start_still_s < 0 or cfg.end_still_s < 0 or cfg.step_length_jitter < 0:
        raise ValueError("walk.start_still_s, end_still_s and step_length_jitter must be >= 0")
    rng = np.random.default_rng([scenario.seed, WALK_STREAM])
    path = build_path(cfg.waypoints_m, cfg.closed, cfg.corner_radius_m)
    s_stop, stand = _stop_distances(cfg, path)
    t_nodes, s_nodes = _time_of_distance(cfg, path, s_stop, stand)

    t = np.arange(int(np.floor(t_nodes[-1] * rate_hz)) + 1) / rate_hz
    s = np.interp(t, t_nodes, s_nodes)
    x, y, heading = path.evaluate(s)
    speed = _speed_profile(cfg, s, s_stop)
    track = Track(t_s=t, x_m=x, y_m=y, heading_rad=heading, speed_mps=speed)

    strike_s = _place_steps(cfg, s_stop, rng)
    # A strike that ends a leg happens on arrival at the stop; a leg's first step starts on departure.
    strike_t = _time_at(strike_s, t_nodes, s_nodes)
    leg_of_strike = np.searchsorted(s_stop, strike_s, side="left") - 1
    departure_t = _time_at(s_stop[:-1], t_nodes, s_nodes, depart=True)
    first_in_leg = np.concatenate([[True], leg_of_strike[1:] != leg_of_strike[:-1]])
    step_start = np.where(first_in_leg, departure_t[leg_of_strike], np.concatenate([[0.0], strike_t[:-1]]))
    step_length = np.diff(np.concatenate([[0.0], strike_s]))  # each leg's last strike is at its stop
    return Walk(track=track, step_t_s=strike_t, step_start_t_s=step_start, step_length_m=step_length,
                first_of_leg=first_in_leg, rate_hz=float(rate_hz), walk_start_t_s=float(departure_t[0]),
                walk_end_t_s=float(_time_at(np.array([path.total_m]), t_nodes, s_nodes)[0]),
                path=path, distance_m=s)
