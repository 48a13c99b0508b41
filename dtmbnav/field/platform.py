"""Which phone platform's sign a Sensor Logger export's acceleration carries: Android's or iOS's.

The Sensor Logger app on iOS, unless its "Standardise Units & Frames" setting is on, logs acceleration and
gravity with the opposite sign to Android's, in the same units and on the same axes; its gyroscope and
magnetometer agree with Android's (:mod:`dtmbnav_core.phone_formats`). So the sign to read with comes,
in this order, from

1. ``--platform`` (``dtmbnav sensors``), where the user gives it; it must agree with ``Metadata.csv``
   where that states a platform (else a ValueError: two sources that disagree are not guessed between);
2. ``Metadata.csv``'s platform and standardisation (:func:`stated_platform`);
3. ``TotalAcceleration.csv``, which only Android's app writes;
4. the data (:func:`platform_from_data`), where it is unambiguous; else the export is refused with a
   message that names ``--platform``.

The data's evidence is the magnetic dip. Wherever the phone points, the angle between the specific force
(Android's sign: up, at rest) and the Earth's field is 90 deg plus the field's inclination I, which is
positive (field pointing down) in the northern hemisphere and negative in the southern one: so the median
over the log of cos(angle) = -sin(I) is negative for Android's sign north of the dip equator, positive for
iOS's. The fixes' latitude says the hemisphere. The evidence is taken only where the fixes lie at least
:data:`MIN_ABS_LATITUDE_DEG` from the equator (the magnetic dip equator wanders up to about 15 deg from the
geographic one, IGRF), the measured dip is at least :data:`MIN_DIP_DEG` (a steel building can bend the field
indoors) and :data:`MIN_AGREEING_SHARE` of the samples agree on its sign; the magnitude cannot help, since both
platforms log acceleration in m/s^2.
"""

from __future__ import annotations

import math

import numpy as np

from dtmbnav_core import phone_formats as fmt
from dtmbnav_core.text_tables import Table

ANDROID = "android"
IOS = "ios"
#: The platforms ``--platform`` takes: the sign of Android's accelerometer, or of iOS's (not standardised).
PLATFORMS = (ANDROID, IOS)
#: Least |latitude| of the fixes at which the field's inclination has the hemisphere's sign, deg.
MIN_ABS_LATITUDE_DEG = 20.0
#: Least measured |inclination| taken as evidence, deg.
MIN_DIP_DEG = 15.0
#: Least share of the samples whose dip has the sign of the median dip.
MIN_AGREEING_SHARE = 0.8
#: What a refusal tells the user to do.
GIVE_PLATFORM = ("give --platform android or --platform ios (an iPhone with \"Standardise Units & Frames\" on "
                 "logs with Android's sign: --platform android)")


def stated_platform(metadata: Table) -> str | None:
    """The sign ``Metadata.csv`` states: :data:`IOS` for iOS without standardised units and frames, else
    :data:`ANDROID`; None where it names no platform (no row, no column, an empty field)."""
    column = metadata.index((fmt.METADATA_PLATFORM,))
    if column is None or not metadata.texts or not metadata.fields[0][column].strip():
        return None
    row = [text.strip().lower() for text in metadata.fields[0]]
    standard = metadata.index(fmt.METADATA_STANDARDISATION)
    standardised = standard is not None and row[standard] in ("true", "1")
    return IOS if row[column] == IOS and not standardised else ANDROID


def check_given(given: str | None, stated: str | None, where: str) -> str | None:
    """The sign to read with from ``--platform`` (``given``) and ``Metadata.csv`` (``stated``); None where
    neither says.

    Raises
    ------
    ValueError
        The two disagree (``where`` names the export).
    """
    if given is not None and stated is not None and given != stated:
        raise ValueError(f"{where}: --platform {given}, but Metadata.csv says the acceleration carries {stated}'s "
                         f"sign; drop --platform (Metadata.csv is the app's own record) or give --platform {stated}")
    return given or stated


def platform_from_data(specific_force: np.ndarray, force_t_ns: np.ndarray, field_ut: np.ndarray | None,
                       field_t_ns: np.ndarray | None, latitude_deg: np.ndarray | None, where: str) -> str:
    """The platform whose sign ``specific_force`` carries, from the magnetic dip (module docstring).

    Parameters
    ----------
    specific_force : ndarray, shape (N, 3)
        The specific force (or gravity) as logged, m/s^2, of unknown sign.
    force_t_ns : ndarray of int64
        Its sample times, ns.
    field_ut, field_t_ns : ndarray or None
        The magnetometer's samples (uT) and times (ns); None without a magnetometer.
    latitude_deg : ndarray or None
        The fixes' WGS84 latitudes, deg; None without fixes.
    where : str
        The export, for messages.

    Raises
    ------
    ValueError
        The data cannot decide: the message says why and names ``--platform``.
    """
    def refuse(why: str) -> ValueError:
        return ValueError(f"{where}: no platform (Metadata.csv), and {why}, so the data cannot tell iOS's "
                          f"acceleration sign from Android's; {GIVE_PLATFORM}")

    if field_ut is None or field_t_ns is None:
        raise refuse("no magnetometer (the dip of the Earth's field against gravity tells them apart)")
    if latitude_deg is None or not np.isfinite(latitude_deg).any():
        raise refuse("no fixes (their latitude says which way the Earth's field dips)")
    latitude = float(np.nanmedian(latitude_deg))
    if abs(latitude) < MIN_ABS_LATITUDE_DEG:
        raise refuse(f"the fixes lie at latitude {latitude:.1f} deg, within {MIN_ABS_LATITUDE_DEG:g} deg of the "
                     "equator, where the Earth's field may dip either way")
    t_s = (field_t_ns - force_t_ns[0]) / 1e9
    inside = (force_t_ns >= field_t_ns[0]) & (force_t_ns <= field_t_ns[-1])
    at = (force_t_ns[inside] - force_t_ns[0]) / 1e9
    field = np.column_stack([np.interp(at, t_s, field_ut[:, k]) for k in range(3)])
    force = specific_force[inside]
    norms = np.linalg.norm(force, axis=1) * np.linalg.norm(field, axis=1)
    usable = norms > 0
    if not usable.any():
        raise refuse("the accelerometer and magnetometer share no non-zero samples")
    cosine = np.einsum("ij,ij->i", force[usable], field[usable]) / norms[usable]
    median = float(np.median(cosine))
    dip_deg = math.degrees(math.asin(min(1.0, abs(median))))
    agreeing = float(np.mean(np.sign(cosine) == np.sign(median)))
    if dip_deg < MIN_DIP_DEG or agreeing < MIN_AGREEING_SHARE:
        raise refuse(f"the field's measured dip against gravity ({dip_deg:.0f} deg, {agreeing:.0%} of the samples "
                     f"agreeing on its sign) is below the {MIN_DIP_DEG:g} deg and {MIN_AGREEING_SHARE:.0%} taken as "
                     "evidence (a disturbed field?)")
    # Android's sign (specific force up) against a field dipping down in the north: cos < 0 there.
    return ANDROID if (median < 0) == (latitude > 0) else IOS


def detected_note(where: str, sign: str) -> str:
    """What the user is told when the data gave the platform."""
    return (f"{where}: no platform (Metadata.csv): the Earth's field's dip against gravity says the acceleration "
            f"carries {sign}'s sign (--platform says it outright)")
