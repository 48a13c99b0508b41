"""Smoothers for recorded walks: every position estimated from the whole recording, with its covariance.

A walk processed after the fact is a recording: each epoch's position can use
the observations after it too. The filtered track stays the real-time answer
(``/fusion/<filter>``); the smoothed one is written beside it
(``/fusion/<filter>/smoothed``, docs/schema.md).

Kalman-type filters: the Rauch-Tung-Striebel smoother in its cross-covariance
form. With ``x_k``, ``P_k`` the filtered state and covariance of epoch ``k``,
``x_{k+1}^-``, ``P_{k+1}^-`` the prior the next epoch's correction starts
from, and ``C_{k+1} = Cov(x_k, x_{k+1}^-)``::

    G_k = C_{k+1} (P_{k+1}^-)^-1
    x_k^s = x_k + G_k (x_{k+1}^s - x_{k+1}^-)
    P_k^s = P_k + G_k (P_{k+1}^s - P_{k+1}^-) G_k^T

For an EKF ``C_{k+1} = P_k F_k^T`` and this is filterpy's ``rts_smoother``;
for the sigma-point filters ``C_{k+1}`` is the sigma points' cross-covariance
(filterpy's ``UnscentedKalmanFilter.rts_smoother``). Neither filterpy
smoother fits the range filters, which is why this one is written here: both
rebuild the prior from the filtered state as ``F P F^T + Q`` (or by pushing
sigma points through ``fx``), but between the prediction and the correction
the range filters re-anchor origins by stochastic cloning, take origins from
codes and may replace the motion state by the integrity monitor's
(:mod:`fusion.kalman`). Each filter therefore records the prior it really
corrected and carries ``C`` through those steps (a clone's column of ``C`` is
``C h``; a reset column is 0), and the smoother takes them as recorded.
Headings are differenced on the circle.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fusion.model import HEADING, wrap_angle


@dataclass
class KalmanHistory:
    """What a Kalman-type filter records per epoch for :func:`rts_smooth`.

    Attributes
    ----------
    prior_x, prior_P : list of ndarray
        The prior each epoch's correction started from (after re-anchoring).
    cross : list of ndarray
        ``Cov(x_{k-1}, x_k^-)``: the previous epoch's filtered state with this prior
        (the first epoch's links the initial state and is not used).
    post_x, post_P : list of ndarray
        The filtered state and covariance of each epoch.
    """

    prior_x: list[np.ndarray] = field(default_factory=list)
    prior_P: list[np.ndarray] = field(default_factory=list)
    cross: list[np.ndarray] = field(default_factory=list)
    post_x: list[np.ndarray] = field(default_factory=list)
    post_P: list[np.ndarray] = field(default_factory=list)

    def record_prior(self, x: np.ndarray, P: np.ndarray, cross: np.ndarray) -> None:
        """Store an epoch's prior and its cross-covariance with the previous filtered state (copies)."""
        self.prior_x.append(np.array(x, dtype=np.float64))
        self.prior_P.append(np.array(P, dtype=np.float64))
        self.cross.append(np.array(cross, dtype=np.float64))

    def record_posterior(self, x: np.ndarray, P: np.ndarray) -> None:
        """Store an epoch's filtered state and covariance (copies)."""
        self.post_x.append(np.array(x, dtype=np.float64))
        self.post_P.append(np.array(P, dtype=np.float64))


def _residual(a: np.ndarray, b: np.ndarray, heading: int | None) -> np.ndarray:
    d = a - b
    if heading is not None:
        d[heading] = wrap_angle(d[heading])
    return d


def rts_smooth(history: KalmanHistory, heading: int | None = HEADING) -> tuple[np.ndarray, np.ndarray]:
    """The Rauch-Tung-Striebel smoother over a recorded filter run (module docstring).

    Parameters
    ----------
    history : KalmanHistory
        One prior, cross-covariance and posterior per epoch.
    heading : int or None
        Index of the state's heading (differenced on the circle, the result wrapped to [0, 2 pi)); None: no angle.

    Returns
    -------
    x, P : ndarray
        Smoothed states (N, n) and covariances (N, n, n).
    """
    n = len(history.post_x)
    xs = np.array(history.post_x)
    Ps = np.array(history.post_P)
    for k in range(n - 2, -1, -1):
        prior_P = history.prior_P[k + 1]
        try:
            gain = np.linalg.solve(prior_P, history.cross[k + 1].T).T   # prior_P is symmetric
        except np.linalg.LinAlgError:      # a singular prior (a state set to an exact value)
            gain = history.cross[k + 1] @ np.linalg.pinv(prior_P, hermitian=True)
        xs[k] = xs[k] + gain @ _residual(xs[k + 1], history.prior_x[k + 1], heading)
        P = Ps[k] + gain @ (Ps[k + 1] - prior_P) @ gain.T
        Ps[k] = 0.5 * (P + P.T)
    if heading is not None:
        xs[:, heading] %= 2.0 * np.pi
    return xs, Ps
