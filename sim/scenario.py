"""Scenario description: one small TOML file says everything a simulation needs.

A scenario names the tower (or the towers of a single-frequency network,
``[[towers]]``) and its signal, the walk, the receiver front end and
clock, the propagation scene, the IMU and the GNSS start fix, where the local frame
lies on the Earth (``[origin]``), plus the seed. The
four reference walks of ``docs/scenarios.md`` ship as package data
(``park-loop-cw``, ``park-loop-ccw``, ``street-out``, ``street-back``; the aliases
``park-loop`` and ``street`` name the first run of each).

Every field has a default, so a scenario file only states what differs. The
parsed :class:`Scenario` round-trips to TOML text (:func:`scenario_to_toml`),
which is stored verbatim in every truth file.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from dtmbnav_core.constants import TRANSMIT_DELAY_KNOWLEDGE
from dtmbnav_core.geodetic import GeodeticPoint

#: Short names that resolve to a packaged scenario.
ALIASES = {"park-loop": "park-loop-cw", "street": "street-out"}
#: The site keys of ``[tower]`` that ``[[towers]]`` takes over when a scenario lists several towers.
SITE_KEYS = ("x_m", "y_m", "height_m")


@dataclass(frozen=True)
class TowerConfig:
    """The DTMB transmitter.

    Attributes
    ----------
    x_m, y_m : float
        Tower position in the local ENU frame, m.
    height_m : float
        Antenna height above the walker's plane, m.
    carrier_hz : float
        RF centre frequency, Hz.
    pn_mode : str
        Header mode, ``"PN420"``, ``"PN595"`` or ``"PN945"``.
    rotating_phase : bool
        Variable (frame-to-frame rotating) header phase; ignored for PN595.
    si_index : int
        SI word sent in every frame (1..24).
    si_polarity : int
        +1: SI chip 0 -> +(1+j); -1 the opposite convention.
    si_power_db : float
        SI symbol power relative to data, dB.
    """

    x_m: float = 2000.0
    y_m: float = 2200.0
    height_m: float = 150.0
    carrier_hz: float = 666e6
    pn_mode: str = "PN420"
    rotating_phase: bool = True
    si_index: int = 15
    si_polarity: int = 1
    si_power_db: float = 0.0


@dataclass(frozen=True)
class TowerSite:
    """One transmitter of a single-frequency network (SFN): where it is and how it is heard.

    Every tower of an SFN sends the same signal (``[tower]``: carrier, header
    mode, SI word) on the same GNSS-synchronised time base (docs/paths.md).

    Attributes
    ----------
    x_m, y_m : float
        Tower position in the local ENU frame, m.
    height_m : float
        Antenna height above the walker's plane, m.
    power_db : float
        Power of its unobstructed direct path relative to that of the first
        tower (whose power sets ``receiver.cn_db``), dB.
    transmit_delay_s : float
        Transmit-delay offset of this tower in the network plan, s, >= 0; the
        tower's true offset differs from it by ``[network] plan_error_s``
        (:meth:`Scenario.transmit_delays_s`).
    """

    x_m: float = 2000.0
    y_m: float = 2200.0
    height_m: float = 150.0
    power_db: float = 0.0
    transmit_delay_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.transmit_delay_s >= 0.0:
            raise ValueError(f"towers: transmit_delay_s must be >= 0, got {self.transmit_delay_s!r}")


@dataclass(frozen=True)
class Pause:
    """The walker stands still at a waypoint.

    Attributes
    ----------
    at_waypoint : int
        Index of the waypoint where the pause happens.
    duration_s : float
        Time spent standing, s.
    """

    at_waypoint: int
    duration_s: float


@dataclass(frozen=True)
class PaceChange:
    """From ``after_m`` metres of walked distance on, walk at another pace.

    Attributes
    ----------
    after_m : float
        Walked distance at which the pace changes, m.
    speed_mps : float
        New mean speed, m/s.
    step_frequency_hz : float
        New cadence, steps/s.
    """

    after_m: float
    speed_mps: float
    step_frequency_hz: float


@dataclass(frozen=True)
class WalkConfig:
    """The walker's path and gait.

    Attributes
    ----------
    waypoints_m : list of [x, y]
        Polyline of the path, ENU metres; the first point is the start P0.
    closed : bool
        Return to the first waypoint at the end (a loop).
    start_still_s : float
        Standing still before the walk, s (oscillator calibration window).
    end_still_s : float
        Standing still after the walk, s.
    speed_mps : float
        Mean walking speed, m/s.
    step_frequency_hz : float
        Mean cadence, steps/s.
    step_length_jitter : float
        Relative standard deviation of individual step lengths.
    corner_radius_m : float
        Radius with which corners are rounded, m.
    pauses : list of Pause
    pace_changes : list of PaceChange
    """

    waypoints_m: list[list[float]] = field(default_factory=lambda: [[0.0, 0.0], [0.0, 50.0]])
    closed: bool = False
    start_still_s: float = 10.0
    end_still_s: float = 2.0
    speed_mps: float = 1.3
    step_frequency_hz: float = 1.85
    step_length_jitter: float = 0.04
    corner_radius_m: float = 1.5
    pauses: list[Pause] = field(default_factory=list)
    pace_changes: list[PaceChange] = field(default_factory=list)


@dataclass(frozen=True)
class ClockConfig:
    """Receiver reference oscillator (drives both the LO and the ADC clock).

    Attributes
    ----------
    preset : str
        ``"gnss-disciplined"``, ``"free-running"`` (TCXO) or ``"custom"``.
    offset_ppb : float or None
        Constant fractional frequency offset, parts per 1e9; None draws one
        from the preset's range using the seed.
    drift_adev : float or None
        Allan deviation of the random-walk frequency wander at 1 s; None uses
        the preset's value.
    """

    preset: str = "gnss-disciplined"
    offset_ppb: float | None = None
    drift_adev: float | None = None


@dataclass(frozen=True)
class FrontEndConfig:
    """The SDR front end that records the capture.

    Attributes
    ----------
    sample_rate_hz : float
        Recording rate, samples/s.
    sample_format : str
        ``"cf32"``, ``"ci16"``, ``"ci8"`` or ``"cu8"``.
    cn_db : float
        Carrier-to-noise ratio in the 7.56 MHz band with the direct path
        unobstructed, dB.
    bulk_cfo_hz : float
        Extra frequency error of the tuner, Hz (a cheap SDR's kHz-level offset;
        it is not part of the method's f_s and is removed by acquisition).
    iq_conjugate : bool
        The front end swaps I and Q (spectrum inverted).
    agc_backoff_db : float
        Headroom of the quantiser's full scale above the signal RMS, dB.
    start_offset_s : float
        Transmitter time at the first sample, s (where in a superframe the
        recording starts).
    clock : ClockConfig
    tuning_offset_hz : float
        Capture centre minus the DTMB channel's centre, Hz: a zero-IF SDR
        tuned beside the channel to keep its DC spike out of it; the channel
        then lies at ``-tuning_offset_hz`` from DC in the capture
        (:mod:`sim.frontend`). 0 tunes on the channel.
    lo_leakage_dbc : float or None
        Power of the LO leakage tone (at the capture's DC) relative to the
        signal power of the capture (direct path, after the anti-alias
        filter), dBc; None: no leakage.
    lo_leakage_phase_deg : float
        Phase of the leakage tone, degrees.
    iq_gain_db : float
        Gain of the Q rail relative to the I rail, dB (IQ amplitude imbalance).
    iq_phase_deg : float
        Quadrature error of the Q rail, degrees: the front end records
        ``I + j g (Q cos(phi) - I sin(phi))`` for the ideal ``I + j Q``,
        ``g = 10 ** (iq_gain_db / 20)`` (:mod:`sim.frontend`).
    adc_bits : int or None
        ADC resolution, bits: the rails are quantised to ``2 ** adc_bits``
        levels across the format's full scale; None: the format's own width.
    adc_dc_lsb : list of float
        DC of the I and Q rails after the ADC, in ADC LSB (an RTL2832U centres
        its bytes about 0.5 LSB below 128: ``[-0.5, -0.5]``).
    agc_step_db : float
        Size of the AGC's gain steps, dB (0: a fixed gain).
    agc_steps_per_minute : float
        Mean rate of the AGC's gain steps (Poisson times, up or down, drawn
        from the seed).
    drops_per_minute : float
        Mean rate of dropped-sample runs (USB overflows; Poisson times drawn
        from the seed); the samples are missing from the capture, the truth
        keeps the receiver's clock.
    drop_samples : list of int
        Smallest and largest run of dropped samples (log-uniform between).
    phase_noise_dbc_hz : list of list of float or None
        The LO's single-sideband phase noise profile, ``[[offset_hz, dBc/Hz],
        ...]`` (log-log interpolated between the points); None: none.
    """

    sample_rate_hz: float = 7.56e6
    sample_format: str = "ci8"
    cn_db: float = 15.0
    bulk_cfo_hz: float = 0.0
    iq_conjugate: bool = False
    agc_backoff_db: float = 12.0
    start_offset_s: float = 0.0371
    clock: ClockConfig = field(default_factory=ClockConfig)
    tuning_offset_hz: float = 0.0
    lo_leakage_dbc: float | None = None
    lo_leakage_phase_deg: float = 0.0
    iq_gain_db: float = 0.0
    iq_phase_deg: float = 0.0
    adc_bits: int | None = None
    adc_dc_lsb: list[float] = field(default_factory=lambda: [0.0, 0.0])
    agc_step_db: float = 0.0
    agc_steps_per_minute: float = 0.0
    drops_per_minute: float = 0.0
    drop_samples: list[int] = field(default_factory=lambda: [1, 100000])
    phase_noise_dbc_hz: list[list[float]] | None = None


#: Keys written to TOML only when they differ from their default (so scenarios without them serialise as
#: they did before the key existed).
_OMIT_DEFAULT = {("receiver", "tuning_offset_hz"): 0.0, ("receiver", "lo_leakage_phase_deg"): 0.0,
                 ("receiver", "iq_gain_db"): 0.0, ("receiver", "iq_phase_deg"): 0.0,
                 ("receiver", "adc_dc_lsb"): [0.0, 0.0], ("receiver", "agc_step_db"): 0.0,
                 ("receiver", "agc_steps_per_minute"): 0.0, ("receiver", "drops_per_minute"): 0.0,
                 ("receiver", "drop_samples"): [1, 100000], ("imu", "carriage"): "hand",
                 ("imu", "carriage_changes"): [],
                 ("imu", "magnetometer"): True, ("imu", "time_jitter"): 0.0, ("imu", "gaps_per_minute"): 0.0,
                 ("imu", "gap_s"): 0.5}


@dataclass(frozen=True)
class Scatterer:
    """A point scatterer (e.g. a building corner or face) in the scene.

    Attributes
    ----------
    x_m, y_m : float
        Position, m.
    gain_db : float
        Path power relative to the unobstructed direct path, dB.
    """

    x_m: float
    y_m: float
    gain_db: float


@dataclass(frozen=True)
class Building:
    """A building footprint that blocks the line of sight.

    Attributes
    ----------
    polygon_m : list of [x, y]
        Footprint vertices, m.
    attenuation_db : float
        Direct-path loss when the line of sight crosses the footprint, dB.
    """

    polygon_m: list[list[float]]
    attenuation_db: float = 20.0


@dataclass(frozen=True)
class Wall:
    """A vertical building face that reflects the tower's signal specularly.

    Attributes
    ----------
    start_m, end_m : [x, y]
        End points of the face's 2-D footprint segment, m.
    gain_db : float
        Reflected power relative to the unobstructed direct path, dB.
    """

    start_m: list[float]
    end_m: list[float]
    gain_db: float


@dataclass(frozen=True)
class ChannelConfig:
    """Propagation scene.

    Attributes
    ----------
    ground_reflection : bool
        Add the flat-earth ground-reflected ray.
    ground_reflection_db : float
        Its power relative to the direct path, dB.
    antenna_height_m : float
        Receiver antenna height above ground, m.
    rician_k_db : float or None
        K factor of a diffuse (Rayleigh) component added to the specular
        paths; None for no diffuse component.
    diffuse_doppler_hz : float
        Maximum Doppler of the diffuse component, Hz.
    diffuse_delay_s : float
        Mean excess delay of the diffuse component, s.
    scatterers : list of Scatterer
    walls : list of Wall
    buildings : list of Building
    """

    ground_reflection: bool = True
    ground_reflection_db: float = -10.0
    antenna_height_m: float = 1.2
    rician_k_db: float | None = 10.0
    diffuse_doppler_hz: float = 3.0
    diffuse_delay_s: float = 0.3e-6
    scatterers: list[Scatterer] = field(default_factory=list)
    walls: list[Wall] = field(default_factory=list)
    buildings: list[Building] = field(default_factory=list)


@dataclass(frozen=True)
class CarriageChange:
    """The walker handles the phone into another carriage (take it out, put it to the ear, pocket it).

    Attributes
    ----------
    t_s : float
        When the handling starts, s from the scenario's start.
    carriage : str
        The carriage after it (:data:`sim.carriage.CARRIAGES`).
    duration_s : float
        How long the handling lasts (the phone turns and moves between the carriages), s.
    """

    t_s: float
    carriage: str
    duration_s: float = 1.5


@dataclass(frozen=True)
class ImuConfig:
    """Handheld or foot-mounted IMU.

    Attributes
    ----------
    preset : str
        ``"phone"`` or ``"foot-mems"``.
    rate_hz : float
        Sample rate, Hz.
    gyro_bias_dps : float or None
        Initial z-gyro bias, deg/s; None draws one from the preset's range.
    step_gain_error : float
        Relative error of the walker's step-length gain seen by PDR
        (e.g. 0.15 makes PDR steps 15 % too long).
    heading_drift_start_s : float or None
        Time from which an extra gyro bias ``heading_drift_dps`` acts
        (late heading drift); None for none.
    heading_drift_dps : float
        Extra z-gyro bias after ``heading_drift_start_s``, deg/s.
    mag_disturbance_ut : float
        Peak magnetic disturbance near buildings, uT.
    carriage : str
        How the phone is carried (:data:`sim.carriage.CARRIAGES`): ``"hand"`` (held in
        front), ``"texting"`` (held in front to read, the bounce damped by the arm),
        ``"pocket"`` or ``"pocket-gait"`` (front trouser pocket, the thigh a pendulum or
        its measured profile), ``"swinging"`` or ``"swinging-wide"`` (in a hand swinging
        at the side, +-20 or +-45 deg), ``"ear"`` (at the ear, in a call) or ``"bag"``
        (in a shoulder bag). The phone preset only; the carriage at the start.
    swing_deg : float or None
        Amplitude of a swinging arm, deg, for the swinging carriages of the walk; None:
        the carriage's own.
    carriage_changes : list of CarriageChange
        Handling into other carriages during the walk, in time order, not overlapping.
    magnetometer : bool
        False: the device has none, and ``mag_ut`` holds zeros (the convention of an
        imported log without one, :func:`dtmbnav_core.sensors.read_has_magnetometer`).
    time_jitter : float
        Standard deviation of the sample interval over the nominal one (a phone's
        uneven sample times; 0 is a uniform grid), at most 0.2.
    gaps_per_minute : float
        Mean number of dropped runs of samples per minute (Poisson).
    gap_s : float
        Length of each dropped run, s.
    """

    preset: str = "phone"
    rate_hz: float = 100.0
    gyro_bias_dps: float | None = None
    step_gain_error: float = 0.0
    heading_drift_start_s: float | None = None
    heading_drift_dps: float = 0.0
    mag_disturbance_ut: float = 5.0
    carriage: str = "hand"
    swing_deg: float | None = None
    carriage_changes: list[CarriageChange] = field(default_factory=list)
    magnetometer: bool = True
    time_jitter: float = 0.0
    gaps_per_minute: float = 0.0
    gap_s: float = 0.5


@dataclass(frozen=True)
class GnssConfig:
    """GNSS fixes available to the walker.

    Attributes
    ----------
    start_fix_sigma_m : float
        Horizontal error (1 sigma per axis) of the start fix P0, m.
    rate_hz : float
        Fix rate for the per-epoch GNSS log, Hz.
    open_sky_cn0_dbhz : float
        Mean C/N0 under open sky, dB-Hz.
    blocked_cn0_drop_db : float
        C/N0 loss where buildings block the sky, dB.
    """

    start_fix_sigma_m: float = 1.5
    rate_hz: float = 1.0
    open_sky_cn0_dbhz: float = 44.0
    blocked_cn0_drop_db: float = 12.0


@dataclass(frozen=True)
class OriginConfig:
    """Where the scenario's local ENU frame lies on the Earth: the WGS84 point of x = y = 0 on the walker's plane.

    The simulator writes the phone's fixes and the towers as latitude, longitude and height about it
    (``simulate --phone-log``, ``towers.csv``). The default lies in Wuhan, where the magnetometer's Earth
    field (:data:`sim.imu.EARTH_FIELD_UT`) is taken.

    Attributes
    ----------
    lat_deg, lon_deg : float
        WGS84 latitude (-90..90) and longitude (-180..180), deg.
    height_m : float
        Height of the walker's plane (the ground) above the WGS84 ellipsoid, m.
    """

    lat_deg: float = 30.52
    lon_deg: float = 114.36
    height_m: float = 20.0

    def __post_init__(self) -> None:
        try:
            self.point
        except ValueError as exc:
            raise ValueError(f"[origin]: {exc}") from None

    @property
    def point(self) -> GeodeticPoint:
        """The origin as a :class:`~dtmbnav_core.geodetic.GeodeticPoint`."""
        return GeodeticPoint(self.lat_deg, self.lon_deg, self.height_m)


#: Random stream of the towers' true transmit delay offsets (:meth:`Scenario.transmit_delays_s`).
STREAM_TRANSMIT_DELAY = 0x7D1


@dataclass(frozen=True)
class NetworkConfig:
    """A single-frequency network's transmit delay offsets: how far the plan is off, and what the user knows.

    Attributes
    ----------
    plan_error_s : float
        Standard deviation of each tower's true transmit delay offset about
        the plan's (``[[towers]] transmit_delay_s``), s, >= 0: drawn from
        the network's seed (:meth:`Scenario.transmit_delays_s`).
    known : {"unknown", "plan", "surveyed", "exact"}
        What the fusion is given: nothing (it estimates the offsets at the
        start fix), the plan with ``plan_error_s`` as its sigma, a survey on
        another walk of the same network (``evaluate``'s survey walk, of
        this network's seed), or the walk's true offsets (``dtmbnav fuse``
        and ``evaluate`` follow it).
    seed : int or None
        The network's identity, >= 0: walks with one network seed are walks
        of one network and share its true offsets; None: the walk's own seed
        (each walk another network, as before network seeds).
    """

    plan_error_s: float = 0.0
    known: str = "unknown"
    seed: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.plan_error_s) and self.plan_error_s >= 0.0):
            raise ValueError(f"network.plan_error_s must be finite and >= 0, got {self.plan_error_s!r}")
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)
                                      or self.seed < 0):
            raise ValueError(f"network.seed must be an integer >= 0, got {self.seed!r}")
        if self.known not in TRANSMIT_DELAY_KNOWLEDGE:
            raise ValueError(f"network.known must be one of {TRANSMIT_DELAY_KNOWLEDGE}, got {self.known!r}")


@dataclass(frozen=True)
class Scenario:
    """A complete simulation scenario (see the module docstring).

    ``towers`` lists the sites of a single-frequency network; empty for the
    single tower of ``tower``. When it is given, ``tower``'s site
    (:data:`SITE_KEYS`) is kept equal to the first entry's, so code that
    knows one tower sees the first one.
    """

    name: str = "custom"
    description: str = ""
    seed: int = 1
    tower: TowerConfig = field(default_factory=TowerConfig)
    walk: WalkConfig = field(default_factory=WalkConfig)
    receiver: FrontEndConfig = field(default_factory=FrontEndConfig)
    channel: ChannelConfig = field(default_factory=ChannelConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    towers: list[TowerSite] = field(default_factory=list)
    origin: OriginConfig = field(default_factory=OriginConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)

    def __post_init__(self) -> None:
        towers = [t if isinstance(t, TowerSite) else _build(TowerSite, t, "towers") for t in self.towers]
        object.__setattr__(self, "towers", towers)
        if towers:
            first = towers[0]
            object.__setattr__(self, "tower", dataclasses.replace(
                self.tower, **{key: getattr(first, key) for key in SITE_KEYS}))

    @property
    def sites(self) -> list[TowerSite]:
        """Every transmitter of the scenario, the first one first (one site without ``[[towers]]``)."""
        if self.towers:
            return list(self.towers)
        return [TowerSite(**{key: getattr(self.tower, key) for key in SITE_KEYS})]

    @property
    def network_seed(self) -> int:
        """The network's identity (``[network] seed``; the walk's ``seed`` without one): what its offsets are drawn
        from."""
        return self.seed if self.network.seed is None else self.network.seed

    def transmit_delays_s(self) -> np.ndarray:
        """Each site's true transmit delay offset on this walk, s: the plan's plus N(0, ``network.plan_error_s``),
        drawn from the network's seed (:attr:`network_seed`; the plan's exactly where the error is 0)."""
        plan = np.array([site.transmit_delay_s for site in self.sites], dtype=np.float64)
        if self.network.plan_error_s == 0.0:
            return plan
        rng = np.random.default_rng([self.network_seed, STREAM_TRANSMIT_DELAY])
        return plan + self.network.plan_error_s * rng.standard_normal(len(plan))

    def replace(self, **sections: dict[str, Any]) -> "Scenario":
        """Return a copy with fields of named sections changed.

        ``scn.replace(receiver={"cn_db": 10}, seed=3)`` changes one receiver
        field and the seed; top-level scalars and ``towers`` (a list of
        :class:`TowerSite` or tables) are passed as plain values. A tower
        site is moved through ``towers`` when the scenario has several.
        """
        tower_keys = set(sections.get("tower", {})) & set(SITE_KEYS)
        if tower_keys and (self.towers or sections.get("towers")):
            raise ValueError(f"scenario: {sorted(tower_keys)} of [tower] with [[towers]] given; change towers instead")
        updates: dict[str, Any] = {}
        for key, value in sections.items():
            current = getattr(self, key)
            if dataclasses.is_dataclass(current) and isinstance(value, dict):
                updates[key] = _build(type(current), {**_to_dict(current), **value}, key)
            else:
                updates[key] = value
        return dataclasses.replace(self, **updates)


def _describe(hint: Any) -> str:
    """A type annotation in words, for error messages."""
    names = {float: "a number", int: "a whole number", bool: "true or false", str: "a string"}
    if hint in names:
        return names[hint]
    if typing.get_origin(hint) is list:
        return f"a list of {_describe(typing.get_args(hint)[0]).removeprefix('a ').removeprefix('an ')}s"
    if dataclasses.is_dataclass(hint):
        return "a table"
    return str(hint)


def _check_type(value: Any, hint: Any, where: str) -> None:
    """Raise ValueError naming ``where`` when a TOML value does not fit a field's annotation."""
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        options = [o for o in typing.get_args(hint) if o is not type(None)]
        problems = []
        for option in options:
            try:
                _check_type(value, option, where)
                return
            except ValueError as exc:
                problems.append(str(exc))
        raise ValueError(problems[0])
    if origin is list:
        if not isinstance(value, list):
            raise ValueError(f"{where}: expected {_describe(hint)}, got {value!r}")
        for i, item in enumerate(value):
            _check_type(item, typing.get_args(hint)[0], f"{where}[{i}]")
        return
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, (dict, hint)):
            raise ValueError(f"{where}: expected a table, got {value!r}")
        return
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    ok = {bool: isinstance(value, bool), int: number and isinstance(value, int), float: number,
          str: isinstance(value, str)}.get(hint, True)
    if not ok:
        raise ValueError(f"{where}: expected {_describe(hint)}, got {value!r}")
    if hint is float and not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r}")


def _build(cls: type, data: dict[str, Any], where: str, check: bool = False) -> Any:
    """Instantiate dataclass ``cls`` from a TOML table, checking the keys (and, with ``check``, the value types)."""
    if not isinstance(data, dict):
        raise ValueError(f"scenario [{where}]: expected a table, got {data!r}")
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(data) - set(known)
    if unknown:
        raise ValueError(f"scenario [{where}]: unknown key(s) {sorted(unknown)}; known: {sorted(known)}")
    hints = typing.get_type_hints(cls) if check else {}
    kwargs: dict[str, Any] = {}
    nested = {
        "clock": ClockConfig, "pauses": Pause, "pace_changes": PaceChange,
        "scatterers": Scatterer, "walls": Wall, "buildings": Building, "carriage_changes": CarriageChange,
    }
    for key, value in data.items():
        if check:
            _check_type(value, hints[key], f"scenario [{where}] {key}")
        sub = nested.get(key)
        if sub is not None and isinstance(value, list):
            kwargs[key] = [v if isinstance(v, sub) else _build(sub, v, f"{where}.{key}", check) for v in value]
        elif sub is not None and isinstance(value, dict):
            kwargs[key] = _build(sub, value, f"{where}.{key}", check)
        else:
            kwargs[key] = value
    for name, f in known.items():
        if name not in kwargs and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"scenario [{where}]: missing key {name!r}")
    return cls(**kwargs)


def _to_dict(obj: Any) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


_SECTIONS = {
    "tower": TowerConfig, "walk": WalkConfig, "receiver": FrontEndConfig,
    "channel": ChannelConfig, "imu": ImuConfig, "gnss": GnssConfig, "origin": OriginConfig,
    "network": NetworkConfig,
}


def scenario_from_dict(data: dict[str, Any]) -> Scenario:
    """Build a :class:`Scenario` from a parsed TOML document (ValueError naming a bad key or value).

    ``[[towers]]`` (an array of tables) lists the sites of an SFN; the site
    keys of ``[tower]`` (:data:`SITE_KEYS`) are then an error, so that no
    file states a position twice.
    """
    top = {k: v for k, v in data.items() if k not in _SECTIONS and k != "towers"}
    unknown = set(top) - {"name", "description", "seed"}
    if unknown:
        raise ValueError(f"scenario: unknown top-level key(s) {sorted(unknown)}")
    for key in ("name", "description"):
        _check_type(top.get(key, ""), str, f"scenario: {key}")
    _check_type(top.get("seed", 0), int, "scenario: seed")
    if top.get("seed", 0) < 0:
        raise ValueError(f"scenario: seed must not be negative, got {top['seed']}")
    towers = data.get("towers", [])
    if not isinstance(towers, list) or not all(isinstance(t, dict) for t in towers):
        raise ValueError("scenario: towers must be an array of tables ([[towers]])")
    doubled = sorted(set(SITE_KEYS) & set(data.get("tower", {}))) if towers else []
    if doubled:
        raise ValueError(f"scenario [tower]: {doubled} given together with [[towers]]; "
                         "give the sites in [[towers]] only")
    sections = {k: _build(cls, data.get(k, {}), k, check=True) for k, cls in _SECTIONS.items()}
    return Scenario(**top, **sections,
                    towers=[_build(TowerSite, t, f"towers.{i}", check=True) for i, t in enumerate(towers)])


def packaged_scenarios() -> list[str]:
    """Names of the scenarios shipped with the package."""
    files = resources.files("sim") / "scenarios"
    return sorted(p.name.removesuffix(".toml") for p in files.iterdir() if p.name.endswith(".toml"))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a packaged scenario by name (or alias) or a scenario TOML file.

    Parameters
    ----------
    name_or_path : str or Path
        ``"park-loop"``, ``"street-back"``, ... or a path to a ``.toml`` file.

    Raises
    ------
    ValueError
        Unknown name, or a file that is not a valid scenario (the message names it).
    """
    text_path = Path(name_or_path)
    if text_path.suffix == ".toml" or text_path.exists():
        if not text_path.is_file():
            raise ValueError(f"scenario file {text_path} " + ("is not a file" if text_path.exists() else
                                                               "does not exist"))
        try:
            source = text_path.read_text()
        except UnicodeDecodeError as exc:
            raise ValueError(f"scenario file {text_path}: not a text file ({exc.reason})") from None
        where = str(text_path)
    else:
        name = ALIASES.get(str(name_or_path), str(name_or_path))
        res = resources.files("sim") / "scenarios" / f"{name}.toml"
        if not res.is_file():
            raise ValueError(
                f"unknown scenario {name_or_path!r}; packaged: {', '.join(packaged_scenarios())} "
                f"(aliases: {', '.join(ALIASES)}), or give a .toml path"
            )
        source = res.read_text()
        where = name
    try:
        return scenario_from_dict(tomllib.loads(source))
    except (tomllib.TOMLDecodeError, TypeError, ValueError) as exc:
        raise ValueError(f"scenario {where}: {exc}") from None


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if dataclasses.is_dataclass(value):
        items = {k: v for k, v in _to_dict(value).items() if v is not None}
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in items.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def scenario_to_toml(scn: Scenario) -> str:
    """Serialise a scenario to TOML text that :func:`scenario_from_dict` reads back."""
    lines = [f"name = {_toml_value(scn.name)}", f"description = {_toml_value(scn.description)}",
             f"seed = {scn.seed}"]
    for section in _SECTIONS:
        lines.append(f"\n[{section}]")
        for key, value in _to_dict(getattr(scn, section)).items():
            if (section, key) in _OMIT_DEFAULT and value == _OMIT_DEFAULT[(section, key)]:
                continue
            if value is not None and not (section == "tower" and scn.towers and key in SITE_KEYS):
                lines.append(f"{key} = {_toml_value(value)}")
    for site in scn.towers:
        lines.append("\n[[towers]]")
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in _to_dict(site).items())
    return "\n".join(lines) + "\n"
