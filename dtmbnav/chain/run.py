"""``dtmbnav run``'s work: the whole chain (receive, PDR, fuse, report) on a folder with one capture set."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dtmbnav.chain.fuse import MIN_FUSION_COVERAGE, fuse_files, range_coverage_s
from dtmbnav.chain.inputs import read_checked_imu
from dtmbnav.chain.receive import receive_capture
from dtmbnav.chain.report import write_report_folder
from dtmbnav_core import schema
from dtmbnav_core.h5io import open_h5
from fusion.pdr import PdrConfig
from receiver.capture import open_capture
from receiver.pipeline import ReceiverConfig


@dataclass(frozen=True)
class RunOutcome:
    """Files written by :func:`run_directory` and a summary for the user."""

    receiver_path: Path
    results_path: Path | None
    report_path: Path | None
    summary: str
    found: bool = True


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

    Both inputs are opened and checked before any work. Fusion needs the
    receiver's range over the walk: when the capture spans less than
    :data:`MIN_FUSION_COVERAGE` of the IMU log (the bundled capture is a few
    seconds), the run stops after the receiver, says so, and reports the
    receiver against the truth.
    """
    capture_path, sensors_path = find_capture_set(directory)
    source = open_capture(capture_path)
    read_checked_imu(sensors_path)
    with open_h5(sensors_path) as f:
        has_truth = schema.TRUTH_TRAJECTORY in f
    truth_path = sensors_path if has_truth else None
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    rx_path = out / "receiver.h5"
    summary = receive_capture(source, rx_path, ReceiverConfig(), progress=progress)
    lines = [f"capture  {capture_path}", f"receiver {summary.describe()}"]
    if not summary.frames:
        return RunOutcome(rx_path, None, None, "\n".join(lines), found=False)
    covered_s, walk_s = range_coverage_s(rx_path, sensors_path)
    report = out / "report"
    if covered_s < MIN_FUSION_COVERAGE * walk_s:
        lines.append(f"fusion   skipped: the capture covers {covered_s:.1f} s of the {walk_s:.1f} s IMU log; the "
                     "filters need the DTMB range over the walk (try 'dtmbnav demo', which streams a whole walk)")
        write_report_folder(rx_path, report, truth_path=truth_path, receiver_only=True)
        lines.append((report / "summary.md").read_text())
        lines.append(f"report   {report}")
        return RunOutcome(rx_path, None, report, "\n".join(lines))
    results_path = out / "results.h5"
    result, _ = fuse_files(rx_path, sensors_path, results_path, filters, PdrConfig())
    ranged = int(np.count_nonzero(np.isfinite(result.epochs.range_change_m)))
    lines.append(f"fusion   {len(result.epochs)} PDR steps, {ranged} with a DTMB range; initial heading "
                 f"{result.heading.describe()}")
    write_report_folder(results_path, report, truth_path=truth_path)
    if (report / "summary.md").is_file():
        lines.append((report / "summary.md").read_text())
    lines.append(f"report   {report}")
    return RunOutcome(rx_path, results_path, report, "\n".join(lines))
