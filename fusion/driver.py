"""One loop that drives any fusion filter over the epochs.

Every filter (the particle filter and the Kalman family) has the same face,
as in filterpy: ``predict(control)`` with the PDR's step as control input,
``update(observation)`` with an :class:`~fusion.model.EpochObservation` that
may lack the range, ``estimate()`` returning the state vector and
``position_covariance_m2()`` the east/north covariance it states for it. For
a recorded walk it also smooths (``record_history()`` before the run,
``smoothed()`` after it: :mod:`fusion.smoothing`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from dtmbnav_core.records import FusedTrack, Track
from fusion.model import HEADING, SPEED, STATE_SIZE, EpochObservation, StepControl, X, Y
from fusion.observations import FilterEpochs


class FusionFilter(Protocol):
    """What :func:`drive_filter` needs from a filter."""

    def predict(self, control: StepControl) -> None: ...

    def update(self, observation: EpochObservation) -> None: ...

    def estimate(self) -> np.ndarray: ...

    def position_covariance_m2(self) -> np.ndarray: ...

    def record_history(self) -> None: ...

    def smoothed(self) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass
class FilterRun:
    """A filter's run over a recording.

    Attributes
    ----------
    track : FusedTrack
        The filtered track (each row from the epochs up to it: the real-time answer) with its stated error.
    smoothed : FusedTrack or None
        The smoothed track (each row from the whole recording) with its error; None where not asked for.
    """

    track: FusedTrack
    smoothed: FusedTrack | None = None


def step_track(epochs: FilterEpochs, states: np.ndarray, covariances_m2: np.ndarray) -> FusedTrack:
    """The rows of the step epochs (standstills give none) as a track."""
    step = epochs.is_step
    states, covariances_m2 = states[step], covariances_m2[step]
    track = Track(t_s=np.asarray(epochs.t_s, dtype=np.float64)[step], x_m=states[:, X], y_m=states[:, Y],
                  heading_rad=states[:, HEADING] % (2.0 * np.pi), speed_mps=states[:, SPEED])
    return FusedTrack.from_track(track, covariances_m2)


def step_filter(fusion_filter: FusionFilter, epochs: FilterEpochs, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Predict and update with epoch ``n``; the state (its first ``STATE_SIZE`` entries) and east/north covariance."""
    fusion_filter.predict(epochs.control(n))
    fusion_filter.update(epochs.observation(n))
    return fusion_filter.estimate()[:STATE_SIZE], fusion_filter.position_covariance_m2()


def drive_filter(fusion_filter: FusionFilter, epochs: FilterEpochs, smooth: bool = False) -> FilterRun:
    """Predict, update and read the estimate and its covariance at every epoch; one track row per step epoch.

    The filter has been initialised (state at P0) by the caller. Epochs
    without a step (standstills, :mod:`fusion.observations`) are run but
    give no row, so a track has one row per PDR step. With ``smooth`` the
    filter records its run and smooths it afterwards.
    """
    if smooth:
        fusion_filter.record_history()
    states = np.empty((len(epochs), STATE_SIZE))
    covariances = np.empty((len(epochs), 2, 2))
    for n in range(len(epochs)):
        states[n], covariances[n] = step_filter(fusion_filter, epochs, n)
    run = FilterRun(step_track(epochs, states, covariances))
    if smooth:
        smoothed_states, smoothed_covariances = fusion_filter.smoothed()
        run.smoothed = step_track(epochs, smoothed_states[:, :STATE_SIZE], smoothed_covariances)
    return run


def run_filter(fusion_filter: FusionFilter, epochs: FilterEpochs) -> FusedTrack:
    """:func:`drive_filter` without smoothing: the filtered track."""
    return drive_filter(fusion_filter, epochs).track
