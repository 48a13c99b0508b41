"""One loop that drives any fusion filter over the epochs.

Every filter (the particle filter and the Kalman family) has the same face,
as in filterpy: ``predict(control)`` with the PDR's step as control input,
``update(observation)`` with an :class:`~fusion.model.EpochObservation` that
may lack the range, and ``estimate()`` returning the state vector.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from dtmbnav_core.records import Track
from fusion.model import HEADING, SPEED, STATE_SIZE, EpochObservation, StepControl, X, Y
from fusion.observations import FilterEpochs


class FusionFilter(Protocol):
    """What :func:`run_filter` needs from a filter."""

    def predict(self, control: StepControl) -> None: ...

    def update(self, observation: EpochObservation) -> None: ...

    def estimate(self) -> np.ndarray: ...


def run_filter(fusion_filter: FusionFilter, epochs: FilterEpochs) -> Track:
    """Predict, update and read the estimate at every epoch; one track row per step epoch.

    The filter has been initialised (state at P0) by the caller. Epochs
    without a step (standstills, :mod:`fusion.observations`) are run but
    give no row, so a track has one row per PDR step.
    """
    states = np.empty((len(epochs), STATE_SIZE))
    for n in range(len(epochs)):
        fusion_filter.predict(epochs.control(n))
        fusion_filter.update(epochs.observation(n))
        states[n] = fusion_filter.estimate()[:STATE_SIZE]
    step = epochs.is_step
    states = states[step]
    return Track(t_s=np.asarray(epochs.t_s, dtype=np.float64)[step], x_m=states[:, X], y_m=states[:, Y],
                 heading_rad=states[:, HEADING] % (2.0 * np.pi), speed_mps=states[:, SPEED])
