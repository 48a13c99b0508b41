"""Simulate a scenario: the IQ capture and the truth file.

:func:`simulate` writes into ``out_dir``:

- the capture ``<scenario name>.sigmf-meta/.sigmf-data`` (or raw
  ``<name>.<fmt>`` + ``.json`` sidecar), streamed chunk by chunk from
  :class:`sim.rf.CaptureGenerator` (flat memory);
- ``truth.h5`` (written atomically): the walk, IMU and GNSS groups of
  ``sim.walk_io.write_walk_groups`` (whole scenario, times from the scenario
  start) and ``/truth/frames`` (:class:`sim.rf.FrameTruth` of the captured
  segment) with the attributes ``pn_mode``, ``si_index``,
  ``sample_rate_hz``, ``carrier_hz``, ``seed``, ``sample_format``,
  ``capture_start_s``, ``num_samples`` and ``scenario`` (TOML text), and
  ``/truth/paths`` (:func:`sim.path_truth.path_truth`: every tower's every
  path at 100 Hz). A scenario whose front end drops samples
  (``receiver.drops_per_minute`` > 0) also gets ``/truth/drops``
  (:meth:`sim.rf.CaptureGenerator.drops`, columns
  ``dtmbnav_core.schema.DROP_COLUMNS``, no rows when none fell in the
  segment); ``num_samples`` is then the samples in the file and
  ``receiver_num_samples`` those the receiver's clock spans;
- ``towers.csv``: every tower as latitude, longitude and height about the
  scenario's ``[origin]`` (:mod:`sim.towers_csv`);
- with ``phone_log``, the walk's IMU and GNSS as that phone app logs them,
  stamped on a phone clock (:mod:`sim.phone_log_writer`): the log starts at
  the scenario's time 0, whose true UTC is :data:`SIM_START_UTC_NS`, like
  the capture's ``core:datetime`` (``SIM_START_UTC_NS`` + ``capture_start_s``).

Segments: ``start_s``/``seconds`` select a window of the scenario. The
capture's first sample is sample ``round(start_s * fs)`` of the full
scenario's capture (bit-identical to it) and ``/truth/frames/t_s`` is seconds
since that sample on the receiver clock. ``capture_start_s`` (= that sample
index / fs) converts to scenario time: scenario time ~ ``t_s +
capture_start_s`` (to the receiver clock's time error, microseconds).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from dtmbnav_core import schema
from dtmbnav_core.h5io import atomic_h5, write_columns
from dtmbnav_core.phone import PhoneClock
from sim.capture_writer import CaptureWriter
from sim.gnss import simulate_gnss
from sim.imu import simulate_imu
from sim.path_truth import path_truth, path_truth_attributes
from sim.phone_log_writer import check_format, write_phone_log
from sim.rf import CaptureGenerator
from sim.scenario import Scenario, scenario_to_toml
from sim.towers_csv import write_towers_csv
from sim.walk import simulate_walk
from sim.walk_io import write_walk_groups

#: UTC time stamped on the scenario's first sample (2026-01-01T00:00:00Z), ns since the epoch:
#: a fixed value so that the same scenario and seed give the same bytes.
SIM_START_UTC_NS = 1_767_225_600 * 1_000_000_000

#: Samples per generated chunk (about 0.13 s at 7.56 Msps).
DEFAULT_CHUNK_SAMPLES = 1 << 20


@dataclass(frozen=True)
class SimulationResult:
    """Files written by :func:`simulate`.

    Attributes
    ----------
    capture_path : Path or None
        The capture (SigMF meta or raw data file); None with ``with_iq=False``.
    truth_path : Path
        ``truth.h5``.
    towers_path : Path
        ``towers.csv``.
    phone_log_path : Path or None
        The phone log (GnssLogger's file, Sensor Logger's folder); None without ``phone_log``.
    """

    capture_path: Path | None
    truth_path: Path
    towers_path: Path
    phone_log_path: Path | None = None


def simulate(scenario: Scenario, out_dir: str | Path, *, seconds: float | None = None, start_s: float = 0.0,
             sample_rate_hz: float | None = None, sample_format: str | None = None, pn_mode: str | None = None,
             seed: int | None = None, container: str = "sigmf", with_iq: bool = True,
             chunk_samples: int = DEFAULT_CHUNK_SAMPLES, progress: bool = False,
             weinberg_k_m: float | None = None, jobs: int = 1, phone_log: str | None = None,
             phone_clock: PhoneClock = PhoneClock()) -> SimulationResult:
    """Write the capture and ``truth.h5`` of a scenario (module docstring).

    Parameters
    ----------
    scenario : Scenario
    out_dir : path
        Created if missing.
    seconds, start_s : float
        Segment length (default: to the end of the walk) and start, s.
    sample_rate_hz, sample_format, pn_mode, seed : optional
        Override the scenario's values (the seed also replaces ``scenario.seed``
        for the walk, IMU and GNSS).
    container : str
        ``"sigmf"`` or ``"raw"`` (raw file + JSON sidecar).
    with_iq : bool
        Write the capture (False: truth file only).
    chunk_samples : int
        Generation chunk; the output does not depend on it.
    progress : bool
        Show a progress bar on stderr.
    weinberg_k_m : float, optional
        The walker's calibrated Weinberg gain, stored with ``/imu`` for the
        PDR (see :func:`sim.walk_io.write_walk_groups`).
    jobs : int
        Threads generating the capture; the bytes do not depend on it.
    phone_log : str, optional
        Also write the phone's log in this app's format (``"gnsslogger"`` or
        ``"sensorlogger"``, :func:`sim.phone_log_writer.write_phone_log`).
    phone_clock : PhoneClock
        The phone's clock against the capture's (offset, drift) for ``phone_log``.
    """
    if phone_log is not None:
        check_format(phone_log)
    if seed is not None:
        scenario = scenario.replace(seed=int(seed))
    walk = simulate_walk(scenario)
    imu = simulate_imu(scenario, walk)
    gnss = simulate_gnss(scenario, walk)
    generator = CaptureGenerator(scenario, walk.track, seconds=seconds, start_s=start_s,
                                 sample_rate_hz=sample_rate_hz, sample_format=sample_format, pn_mode=pn_mode)
    # Only now, with every value checked (the front end's keys by the generator), does anything get written.
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    capture_start_s = generator.first_sample / generator.sample_rate_hz

    capture_path = None
    if with_iq:
        writer = CaptureWriter(
            out_dir / scenario.name, container, generator.sample_format, generator.sample_rate_hz,
            generator.center_hz, start_utc_unix_ns=SIM_START_UTC_NS + round(capture_start_s * 1e9),
            description=scenario.description,
            channel_hz=generator.carrier_hz if generator.tuning_offset_hz != 0.0 else None,
            project={"scenario": scenario.name, "seed": generator.seed, "pn_mode": generator.frame_config.pn_mode.name,
                     "capture_start_s": capture_start_s})
        with writer, tqdm(total=generator.capture_samples, unit="S", unit_scale=True, disable=not progress,
                          file=sys.stderr) as bar:
            for rails in generator.quantised_chunks(chunk_samples, jobs=jobs):
                writer.write(rails)
                bar.update(rails.size // 2)
        capture_path = writer.capture_path

    truth_path = out_dir / "truth.h5"
    frames_attrs = {
        "pn_mode": generator.frame_config.pn_mode.name, "si_index": scenario.tower.si_index,
        "sample_rate_hz": generator.sample_rate_hz, "carrier_hz": generator.carrier_hz,
        "seed": generator.seed, "sample_format": generator.sample_format,
        schema.CAPTURE_START_ATTR: capture_start_s, "num_samples": generator.capture_samples,
        "scenario": scenario_to_toml(scenario)}
    if generator.capture_samples != generator.num_samples:
        frames_attrs["receiver_num_samples"] = generator.num_samples
    with atomic_h5(truth_path) as h5:
        write_walk_groups(h5, scenario, walk, imu, gnss, weinberg_k_m)
        write_columns(h5, schema.TRUTH_FRAMES, generator.frame_truth(), attrs=frames_attrs)
        write_columns(h5, schema.TRUTH_PATHS, path_truth(generator), attrs=path_truth_attributes(generator))
        # Only a scenario that drops samples gets the table (its other truth files keep their layout).
        if scenario.receiver.drops_per_minute > 0:
            write_columns(h5, schema.TRUTH_DROPS, generator.drops())
    towers_path = write_towers_csv(out_dir, scenario)
    phone_log_path = None
    if phone_log is not None:
        phone_log_path = write_phone_log(phone_log, out_dir, scenario, imu, gnss, phone_clock, SIM_START_UTC_NS)
    return SimulationResult(capture_path, truth_path, towers_path, phone_log_path)
