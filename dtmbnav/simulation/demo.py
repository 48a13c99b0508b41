"""``dtmbnav demo``: the whole method on a simulated walk, end to end.

1. Simulate the walk, its phone IMU, GNSS start fix and truth (``truth.h5``).
2. Generate the IQ capture of the walk at the scenario's rate and format and
   stream it straight into the receiver, chunk by chunk: the samples go
   through the same quantisation and decoding as a file would, but no
   multi-GB capture is written (memory stays flat).
3. PDR on the IMU, initial heading (eq. 15) and every filter (``results.h5``).
4. A report folder: trajectory map, range vs truth, error CDF, summary table
   next to the paper's figures, and the tracks on WGS84 from the scenario's
   ``[origin]`` (``tracks.geojson``, ``tracks.gpx``, ``map.html``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from dtmbnav.chain.fuse import fuse_files
from dtmbnav.chain.report import write_report
from dtmbnav.simulation.capture_set import receiver_clock_model, simulate_capture_set
from dtmbnav.simulation.iq_range import generated_chunks, simulated_receiver_config
from dtmbnav_core import schema
from fusion.pdr import PdrConfig
from fusion.run import FILTERS, FusionConfig
from receiver.pipeline import Receiver, receive_into_sink
from receiver.writer import FrameSink
from sim.rf import CaptureGenerator
from sim.scenario import load_scenario
from sim.walk import simulate_walk


def stream_receive(scenario, seconds: float | None, rx_path: Path, progress: bool, jobs: int = 1) -> int:
    """Generate the scenario's capture and receive it on the fly; returns the frame count.

    ``jobs`` threads generate the capture ahead of the receiver, which runs
    on the calling thread (the synthesis kernels release the GIL).
    """
    generator = CaptureGenerator(scenario, simulate_walk(scenario).track, seconds=seconds)
    # The walker stands still for start_still_s: that is the f_s calibration window (eq. 9-10).
    receiver = Receiver(generator.sample_rate_hz, generator.carrier_hz, simulated_receiver_config(scenario))
    sink = FrameSink(rx_path)
    receive_into_sink(receiver, generated_chunks(generator, jobs=jobs), sink,
                      source=f"simulated {scenario.name} (streamed)", total_samples=generator.num_samples,
                      progress=progress,
                      attrs={schema.CAPTURE_SCENARIO_ATTR: scenario.name, schema.CAPTURE_SEED_ATTR: generator.seed})
    return sink.frames


def run_demo(out_dir: Path, scenario: str = "park-loop", seconds: float | None = None, progress: bool = True,
             jobs: int | None = None) -> Path:
    """Run the demo into ``out_dir``; returns the report folder.

    ``jobs`` threads generate the IQ (default: one per CPU core).
    """
    jobs = jobs or os.cpu_count() or 1
    scn = load_scenario(scenario)
    out_dir = Path(out_dir)
    print(f"[1/4] simulating the {scn.name} walk, IMU and truth", file=sys.stderr)
    truth_path = simulate_capture_set(scn, out_dir, seconds=seconds, with_iq=False).truth_path
    print(f"[2/4] generating the IQ at {scn.receiver.sample_rate_hz / 1e6:g} Msps {scn.receiver.sample_format} "
          "and receiving it (streamed, nothing large on disk)", file=sys.stderr)
    rx_path = out_dir / "receiver.h5"
    if stream_receive(scn, seconds, rx_path, progress, jobs) == 0:
        raise RuntimeError("the receiver found no DTMB signal in the simulated capture")
    print("[3/4] PDR, initial heading and fusion", file=sys.stderr)
    results_path = out_dir / "results.h5"
    result, _ = fuse_files(rx_path, truth_path, results_path, tuple(FILTERS), PdrConfig(),
                        config=FusionConfig(clock_model=receiver_clock_model(scn)))
    print(f"      initial heading {result.heading.describe()}", file=sys.stderr)
    print("[4/4] writing the report", file=sys.stderr)
    # The scenario's ENU frame is the tangent plane at its [origin]: the same frame a phone's import gets.
    report = write_report(results_path, out_dir / "report", truth_path=truth_path, origin=scn.origin.point)
    print((report / "summary.md").read_text())
    print(f"map: {report / 'map.html'} (tracks also as {report / 'tracks.geojson'} and {report / 'tracks.gpx'})",
          file=sys.stderr)
    return report
