"""Positions from steps (eq. 12-13 of docs/method.md §3) and their fixed-rate resampling.

Each step moves the walker by its length along the mean heading over the
step's window: ``x += L sin(psi)``, ``y += L cos(psi)`` (psi clockwise from
north). Averaging over the window cancels most of the device's sway, which
alternates sides from step to step. Speed is step length over step duration.
"""

from __future__ import annotations

import numpy as np

from dtmbnav_core.records import PdrSteps, Track


def mean_heading_over_windows(t_s: np.ndarray, heading_rad: np.ndarray, start_t_s: np.ndarray,
                              end_t_s: np.ndarray) -> np.ndarray:
    """Mean of a continuous (unwrapped) heading over each window [start, end], rad.

    Uses the running integral of the heading, so every window costs O(1).
    """
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (heading_rad[1:] + heading_rad[:-1]) * np.diff(t_s))])
    width = end_t_s - start_t_s
    area = np.interp(end_t_s, t_s, integral) - np.interp(start_t_s, t_s, integral)
    at_end = np.interp(end_t_s, t_s, heading_rad)
    return np.where(width > 0, area / np.where(width > 0, width, 1.0), at_end)


def dead_reckon(t_s: np.ndarray, start_t_s: np.ndarray, step_length_m: np.ndarray,
                heading_rad: np.ndarray) -> PdrSteps:
    """Accumulate steps into positions in the PDR frame (start at the origin).

    Parameters
    ----------
    t_s, start_t_s : ndarray
        End (peak) and start time of each step, s.
    step_length_m : ndarray
        Length of each step, m.
    heading_rad : ndarray
        Relative heading during each step, rad (clockwise).
    """
    x = np.cumsum(step_length_m * np.sin(heading_rad))
    y = np.cumsum(step_length_m * np.cos(heading_rad))
    duration = t_s - start_t_s
    speed = np.where(duration > 0, step_length_m / np.where(duration > 0, duration, 1.0), 0.0)
    return PdrSteps(t_s=np.asarray(t_s, dtype=np.float64), x_m=x, y_m=y,
                    heading_rad=np.mod(heading_rad, 2.0 * np.pi), speed_mps=speed,
                    step_length_m=np.asarray(step_length_m, dtype=np.float64))


def resample_steps(steps: PdrSteps, start_t_s: np.ndarray, t_s: np.ndarray) -> Track:
    """The step-wise PDR at arbitrary times (e.g. a fixed rate), as a Track.

    Within a step the position moves linearly from the previous position to
    the step's end point; between steps (standing) it holds and the speed is 0.
    Before the first step the walker is at the origin with heading 0; the
    heading is that of the step in progress (or the last one).
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    n = len(steps)
    if n == 0:
        zeros = np.zeros_like(t_s)
        return Track(t_s=t_s, x_m=zeros, y_m=zeros.copy(), heading_rad=zeros.copy(), speed_mps=zeros.copy())
    prev_x = np.concatenate([[0.0], steps.x_m[:-1]])
    prev_y = np.concatenate([[0.0], steps.y_m[:-1]])
    # Nodes: (start, previous position) and (end, new position) of every step, in time order.
    node_t = np.column_stack([start_t_s, steps.t_s]).ravel()
    node_x = np.column_stack([prev_x, steps.x_m]).ravel()
    node_y = np.column_stack([prev_y, steps.y_m]).ravel()
    i = np.searchsorted(steps.t_s, t_s, side="left")  # the step that ends next
    in_step = (i < n) & (t_s >= start_t_s[np.minimum(i, n - 1)])
    current = np.where(in_step, i, i - 1)  # the step in progress, else the last one done (-1: none yet)
    heading = np.where(current >= 0, steps.heading_rad[np.maximum(current, 0)], 0.0)
    return Track(t_s=t_s, x_m=np.interp(t_s, node_t, node_x), y_m=np.interp(t_s, node_t, node_y),
                 heading_rad=heading, speed_mps=np.where(in_step, steps.speed_mps[np.maximum(current, 0)], 0.0))
