"""IQ-level range: a scenario's capture generated and streamed through the real receiver.

The transmitter, channel and front end of :class:`sim.rf.CaptureGenerator`
produce the capture chunk by chunk; each chunk is quantised to the scenario's
sample format and decoded back, as a file would be, and fed to
:class:`receiver.pipeline.Receiver`; the receiver's frames become the
:class:`~dtmbnav_core.records.RangeSeries` the fusion consumes through
:func:`receiver.observables.ranges_from_frames`, batch by batch, so nothing
sample-sized is kept (memory stays flat over a whole walk).

The receiver measures f_s while the walker stands at the start
(docs/method.md §2, eq. 9): its static window is the scenario's
``walk.start_still_s`` less the same guard the observation-level model uses
(:class:`sim.obs_range.ObsRangeConfig`), so both levels calibrate on the same
stretch.

This is the range source of ``dtmbnav evaluate --level iq``
(:func:`iq_range_source`: the SI-carrier range and, from the path tracker,
each tower's first-path range and the tower differences, as ``dtmbnav fuse``
reads them from a receiver file) and of the demo.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from dtmbnav_core.iqformat import decode, get_format
from dtmbnav_core.records import FrameBatch, Observations, PathBatch, PathFlag, RangeSeries, Track
from fusion.model import Geometry
from receiver.observables import observations_from_receiver, ranges_from_frames
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream
from sim.obs_range import ObsRangeConfig
from sim.rf import CaptureGenerator
from sim.scenario import Scenario

#: Samples generated and received per step of the stream.
CHUNK_SAMPLES = 1 << 20
#: Shortest static window the receiver is given, s.
MIN_STATIC_WINDOW_S = 0.5


class NoSignal(RuntimeError):
    """The receiver found no DTMB signal in a simulated capture: no lock, no frame (a weak enough signal)."""


def simulated_receiver_config(scenario: Scenario) -> ReceiverConfig:
    """Receiver settings for a simulated capture: the static window is the walker's standstill less the guard."""
    guard_s = ObsRangeConfig().calibration_guard_s
    return ReceiverConfig(static_window_s=max(scenario.walk.start_still_s - guard_s, MIN_STATIC_WINDOW_S))


def generated_chunks(generator: CaptureGenerator, chunk_samples: int = CHUNK_SAMPLES,
                     jobs: int = 1) -> Iterator[np.ndarray]:
    """The generator's capture, quantised to its sample format and decoded back (what a file would give).

    ``jobs`` threads generate chunks ahead of the consumer (the same samples for any ``jobs``).
    """
    fmt = get_format(generator.sample_format)
    return (decode(rails, fmt) for rails in generator.quantised_chunks(chunk_samples, jobs=jobs))


def iq_frame_batches(scenario: Scenario, track: Track, seconds: float | None = None,
                     start_s: float = 0.0) -> Iterator[FrameBatch]:
    """Receiver frame batches of the scenario's capture (or a segment of it), as they complete.

    Parameters
    ----------
    scenario : Scenario
    track : Track
        The walk's true trajectory (``simulate_walk(scenario).track``).
    seconds, start_s : float
        Segment of the capture, s (:class:`sim.rf.CaptureGenerator`); default the whole walk.
    """
    generator = CaptureGenerator(scenario, track, seconds=seconds, start_s=start_s)
    yield from receive_stream(generated_chunks(generator), generator.sample_rate_hz, generator.carrier_hz,
                              simulated_receiver_config(scenario))


def iq_ranges(scenario: Scenario, track: Track, seconds: float | None = None) -> RangeSeries:
    """The receiver's range series of the scenario's capture (its first ``seconds``, default the whole walk).

    Raises
    ------
    NoSignal
        When the receiver finds no DTMB signal in the capture.
    """
    parts = [ranges_from_frames(batch.columns()) for batch in iq_frame_batches(scenario, track, seconds)]
    if not parts:
        raise NoSignal(f"{scenario.name} (seed {scenario.seed}): the receiver found no DTMB signal in the "
                       "simulated capture")
    return RangeSeries(**{name: np.concatenate([getattr(p, name) for p in parts])
                          for name in RangeSeries.__dataclass_fields__})


def iq_observations(scenario: Scenario, track: Track, seconds: float | None = None) -> Observations:
    """The receiver's SI-carrier range and path tracker output for the scenario's capture.

    The path rows kept are those of each tower's first path (what
    :func:`receiver.observables.paths_from_frames` reads), batch by batch: a whole
    walk's rows of every tracked path are not held.

    Raises
    ------
    NoSignal
        When the receiver finds no DTMB signal in the capture.
    """
    generator = CaptureGenerator(scenario, track, seconds=seconds)
    receiver = Receiver(generator.sample_rate_hz, generator.carrier_hz, simulated_receiver_config(scenario))
    frames: list[FrameBatch] = []
    rows: list[PathBatch] = []

    def keep_first_paths() -> None:
        batch = receiver.pop_paths()
        rows.append(batch.select((batch.flags & PathFlag.FIRST_PATH) > 0))

    for chunk in generated_chunks(generator):
        frames += receiver.process(chunk)
        keep_first_paths()
    frames += receiver.finish()
    keep_first_paths()
    if not frames:
        raise NoSignal(f"{scenario.name} (seed {scenario.seed}): the receiver found no DTMB signal in the "
                       "simulated capture")
    columns = FrameBatch.concatenate(frames).columns()
    if not receiver.config.track_paths:
        return Observations(ranges_from_frames(columns))
    path_rows = PathBatch.concatenate(rows).columns()
    # The tower table as a user has it: positions (heights above the antenna) and the network's transmit delays;
    # the towers are put in its order from where the walk starts (a fix metres off would do as well).
    antenna_m = scenario.channel.antenna_height_m
    tower, *others = [(site.x_m, site.y_m, site.height_m - antenna_m) for site in scenario.sites]
    geometry = Geometry(float(track.x_m[0]), float(track.y_m[0]), *tower, other_towers=tuple(others))
    transmit_delays = [site.transmit_delay_s for site in scenario.sites]
    return observations_from_receiver(columns, path_rows, receiver.attributes(), len(scenario.sites),
                                      transmit_delays_s=transmit_delays,
                                      start_ranges_m=geometry.start_ranges_m())


def iq_range_source(scenario: Scenario, truth: Track) -> Observations:
    """IQ-level receiver range and paths of the whole walk (a :data:`dtmbnav.evaluation.evaluate.RangeSource`)."""
    return iq_observations(scenario, truth)
