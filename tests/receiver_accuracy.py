"""End-to-end accuracy of the receiver on simulated captures (tests and a report script).

:func:`run_capture` simulates a scenario segment with :class:`sim.rf.CaptureGenerator`
(quantised to the requested format and decoded back, as a file would be),
runs the receiver on it in chunks and returns its rows with the simulator's
per-frame truth; :func:`accuracy` scores them over the walking part.

Run ``python tests/receiver_accuracy.py`` (from the repository root) to print
the 60 s figures of the brief: park-loop with the GNSS-disciplined and the
free-running clock, and street. ``python tests/receiver_accuracy.py narrowband``
prints the narrowband figures: park-loop, GNSS-disciplined clock, 40 s of
walking recorded at 2.048, 2.4 and 3.2 Msps (an RTL-SDR's rates).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dtmbnav.core.iqformat import decode  # noqa: E402
from dtmbnav.core.records import FrameBatch, FrameFlag  # noqa: E402
from receiver.pipeline import Receiver, ReceiverConfig, receive_stream  # noqa: E402
from sim.rf import CaptureGenerator, FrameTruth  # noqa: E402
from sim.scenario import Scenario, load_scenario  # noqa: E402
from sim.walk import simulate_walk  # noqa: E402


@dataclass
class CaptureRun:
    """A receiver run on a simulated segment."""

    frames: FrameBatch
    truth: FrameTruth
    receiver: Receiver
    scenario: Scenario
    start_s: float
    seconds_per_second: float


def run_capture(scenario: str | Scenario, *, start_s: float, seconds: float, config: ReceiverConfig,
                sample_rate_hz: float | None = None, sample_format: str | None = None, pn_mode: str | None = None,
                chunk_samples: int = 1 << 20, **receiver_overrides) -> CaptureRun:
    """Simulate a segment and receive it.

    ``receiver_overrides`` change fields of the scenario's ``[receiver]``
    section (e.g. ``bulk_cfo_hz=5000``, ``clock={"preset": "free-running"}``).
    """
    scn = load_scenario(scenario) if isinstance(scenario, str) else scenario
    if receiver_overrides:
        scn = scn.replace(receiver=receiver_overrides)
    walk = simulate_walk(scn)
    gen = CaptureGenerator(scn, walk.track, seconds=seconds, start_s=start_s, sample_rate_hz=sample_rate_hz,
                           sample_format=sample_format, pn_mode=pn_mode)
    fmt = gen.sample_format

    def chunks():
        for chunk in gen.chunks(chunk_samples):
            yield chunk if fmt == "cf32" else decode(gen.frontend.quantise(chunk), fmt)

    rx = Receiver(gen.sample_rate_hz, gen.carrier_hz, config)
    t0 = time.perf_counter()
    frames = FrameBatch.concatenate(list(receive_stream(chunks(), gen.sample_rate_hz, gen.carrier_hz, receiver=rx)))
    elapsed = time.perf_counter() - t0
    return CaptureRun(frames, gen.frame_truth(), rx, scn, start_s, elapsed / seconds)


def match_truth(frames: FrameBatch, truth: FrameTruth) -> np.ndarray:
    """Index of the truth frame nearest in time to each receiver frame."""
    j = np.clip(np.searchsorted(truth.t_s, frames.t_s), 1, len(truth.t_s) - 1)
    return np.where(np.abs(truth.t_s[j - 1] - frames.t_s) < np.abs(truth.t_s[j] - frames.t_s), j - 1, j)


@dataclass
class Accuracy:
    """Scores over a time window of a run."""

    velocity_rmse_1s_mps: float
    cfo_rmse_1s_hz: float
    range_error_p95_m: float
    range_error_max_m: float
    clock_offset_error_hz: float
    frames: int
    seconds: float

    def __str__(self) -> str:
        return (f"velocity RMSE (1 s means) {self.velocity_rmse_1s_mps:.4f} m/s, CFO RMSE against the true "
                f"Doppler + clock offset (1 s means) {self.cfo_rmse_1s_hz:.3f} Hz, range error p95 "
                f"{self.range_error_p95_m:.3f} m (max {self.range_error_max_m:.3f} m), f_s error "
                f"{self.clock_offset_error_hz:+.3f} Hz, {self.frames} frames over {self.seconds:.1f} s")


def accuracy(run: CaptureRun, t_from_s: float, t_to_s: float) -> Accuracy:
    """Velocity RMSE of 1 s means and range-change error over ``[t_from_s, t_to_s)`` (capture time).

    The range change is compared with the true range change since the
    receiver's first frame.
    """
    f, tr = run.frames, run.truth
    j = match_truth(f, tr)
    true_range = tr.range_m[j] - tr.range_m[j[0]]
    sel = (f.t_s >= t_from_s) & (f.t_s < t_to_s)
    range_err = np.abs(f.range_change_m[sel] - true_range[sel])
    bins = np.floor(f.t_s[sel] - t_from_s).astype(int)
    ok = np.isfinite(f.velocity_mps[sel])
    counts = np.bincount(bins[ok])
    rx_mean = np.bincount(bins[ok], f.velocity_mps[sel][ok]) / np.maximum(counts, 1)
    true_mean = np.bincount(bins[ok], tr.radial_velocity_mps[j][sel][ok]) / np.maximum(counts, 1)
    full = counts > 0.9 * np.max(counts)
    rmse = float(np.sqrt(np.mean((rx_mean - true_mean)[full] ** 2)))
    # The CFO itself against the truth (separates receiver errors from the f_s model's: oscillator drift).
    true_cfo = tr.doppler_hz[j] + tr.clock_offset_hz[j] + run.scenario.receiver.bulk_cfo_hz
    rx_cfo = np.bincount(bins[ok], f.cfo_hz[sel][ok]) / np.maximum(counts, 1)
    true_cfo_mean = np.bincount(bins[ok], true_cfo[sel][ok]) / np.maximum(counts, 1)
    cfo_rmse = float(np.sqrt(np.mean((rx_cfo - true_cfo_mean)[full] ** 2)))
    # The receiver's f_s is the bulk tuner offset plus the clock offset; the truth's clock offset
    # is the oscillator part only.
    fs_true = float(np.mean(tr.clock_offset_hz[j][f.flags & FrameFlag.CALIBRATION > 0])) + run.scenario.receiver.bulk_cfo_hz
    fs_err = (run.receiver.ranging.clock_offset_hz or np.nan) - fs_true
    return Accuracy(rmse, cfo_rmse, float(np.percentile(range_err, 95)), float(np.max(range_err)), fs_err, int(sel.sum()),
                    float(t_to_s - t_from_s))


#: Narrowband case: rates (an RTL-SDR's) and seconds of walking.
NARROWBAND_RATES_HZ = (2.048e6, 2.4e6, 3.2e6)
NARROWBAND_WALK_S = 40.0


def main(which: str = "wideband") -> None:
    """Print the brief's 60 s figures (about 3 minutes of simulation per case on one core), or the narrowband ones."""
    if which == "narrowband":
        cases = [("park-loop-cw", {"sample_rate_hz": rate}, f"park-loop at {rate / 1e6:g} Msps, GNSS-disciplined clock",
                  NARROWBAND_WALK_S) for rate in NARROWBAND_RATES_HZ]
    else:
        cases = [("park-loop-cw", {}, "park-loop, GNSS-disciplined clock", 60.0),
                 ("park-loop-cw", {"clock": {"preset": "free-running"}}, "park-loop, free-running clock", 60.0),
                 ("street-out", {}, "street (out), GNSS-disciplined clock", 60.0)]
    for name, overrides, label, walk_s in cases:
        scn = load_scenario(name)
        still = scn.walk.start_still_s
        # Static window: the whole still period but the last 0.5 s (the walker may lean off).
        config = ReceiverConfig(static_window_s=still - 0.5)
        rate = overrides.pop("sample_rate_hz", None)
        run = run_capture(scn, start_s=0.0, seconds=still + walk_s, config=config, sample_rate_hz=rate, **overrides)
        print(f"{label}: {accuracy(run, still, still + walk_s)}; receiver at "
              f"{1 / run.seconds_per_second:.1f}x real time incl. simulation wait", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:2])
