"""The processing chain behind ``receive``, ``pdr``, ``fuse`` and ``run``.

Files in, files out: the receiver's ``/receiver/frames``, the sensors file's
``/imu`` and ``/gnss`` (a simulation's ``truth.h5`` is one), and the results
file with ``/receiver``, ``/pdr`` and ``/fusion/<filter>`` groups. The
libraries do the work; this module only reads, converts and writes.

Time bases: the receiver's ``t_s`` counts from the capture's first sample,
the IMU's from the start of its log. A capture made by ``dtmbnav simulate``
records where it starts in the sensors file (``/truth/frames`` attribute
``capture_start_s``); other captures are assumed to start with the IMU log
unless ``time_offset_s`` says otherwise.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from dtmbnav.core import schema
from dtmbnav.core.h5io import atomic_h5, read_attrs, read_columns, write_columns
from dtmbnav.core.records import FrameFlag, RangeSeries
from dtmbnav.core.sensors import (
    read_capture_start_s,
    read_gnss,
    read_imu,
    read_tower,
    read_weinberg_k_m,
)
from fusion.pdr import PdrConfig, PdrResult, run_pdr
from fusion.run import FusionConfig, FusionResult, fuse
from receiver.capture import CaptureSource, open_capture
from receiver.pipeline import ReceiverConfig, receive_file
from receiver.writer import write_csv

#: Frame flags that make a frame's range unusable for fusion.
UNUSABLE_FLAGS = FrameFlag.GAP | FrameFlag.LOW_QUALITY


@dataclass(frozen=True)
class ReceiveSummary:
    """What one receiver run found (for the command line's diagnostics).

    Attributes
    ----------
    frames : int
        Frames written.
    attrs : dict
        The ``/receiver/frames`` attributes (mode, SI word, f_s, ...).
    gaps : int
        Frames flagged as the first after a loss of lock.
    seconds : float
        Span of the frames, s.
    path_rows : int
        Rows written to ``/receiver/paths``.
    """

    frames: int
    attrs: dict
    gaps: int
    seconds: float
    path_rows: int = 0

    def describe(self) -> str:
        if not self.frames:
            return "no lock: no DTMB signal found in the capture; no frames written"
        a = self.attrs
        text = (f"{self.frames} frames over {self.seconds:.1f} s, {a.get('pn_mode')}, SI word {a.get('si_index')}, "
                f"f_s = {a.get('clock_offset_hz', float('nan')):.2f} Hz, {self.gaps} gap(s)")
        if a.get("path_tracking"):
            text += f", {self.path_rows} path rows"
        return text


def receive_capture(source: CaptureSource, out_path: str | os.PathLike, config: ReceiverConfig,
                    csv_path: str | None = None, progress: bool = True) -> ReceiveSummary:
    """Receive a capture into ``out_path`` (``/receiver/frames``) and summarise it."""
    sink, attrs = receive_file(source, out_path, config, csv_path=csv_path, progress=progress)
    span = sink.last_t_s - sink.first_t_s if sink.frames else 0.0
    return ReceiveSummary(frames=sink.frames, attrs=attrs, gaps=sink.gaps, seconds=span, path_rows=sink.paths)


def ranges_from_frames(columns: dict[str, np.ndarray], time_offset_s: float = 0.0) -> RangeSeries:
    """Receiver frame columns -> the :class:`RangeSeries` fusion consumes.

    Frames flagged as a gap or low quality, and frames without a range
    (NaN), are marked invalid; ``time_offset_s`` moves the receiver's times
    onto the IMU's time base. The SNR handed on is the SI-carrier SNR (the
    slice of the band the range is measured on, whose fading the fusion
    watches for multipath); files from receivers that did not write it give
    the header SNR instead.
    """
    rng = columns["range_change_m"]
    valid = np.isfinite(rng) & ((columns["flags"].astype(np.int64) & int(UNUSABLE_FLAGS)) == 0)
    return RangeSeries(t_s=columns["t_s"] + time_offset_s, range_change_m=np.where(np.isfinite(rng), rng, 0.0),
                       snr_db=columns.get("si_snr_db", columns["snr_db"]).astype(np.float64), valid=valid)


def resolve_pdr_config(config: PdrConfig, sensors_path: str | os.PathLike) -> PdrConfig:
    """Fill in the Weinberg gain from the sensors file when the user gave none.

    A file without a calibrated gain falls back to the linear step-frequency
    model, which needs no calibration (docs/method.md §3).
    """
    if config.step_model != "weinberg" or config.weinberg_k_m is not None:
        return config
    k_m = read_weinberg_k_m(sensors_path)
    if k_m is None:
        return dataclasses.replace(config, step_model="frequency")
    return dataclasses.replace(config, weinberg_k_m=k_m)


def write_pdr(h5: h5py.File, result: PdrResult, config: PdrConfig) -> None:
    """Write ``/pdr`` (per step) and ``/pdr/track`` (resampled)."""
    attrs = {"step_model": config.step_model, "weinberg_k_m": config.weinberg_k_m or np.nan,
             "frame": "PDR frame: starts at (0, 0), heading relative to the initial one"}
    write_columns(h5, schema.PDR, result.steps, attrs)
    write_columns(h5, schema.PDR_TRACK, result.track, {"rate_hz": config.output_rate_hz})


def run_pdr_file(sensors_path: str | os.PathLike, out_path: str | os.PathLike, config: PdrConfig,
                 csv_path: str | None = None) -> PdrResult:
    """``dtmbnav pdr``: PDR on the ``/imu`` of a file, written to ``out_path``."""
    config = resolve_pdr_config(config, sensors_path)
    result = run_pdr(read_imu(sensors_path), config)
    with atomic_h5(out_path) as h5:
        write_pdr(h5, result, config)
    if csv_path is not None:
        write_csv(csv_path, result.steps.columns())
    return result


def write_fusion(h5: h5py.File, result: FusionResult) -> None:
    """Write ``/fusion/<filter>`` for every filter, with the initial heading used."""
    heading = result.heading
    for name, track in result.tracks.items():
        write_columns(h5, schema.fusion_group(name), track, {
            schema.INITIAL_HEADING_ATTR: heading.heading_rad, "initial_heading_confidence": heading.confidence,
            "initial_heading_minima_rad": heading.minima_rad, "initial_heading_costs_m": heading.costs_m})


def fuse_files(receiver_path: str | os.PathLike, sensors_path: str | os.PathLike, out_path: str | os.PathLike,
               filters: tuple[str, ...], pdr_config: PdrConfig, tower_xy_m: tuple[float, float] | None = None,
               start_xy_m: tuple[float, float] | None = None, n_particles: int | None = None,
               seed: int = 0) -> FusionResult:
    """``dtmbnav fuse``: receiver range + PDR of the sensors file -> ``/pdr`` and ``/fusion/*``."""
    frames = read_columns(receiver_path, schema.RECEIVER_FRAMES)
    ranges = ranges_from_frames(frames, read_capture_start_s(sensors_path))
    pdr_config = resolve_pdr_config(pdr_config, sensors_path)
    pdr = run_pdr(read_imu(sensors_path), pdr_config)
    if start_xy_m is None:
        fix = read_gnss(sensors_path)[1]
        start_xy_m = (fix.x_m, fix.y_m)
    height_m = 0.0
    if tower_xy_m is None:
        *tower_xy, height_m = read_tower(sensors_path)
        tower_xy_m = (tower_xy[0], tower_xy[1])
    config = FusionConfig(seed=seed) if n_particles is None else FusionConfig(n_particles=n_particles, seed=seed)
    result = fuse(pdr.steps, ranges, start_xy_m, tower_xy_m, filters, tower_height_m=height_m, config=config)
    rx_attrs = read_attrs(receiver_path, schema.RECEIVER_FRAMES)
    with atomic_h5(out_path) as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, frames, rx_attrs)
        write_pdr(h5, pdr, pdr_config)
        write_fusion(h5, result)
    return result


#: Share of the IMU log the receiver's frames must span before ``run`` fuses.
MIN_FUSION_COVERAGE = 0.5


def range_coverage_s(receiver_path: str | os.PathLike, sensors_path: str | os.PathLike) -> tuple[float, float]:
    """Seconds of the IMU log covered by receiver frames, and the log's length, s."""
    frames = read_columns(receiver_path, schema.RECEIVER_FRAMES)
    imu_t = read_columns(sensors_path, schema.IMU)["t_s"]
    if len(frames["t_s"]) == 0:
        return 0.0, float(imu_t[-1] - imu_t[0])
    t = frames["t_s"] + read_capture_start_s(sensors_path)
    covered = max(0.0, min(t[-1], imu_t[-1]) - max(t[0], imu_t[0]))
    return covered, float(imu_t[-1] - imu_t[0])


@dataclass(frozen=True)
class RunOutcome:
    """Files written by :func:`run_directory` and a summary for the user."""

    receiver_path: Path
    results_path: Path | None
    report_path: Path | None
    summary: str


def find_capture_set(directory: str | os.PathLike) -> tuple[Path, Path]:
    """The capture and the sensors file of a capture-set folder.

    The folder holds one capture (``*.sigmf-meta``, or a raw file with a
    ``.json`` sidecar) and one HDF5 file with ``/imu`` and ``/gnss``
    (``truth.h5`` as written by ``dtmbnav simulate``, or ``sensors.h5``).
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    captures = sorted(folder.glob("*.sigmf-meta")) or sorted(
        p.with_suffix("") for p in folder.glob("*.json") if p.with_suffix("").is_file())
    sensors = [p for p in (folder / "truth.h5", folder / "sensors.h5") if p.is_file()]
    if len(captures) != 1:
        raise ValueError(f"{folder}: expected exactly one capture (*.sigmf-meta or raw + .json), found "
                         f"{len(captures)}")
    if not sensors:
        raise ValueError(f"{folder}: no sensors file (truth.h5 or sensors.h5 with /imu and /gnss)")
    return captures[0], sensors[0]


def run_directory(directory: str | os.PathLike, output: str | os.PathLike, filters: tuple[str, ...],
                  progress: bool = True) -> RunOutcome:
    """``dtmbnav run``: receive the folder's capture, then PDR, fusion and the report.

    Fusion needs the receiver's range over the walk: when the capture spans
    less than :data:`MIN_FUSION_COVERAGE` of the IMU log (the bundled capture
    is a few seconds), the run stops after the receiver, says so, and
    reports the receiver against the truth.
    """
    from dtmbnav.report import write_receiver_report, write_report

    capture_path, sensors_path = find_capture_set(directory)
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    rx_path = out / "receiver.h5"
    summary = receive_capture(open_capture(capture_path), rx_path, ReceiverConfig(), progress=progress)
    lines = [f"capture  {capture_path}", f"receiver {summary.describe()}"]
    if not summary.frames:
        return RunOutcome(rx_path, None, None, "\n".join(lines))
    with h5py.File(sensors_path, "r") as f:
        has_truth = schema.TRUTH_TRAJECTORY in f
    truth_path = sensors_path if has_truth else None
    covered_s, walk_s = range_coverage_s(rx_path, sensors_path)
    if covered_s < MIN_FUSION_COVERAGE * walk_s:
        lines.append(f"fusion   skipped: the capture covers {covered_s:.1f} s of the {walk_s:.1f} s IMU log; the "
                     "filters need the DTMB range over the walk (try 'dtmbnav demo', which streams a whole walk)")
        report = write_receiver_report(rx_path, out / "report", truth_path=truth_path)
        lines.append((report / "summary.md").read_text())
        lines.append(f"report   {report}")
        return RunOutcome(rx_path, None, report, "\n".join(lines))
    results_path = out / "results.h5"
    result = fuse_files(rx_path, sensors_path, results_path, filters, PdrConfig())
    ranged = int(np.count_nonzero(np.isfinite(result.epochs.range_change_m)))
    lines.append(f"fusion   {len(result.epochs)} PDR steps, {ranged} with a DTMB range; initial heading "
                 f"{result.heading.describe()}")
    report = write_report(results_path, out / "report", truth_path=truth_path)
    if (report / "summary.md").is_file():
        lines.append((report / "summary.md").read_text())
    lines.append(f"report   {report}")
    return RunOutcome(rx_path, results_path, report, "\n".join(lines))
