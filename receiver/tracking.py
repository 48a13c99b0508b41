"""Frame-timing tracking and loss-of-lock detection.

The frame grid drifts with the sampling-rate offset and the receiver's motion.
A second-order loop (a phase-locked-loop of the frame timing) follows it: per
frame it compares the measured frame timing (window start plus the channel
taps' power centroid) with its prediction and corrects both the timing and
the frame period. The period it settles on gives the sampling offset
``eta = period / nominal - 1`` (per frame, from the period each frame was
predicted with) used by the CFO estimator (eq. 5-6). The
centroid moves continuously when an echo appears or fades, so an echo shifts
the timing smoothly instead of making it jump between paths.

Frames are processed in batches: window starts are predicted for a whole
batch from the loop state, then the loop runs over the batch's measurements
(a tiny numba kernel). Batches are a fixed number of frames, so the result
does not depend on how the input was chunked.

Loss of lock: ``loss_frames`` consecutive frames whose header metric is below
``threshold``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def timing_loop_kernel(measured: np.ndarray, valid: np.ndarray, tau: float, period: float, alpha: float,
                       beta: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Run the timing loop over a batch of frames.

    Parameters
    ----------
    measured : (B,) float64
        Measured frame timing, stream samples.
    valid : (B,) bool
        Frames whose measurement is trusted (others coast on the prediction).
    tau : float
        Predicted timing of the batch's first frame.
    period : float
        Current frame-period estimate, samples.
    alpha, beta : float
        Timing and period gains.

    Returns
    -------
    smoothed : (B,) float64
        Filtered timing of each frame.
    periods : (B,) float64
        Period estimate each frame was predicted with (before its update).
    tau, period : float
        Prediction for the next frame and the updated period.
    """
    smoothed = np.empty(measured.shape[0])
    periods = np.empty(measured.shape[0])
    for b in range(measured.shape[0]):
        periods[b] = period
        err = measured[b] - tau if valid[b] else 0.0
        smoothed[b] = tau + alpha * err
        period += beta * err
        tau = smoothed[b] + period
    return smoothed, periods, tau, period


def timing_loop_reference(measured: np.ndarray, valid: np.ndarray, tau: float, period: float, alpha: float,
                          beta: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Plain-Python :func:`timing_loop_kernel` (same arithmetic)."""
    smoothed = np.empty(len(measured))
    periods = np.empty(len(measured))
    for b, (m, ok) in enumerate(zip(measured, valid)):
        periods[b] = period
        err = m - tau if ok else 0.0
        smoothed[b] = tau + alpha * err
        period += beta * err
        tau = smoothed[b] + period
    return smoothed, periods, tau, period


@dataclass
class FrameTracker:
    """State of the frame-timing loop while locked.

    Attributes
    ----------
    tau : float
        Predicted timing (stream sample) of the next frame to process.
    period : float
        Frame period, stream samples.
    nominal_period : int
        Frame length of the mode, samples.
    alpha, beta : float
        Loop gains.
    """

    tau: float
    period: float
    nominal_period: int
    alpha: float = 0.05
    beta: float = 0.001

    def predict(self, count: int) -> np.ndarray:
        """Predicted timing of the next ``count`` frames."""
        return self.tau + self.period * np.arange(count)

    def update(self, measured: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed a batch's measurements; return the smoothed timings and each frame's period estimate."""
        smoothed, periods, self.tau, self.period = timing_loop_kernel(
            measured.astype(np.float64), valid, float(self.tau), float(self.period), self.alpha, self.beta)
        return smoothed, periods


@dataclass
class LockMonitor:
    """Counts consecutive weak frames and declares loss of lock.

    Attributes
    ----------
    threshold : float
        Header metric below which a frame is weak.
    loss_frames : int
        Consecutive weak frames that mean the lock is lost.
    run : int
        Current run of weak frames (carried across batches).
    """

    threshold: float
    loss_frames: int
    run: int = 0

    def check(self, metric: np.ndarray) -> int | None:
        """Position in ``metric`` of the first frame of a run that loses lock, or None.

        Updates the carried run length; the run may have started in an
        earlier batch, in which case the returned position is 0.
        """
        weak = metric < self.threshold
        # Run length ending at each frame, counting the run carried in.
        strong_at = np.where(~weak, np.arange(len(weak)), -1 - self.run)
        run = np.arange(len(weak)) - np.maximum.accumulate(strong_at)
        lost = np.flatnonzero(run >= self.loss_frames)
        if lost.size:
            self.run = 0
            return max(int(lost[0]) - self.loss_frames + 1, 0)
        self.run = int(run[-1]) if len(run) else self.run
        return None
