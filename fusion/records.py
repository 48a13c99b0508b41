"""Typed records that the fusion stages exchange.

Each record is a dataclass of equal-length 1-D numpy arrays (one per column,
names carry units, as in ``shared/spec/conventions.md``). The HDF5 layer writes
them column by column, so a record's fields are its file schema.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

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

    def select(self, mask: np.ndarray):
        """A new record with the rows where ``mask`` (bool or index array) selects."""
        return type(self)(**{k: v[mask] for k, v in self.columns().items()})


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
    """

    t_s: np.ndarray
    range_change_m: np.ndarray
    snr_db: np.ndarray
    valid: np.ndarray


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
