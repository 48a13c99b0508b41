"""Geometry-driven propagation channel from the tower(s) to the walking receiver.

The channel is a sum of paths, each with a delay ``tau_p(t)``, a real or
complex gain and the carrier phase ``-2 pi fc tau_p(t)`` that its geometry
implies (never a constant frequency times time: the Doppler of a path is
``-fc d tau_p / dt`` and comes out of its length changing). Amplitudes are
relative to the unobstructed direct path (amplitude 1); the free-space loss
change over a walk (a few per cent of 3 km) is ignored.

Paths (``ChannelConfig`` of the scenario):

- **direct**: 3-D distance from the tower antenna (``tower.height_m``) to the
  receiver antenna (``channel.antenna_height_m``), attenuated by
  ``Building.attenuation_db`` of every building footprint that the 2-D line of
  sight crosses (then ``los`` is False);
- **ground**: flat-earth ground reflection (image tower at ``-height_m``),
  reflection coefficient ``-10^(ground_reflection_db / 20)``, blocked like the
  direct path;
- **scatterers**: tower -> scatterer -> receiver, amplitude
  ``10^(gain_db / 20)``, attenuated by buildings crossing the
  scatterer-receiver segment;
- **walls**: specular reflection from a vertical building face (``Wall``) by
  the image method: the tower is mirrored (2-D) across the wall's line and
  the path length is the 3-D distance from that image tower (at the tower's
  height) to the receiver. Walking along a wall, the length changes like the
  direct path's in the component along the wall, so its Doppler is close to
  the direct path's (the canyon physics that keeps the NLOS range error
  small). Amplitude ``10^(gain_db / 20)`` while the specular point (where the
  image-receiver line meets the wall's line) lies on the segment and the tower
  is on the receiver's side of the wall; a raised-cosine taper over
  ``WALL_EDGE_TAPER_M`` past each end switches it off without a jump. The
  receiver leg (specular point -> receiver, at street level) is attenuated by
  the buildings it crosses, so a face is not heard through a block; the
  incoming leg is not (a simplification: on a tall face the specular point is
  high enough to see the 150 m tower over the roofs);
- **diffuse**: ``diffuse_taps`` taps at excess delays spread as an exponential
  profile of mean ``diffuse_delay_s`` (the quantile mid-points) behind the
  direct path, total power ``10^(-rician_k_db / 10)``, each a Rayleigh-fading
  gain made of ``DIFFUSE_SINUSOIDS`` sinusoids with Doppler
  ``diffuse_doppler_hz * cos(theta)`` and random phase (Jakes / Clarke model),
  drawn from the seed. The diffuse fading runs in true time, so it also
  moves while the walker stands still (environmental motion).

Several towers (a single-frequency network, ``Scenario.sites``): each tower
has all of the paths above, computed from its own position in the same scene
(so its own blockage and reflections), with its power (``power_db``, all of
its paths) and fixed transmit delay (``transmit_delay_s``) added; amplitudes
are then relative to the first tower's unobstructed direct path. Blockage
attenuates a direct path (diffraction over and around the block), it never
removes it: a blocked direct path is still the first to arrive, 20-22 dB down
in the shipped streets (docs/paths.md).

Path lengths are computed at the track's samples and interpolated with a
cubic spline of each length against time, so delays and Dopplers are smooth
between the ~100 Hz track samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import Track
from sim.scenario import Building, ChannelConfig, Scenario, TowerSite, Wall

#: Sinusoids summed in each diffuse tap (sum-of-sinusoids Rayleigh fading).
DIFFUSE_SINUSOIDS = 16

#: Distance past a wall's end over which its reflection fades out, m (about a
#: Fresnel-zone width at UHF for reflectors tens of metres away).
WALL_EDGE_TAPER_M = 1.0


def segment_crosses_polygon(ax: np.ndarray, ay: np.ndarray, bx: float | np.ndarray, by: float | np.ndarray,
                            polygon_m: list[list[float]]) -> np.ndarray:
    """Whether segments A-B (A vectorised) cross any edge of a polygon (2-D)."""
    poly = np.asarray(polygon_m, dtype=np.float64)
    crosses = np.zeros(np.shape(ax), dtype=bool)

    def side(px, py, qx, qy, rx, ry):  # z of (q - p) x (r - p): which side of line p-q r lies on
        return (qx - px) * (ry - py) - (qy - py) * (rx - px)

    for (cx, cy), (dx, dy) in zip(poly, np.roll(poly, -1, axis=0)):
        d1 = side(cx, cy, dx, dy, ax, ay)
        d2 = side(cx, cy, dx, dy, bx, by)
        d3 = side(ax, ay, bx, by, cx, cy)
        d4 = side(ax, ay, bx, by, dx, dy)
        crosses |= (d1 * d2 < 0) & (d3 * d4 < 0)
    return crosses


def blocking_loss_db(ax: np.ndarray, ay: np.ndarray, bx: float | np.ndarray, by: float | np.ndarray,
                     buildings: list[Building]) -> np.ndarray:
    """Total attenuation of segments A-B by the buildings they cross, dB."""
    loss = np.zeros(np.shape(ax))
    for building in buildings:
        loss += np.where(segment_crosses_polygon(ax, ay, bx, by, building.polygon_m), building.attenuation_db, 0.0)
    return loss



@dataclass(frozen=True)
class WallImage:
    """Image-method geometry of one wall for one tower (module docstring).

    Attributes
    ----------
    start_xy : ndarray, shape (2,)
        Wall start point, m.
    along : ndarray, shape (2,)
        Unit vector from the start to the end of the wall.
    normal : ndarray, shape (2,)
        Unit normal of the wall (``along`` turned by +90 degrees).
    length_m : float
        Wall length, m.
    image_xy : ndarray, shape (2,)
        Tower position mirrored across the wall's line, m.
    tower_offset_m : float
        Signed distance of the tower from the wall's line along ``normal``, m.
    amplitude : float
        ``10^(gain_db / 20)``.
    """

    start_xy: np.ndarray
    along: np.ndarray
    normal: np.ndarray
    length_m: float
    image_xy: np.ndarray
    tower_offset_m: float
    amplitude: float

    @classmethod
    def of(cls, wall: Wall, tower_x_m: float, tower_y_m: float) -> "WallImage":
        """Mirror the tower across ``wall``.

        Raises
        ------
        ValueError
            For a wall of zero length.
        """
        start = np.asarray(wall.start_m, dtype=np.float64)
        end = np.asarray(wall.end_m, dtype=np.float64)
        if start.shape != (2,) or end.shape != (2,):
            raise ValueError(f"wall {wall}: start_m and end_m must be [x, y]")
        length = float(np.hypot(*(end - start)))
        if length == 0.0:
            raise ValueError(f"wall {wall}: start_m and end_m coincide")
        along = (end - start) / length
        normal = np.array([-along[1], along[0]])
        offset = float(np.dot([tower_x_m, tower_y_m] - start, normal))
        image = np.array([tower_x_m, tower_y_m]) - 2.0 * offset * normal
        return cls(start, along, normal, length, image, offset, 10.0 ** (wall.gain_db / 20.0))

    def path_length_m(self, x_m: np.ndarray, y_m: np.ndarray, height_diff_m: float) -> np.ndarray:
        """Tower -> wall -> receiver length: 3-D distance from the image tower, m."""
        return np.hypot(np.hypot(x_m - self.image_xy[0], y_m - self.image_xy[1]), height_diff_m)

    def specular_point_m(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Position of the specular point along the wall (0 at the start), m; NaN off the tower's side."""
        rx, ry = x_m - self.start_xy[0], y_m - self.start_xy[1]
        receiver_offset = rx * self.normal[0] + ry * self.normal[1]
        receiver_along = rx * self.along[0] + ry * self.along[1]
        image_along = float(np.dot(self.image_xy - self.start_xy, self.along))
        same_side = receiver_offset * self.tower_offset_m > 0.0
        # The image sits at -tower_offset; the line image -> receiver crosses offset 0 at this fraction.
        denominator = np.where(same_side, receiver_offset + self.tower_offset_m, 1.0)
        fraction = self.tower_offset_m / denominator
        return np.where(same_side, image_along + fraction * (receiver_along - image_along), np.nan)

    def amplitude_at(self, x_m: np.ndarray, y_m: np.ndarray, buildings: list[Building]) -> np.ndarray:
        """Path amplitude: edge taper, blockage of the receiver leg; 0 where no specular point is on the wall."""
        along = self.specular_point_m(x_m, y_m)
        missing = np.isnan(along)
        along = np.where(missing, 0.0, along)
        overshoot = np.maximum(np.maximum(-along, along - self.length_m), 0.0)
        taper = 0.5 * (1.0 + np.cos(np.pi * np.minimum(overshoot / WALL_EDGE_TAPER_M, 1.0)))
        spec_x = self.start_xy[0] + along * self.along[0]
        spec_y = self.start_xy[1] + along * self.along[1]
        leg_gain = 10.0 ** (-blocking_loss_db(x_m, y_m, spec_x, spec_y, buildings) / 20.0)
        return self.amplitude * np.where(missing, 0.0, taper) * leg_gain


@dataclass(frozen=True)
class ChannelState:
    """Paths at a set of true times (shape (P, M): P paths, M times).

    Attributes
    ----------
    delay_s : ndarray, shape (P, M)
        Propagation delay of each path, s.
    coef : ndarray of complex, shape (P, M)
        Complex path coefficient: gain times ``exp(-j 2 pi fc delay_s)``.
    los : ndarray of bool, shape (M,)
        True where no building crosses the 2-D line of sight.
    """

    delay_s: np.ndarray
    coef: np.ndarray
    los: np.ndarray


@dataclass(frozen=True)
class DirectPath:
    """The unobstructed direct path (the truth the receiver should measure).

    Attributes
    ----------
    range_m : ndarray
        3-D distance from the receiver antenna to the tower antenna, m.
    range_rate_mps : ndarray
        ``d range_m / dt``, m/s (negative while closing on the tower).
    los : ndarray of bool
        Line of sight (no building on the 2-D line).
    """

    range_m: np.ndarray
    range_rate_mps: np.ndarray
    los: np.ndarray


#: Path kinds, in the order a tower's paths come in :meth:`Channel.state` (``PATH_KINDS[kind]`` names a kind code).
PATH_KINDS = ("direct", "ground", "scatterer", "wall", "diffuse")
DIRECT, GROUND, SCATTERER, WALL, DIFFUSE = range(len(PATH_KINDS))


class _TowerPaths:
    """The paths from one tower of the scenario to the receiver along the track (module docstring)."""

    def __init__(self, site: TowerSite, channel: ChannelConfig, track: Track, rng: np.random.Generator,
                 diffuse_taps: int, transmit_delay_s: float) -> None:
        self.site = site
        #: The tower's true transmit delay offset on this walk, s (:meth:`sim.scenario.Scenario.transmit_delays_s`).
        self.transmit_delay_s = transmit_delay_s
        self.gain = 10.0 ** (site.power_db / 20.0)
        ground = np.hypot(track.x_m - site.x_m, track.y_m - site.y_m)
        h_r = channel.antenna_height_m
        lengths = [np.hypot(ground, site.height_m - h_r)]
        #: (amplitude, blocked-by-LOS?, scatterer xy or None) per specular path
        self.specular: list[tuple[float, bool, tuple[float, float] | None]] = [(1.0, True, None)]
        self.kinds = [DIRECT]
        if channel.ground_reflection:
            lengths.append(np.hypot(ground, site.height_m + h_r))
            self.specular.append((-(10.0 ** (channel.ground_reflection_db / 20.0)), True, None))
            self.kinds.append(GROUND)
        for s in channel.scatterers:
            leg_in = np.hypot(np.hypot(s.x_m - site.x_m, s.y_m - site.y_m), site.height_m - h_r)
            lengths.append(leg_in + np.hypot(track.x_m - s.x_m, track.y_m - s.y_m))
            self.specular.append((10.0 ** (s.gain_db / 20.0), False, (s.x_m, s.y_m)))
            self.kinds.append(SCATTERER)
        self.walls = [WallImage.of(wall, site.x_m, site.y_m) for wall in channel.walls]
        lengths += [w.path_length_m(track.x_m, track.y_m, site.height_m - h_r) for w in self.walls]
        self.kinds += [WALL] * len(self.walls)
        self.lengths = [CubicSpline(track.t_s, length) for length in lengths]
        self.direct_rate = self.lengths[0].derivative()

        self.diffuse_excess_s = np.zeros(0)
        if channel.rician_k_db is not None:
            quantiles = (np.arange(diffuse_taps) + 0.5) / diffuse_taps
            self.diffuse_excess_s = -channel.diffuse_delay_s * np.log1p(-quantiles)
            self.diffuse_amp = np.sqrt(10.0 ** (-channel.rician_k_db / 10.0) / (diffuse_taps * DIFFUSE_SINUSOIDS))
            self.diffuse_freq_hz = channel.diffuse_doppler_hz * np.cos(
                rng.uniform(0.0, 2.0 * np.pi, (diffuse_taps, DIFFUSE_SINUSOIDS)))
            self.diffuse_phase = rng.uniform(0.0, 2.0 * np.pi, (diffuse_taps, DIFFUSE_SINUSOIDS))
        self.kinds += [DIFFUSE] * len(self.diffuse_excess_s)

    def state(self, t_s: np.ndarray, x: np.ndarray, y: np.ndarray,
              buildings: list[Building]) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
        """Delays (s, the transmit delay included), gains and the line-of-sight loss (dB) of this tower's paths."""
        site = self.site
        los_loss = blocking_loss_db(x, y, site.x_m, site.y_m, buildings)
        los_gain = 10.0 ** (-los_loss / 20.0)
        delays, gains = [], []
        for spline, (amp, los_blocked, scatterer) in zip(self.lengths, self.specular):
            delays.append(spline(t_s) / SPEED_OF_LIGHT_MPS + self.transmit_delay_s)
            if los_blocked:
                gains.append(amp * los_gain)
            else:
                loss = blocking_loss_db(x, y, scatterer[0], scatterer[1], buildings)
                gains.append(amp * 10.0 ** (-loss / 20.0))
        for spline, wall in zip(self.lengths[len(self.specular):], self.walls):
            delays.append(spline(t_s) / SPEED_OF_LIGHT_MPS + self.transmit_delay_s)
            gains.append(wall.amplitude_at(x, y, buildings))
        for tap, excess in enumerate(self.diffuse_excess_s):
            delays.append(delays[0] + excess)
            phases = 2.0 * np.pi * self.diffuse_freq_hz[tap][:, None] * t_s + self.diffuse_phase[tap][:, None]
            gains.append(self.diffuse_amp * np.exp(1j * phases).sum(axis=0))
        return delays, [self.gain * g for g in gains], los_loss


class Channel:
    """Multipath channel of a scenario along a track (module docstring).

    Every tower of the scenario (``Scenario.sites``: one, or the towers of a
    single-frequency network) contributes its own paths, computed from its
    position with the same scene (buildings, walls, scatterers), scaled by its
    ``power_db`` and delayed by its true transmit delay offset
    (:meth:`sim.scenario.Scenario.transmit_delays_s`); :meth:`state`
    returns them as one flat list, tower by tower (``path_tower``,
    ``path_kind`` say which is which).

    Parameters
    ----------
    scenario : Scenario
        ``tower`` (carrier), ``sites`` and ``channel`` are used.
    track : Track
        Receiver trajectory; ``t_s`` is true time, s.
    rng : numpy.random.Generator
        Draws the diffuse component (tower by tower).
    diffuse_taps : int
        Number of diffuse delay taps per tower.
    """

    def __init__(self, scenario: Scenario, track: Track, rng: np.random.Generator, diffuse_taps: int = 2) -> None:
        if len(track) < 4 or np.any(np.diff(track.t_s) <= 0):
            raise ValueError("track: need at least 4 samples with strictly increasing t_s")
        if diffuse_taps < 1:
            raise ValueError(f"diffuse_taps must be >= 1, got {diffuse_taps}")
        self.carrier_hz = scenario.tower.carrier_hz
        self._channel = scenario.channel
        self._x = CubicSpline(track.t_s, track.x_m)
        self._y = CubicSpline(track.t_s, track.y_m)
        self._t_range = (float(track.t_s[0]), float(track.t_s[-1]))
        # Each site at its true transmit delay offset of this walk (the plan's plus its error).
        self._towers = [_TowerPaths(site, scenario.channel, track, rng, diffuse_taps, float(delay))
                        for site, delay in zip(scenario.sites, scenario.transmit_delays_s())]
        #: Tower index (0 = the first tower) and kind (:data:`PATH_KINDS`) of each path of :meth:`state`.
        self.path_tower = np.concatenate([np.full(len(t.kinds), i) for i, t in enumerate(self._towers)])
        self.path_kind = np.concatenate([np.asarray(t.kinds) for t in self._towers])

    def max_doppler_hz(self) -> float:
        """Upper bound of any path's Doppler magnitude over the track, Hz.

        A path length changes at most twice as fast as the receiver moves (a
        scatterer behind the walker); the diffuse taps add their own Doppler.
        """
        speed = np.hypot(self._x.derivative()(self._x.x), self._y.derivative()(self._y.x)).max()
        diffuse = self._channel.diffuse_doppler_hz if len(self._towers[0].diffuse_excess_s) else 0.0
        return 2.0 * speed * self.carrier_hz / SPEED_OF_LIGHT_MPS + diffuse

    @property
    def num_paths(self) -> int:
        """Number of paths P (per tower: direct, ground, scatterers, walls, then diffuse taps)."""
        return len(self.path_kind)

    @property
    def num_towers(self) -> int:
        """Number of towers."""
        return len(self._towers)

    def _check(self, t_s: np.ndarray) -> np.ndarray:
        t_s = np.asarray(t_s, dtype=np.float64)
        lo, hi = self._t_range
        # One second of tolerance: the evaluation grid may reach a little past the track
        # (those values are never used for a sample).
        if t_s.size and (t_s.min() < lo - 1.0 or t_s.max() > hi + 1.0):
            raise ValueError(f"channel: times [{t_s.min():.3f}, {t_s.max():.3f}] s outside the track "
                             f"[{lo:.3f}, {hi:.3f}] s")
        return t_s

    def position(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Receiver position (x_m, y_m) at true times ``t_s``."""
        t_s = self._check(t_s)
        return self._x(t_s), self._y(t_s)

    def direct(self, t_s: np.ndarray, tower: int = 0) -> DirectPath:
        """Range, range rate and line of sight of one tower's direct path at true times ``t_s``."""
        t_s = self._check(t_s)
        paths = self._towers[tower]
        x, y = self._x(t_s), self._y(t_s)
        loss = blocking_loss_db(x, y, paths.site.x_m, paths.site.y_m, self._channel.buildings)
        return DirectPath(paths.lengths[0](t_s), paths.direct_rate(t_s), loss == 0.0)

    def state(self, t_s: np.ndarray) -> ChannelState:
        """Every path's delay and complex coefficient at true times ``t_s`` (``los``: of the first tower)."""
        t_s = self._check(t_s)
        x, y = self._x(t_s), self._y(t_s)
        delays, gains, los = [], [], None
        for paths in self._towers:
            tower_delays, tower_gains, los_loss = paths.state(t_s, x, y, self._channel.buildings)
            delays += tower_delays
            gains += tower_gains
            los = los_loss == 0.0 if los is None else los
        delay_s = np.array(delays)
        coef = np.array(gains, dtype=np.complex128) * np.exp(-2j * np.pi * self.carrier_hz * delay_s)
        return ChannelState(delay_s, coef, los)
