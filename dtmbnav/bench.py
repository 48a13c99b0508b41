"""``dtmbnav bench``: throughput of every kernel next to its plain-numpy reference.

Each line times the production kernel (numba / pyfftw, after a warm-up run
that loads the numba cache and plans the FFTs) and the plain-numpy version of
the same computation on the same input, single-threaded (numba's thread pool
is limited to one thread so that "one core" means one core):

- generator: the transmitter + multipath channel kernel of the simulator
  (samples/s of a park-loop-like 4-path channel at 7.56 Msps);
- resampler: the streaming polyphase resampler, 20 Msps -> 7.56 Msps input;
- receiver: the streaming receiver on an 8 s cf32 capture at 7.56 Msps (best
  of 3 runs): end to end including acquisition, steady state (acquisition
  left out) and per stage (acquisition, sync, channel estimate, body
  recovery, SI DFT, estimators, path tracking), against the per-frame numpy
  pipeline (:mod:`receiver.reference`), which starts from a finished
  acquisition; and end to end once more with the path tracker switched off
  (``ReceiverConfig.track_paths``), the rate it is measured against;
- particle filter: particle-updates/s at Np = 1k, 10k, 100k.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, replace

import numba
import numpy as np

from dtmbnav.core.gb20600 import SYMBOL_RATE_HZ


@dataclass(frozen=True)
class BenchRow:
    """One kernel: its rate and the numpy reference's, in ``unit``."""

    kernel: str
    unit: str
    rate: float
    reference_rate: float | None
    realtime_factor: float | None
    note: str = ""


def _best_time(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_generator(seconds: float) -> BenchRow:
    """Simulator: samples/s of the shaped multipath stream (noise-free kernel)."""
    from sim.rf import CaptureGenerator
    from sim.scenario import load_scenario
    from sim.transmitter import multipath_kernel, multipath_reference
    from sim.walk import simulate_walk

    scenario = load_scenario("park-loop")
    generator = CaptureGenerator(scenario, simulate_walk(scenario).track, seconds=max(seconds, 0.2), start_s=20.0)
    n = int(seconds * generator.sample_rate_hz)
    args = generator.kernel_arguments(0, n)
    multipath_kernel(*args.kernel)  # warm-up (numba cache)
    fast = _best_time(lambda: multipath_kernel(*args.kernel), 2)
    n_ref = max(n // 20, 1000)
    ref_args = generator.kernel_arguments(0, n_ref)
    slow = _best_time(lambda: multipath_reference(*ref_args.reference), 1)
    rate, ref_rate = n / fast, n_ref / slow
    return BenchRow("generator (shaping + 4-path channel)", "samples/s", rate, ref_rate,
                    rate / generator.sample_rate_hz, f"{generator.num_paths} paths")


def bench_resampler(seconds: float) -> BenchRow:
    """Receiver resampler 20 Msps -> 7.56 Msps: input samples/s."""
    from receiver.resample import StreamResampler, polyphase_reference

    rate_in = 20e6
    rng = np.random.default_rng(1)
    n = int(seconds * rate_in)
    x = (rng.standard_normal(n) + 1j * rng.standard_normal(n)).astype(np.complex64)
    StreamResampler(rate_in).process(x[:10_000])  # warm-up
    fast = _best_time(lambda: StreamResampler(rate_in).process(x), 2)
    res = StreamResampler(rate_in)
    # The reference upsamples by zero insertion (up = 189 at 20 Msps): keep its input small.
    n_ref = min(n, 100_000)
    slow = _best_time(lambda: polyphase_reference(x[:n_ref], res._h, res.up, res.down,
                                                   n_ref * res.up // res.down), 1)
    rate, ref_rate = n / fast, n_ref / slow
    return BenchRow(f"resampler 20 -> 7.56 Msps ({res.up}/{res.down})", "input samples/s", rate, ref_rate,
                    rate / rate_in)


def bench_receiver(seconds: float, reference_frames: int, repeats: int) -> list[BenchRow]:
    """Streaming receiver on a simulated cf32 7.56 Msps capture: end to end, steady state and per stage.

    The receiver runs ``repeats`` times over the same capture (1 Mi-sample
    chunks); the fastest run is reported. "End to end" counts everything
    from the first chunk to the last frame, acquisition included; "steady
    state" leaves out the acquisition stage (a one-off cost per lock, about
    30 ms) and is the rate the receiver sustains once locked, comparable
    with the reference pipeline, which starts from a finished acquisition.
    """
    from receiver.pipeline import STAGES, Receiver, ReceiverConfig, receive_stream
    from receiver.reference import receive_reference
    from sim.rf import CaptureGenerator
    from sim.scenario import load_scenario
    from sim.walk import simulate_walk

    scenario = load_scenario("park-loop").replace(receiver={"sample_format": "cf32", "bulk_cfo_hz": 5000.0})
    generator = CaptureGenerator(scenario, simulate_walk(scenario).track, seconds=seconds, start_s=20.0)
    x = np.concatenate(list(generator.chunks(1 << 20))).astype(np.complex64)
    config = ReceiverConfig(static_window_s=0.1)
    # Warm-up on a separate receiver: numba cache loads and FFTW planning are not part of the rate.
    for _ in receive_stream([x[: int(0.2 * SYMBOL_RATE_HZ)]], SYMBOL_RATE_HZ, generator.carrier_hz, config):
        pass
    def fastest(cfg: ReceiverConfig) -> tuple[float, Receiver, int]:
        best: tuple[float, Receiver, int] | None = None
        for _ in range(repeats):
            rx = Receiver(SYMBOL_RATE_HZ, generator.carrier_hz, cfg)
            t0 = time.perf_counter()
            frames = sum(len(b) for b in receive_stream((x[i:i + (1 << 20)] for i in range(0, len(x), 1 << 20)),
                                                         SYMBOL_RATE_HZ, generator.carrier_hz, receiver=rx))
            elapsed = time.perf_counter() - t0
            if best is None or elapsed < best[0]:
                best = (elapsed, rx, frames)
        assert best is not None
        return best

    elapsed, rx, frames = fastest(config)
    elapsed_off, _, frames_off = fastest(replace(config, track_paths=False))
    if frames == 0:
        raise RuntimeError("benchmark receiver produced no frames")
    ref_stages: dict[str, float] = {}
    t0 = time.perf_counter()
    receive_reference(x, rx.acquisitions[0], reference_frames, stage_seconds=ref_stages)
    ref_per_frame = (time.perf_counter() - t0) / reference_frames
    samples_per_frame = rx.pn_mode.value.frame_length
    locked = elapsed - rx.stage_seconds["acquisition"]
    best_of = f"best of {repeats} runs, " if repeats > 1 else ""
    rows = [BenchRow("receiver end to end incl. acquisition", "samples/s", len(x) / elapsed, None,
                     len(x) / elapsed / SYMBOL_RATE_HZ,
                     f"cf32 7.56 Msps, {seconds:g} s capture, {best_of}{frames / elapsed:.0f} frames/s"),
            BenchRow("receiver end to end, path tracking off", "samples/s", len(x) / elapsed_off, None,
                     len(x) / elapsed_off / SYMBOL_RATE_HZ,
                     f"{frames_off / elapsed_off:.0f} frames/s; with tracking "
                     f"{100 * elapsed_off / elapsed:.0f} % of this speed"),
            BenchRow("receiver steady state (after acquisition)", "samples/s", len(x) / locked,
                     samples_per_frame / ref_per_frame, len(x) / locked / SYMBOL_RATE_HZ,
                     f"{frames / locked:.0f} frames/s; reference {1 / ref_per_frame:.0f} frames/s")]
    for stage in STAGES:
        spent = rx.stage_seconds[stage]
        if spent > 0:
            ref_spent = ref_stages.get(stage)
            rows.append(BenchRow(f"  stage: {stage}", "frames/s", frames / spent,
                                 reference_frames / ref_spent if ref_spent else None,
                                 frames / spent * samples_per_frame / SYMBOL_RATE_HZ,
                                 f"{spent / frames * 1e6:.1f} us/frame"))
    return rows


def bench_particle_filter(sizes: tuple[int, ...], epochs: int) -> list[BenchRow]:
    """Particle-updates/s of the numba filter and the numpy one."""
    from fusion.particle_filter import particle_updates_per_second

    return [BenchRow(f"particle filter Np={n}", "particle-updates/s",
                     particle_updates_per_second(n, "numba", epochs), particle_updates_per_second(n, "numpy", epochs),
                     None) for n in sizes]


def machine_info() -> dict[str, str]:
    """What the numbers were measured on."""
    return {"python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
            "machine": platform.machine(), "processor": platform.processor() or "unknown",
            "cpu_count": str(os.cpu_count()), "numba_threads": str(numba.get_num_threads())}


def format_rows(rows: list[BenchRow]) -> str:
    """The table as text."""
    lines = [f"{'kernel':44s} {'rate':>12s} {'numpy ref':>12s} {'speed-up':>9s} {'x real time':>12s}  unit / note"]
    for r in rows:
        ref = f"{r.reference_rate:12.3g}" if r.reference_rate else f"{'':12s}"
        up = f"{r.rate / r.reference_rate:8.1f}x" if r.reference_rate else f"{'':9s}"
        rt = f"{r.realtime_factor:11.2f}x" if r.realtime_factor else f"{'':12s}"
        lines.append(f"{r.kernel:44s} {r.rate:12.3g} {ref} {up} {rt}  {r.unit}{'; ' + r.note if r.note else ''}")
    return "\n".join(lines)


def run_benchmarks(json_path: str | None = None, quick: bool = False) -> int:
    """Run every benchmark, print the table (JSON to ``json_path``, ``-`` = stdout)."""
    numba.set_num_threads(1)
    seconds = 0.2 if quick else 2.0
    # The receiver needs a longer capture than the kernels: acquisition is a one-off cost that a
    # short capture would let dominate the end-to-end figure.
    receiver_seconds = 0.2 if quick else 8.0
    rows: list[BenchRow] = []
    for name, fn in [("generator", lambda: [bench_generator(seconds / 2)]),
                     ("resampler", lambda: [bench_resampler(seconds / 2)]),
                     ("receiver", lambda: bench_receiver(receiver_seconds, 50 if quick else 400, 1 if quick else 3)),
                     ("particle filter", lambda: bench_particle_filter((1000, 10_000) if quick else
                                                                        (1000, 10_000, 100_000), 5 if quick else 30))]:
        print(f"benchmarking {name} ...", file=sys.stderr)
        rows.extend(fn())
    info = machine_info()
    table = format_rows(rows)
    header = ", ".join(f"{k} {v}" for k, v in info.items())
    if json_path == "-":
        print(json.dumps({"machine": info, "rows": [asdict(r) for r in rows]}, indent=2))
        print(header + "\n" + table, file=sys.stderr)
    else:
        print(header)
        print(table)
        if json_path:
            with open(json_path, "w") as fh:
                json.dump({"machine": info, "rows": [asdict(r) for r in rows]}, fh, indent=2)
    return 0
