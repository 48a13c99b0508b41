"""Typed records that the stages exchange (receiver, simulator, fusion, CLI).

Each record is a dataclass of equal-length 1-D numpy arrays (one per column,
N x 3 for vector sensors; names carry units, ``docs/conventions.md``). The
HDF5 layer writes them column by column, so a record's fields are its file
schema (``docs/schema.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from enum import IntFlag
from typing import Self

import numpy as np


class ColumnRecord:
    """Mixin for dataclasses whose fields are equal-length numpy columns."""

    def __post_init__(self) -> None:
        lengths = {f.name: len(getattr(self, f.name)) for f in fields(self)}  # type: ignore[arg-type]
        if len(set(lengths.values())) > 1:
            raise ValueError(f"{type(self).__name__}: columns differ in length: {lengths}")

    def __len__(self) -> int:
        first = fields(self)[0].name  # type: ignore[arg-type]
        return len(getattr(self, first))

    def columns(self) -> dict[str, np.ndarray]:
        """The columns by name, in field order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]

    def select(self, rows: slice | np.ndarray) -> Self:
        """The rows picked by a slice, index array or boolean mask, as a new record."""
        return type(self)(**{k: v[rows] for k, v in self.columns().items()})

    @classmethod
    def concatenate(cls, records: list[Self]) -> Self:
        """The rows of ``records`` (at least one) in order, as one record."""
        return cls(**{name: np.concatenate([getattr(r, name) for r in records]) for name in records[0].columns()})


@dataclass
class Track(ColumnRecord):
    """A 2-D trajectory (truth, PDR or a filter's estimate).

    Attributes
    ----------
    t_s : ndarray
        Time since the start of the capture, s.
    x_m, y_m : ndarray
        East and north position, m.
    heading_rad : ndarray
        Heading, clockwise from north, rad.
    speed_mps : ndarray
        Ground speed, m/s.
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    speed_mps: np.ndarray


#: The 0.95 quantile of the chi-square distribution with 2 degrees of freedom, ``-2 ln(0.05)``: a 2-D
#: Gaussian error lies inside its ellipse ``d^T C^-1 d <= ELLIPSE_95_CHI2`` with probability 0.95.
ELLIPSE_95_CHI2 = float(-2.0 * np.log(0.05))


@dataclass
class FusedTrack(Track):
    """A fusion filter's track with the error it states: its east/north position covariance per row.

    The covariance is the filter's own (a Kalman-type filter's ``P`` block, the particles' weighted
    spread), or a smoother's (``/fusion/<filter>/smoothed``, ``docs/schema.md``). NaN where the track
    states no error (a file written before the columns existed, :func:`with_unstated_error`).

    Attributes
    ----------
    t_s, x_m, y_m, heading_rad, speed_mps : ndarray
        As :class:`Track`.
    var_x_m2, var_y_m2 : ndarray
        Variance of the east and the north position, m^2.
    cov_xy_m2 : ndarray
        Their covariance, m^2.
    """

    var_x_m2: np.ndarray
    var_y_m2: np.ndarray
    cov_xy_m2: np.ndarray

    @classmethod
    def from_track(cls, track: Track, covariance_m2: np.ndarray) -> FusedTrack:
        """``track`` with ``covariance_m2`` (N x 2 x 2, east/north, m^2) as its stated error."""
        covariance_m2 = np.asarray(covariance_m2, dtype=np.float64)
        return cls(**_track_columns(track), var_x_m2=covariance_m2[:, 0, 0], var_y_m2=covariance_m2[:, 1, 1],
                   cov_xy_m2=0.5 * (covariance_m2[:, 0, 1] + covariance_m2[:, 1, 0]))

    def position_covariance_m2(self) -> np.ndarray:
        """The stated east/north covariance per row, N x 2 x 2, m^2."""
        return np.stack([np.stack([self.var_x_m2, self.cov_xy_m2], axis=-1),
                         np.stack([self.cov_xy_m2, self.var_y_m2], axis=-1)], axis=-2)

    def has_stated_error(self) -> bool:
        """Whether every row states its error (finite covariance)."""
        return bool(np.all(np.isfinite(self.position_covariance_m2())))

    def accuracy_radius_m(self) -> np.ndarray:
        """Radius of the circle that bounds each row's 95 % error ellipse, m: ``sqrt(ELLIPSE_95_CHI2)``
        (2.448) times the square root of the covariance's largest eigenvalue (its semi-major axis). NaN where no
        error is stated."""
        half_trace = 0.5 * (self.var_x_m2 + self.var_y_m2)
        spread = np.sqrt((0.5 * (self.var_x_m2 - self.var_y_m2)) ** 2 + self.cov_xy_m2**2)
        return np.sqrt(ELLIPSE_95_CHI2 * np.maximum(half_trace + spread, 0.0))


def _track_columns(track: Track) -> dict[str, np.ndarray]:
    """The :class:`Track` columns of ``track`` (of a :class:`FusedTrack` too, without its covariance)."""
    return {f.name: getattr(track, f.name) for f in fields(Track)}


def with_unstated_error(track: Track) -> FusedTrack:
    """``track`` as a :class:`FusedTrack` that states no error (NaN covariance): what a fused track written
    before the covariance columns existed reads as."""
    nan = np.full(len(track), np.nan)
    return FusedTrack(**_track_columns(track), var_x_m2=nan, var_y_m2=nan.copy(), cov_xy_m2=nan.copy())


@dataclass
class PdrSteps(ColumnRecord):
    """Pedestrian dead reckoning, one row per detected step.

    Position is in the PDR's own frame: it starts at (0, 0) and its heading is
    relative (the initial heading is unknown until fusion solves it).

    Attributes
    ----------
    t_s : ndarray
        Time of the step (its acceleration peak), s.
    x_m, y_m : ndarray
        Position after the step, m, PDR frame.
    heading_rad : ndarray
        Relative heading during the step, rad (clockwise).
    speed_mps : ndarray
        Step length / step duration, m/s.
    step_length_m : ndarray
        Step length, m.
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    speed_mps: np.ndarray
    step_length_m: np.ndarray


@dataclass
class RangeSeries(ColumnRecord):
    """Integrated DTMB range (range change since a reference) with quality.

    Attributes
    ----------
    t_s : ndarray
        Time, s.
    range_change_m : ndarray
        Range to the tower minus the range at the reference time, m (eq. 11).
    snr_db : ndarray
        Receiver SNR estimate, dB.
    valid : ndarray of bool
        False where the receiver flagged a gap, loss of lock or bad quality.
    segment_id : ndarray of int32, optional
        Lock segment of each row (``/receiver/frames`` column ``segment_id``):
        the range is continuous inside a segment only, so a change of segment
        is a new range origin for the fusion. Zeros (one segment) when omitted.
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    snr_db: np.ndarray
    valid: np.ndarray
    segment_id: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.segment_id is None:
            self.segment_id = np.zeros(len(self.t_s), dtype=np.int32)
        super().__post_init__()


@dataclass
class PathRangeSeries(ColumnRecord):
    """Integrated carrier-phase range of one resolved path, or of a difference of two towers' paths.

    The first-path (direct-path candidate) range change to one tower, or the
    change of the difference of two towers' first-path ranges, which cancels
    the receiver clock (docs/paths.md, "Single-frequency networks"). Which
    tower or pair a series belongs to is said by whoever hands it on
    (:class:`PathRanges`).

    Attributes
    ----------
    t_s : ndarray
        Time, s.
    range_change_m : ndarray
        Range (or range difference) minus its value at the reference time, m.
    snr_db : ndarray
        SNR of the path, dB (of the weaker path for a difference).
    valid : ndarray of bool
        False where the path was not tracked or its phase is unusable.
    slip : ndarray of bool
        True at a frame where the receiver detected a cycle slip (a jump of
        whole wavelengths) or restarted the path's phase: the range continues
        from an unknown new origin.
    path_age_s : ndarray
        How long the path has been tracked without a break, s (of the younger
        path for a difference).
    code_range_m : ndarray or None
        Code (delay) range of the path, m, with the receiver clock's f_s
        drift taken out as from the carrier range, up to an unknown constant
        that does not change at origin breaks: for the direct path the range
        plus that constant; a reflection taken for the first path arrives
        late by its excess path length (docs/paths.md, "The first path's
        code range"). For a difference of two towers whose transmit delay
        offsets are known, the difference of their first paths' code ranges
        with those offsets taken out: the range difference itself, with no
        constant (``receiver.observables.range_difference_code_m``). NaN where
        unknown (a difference of towers whose offsets are not known; a file
        without it); None gives NaN throughout.
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    snr_db: np.ndarray
    valid: np.ndarray
    slip: np.ndarray
    path_age_s: np.ndarray
    code_range_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.code_range_m is None:
            self.code_range_m = np.full(len(self.t_s), np.nan)
        super().__post_init__()

    @classmethod
    def from_runs(cls, t_s: np.ndarray, range_change_m: np.ndarray, path_key: np.ndarray, tracked: np.ndarray,
                  usable: np.ndarray, snr_db: np.ndarray, slip: np.ndarray,
                  code_range_m: np.ndarray | None = None) -> PathRangeSeries:
        """A series from per-frame values and which path gave each, its age and origin breaks derived.

        A run is a stretch of tracked frames with one ``path_key`` (the path,
        or the pair of paths of a difference); the path age restarts where a
        run begins, and that frame is an origin break as a flagged ``slip``
        is. ``range_change_m`` is set to 0 where nothing is tracked, and
        ``code_range_m`` to NaN; ``valid`` is ``tracked & usable``.
        """
        begins = tracked & ~np.concatenate([[False], tracked[:-1] & (path_key[1:] == path_key[:-1])])
        run_start = np.maximum.accumulate(np.where(begins, np.arange(len(t_s)), 0))
        code = None if code_range_m is None else np.where(tracked, code_range_m, np.nan)
        return cls(t_s=t_s, range_change_m=np.where(tracked, range_change_m, 0.0), snr_db=snr_db,
                   valid=tracked & usable, slip=(slip | begins) & tracked,
                   path_age_s=np.where(tracked, t_s - t_s[run_start], 0.0), code_range_m=code)


@dataclass(frozen=True)
class PathRanges:
    """The receiver's path observations of one recording (docs/paths.md).

    Attributes
    ----------
    first_path : dict of int -> PathRangeSeries
        First-path range of tower k (the tower table's order).
    differences : dict of int -> PathRangeSeries
        First-path range of tower k minus that of tower 0 (k >= 1).
    """

    first_path: dict[int, PathRangeSeries] = field(default_factory=dict)
    differences: dict[int, PathRangeSeries] = field(default_factory=dict)


@dataclass
class Observations:
    """What a range source gives the fusion for one recording.

    Attributes
    ----------
    ranges : RangeSeries
        The SI-carrier range.
    paths : PathRanges or None
        First-path ranges and tower differences (``docs/paths.md``); None
        where the source has no path tracker.
    """

    ranges: RangeSeries
    paths: PathRanges | None = None


@dataclass
class ImuLog(ColumnRecord):
    """Inertial and magnetic samples of one IMU.

    The sensor (body) frame is the device's own: for the handheld phone
    x = right, y = forward (towards the top of the phone), z = out of the
    screen; for the foot-mounted unit x = right, y = forward along the foot,
    z = up out of the instep. Each writer states its frame in the file.

    Attributes
    ----------
    t_s : ndarray
        Sample time since the start of the capture, s.
    acc_mps2 : ndarray, shape (N, 3)
        Specific force (acceleration minus gravity; reads +9.8 m/s^2 up at
        rest), m/s^2, sensor frame.
    gyro_radps : ndarray, shape (N, 3)
        Angular rate, rad/s, sensor frame (right-handed).
    mag_ut : ndarray, shape (N, 3)
        Magnetic flux density, uT, sensor frame.
    """

    t_s: np.ndarray
    acc_mps2: np.ndarray
    gyro_radps: np.ndarray
    mag_ut: np.ndarray


@dataclass
class GnssLog(ColumnRecord):
    """Per-epoch GNSS position fixes with their signal strength.

    Attributes
    ----------
    t_s : ndarray
        Epoch time since the start of the capture, s.
    x_m, y_m : ndarray
        Fixed east and north position, m.
    cn0_dbhz : ndarray
        Mean carrier-to-noise density of the satellites used, dB-Hz.
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    cn0_dbhz: np.ndarray


@dataclass
class GeodeticFixes(ColumnRecord):
    """Position fixes on WGS84, as a phone reports them (its log, or its live stream).

    Attributes
    ----------
    t_s : ndarray
        Fix time, s, on the clock of whoever hands them on (the simulation's true time, a stream's own).
    lat_deg, lon_deg : ndarray
        WGS84 latitude and longitude, deg.
    height_m : ndarray
        Height above the WGS84 ellipsoid, m (NaN: none stated).
    accuracy_m : ndarray
        Stated horizontal accuracy (Android's 68 % radius), m (NaN: none stated).
    cn0_dbhz : ndarray
        Mean C/N0 of the satellites used, dB-Hz (NaN: none stated).
    """

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    accuracy_m: np.ndarray
    cn0_dbhz: np.ndarray

    @classmethod
    def empty(cls) -> GeodeticFixes:
        """No fixes."""
        return cls(*(np.zeros(0) for _ in range(6)))


@dataclass(frozen=True)
class StartFix:
    """The GNSS fix P0 where the PDR starts (the last fix before GNSS is given up).

    Attributes
    ----------
    t_s : float
        Time of the fix, s.
    x_m, y_m : float
        Fixed east and north position, m.
    sigma_m : float
        Stated 1-sigma horizontal error per axis, m.
    """

    t_s: float
    x_m: float
    y_m: float
    sigma_m: float



@dataclass(frozen=True)
class WalkTruth:
    """A walk's truth as read back from a truth file.

    Attributes
    ----------
    track : Track
        Truth trajectory.
    step_t_s, step_length_m : ndarray
        Heel-strike times (s) and truth step lengths (m).
    walk_start_t_s : float
        When the walker sets off, s.
    start_fix : StartFix
        The GNSS start fix P0.
    """

    track: Track
    step_t_s: np.ndarray
    step_length_m: np.ndarray
    walk_start_t_s: float
    start_fix: StartFix

# --- receiver frames (/receiver/frames) ------------------------------------------------------

class FrameFlag(IntFlag):
    """Per-frame quality bits (``flags`` column of ``/receiver/frames``)."""

    #: First frame of a lock (acquisition or re-acquisition): no CFO pair.
    LOCK_START = 1
    #: First frame after a loss of lock: the samples before it were not tracked.
    GAP = 2
    #: Header correlation below the lock threshold, or a CFO scatter across the SI carriers above what
    #: the frame's SI SNR explains (frame kept, not trusted).
    LOW_QUALITY = 4
    #: Frame inside the static window used to estimate the clock offset f_s.
    CALIBRATION = 8
    #: First frame after samples the front end dropped (``receiver.drops``): no CFO pair; ``t_s`` counts the lost
    #: samples, and the range bridges the drop with the recent Doppler.
    DROP = 16


#: Storage type of each ``/receiver/frames`` column.
FRAME_COLUMN_DTYPES: dict[str, type] = {
    "t_s": np.float64, "sample_index": np.int64, "frame_index": np.int64, "pn_phase": np.int32,
    "cfo_hz": np.float64, "cfo_pn_hz": np.float64, "doppler_hz": np.float64, "velocity_mps": np.float64,
    "range_change_m": np.float64, "snr_db": np.float32, "si_snr_db": np.float32,
    "peak_metric": np.float32, "flags": np.uint8, "segment_id": np.int32,
    "first_path_cfo_hz": np.float64, "first_path_range_change_m": np.float64, "first_path_delay_s": np.float64,
    "first_path_snr_db": np.float32, "first_path_id": np.int32, "tower_count": np.uint8,
    "range_difference_change_1_m": np.float64, "range_difference_change_2_m": np.float64,
}
#: The path tracker's columns of ``/receiver/frames`` and the value they hold where it found nothing
#: (or does not run).
FIRST_PATH_FILL: dict[str, float] = {
    "first_path_cfo_hz": np.nan, "first_path_range_change_m": np.nan, "first_path_delay_s": np.nan,
    "first_path_snr_db": np.nan, "first_path_id": -1, "tower_count": 0,
    "range_difference_change_1_m": np.nan, "range_difference_change_2_m": np.nan,
}


@dataclass
class FrameBatch(ColumnRecord):
    """Per-frame receiver results, one row per received signal frame.

    The field names are the ``/receiver/frames`` schema; the receiver yields
    frames as a stream of such batches.

    Notes
    -----
    Columns:

    - ``t_s``: frame start (first header sample of the main path) on the capture's
      clock, s: the frame's first sample index in the 7.56 Msps stream divided by
      7.56e6 (the resampler aligns that stream's sample n with input time
      ``n / 7.56e6``), never accumulated.
    - ``sample_index``: index in the INPUT stream (before resampling) of the
      input sample at or just before the frame start, so rows can be matched
      to the capture file.
    - ``frame_index``: the receiver's frame counter. With a rotating header it is
      congruent to the frame's place in the superframe (modulo the frames per
      superframe); it keeps counting across gaps (frame periods elapsed).
    - ``pn_phase``: cyclic phase of the frame's header (``docs/dtmb.md`` §2.3).
    - ``cfo_hz``: total carrier offset (coarse + SI estimate, eq. 5-8) measured
      between this frame and the previous one; NaN on the first frame of a lock.
    - ``cfo_pn_hz``: the independent estimate from the PN headers, same pair.
    - ``doppler_hz``: ``cfo_hz - f_s`` (eq. 9); ``velocity_mps``: eq. 10,
      positive when closing on the tower.
    - ``range_change_m``: eq. 11, m (shrinks when closing): the range change
      since the first frame of the frame's segment plus the last value of the
      segment before it, i.e. held flat across a gap (the first frame of a
      lock has no CFO pair and adds nothing); 0 at the very first frame.
    - ``snr_db``: header-based SNR (over the whole band); ``si_snr_db``: SNR on
      the 36 SI carriers (a 72 kHz slice at the band centre), which fades where
      paths with different delays cancel there, and which the CFO estimate
      (eq. 5-8) lives on; ``peak_metric``: share of the header-window power
      captured by the channel taps (0 on noise, ~1 on a clean signal).
    - ``flags``: :class:`FrameFlag` bits.
    - ``segment_id``: lock segment, 0 for the first lock, +1 at each
      re-acquisition: the range carries no motion across a change of
      segment (whatever moved during the gap is unknown), so it is a new
      origin for the fusion.

    The path tracker's columns (``docs/paths.md``; :data:`FIRST_PATH_FILL`
    where it found nothing; left out of the constructor, they take that fill):

    - ``first_path_cfo_hz``: carrier frequency of the first tower's first
      (earliest) path, as ``cfo_hz``; ``first_path_range_change_m``: eq. 9-11 on
      it (its own f_s), since the first frame: the direct-path range change;
    - ``first_path_delay_s``, ``first_path_snr_db``, ``first_path_id``: that
      path's delay after ``t_s``, SNR and id (``/receiver/paths``);
    - ``tower_count``: towers (groups of paths) tracked;
    - ``range_difference_change_1_m``, ``..._2_m``: change of the range to
      tower 1 (2) minus the range to tower 0, from their first paths' carrier
      phases (clock-free), since the frame where both were first tracked.
    """

    t_s: np.ndarray
    sample_index: np.ndarray
    frame_index: np.ndarray
    pn_phase: np.ndarray
    cfo_hz: np.ndarray
    cfo_pn_hz: np.ndarray
    doppler_hz: np.ndarray
    velocity_mps: np.ndarray
    range_change_m: np.ndarray
    snr_db: np.ndarray
    si_snr_db: np.ndarray
    peak_metric: np.ndarray
    flags: np.ndarray
    segment_id: np.ndarray
    first_path_cfo_hz: np.ndarray | None = None
    first_path_range_change_m: np.ndarray | None = None
    first_path_delay_s: np.ndarray | None = None
    first_path_snr_db: np.ndarray | None = None
    first_path_id: np.ndarray | None = None
    tower_count: np.ndarray | None = None
    range_difference_change_1_m: np.ndarray | None = None
    range_difference_change_2_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name, fill in FIRST_PATH_FILL.items():
            if getattr(self, name) is None:
                setattr(self, name, np.full(len(self.t_s), fill, dtype=FRAME_COLUMN_DTYPES[name]))
        super().__post_init__()

    @classmethod
    def empty(cls) -> "FrameBatch":
        """A batch with no rows (typed columns)."""
        return cls.concatenate([])

    @classmethod
    def concatenate(cls, batches: list["FrameBatch"]) -> "FrameBatch":
        """Rows of ``batches`` in order, as one batch."""
        if not batches:
            return cls(**{name: np.empty(0, dtype=dt) for name, dt in FRAME_COLUMN_DTYPES.items()})
        return cls(**{name: np.concatenate([getattr(b, name) for b in batches]).astype(dt, copy=False)
                      for name, dt in FRAME_COLUMN_DTYPES.items()})


# --- receiver paths (/receiver/paths) --------------------------------------------------------

class PathFlag(IntFlag):
    """Per-row bits of ``/receiver/paths`` (``flags`` column)."""

    #: The earliest tracked path of its tower: the direct-path candidate.
    FIRST_PATH = 1
    #: The path's first row: no phase pair yet (``cfo_hz`` NaN, range change 0).
    BORN = 2
    #: A cycle slip was detected on this frame; the range change is bridged with the path's smoothed Doppler.
    CYCLE_SLIP = 4
    #: The path's power is below the survival threshold in this batch (it is dropped if that lasts).
    FADING = 8


#: Storage type of each ``/receiver/paths`` column.
PATH_COLUMN_DTYPES: dict[str, type] = {
    "t_s": np.float64, "frame_index": np.int64, "path_id": np.int32, "tower_id": np.int32, "delay_s": np.float64,
    "delay_rate": np.float32, "cfo_hz": np.float64, "doppler_hz": np.float64, "range_change_m": np.float64,
    "snr_db": np.float32, "flags": np.uint8,
}


@dataclass
class PathBatch(ColumnRecord):
    """Tracked propagation paths, one row per frame and tracked path (``/receiver/paths``).

    Notes
    -----
    Columns (``docs/schema.md``, ``docs/paths.md``):

    - ``t_s``, ``frame_index``: the frame's, as in :class:`FrameBatch`.
    - ``path_id``: the path's id, unique within a receiver run (a path that is
      lost and found again gets a new id); ``tower_id``: the group of paths it
      belongs to, i.e. the transmitter of a single-frequency network (0 = the
      tower found first in a lock, then in order of discovery).
    - ``delay_s``: arrival of the frame's header over this path after the
      frame's ``t_s``, s (sub-sample, from the pulse-shape fit).
    - ``delay_rate``: rate of change of the path's delay, s/s (range rate over
      c plus the receiver clock's rate).
    - ``cfo_hz``: the path's carrier frequency from its phase between this
      frame and the previous one (the same measure as the frames' ``cfo_hz``,
      coarse CFO included); on frames flagged ``CYCLE_SLIP`` its smoothed value.
    - ``doppler_hz``: ``cfo_hz - f_s`` (eq. 9); ``range_change_m``: eq. 11 for
      this path, since its first row.
    - ``snr_db``: the path's power over the noise per sample, dB (its share of
      the header SNR).
    - ``flags``: :class:`PathFlag` bits.
    """

    t_s: np.ndarray
    frame_index: np.ndarray
    path_id: np.ndarray
    tower_id: np.ndarray
    delay_s: np.ndarray
    delay_rate: np.ndarray
    cfo_hz: np.ndarray
    doppler_hz: np.ndarray
    range_change_m: np.ndarray
    snr_db: np.ndarray
    flags: np.ndarray

    @classmethod
    def concatenate(cls, batches: list["PathBatch"]) -> "PathBatch":
        """Rows of ``batches`` in order, as one batch."""
        if not batches:
            return cls(**{name: np.empty(0, dtype=dt) for name, dt in PATH_COLUMN_DTYPES.items()})
        return cls(**{name: np.concatenate([getattr(b, name) for b in batches]).astype(dt, copy=False)
                      for name, dt in PATH_COLUMN_DTYPES.items()})
