"""The walker's direction from the earth-frame acceleration, and the phone-to-walk offset (docs/method.md §3).

A phone in a trouser pocket or in a hand swinging at the side does not point
where its carrier walks: its yaw swings over every stride, and its forward
axis may stand near vertical, where the heading of its horizontal projection
means nothing. Two estimates are combined, as Kourogi & Kurata's
walking-locomotion PDR does (the gyro for short-term changes, the
acceleration pattern of walking for the direction of travel):

- the phone's yaw, the integral of the attitude's rotation about the vertical
  (defined whatever way the phone points, and gyro-accurate over short times);
- the walking direction, the principal axis of the horizontal acceleration
  over a stride (two steps): the specific force is rotated into the earth
  frame with the AHRS attitude and its mean over the stride (gravity, and
  whatever tilt error the attitude has) is removed. The body's forward surge
  and a limb's swing lie along the walking direction, the sway across it at
  a smaller amplitude, so the axis of largest variance is the walking line.
  This is the PCA of Combettes & Renaudin (2015, "Comparison of misalignment
  estimation techniques between handheld device and walking directions",
  IPIN) and of Deng et al. (2015, "Heading estimation for indoor pedestrian
  navigation using a smartphone in the pocket", Sensors 15:21518), whose
  RMPCA likewise takes it in the earth frame after rotating the phone's
  readings with its attitude.

The offset, walking direction minus yaw, is constant while the carriage is
(the phone rides in the same place), so it is taken per stride and smoothed
by a running median over strides; the heading the PDR integrates is the yaw
plus that smoothed offset. The principal axis leaves forward and backward
undecided; the heading only uses changes of the offset, unwrapped from stride
to stride with a period of pi, so that choice never reaches it (the reported
offset is the one within 90 deg of the phone's yaw).

A change of carriage (hand to pocket, say) is found where the direction of
gravity in the sensor frame, averaged over a stride, moves by more than
``change_deg`` between the strides before and after a step boundary (a stride
average is steady within one carriage, since the limb's swing repeats each
stride). The attitude is started afresh there, from the stride-mean specific
force once the phone rides in its new place: a quick pocketing can saturate
a phone's gyro, and a log whose carriage jumps cannot be followed by
integration. The offset is estimated anew for the new carriage and the
heading carried across the carriage change without a turn: the walker is
taken not to turn while moving the phone (a turn made then is lost).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from fusion.pdr.attitude import madgwick_attitude, rest_reference
from fusion.pdr.dead_reckoning import mean_heading_over_windows

#: Variance ratio (major / minor axis) below which a stride's horizontal acceleration has no usable axis.
MIN_LINEARITY = 1.5


@dataclass(frozen=True)
class WalkingConfig:
    """Settings of the walking-direction estimate.

    Attributes
    ----------
    change_deg : float
        Move of the stride-mean gravity direction in the sensor frame that marks a change of carriage, deg.
    smoothing_steps : int
        Width of the running median that smooths the offset, steps (odd).
    swing_deg : float
        ``heading_source="auto"`` integrates the walking direction when the
        attitude's median swing over a stride exceeds this (a pocket or a
        swinging hand), deg.
    """

    change_deg: float = 30.0
    smoothing_steps: int = 21
    swing_deg: float = 15.0


@dataclass(frozen=True)
class WalkingDirection:
    """Per-step walking direction and the phone-to-walk offset.

    Attributes
    ----------
    heading_rad : ndarray
        Heading of each step, phone yaw plus the smoothed offset, relative to the
        phone's yaw at rest before the walk, clockwise, unwrapped, rad.
    offset_rad : ndarray
        Smoothed phone-to-walk offset (walking direction minus phone yaw), in (-pi, pi], rad.
    carriage_change : ndarray of bool
        True at the first step after a change of carriage.
    swing_rad : ndarray
        Largest rotation of the attitude from its value mid-stride, over each step's stride, rad.
    usable : ndarray of bool
        Whether the step's stride estimated the offset (a clear axis, clear of a change): the
        running median spans ``smoothing_steps`` of these.
    """

    heading_rad: np.ndarray
    offset_rad: np.ndarray
    carriage_change: np.ndarray
    swing_rad: np.ndarray
    usable: np.ndarray


def principal_axis(horizontal_mps2: np.ndarray) -> tuple[float, float]:
    """Axis of largest variance of a horizontal acceleration, and how clearly it stands out.

    Parameters
    ----------
    horizontal_mps2 : ndarray, shape (N, 2)
        North and east components, m/s^2.

    Returns
    -------
    angle_rad : float
        Direction of the axis, clockwise from north, in [0, pi) (forward and backward alike), rad.
    linearity : float
        Variance along the axis over the variance across it (inf for a perfectly straight line).
    """
    centred = horizontal_mps2 - horizontal_mps2.mean(axis=0)
    variances, axes = np.linalg.eigh(centred.T @ centred / len(centred))
    major = axes[:, 1]
    linearity = variances[1] / variances[0] if variances[0] > 0 else np.inf
    return float(np.mod(np.arctan2(major[1], major[0]), np.pi)), float(linearity)


def stride_windows(t_s: np.ndarray, start_t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (s) of the stride around each step: the step and its neighbour.

    The neighbour is the step before when it ends where this one starts (the
    walker did not stop in between), else the step after when that one
    continues this one, else none (a lone step is its own window).
    """
    follows = np.concatenate([[False], start_t_s[1:] <= t_s[:-1] + 1e-6])  # step i continues step i-1
    continued = np.concatenate([follows[1:], [False]])
    start = np.where(follows, np.concatenate([[0.0], start_t_s[:-1]]), start_t_s)
    end = np.where(~follows & continued, np.concatenate([t_s[1:], [0.0]]), t_s)
    return start, end


def _index_windows(t_s: np.ndarray, start_t_s: np.ndarray, end_t_s: np.ndarray) -> list[slice]:
    first = np.searchsorted(t_s, start_t_s, side="left")
    last = np.maximum(np.searchsorted(t_s, end_t_s, side="right"), first + 2)
    return [slice(a, b) for a, b in zip(first, last)]


def _angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cosine, -1.0, 1.0))


def carriage_changes(t_s: np.ndarray, acc_mps2: np.ndarray, windows: list[slice], change_rad: float) -> np.ndarray:
    """Steps that begin a new carriage, and the sample where each change happened.

    Returns
    -------
    ndarray, shape (K, 2), int
        For each change, the index of the first step after it and the sample
        index (into ``t_s``) at which the attitude is restarted.
    """
    n = len(windows)
    gravity = np.array([acc_mps2[w].mean(axis=0) for w in windows])
    moved = np.zeros(n)
    for i in range(1, n):
        # The stride that ends before step i against the one that starts with it.
        moved[i] = _angle_between(gravity[i - 1], gravity[min(i + 1, n - 1)])
    changes = []
    for i in np.flatnonzero(moved > change_rad):
        # Strides that straddle the change move less than the two either side of it: keep the peak.
        if moved[i] >= moved[max(i - 2, 0):i + 3].max():
            changes.append((i, _change_sample(acc_mps2, windows[i - 1].start, windows[min(i + 1, n - 1)].stop,
                                              windows[i].stop - windows[i].start)))
    return np.array(changes, dtype=int).reshape(-1, 2)


def _change_sample(acc_mps2: np.ndarray, first: int, stop: int, width: int) -> int:
    """The sample in [first, stop) where the mean specific force over ``width`` samples before and after differs most."""
    total = np.concatenate([np.zeros((1, 3)), np.cumsum(acc_mps2, axis=0)])
    k = np.arange(first + width, max(stop - width, first + width + 1))
    k = k[k + width <= len(acc_mps2)]
    before, after = total[k] - total[k - width], total[k + width] - total[k]
    return int(k[np.argmax(_angle_between(before, after))]) if k.size else first


def vertical_yaw(attitude: Rotation, restarts: np.ndarray) -> np.ndarray:
    """Yaw of the phone: the attitude's rotation about the vertical summed sample by sample, clockwise, rad.

    A rotation about a horizontal axis (a limb's swing) adds nothing to it,
    whatever way the phone lies. Across a restart of the attitude the
    increment is unknown and taken as zero.
    """
    increments = -(attitude[1:] * attitude[:-1].inv()).as_rotvec()[:, 2]  # about up, counter-clockwise
    increments[restarts[restarts > 0] - 1] = 0.0
    return np.concatenate([[0.0], np.cumsum(increments)])


def segment_attitude(first_attitude: Rotation, gyro_radps: np.ndarray, acc_mps2: np.ndarray, rate_hz: float,
                     gain: float, restarts: np.ndarray, start_width: int) -> Rotation:
    """The attitude restarted at each sample of ``restarts`` (the first segment's is ``first_attitude``).

    Each later segment starts from the mean specific force over its first
    ``start_width`` samples, a stride (gravity, where a walking instant would
    add the swing's acceleration), and runs on the gyro and accelerometer
    alone: the heading is carried across the change, so the segment's yaw
    need not be north's, and a magnetic filter started off north would spend
    the segment pulling its yaw round at its slow rate, which would read as a turn.
    """
    pieces = [first_attitude[:restarts[0]] if restarts.size else first_attitude]
    bounds = np.concatenate([restarts, [len(acc_mps2)]])
    for a, b in zip(bounds[:-1], bounds[1:]):
        initial = (acc_mps2[a:min(a + start_width, b)].mean(axis=0), None)
        pieces.append(madgwick_attitude(gyro_radps[a:b], acc_mps2[a:b], None, rate_hz, gain, initial))
    return Rotation.concatenate(pieces)


def _smoothed_offset(raw_rad: np.ndarray, usable: np.ndarray, width: int) -> np.ndarray:
    """Running median of a per-step offset known modulo pi, unwrapped with that period; NaN where none is usable."""
    out = np.full(len(raw_rad), np.nan)
    if not usable.any():
        return out
    index = np.flatnonzero(usable)
    unwrapped = np.unwrap(raw_rad[index], period=np.pi)
    # The window shrinks at the ends (NaN padding) rather than repeating the first and last strides,
    # whose swing is still building up or dying away.
    half = width // 2
    padded = np.concatenate([np.full(half, np.nan), unwrapped, np.full(half, np.nan)])
    smoothed = np.nanmedian(np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1), axis=1)
    return np.interp(np.arange(len(raw_rad)), index, smoothed)


def walking_direction(t_s: np.ndarray, acc_mps2: np.ndarray, gyro_radps: np.ndarray,
                      attitude: Rotation, still: np.ndarray, step_t_s: np.ndarray, step_start_t_s: np.ndarray,
                      gain: float, config: WalkingConfig) -> WalkingDirection:
    """Per-step walking direction, phone-to-walk offset and carriage changes (module docstring).

    Parameters
    ----------
    t_s : ndarray
        Uniform sample times, s.
    acc_mps2, gyro_radps : ndarray, shape (N, 3)
        Specific force (m/s^2) and bias-corrected angular rate (rad/s), sensor frame.
    attitude : Rotation
        The AHRS attitude of the whole record (:func:`~fusion.pdr.attitude.madgwick_attitude`).
    still : ndarray of bool
        Rest before the walk, whose yaw is the heading's reference.
    step_t_s, step_start_t_s : ndarray
        End (peak) and start of each detected step, s.
    gain : float
        Madgwick ``beta`` for the attitude restarted after a change of carriage.
    config : WalkingConfig
    """
    n = len(step_t_s)
    stride_start, stride_end = stride_windows(step_t_s, step_start_t_s)
    windows = _index_windows(t_s, stride_start, stride_end)
    changes = carriage_changes(t_s, acc_mps2, windows, np.radians(config.change_deg))
    restarts = changes[:, 1]
    rate_hz = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    width = int(np.median([w.stop - w.start for w in windows])) if n else 1
    attitude = segment_attitude(attitude, gyro_radps, acc_mps2, rate_hz, gain, restarts, width)
    yaw = vertical_yaw(attitude, restarts)
    yaw -= rest_reference(t_s, yaw, still)
    earth = attitude.apply(acc_mps2)
    horizontal = np.column_stack([earth[:, 0], -earth[:, 1]])  # earth x north, y west -> north, east
    axis, linearity = np.array([principal_axis(horizontal[w]) for w in windows]).reshape(-1, 2).T
    stride_yaw = np.array([yaw[w].mean() for w in windows])
    # The heading moves with the yaw over each step's own window, as the phone's does (a stride would lag a turn).
    step_yaw = mean_heading_over_windows(t_s, yaw, step_start_t_s, step_t_s)
    swing = np.array([(attitude[w] * attitude[(w.start + w.stop) // 2].inv()).magnitude().max() for w in windows])
    raw = np.mod(axis - stride_yaw, np.pi)
    # A stride near a change mixes the two carriages (and the change's time is known to a step or so):
    # it neither estimates the offset nor moves the heading.
    clean = np.array([all(w.stop <= r - width // 2 or w.start >= r + width // 2 for r in restarts) for w in windows],
                     dtype=bool).reshape(n)
    segment = np.searchsorted(changes[:, 0], np.arange(n), side="right")
    offset = np.zeros(n)
    heading = np.full(n, np.nan)
    for k in range(len(changes) + 1):
        members = np.flatnonzero((segment == k) & clean)
        if members.size == 0:
            continue
        smoothed = _smoothed_offset(raw[members], linearity[members] >= MIN_LINEARITY, config.smoothing_steps)
        # No usable stride: the yaw alone, with the offset it had (nothing better is known).
        smoothed = np.nan_to_num(smoothed, nan=0.0)
        if np.median(swing[members]) < np.radians(config.swing_deg):
            # A phone held steady points along the walk: its yaw is the walking direction up to a constant,
            # where the acceleration's axis may hop between the surge and a comparable sway.
            smoothed = np.full(members.size, np.median(smoothed))
        # The forward sense within 90 deg of the yaw; the heading depends only on the offset's changes.
        offset[members] = smoothed - np.pi * np.round(smoothed[0] / np.pi)
        along = step_yaw[members] + smoothed
        # Carried across a change without a turn; the first segment starts from the yaw at its first step.
        before = heading[:members[0]][np.isfinite(heading[:members[0]])]
        heading[members] = along - along[0] + (before[-1] if before.size else step_yaw[members[0]])
    # Steps by a change hold the heading (and offset) of the step before them.
    for i in np.flatnonzero(~clean):
        heading[i], offset[i] = (heading[i - 1], offset[i - 1]) if i > 0 else (step_yaw[i], 0.0)
    carriage_change = np.zeros(n, dtype=bool)
    carriage_change[changes[:, 0]] = True
    return WalkingDirection(heading_rad=heading, offset_rad=np.angle(np.exp(1j * offset)),
                            carriage_change=carriage_change, swing_rad=swing,
                            usable=clean & (linearity >= MIN_LINEARITY))
