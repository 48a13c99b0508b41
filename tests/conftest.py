"""Shared fixtures: small captures and result files, each built once per session (per xdist worker).

- :func:`tiny_sim`: ``dtmbnav simulate`` of 0.4 s of the tiny walk (SigMF capture + ``truth.h5``);
- :func:`tiny_rx`: ``dtmbnav receive`` of that capture;
- :func:`tiny_walk_truth`: ``truth.h5`` of the whole tiny walk (no IQ);
- :func:`tiny_results`: ``dtmbnav fuse`` of the whole tiny walk with the receiver's output replaced by
  the truth's range (exact), a results file with ``/fusion`` in about a second instead of an IQ-level run;
- :func:`make_capture`: a small capture written by ``sim.capture_writer.CaptureWriter``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import settings

# The suite's property tests draw the same examples on every run (a red CI is then the code's,
# never the dice's); HYPOTHESIS_PROFILE=explore draws fresh ones on each run, to look for new
# counterexamples before a change lands. No deadline: an example's time on a loaded machine is not
# what these tests check (speed is measured by `dtmbnav bench`).
settings.register_profile("repeatable", derandomize=True, print_blob=True, deadline=None)
settings.register_profile("explore", derandomize=False, print_blob=True, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

TINY_WALK = Path(__file__).parent / "data" / "tiny-walk.toml"
#: Length of the tiny capture, s, and its sample rate and format (the tiny walk's front end).
TINY_SECONDS = 0.4
TINY_RATE_HZ = 7.56e6
TINY_FORMAT = "ci8"


@pytest.fixture(scope="session")
def tiny_sim(tmp_path_factory) -> Path:
    """Folder with ``tiny-walk.sigmf-meta/-data`` (0.4 s) and ``truth.h5``."""
    from dtmbnav.cli import EXIT_OK, main

    out = tmp_path_factory.mktemp("tiny-sim")
    assert main(["-q", "simulate", str(TINY_WALK), "--seconds", str(TINY_SECONDS), "-o", str(out)]) == EXIT_OK
    return out


@pytest.fixture(scope="session")
def tiny_rx(tiny_sim, tmp_path_factory) -> Path:
    """``receiver.h5`` of the tiny capture (``/receiver/frames`` with the capture's scenario and seed)."""
    from dtmbnav.cli import EXIT_OK, main

    out = tmp_path_factory.mktemp("tiny-rx") / "receiver.h5"
    assert main(["-q", "receive", str(tiny_sim / "tiny-walk.sigmf-meta"), "-o", str(out)]) == EXIT_OK
    return out


@pytest.fixture(scope="session")
def tiny_walk_truth(tmp_path_factory) -> Path:
    """``truth.h5`` of the whole tiny walk (``simulate --no-iq``: ``/truth/frames`` spans the walk)."""
    from dtmbnav.cli import EXIT_OK, main

    out = tmp_path_factory.mktemp("tiny-walk")
    assert main(["-q", "simulate", str(TINY_WALK), "--no-iq", "-o", str(out)]) == EXIT_OK
    return out / "truth.h5"


@pytest.fixture(scope="session")
def tiny_results(tiny_walk_truth, tmp_path_factory) -> Path:
    """``results.h5`` (``/receiver/frames``, ``/pdr``, ``/fusion/pf``, ``/fusion/ukf``) of the tiny walk."""
    from dtmbnav.cli import EXIT_OK, main
    from dtmbnav_core import schema
    from dtmbnav_core.h5io import atomic_h5, read_attrs, read_columns, write_columns
    from dtmbnav_core.records import FRAME_COLUMN_DTYPES

    truth = read_columns(tiny_walk_truth, schema.TRUTH_FRAMES)
    truth_attrs = read_attrs(tiny_walk_truth, schema.TRUTH_FRAMES)
    n = len(truth["t_s"])
    frames = {name: np.zeros(n, dtype) for name, dtype in FRAME_COLUMN_DTYPES.items()}
    frames.update(t_s=truth["t_s"], range_change_m=truth["range_m"] - truth["range_m"][0],
                  velocity_mps=truth["radial_velocity_mps"], snr_db=np.full(n, 20.0, np.float32),
                  si_snr_db=np.full(n, 20.0, np.float32), peak_metric=np.ones(n, np.float32))
    folder = tmp_path_factory.mktemp("tiny-results")
    rx = folder / "exact-receiver.h5"
    with atomic_h5(rx) as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, frames, {
            schema.CAPTURE_SCENARIO_ATTR: "tiny-walk", schema.CAPTURE_SEED_ATTR: int(truth_attrs["seed"]),
            "source": "the truth's range"})
    out = folder / "results.h5"
    assert main(["-q", "fuse", "--receiver", str(rx), "--sensors", str(tiny_walk_truth), "-o", str(out),
                 "--filters", "pf,ukf", "--particles", "300"]) == EXIT_OK
    return out


class CaptureFiles(NamedTuple):
    """A written capture: the path to open, its metadata file (SigMF meta or sidecar), its data file."""

    capture: Path
    meta: Path
    data: Path


@pytest.fixture
def make_capture():
    """``make_capture(folder, container="sigmf", fmt="ci8", n=10, samples=None)`` -> :class:`CaptureFiles`.

    Writes ``samples`` (default: ``n`` zeros) at 7.56 Msps, 666 MHz, as ``folder/cap`` through
    ``sim.capture_writer.CaptureWriter`` (SigMF, or raw + JSON sidecar).
    """
    from dtmbnav_core import iqformat
    from sim.capture_writer import CaptureWriter

    def make(folder: Path, container: str = "sigmf", fmt: str = "ci8", n: int = 10,
             samples: np.ndarray | None = None) -> CaptureFiles:
        z = np.zeros(n, np.complex64) if samples is None else samples
        with CaptureWriter(folder / "cap", container, fmt, TINY_RATE_HZ, 666e6) as writer:
            writer.write(iqformat.encode(z, fmt))
        return CaptureFiles(writer.capture_path, writer.meta_path, writer.data_path)

    return make
