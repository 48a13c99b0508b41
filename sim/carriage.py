"""How a phone rides on a walker: the carriages' motion models (scenario ``imu.carriage``).

Frames as in :mod:`sim.imu`: navigation ENU, sensor x = right, y = forward, z = out of
the screen. Every carriage gives the phone's attitude and its ENU acceleration
(gravity excluded) at the sample times, built on the body's motion: the smooth truth
track plus a per-step gait (vertical bounce by Weinberg's relation, forward surge, a
sideways sway at the stride frequency). On top of that:

- held (``hand``, ``texting``, ``ear``): the phone rides rigidly with the trunk or the
  head and wobbles with the gait; at the ear the head also turns now and then;
- on a limb (``pocket``, ``pocket-gait``, ``swinging``, ``swinging-wide``): the thigh or
  the arm swings about the hip or the shoulder at the stride frequency; the phone's
  offset from that joint is differentiated twice in ENU, which gives exactly the
  tangential (``L theta''``) and centripetal (``L theta'^2``) terms of a point on a
  rotating limb, and gravity enters through the rotating attitude (:mod:`sim.imu`
  projects the specific force into the sensor frame);
- in a shoulder bag (``bag``): a damped pendulum hanging from the shoulder, driven by the
  shoulder's acceleration and by random jostling, so that it sways at its own frequency.

A walk may change carriage (``imu.carriage_changes``): over a change's duration the
attitude turns from the old carriage's to the new one's and the phone moves between
the two carry positions on a minimum-jerk path, as a hand taking a phone out of a
pocket or putting it to the ear does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import uniform_filter1d
from scipy.signal import butter, cont2discrete, lfilter, sosfilt
from scipy.spatial.transform import Rotation

from dtmbnav_core.constants import GRAVITY_MPS2
from sim.walk import Walk


@dataclass(frozen=True)
class Carriage:
    """How the phone rides on the walker (scenario ``imu.carriage``).

    Attributes
    ----------
    bounce_scale : float
        Part of the body's vertical bounce (Weinberg's relation) that reaches the phone.
    pitch_rad : float
        Pitch at which the phone is held, nose up, rad (for a limb: when the limb hangs straight).
    roll_rad : float
        Roll of the phone about its forward axis, rad (pi/2: the screen faces right).
    limb_m : float
        Distance from the joint the limb swings about (hip, shoulder) to the phone, or the
        bag's strap length, m; 0 for a phone held rigidly.
    swing_rad : float
        Amplitude of the limb's swing about the lateral axis (at half the step frequency), rad.
    swing_mean_rad : float
        Mean angle of the limb forward of the vertical while walking, rad.
    leg_asymmetry : float
        Stride-frequency part of the vertical bounce, relative: the strike of the leg
        that carries the phone peaks ``1 + a`` times the body's, the other leg's ``1 - a``.
    strike_mps2 : float
        Peak of the heel-strike transient of the leg that carries the phone, m/s^2 (the
        other leg's reaches it through the pelvis at a third of that).
    placement : str
        The phone's orientation: ``"held"`` (by ``pitch_rad`` and ``roll_rad``),
        ``"pocket"`` (flat on the front of the thigh, screen in or out and turned in the
        pocket's plane, drawn per walk) or ``"any"`` (uniformly random, drawn per walk).
    thigh_profile_deg : tuple of (float, float)
        Limb angle forward of the vertical over a stride, as (fraction of the stride from
        the heel strike of the leg that carries the phone, deg) knots of a periodic
        spline; empty: ``swing_mean_rad + swing_rad cos`` (a pendulum).
    wobble : float
        Scale of a held phone's attitude wobble with the gait (1: a hand's).
    head_turn_rad : float
        Spread (1 sigma) of the head's turns to look around, rad; 0: none.
    sway_damping : float
        Damping ratio of the bag's pendulum; 0 for carriages that are no bag.
    bounce_lowpass_hz : float
        Corner of the low-pass that the bounce passes before it reaches the phone, Hz; 0: none.
    joint_m : tuple of float
        Where the phone is held, or the joint its limb or strap hangs from: (forward,
        right, up) of the pelvis's centre, m. Used for the move between carriages.
    """

    bounce_scale: float
    pitch_rad: float
    roll_rad: float = 0.0
    limb_m: float = 0.0
    swing_rad: float = 0.0
    swing_mean_rad: float = 0.0
    leg_asymmetry: float = 0.0
    strike_mps2: float = 0.0
    placement: str = "held"
    thigh_profile_deg: tuple[tuple[float, float], ...] = ()
    wobble: float = 1.0
    head_turn_rad: float = 0.0
    sway_damping: float = 0.0
    bounce_lowpass_hz: float = 0.0
    joint_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def swings_arm(self) -> bool:
        """Whether the phone rides in a hand swinging as a pendulum (what ``imu.swing_deg`` sets)."""
        return self.limb_m > 0.0 and self.placement == "held" and self.sway_damping == 0.0


#: Joint and carry positions, (forward, right, up) of the pelvis's centre, m, for a walker of
#: about 1.75 m, from the segment proportions of Drillis & Contini as tabulated by Winter
#: (Biomechanics and Motor Control of Human Movement, 4th ed., 2009, fig. 4.1): hip joint 0.09 m
#: to the side, shoulder 0.5 m above the hip and 0.2 m to the side, ear 0.7 m above it; where a
#: hand holds the phone in front is an assumption.
_HIP_M = (0.0, 0.09, 0.0)
_SHOULDER_M = (0.0, 0.2, 0.5)
_POCKET = {"bounce_scale": 1.0, "pitch_rad": 0.0, "limb_m": 0.2, "leg_asymmetry": 0.4, "strike_mps2": 5.0,
           "placement": "pocket", "joint_m": _HIP_M}
_SWINGING = {"bounce_scale": 1.0, "pitch_rad": 0.0, "roll_rad": np.radians(90.0), "limb_m": 0.65,
             "joint_m": _SHOULDER_M}

#: Carriages of the phone preset (``imu.carriage``). Typical values of the gait literature:
#: - ``hand``: held in front at about 20 deg nose up, rigidly enough that the body's bounce reaches it;
#: - ``texting``: held closer and steeper (the screen faced towards the eyes), and kept steady to be read,
#:   so the arm damps the trunk's bounce to some 40 %; people walk slower and with a lower cadence
#:   while texting (Lamberg & Muratori 2012, Gait & Posture 35:688; Schabrun et al. 2014, PLoS ONE
#:   9:e84312): the scenario's ``[walk]`` sets that gait (e.g. 1.1 steps/s at 0.7 m/s);
#: - ``pocket``: front trouser pocket about 0.2 m below the hip joint; the hip flexes and extends over
#:   some 40 deg each stride (about +25 to -15 deg, Perry & Burnfield, Gait Analysis, 2010), the leg that
#:   carries the phone dominates the signal, and its heel strike reaches the thigh as a transient of the
#:   order of half a g (the shock at the shin, one to a few g, is damped up the leg); the swing is a
#:   pendulum of +-20 deg about +5 deg;
#: - ``pocket-gait``: the same pocket with the thigh's measured angle over a stride instead of the
#:   pendulum: flexed some 20-25 deg at its heel strike, extending steadily through stance to about
#:   -15 deg at 50-55 % of the stride, then flexing fast (pre-swing and initial swing, when the knee
#:   flexes to 60 deg and the thigh is thrown forward) to its peak of about +26 deg at 85-90 % (thigh
#:   angle curves of Perry & Burnfield 2010, ch. 4 and 7, and Winter 2009, knots read off them): the
#:   uneven thigh rates and the two legs' strikes give the double-peaked stride real pocket traces show;
#: - ``swinging``: gripped across the palm (top forward, screen facing out) in an arm that hangs about
#:   0.65 m from the shoulder and swings as a pendulum at half the step frequency, some +-20 deg at a
#:   normal pace (arm swing reviewed by Meyns, Bruijn & Duysens 2013, Gait & Posture 38:555): angular
#:   rates of well over 100 deg/s; ``swinging-wide``: the +-45 deg swing of a brisk walk (the review's
#:   upper range; ``imu.swing_deg`` sets any amplitude), centred 10 deg forward (assumption: the hand
#:   swings further in front than behind, the elbow flexing in the forward swing). At that amplitude the
#:   centripetal term ``L theta'^2`` (up to some 13 m/s^2) beats at the step frequency, and the offset centre
#:   makes gravity's part along the arm differ between the forward and the backward swing, which puts a
#:   strong stride-frequency component into the acceleration's norm;
#: - ``ear``: held to the right ear during a call, the long axis pitched some 70 deg up and rolled 80 deg
#:   so that the screen faces the head (the "call" placement of Brajdic & Harle, UbiComp 2013); the head
#:   is stabilised during walking, its pitch and yaw oscillations a few degrees (Pozzo, Berthoz & Lefort
#:   1990, Exp. Brain Res. 82:97; Hirasaki et al. 1999, Exp. Brain Res. 127:117), so the wobble is half a
#:   hand's, while its vertical acceleration is near the pelvis's (Menz, Lord & Fitzpatrick 2003, Gait &
#:   Posture 18:35): the arm pressing the phone to the head passes 70 % of it (assumption); the walker
#:   turns the head to look around (turns of 25 deg, 1 sigma, about every 8 s: assumption);
#: - ``bag``: in a shoulder bag hanging at the hip on a 0.35 m strap: a pendulum of natural frequency
#:   sqrt(g / L) / (2 pi) = 0.84 Hz, damped (ratio 0.15, assumption: the bag rubs on the hip) and
#:   jostled by the walker's body, so that it is not locked to the steps; the bag's contents and the
#:   strap damp the bounce to some 60 % and low-pass it at 3 Hz (assumptions); the phone lies in the
#:   bag at any orientation ("bag" placement of Brajdic & Harle 2013).
CARRIAGES: dict[str, Carriage] = {
    "hand": Carriage(bounce_scale=1.0, pitch_rad=np.radians(20.0), joint_m=(0.3, 0.1, 0.25)),
    "texting": Carriage(bounce_scale=0.4, pitch_rad=np.radians(35.0), joint_m=(0.3, 0.05, 0.3)),
    "pocket": Carriage(swing_rad=np.radians(20.0), swing_mean_rad=np.radians(5.0), **_POCKET),
    "pocket-gait": Carriage(thigh_profile_deg=((0.0, 22.0), (0.12, 20.0), (0.3, 3.0), (0.5, -15.0),
                                               (0.6, -8.0), (0.73, 15.0), (0.87, 26.0)), **_POCKET),
    "swinging": Carriage(swing_rad=np.radians(20.0), **_SWINGING),
    "swinging-wide": Carriage(swing_rad=np.radians(45.0), swing_mean_rad=np.radians(10.0), **_SWINGING),
    "ear": Carriage(bounce_scale=0.7, pitch_rad=np.radians(70.0), roll_rad=np.radians(-80.0), wobble=0.5,
                    head_turn_rad=np.radians(25.0), joint_m=(0.0, 0.1, 0.7)),
    "bag": Carriage(bounce_scale=0.6, pitch_rad=0.0, limb_m=0.35, placement="any", sway_damping=0.15,
                    bounce_lowpass_hz=3.0, joint_m=_SHOULDER_M),
}
#: Width (standard deviation of the Gaussian it is built on) of a heel-strike transient, s.
STRIKE_WIDTH_S = 0.02
#: Moving-average window over which a swinging limb's phase follows the steps', s (about a stride).
SWING_SMOOTHING_S = 1.0
#: Mean time between the head's turns at the ear, s, and how long one lasts (out, look, back), s (assumptions).
HEAD_TURN_EVERY_S = 8.0
HEAD_TURN_S = 2.0
#: RMS of the bag's sway that the walker's body jostles into it, rad (assumption: a few degrees).
BAG_JOSTLE_RAD = np.radians(5.0)


@dataclass(frozen=True)
class Motion:
    """True motion of the sensor at the sample times.

    Attributes
    ----------
    attitude : Rotation
        Sensor-to-ENU rotation.
    acc_enu_mps2 : ndarray, shape (N, 3)
        Acceleration, gravity excluded, m/s^2.
    offset_enu_m : ndarray, shape (N, 3) or None
        The phone's place relative to the pelvis's centre, ENU m (None for a foot unit).
    """

    attitude: Rotation
    acc_enu_mps2: np.ndarray
    offset_enu_m: np.ndarray | None = None


def resample_walk(walk: Walk, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Truth position (N x 2, m) and unwrapped heading (rad) at times ``t_s``."""
    tr = walk.track
    xy = np.column_stack([np.interp(t_s, tr.t_s, tr.x_m), np.interp(t_s, tr.t_s, tr.y_m)])
    return xy, np.interp(t_s, tr.t_s, np.unwrap(tr.heading_rad))


def second_difference(values: np.ndarray, dt_s: float) -> np.ndarray:
    """Central second derivative along axis 0 (one-sided at the ends)."""
    return np.gradient(np.gradient(values, dt_s, axis=0), dt_s, axis=0)


def attitude_ypr(yaw_rad: np.ndarray, pitch_rad: np.ndarray, roll_rad: np.ndarray) -> Rotation:
    """Sensor-to-ENU rotation from yaw (clockwise from north), pitch and roll (:mod:`sim.imu` docstring)."""
    return Rotation.from_euler("ZXY", np.column_stack([-yaw_rad, pitch_rad, roll_rad]))


def _body_to_enu(heading_rad: np.ndarray, forward: np.ndarray, right: np.ndarray, up: np.ndarray) -> np.ndarray:
    """ENU vectors (N x 3) from their forward, right and up parts in the walking direction's frame."""
    return np.column_stack([forward * np.sin(heading_rad) + right * np.cos(heading_rad),
                            forward * np.cos(heading_rad) - right * np.sin(heading_rad), up])


@dataclass(frozen=True)
class _Gait:
    """The body's part of a phone's motion at the sample times.

    ``heading`` is the truth heading (unwrapped, rad); ``walking`` marks the samples
    inside a step; ``cycle`` is the step's phase angle (2 pi per step) and ``stride``
    the stride's (pi per step, continuous from step to step); ``bounce_pp`` the
    peak-to-peak bounce reaching the phone, m/s^2; ``acc_enu_mps2`` the truth
    track's acceleration plus the bounce, surge and sway.
    """

    heading: np.ndarray
    walking: np.ndarray
    cycle: np.ndarray
    stride: np.ndarray
    bounce_pp: np.ndarray
    acc_enu_mps2: np.ndarray


def _body_gait(walk: Walk, t_s: np.ndarray, weinberg_k_m: float, carriage: Carriage, gain_error: float) -> _Gait:
    """Smooth truth motion plus the per-step gait of the body (module docstring)."""
    dt = t_s[1] - t_s[0]
    xy, heading = resample_walk(walk, t_s)
    acc = np.zeros((len(t_s), 3))
    acc[:, :2] = second_difference(xy, dt)

    step, phase = walk.step_phase(t_s)
    walking = step >= 0
    length = np.where(walking, walk.step_length_m[np.maximum(step, 0)], 0.0)
    # Weinberg, peak-to-peak, of which the carriage passes on a part.
    bounce_pp = carriage.bounce_scale * ((1.0 + gain_error) * length / weinberg_k_m) ** 4
    # The body is lowest and decelerating upwards (vertical acceleration at its peak) at heel
    # strike, phase 0 and 1 of a step, and highest at mid-stance. Setting off from a standstill
    # there is no strike at phase 0: the first step of a leg fades in from zero.
    cycle = 2.0 * np.pi * phase
    fade_in = np.where(walking & walk.first_of_leg[np.maximum(step, 0)], np.sin(0.5 * np.pi * phase) ** 2, 1.0)
    stride = np.pi * (np.maximum(step, 0) + phase)  # the sway alternates sides every step
    vertical = 0.5 * bounce_pp * np.cos(cycle) * fade_in
    if carriage.bounce_lowpass_hz > 0.0:
        # A causal low-pass: what damps the bounce (a strap, a bag's contents) lags it too.
        vertical = sosfilt(butter(2, carriage.bounce_lowpass_hz, fs=1.0 / dt, output="sos"), vertical)
    forward = 0.15 * bounce_pp * np.sin(cycle)
    sideways = np.where(walking, 0.4 * np.sin(stride), 0.0)
    fwd_unit = np.column_stack([np.sin(heading), np.cos(heading)])
    right_unit = np.column_stack([np.cos(heading), -np.sin(heading)])
    acc[:, :2] += forward[:, None] * fwd_unit + sideways[:, None] * right_unit
    acc[:, 2] += vertical
    return _Gait(heading=heading, walking=walking, cycle=cycle, stride=stride, bounce_pp=bounce_pp,
                 acc_enu_mps2=acc)


def _joint_enu(gait: _Gait, carriage: Carriage) -> np.ndarray:
    """Where the carriage's joint (or grip) lies from the pelvis, ENU m (N x 3).

    The joint turns with the walker; its own centripetal acceleration in a turn (the turn
    rate squared times some 0.2 m: a few hundredths of m/s^2) is left out of the carriages'
    accelerations, and enters only through a carriage change's move.
    """
    forward, right, up = (np.full(len(gait.heading), v) for v in carriage.joint_m)
    return _body_to_enu(gait.heading, forward, right, up)


def _head_turns(t_s: np.ndarray, spread_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Yaw of the head's turns to look around, rad: raised-cosine out-and-back turns at Poisson times."""
    yaw = np.zeros(len(t_s))
    count = rng.poisson((t_s[-1] - t_s[0]) / HEAD_TURN_EVERY_S)
    for start, size in zip(rng.uniform(t_s[0], t_s[-1], count), rng.normal(0.0, spread_rad, count)):
        u = np.clip((t_s - start) / HEAD_TURN_S, 0.0, 1.0)
        yaw += size * 0.5 * (1.0 - np.cos(2.0 * np.pi * u))
    return yaw


def _held_motion(t_s: np.ndarray, gait: _Gait, carriage: Carriage, mount_yaw_rad: float,
                 rng: np.random.Generator) -> Motion:
    """Phone held in front or at the ear: the body's motion and an attitude wobble with the gait."""
    # Attitude wobble grows with the bounce (a relaxed arm swings more at a brisk pace).
    wobble = carriage.wobble * np.sqrt(gait.bounce_pp / 5.0)
    yaw = gait.heading + mount_yaw_rad + np.radians(2.0) * wobble * np.sin(gait.stride)
    if carriage.head_turn_rad > 0.0:
        yaw = yaw + _head_turns(t_s, carriage.head_turn_rad, rng)
    pitch = carriage.pitch_rad + np.radians(1.5) * wobble * np.sin(gait.cycle)
    roll = carriage.roll_rad + np.radians(1.5) * wobble * np.sin(gait.stride)
    return Motion(attitude=attitude_ypr(yaw, pitch, roll), acc_enu_mps2=gait.acc_enu_mps2,
                  offset_enu_m=_joint_enu(gait, carriage))


def _limb_angle(carriage: Carriage, stride: np.ndarray, envelope: np.ndarray) -> np.ndarray:
    """The limb's angle forward of the vertical, rad: a pendulum or the thigh's profile, faded by ``envelope``."""
    if not carriage.thigh_profile_deg:
        return carriage.swing_mean_rad * envelope + carriage.swing_rad * envelope**2 * np.cos(stride)
    knots = np.array(carriage.thigh_profile_deg + ((1.0, carriage.thigh_profile_deg[0][1]),))
    profile = CubicSpline(knots[:, 0], np.radians(knots[:, 1]), bc_type="periodic")
    mean = profile.integrate(0.0, 1.0)
    return mean * envelope + envelope**2 * (profile(np.mod(stride / (2.0 * np.pi), 1.0)) - mean)


def _limb_motion(walk: Walk, t_s: np.ndarray, gait: _Gait, carriage: Carriage, mount_yaw_rad: float,
                 placement: Rotation) -> Motion:
    """Phone on a limb swinging about the hip or shoulder at half the step frequency.

    The limb's angle forward of the vertical is ``mean + swing cos(stride)`` (or the thigh's
    profile over the stride): it is at its extremes about the heel strikes (the leg that
    carries the phone forward at its own strikes) and hangs straight while standing. A limb
    is a pendulum with inertia: its stride angle is the steps' smoothed over
    :data:`SWING_SMOOTHING_S`, so that its rate does not jump with each step's duration.
    From a standstill the swing fades in over the leg's first step and out over its last,
    with the square of a half-cosine ramp (zero rate at both ends: attitude and rates stay
    continuous; squared, so that the limb hardly moves against its first swing while the
    ramp is low). ``placement`` is the phone's fixed orientation on the limb.
    """
    dt = t_s[1] - t_s[0]
    step, phase = walk.step_phase(t_s)
    index = np.maximum(step, 0)
    first = gait.walking & walk.first_of_leg[index]
    last = gait.walking & np.concatenate([walk.first_of_leg[1:], [True]])[index]
    rise, fall = 0.5 * (1.0 - np.cos(np.pi * phase)), 0.5 * (1.0 + np.cos(np.pi * phase))
    envelope = np.where(gait.walking, np.where(first, rise, 1.0) * np.where(last, fall, 1.0), 0.0)
    # Steps done plus the current one's phase: continuous through standstills too.
    steps_done = np.searchsorted(walk.step_t_s, t_s, side="right") + phase
    stride = uniform_filter1d(np.pi * steps_done, max(1, round(SWING_SMOOTHING_S / dt)), mode="nearest")
    angle = _limb_angle(carriage, stride, envelope)
    # The phone's offset from the joint (forward and up in the walking direction's vertical plane).
    forward = carriage.limb_m * np.sin(angle)
    offset = np.column_stack([forward * np.sin(gait.heading), forward * np.cos(gait.heading),
                              -carriage.limb_m * np.cos(angle)])
    acc = gait.acc_enu_mps2 + second_difference(offset, dt)
    # The leg that carries the phone dominates: its strikes (the ends of odd steps, where cos(stride) = 1)
    # bounce more than the other leg's.
    acc[:, 2] += carriage.leg_asymmetry * 0.5 * gait.bounce_pp * np.cos(gait.stride) * envelope
    # Heel-strike transients: a Mexican hat (zero net velocity change) at each strike, full size on that leg.
    strikes = walk.step_t_s
    j = np.clip(np.searchsorted(strikes, t_s), 1, len(strikes) - 1)
    nearest = np.where(np.abs(t_s - strikes[j - 1]) < np.abs(t_s - strikes[j]), j - 1, j)
    size = np.where(nearest % 2 == 1, carriage.strike_mps2, carriage.strike_mps2 / 3.0)
    u = (t_s - strikes[nearest]) / STRIKE_WIDTH_S
    acc[:, 2] += size * (1.0 - u**2) * np.exp(-0.5 * u**2)
    limb = Rotation.from_euler("ZX", np.column_stack([-(gait.heading + mount_yaw_rad), angle]))
    return Motion(attitude=limb * placement, acc_enu_mps2=acc, offset_enu_m=_joint_enu(gait, carriage) + offset)


def _pendulum(drive: np.ndarray, omega_rad_s: float, damping: float, dt_s: float) -> np.ndarray:
    """Angle (rad) of a damped pendulum ``theta'' + 2 z w theta' + w^2 theta = drive`` from rest, per column."""
    num, den, _ = cont2discrete(([1.0], [1.0, 2.0 * damping * omega_rad_s, omega_rad_s**2]), dt_s, method="bilinear")
    return lfilter(np.ravel(num), den, drive, axis=0)


def _bag_motion(t_s: np.ndarray, gait: _Gait, carriage: Carriage, placement: Rotation,
                rng: np.random.Generator) -> Motion:
    """Phone in a bag hanging from the shoulder: a damped pendulum swaying forward and sideways.

    The bag hangs ``limb_m`` below the shoulder; in the shoulder's accelerating frame the
    pivot's horizontal acceleration ``a`` drives its angle as ``-a / L`` (forward) and the
    walker's body jostles it at random (white angular acceleration while walking, scaled
    to :data:`BAG_JOSTLE_RAD` RMS sway), so that it sways at its own frequency
    ``sqrt(g / L)`` too and rings on after the walker stops.
    """
    dt = t_s[1] - t_s[0]
    omega = np.sqrt(GRAVITY_MPS2 / carriage.limb_m)
    heading = gait.heading
    fwd_unit = np.column_stack([np.sin(heading), np.cos(heading)])
    right_unit = np.column_stack([np.cos(heading), -np.sin(heading)])
    pivot = gait.acc_enu_mps2[:, :2]
    # Forward angle: displacement forward is L sin(theta); sideways angle about the forward axis:
    # a positive one swings the bag to the left, so the pivot's rightward acceleration drives it positive.
    drive = np.column_stack([-np.sum(pivot * fwd_unit, axis=1), np.sum(pivot * right_unit, axis=1)]) / carriage.limb_m
    sway = _pendulum(drive, omega, carriage.sway_damping, dt)
    jostle = _pendulum(rng.standard_normal((len(t_s), 2)) * gait.walking[:, None], omega, carriage.sway_damping, dt)
    jostle_rms = np.sqrt(np.mean(jostle[gait.walking] ** 2)) if gait.walking.any() else 1.0
    sway += BAG_JOSTLE_RAD * jostle / jostle_rms
    bag = Rotation.from_euler("ZXY", np.column_stack([-heading, sway]))
    offset = bag.apply([0.0, 0.0, -carriage.limb_m])
    acc = gait.acc_enu_mps2 + second_difference(offset, dt)
    return Motion(attitude=bag * placement, acc_enu_mps2=acc, offset_enu_m=_joint_enu(gait, carriage) + offset)


def _placement(carriage: Carriage, rng: np.random.Generator) -> Rotation:
    """The phone's orientation on its limb or in its bag: fixed, or drawn.

    In a pocket the phone lies flat on the front of the thigh, its screen towards the
    thigh or away from it, its long axis at any angle in the pocket's plane; in a bag
    it lies at any orientation.
    """
    if carriage.placement == "pocket":
        screen = rng.choice([-0.5 * np.pi, 0.5 * np.pi])
        return Rotation.from_euler("XZ", [screen, rng.uniform(0.0, 2.0 * np.pi)])
    if carriage.placement == "any":
        return Rotation.random(random_state=rng)
    return Rotation.from_euler("XY", [carriage.pitch_rad, carriage.roll_rad])


def carriage_motion(walk: Walk, t_s: np.ndarray, weinberg_k_m: float, carriage: Carriage, gain_error: float,
                    mount_yaw_rad: float, rng: np.random.Generator) -> Motion:
    """A phone carried as ``carriage`` says over the whole walk (module docstring).

    Parameters
    ----------
    walk : Walk
        The walker.
    t_s : ndarray
        Uniform sample times, s.
    weinberg_k_m : float
        The walker's true Weinberg gain, m.
    carriage : Carriage
        How the phone rides.
    gain_error : float
        Relative step-length gain error (``imu.step_gain_error``).
    mount_yaw_rad : float
        Yaw of the phone (or the limb) off the walking direction, rad.
    rng : numpy.random.Generator
        Draws the carriage's own randomness (placement, head turns, jostling).
    """
    gait = _body_gait(walk, t_s, weinberg_k_m, carriage, gain_error)
    if carriage.limb_m == 0.0:
        return _held_motion(t_s, gait, carriage, mount_yaw_rad, rng)
    if carriage.sway_damping > 0.0:
        return _bag_motion(t_s, gait, carriage, _placement(carriage, rng), rng)
    return _limb_motion(walk, t_s, gait, carriage, mount_yaw_rad, _placement(carriage, rng))


def minimum_jerk(t_s: np.ndarray, start_s: float, duration_s: float) -> np.ndarray:
    """The minimum-jerk ramp from 0 (before ``start_s``) to 1 (after ``start_s + duration_s``)."""
    tau = np.clip((t_s - start_s) / duration_s, 0.0, 1.0)
    return 10.0 * tau**3 - 15.0 * tau**4 + 6.0 * tau**5


def change_carriage(before: Motion, after: Motion, t_s: np.ndarray, start_s: float, duration_s: float) -> Motion:
    """The phone handled from one carriage to another over ``[start_s, start_s + duration_s]``.

    The attitude turns from ``before``'s to ``after``'s along the shortest rotation between
    them, and the phone's place moves between theirs, both on the minimum-jerk ramp ``w``
    (Flash & Hogan 1985, J. Neurosci. 5:1688: how a hand moves from point to point). With
    ``r = (1 - w) r_before + w r_after`` the acceleration is exactly ``(1 - w) a_before +
    w a_after + (w dr)'' - w dr''`` (``dr = r_after - r_before``): the blend of the two
    motions plus the move's transient.
    """
    dt = t_s[1] - t_s[0]
    w = minimum_jerk(t_s, start_s, duration_s)
    turn = (before.attitude.inv() * after.attitude).as_rotvec()
    attitude = before.attitude * Rotation.from_rotvec(w[:, None] * turn)
    move = after.offset_enu_m - before.offset_enu_m
    acc = ((1.0 - w)[:, None] * before.acc_enu_mps2 + w[:, None] * after.acc_enu_mps2
           + second_difference(w[:, None] * move, dt) - w[:, None] * second_difference(move, dt))
    return Motion(attitude=attitude, acc_enu_mps2=acc, offset_enu_m=before.offset_enu_m + w[:, None] * move)
