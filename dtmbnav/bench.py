"""``dtmbnav bench``: throughput of every kernel next to its plain-numpy reference.

Each line times the production kernel (numba / pyfftw, after a warm-up run
that loads the numba cache and plans the FFTs) and the plain-numpy version of
the same computation on the same input, single-threaded (numba's thread pool
is limited to one thread so that "one core" means one core):

- generator: the simulator's noise-free synthesis of the park-loop walk's
  4-path channel at 7.56 Msps (samples/s, symbols and channel included):
  block synthesis (the default) against its exact twin, and the exact twin's
  numba kernel against its numpy reference; then the whole
  ``dtmbnav simulate park-loop`` process (one job, numba on one thread) for a
  short and a long capture, with its peak resident memory (flat when it does
  not grow with the capture's length);
- resampler: the streaming polyphase resampler, 20 Msps -> 7.56 Msps input;
- receiver: the streaming receiver on an 8 s cf32 capture at 7.56 Msps (best
  of 3 runs): end to end including acquisition, steady state (acquisition
  left out) and per stage (acquisition, sync, channel estimate, body
  recovery, SI DFT, estimators), against the per-frame numpy pipeline
  (:mod:`receiver.reference`), which starts from a finished acquisition;
- particle filter: particle-updates/s at Np = 1k, 10k, 100k.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass

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


def _best_cpu_time(fn, repeats: int) -> float:
    """Fewest CPU seconds of this process over ``repeats`` calls of a single-threaded ``fn``.

    For work on one thread the CPU time is what a quiet core would take; unlike
    the wall time it does not grow when other processes share the core.
    """
    best = np.inf
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def bench_generator(seconds: float) -> list[BenchRow]:
    """Simulator: samples/s of the noise-free received stream, block synthesis and its exact twin.

    One thread; CPU time (:func:`_best_cpu_time`). Block synthesis runs in the
    simulator's chunks over samples not computed before, so symbols, channel
    and FFTs are all counted.
    """
    from sim.rf import CaptureGenerator
    from sim.scenario import load_scenario
    from sim.simulate import DEFAULT_CHUNK_SAMPLES
    from sim.transmitter import multipath_kernel, multipath_reference
    from sim.walk import simulate_walk

    scenario = load_scenario("park-loop")
    track = simulate_walk(scenario).track
    span_s = 3 * seconds + 0.5
    block = CaptureGenerator(scenario, track, seconds=span_s, start_s=20.0)
    exact = CaptureGenerator(scenario, track, seconds=span_s, start_s=20.0, synthesis="exact")
    n = int(seconds * block.sample_rate_hz)
    starts = iter(block.first_sample + 1000 + i * n for i in range(3))

    def synthesise() -> None:
        first = next(starts)
        for offset in range(0, n, DEFAULT_CHUNK_SAMPLES):
            block.clean_samples(first + offset, min(DEFAULT_CHUNK_SAMPLES, n - offset))

    block.clean_samples(block.first_sample, 1000)  # warm-up (numba cache, FFTW plans)
    fast = _best_cpu_time(synthesise, 2)
    args = exact.kernel_arguments(exact.first_sample, n)
    multipath_kernel(*args.kernel)  # warm-up (numba cache)
    exact_time = _best_cpu_time(lambda: multipath_kernel(*args.kernel), 1)
    n_ref = max(n // 50, 1000)
    ref_args = exact.kernel_arguments(exact.first_sample, n_ref)
    slow = _best_cpu_time(lambda: multipath_reference(*ref_args.reference), 1)
    rate, exact_rate = n / fast, n / exact_time
    layout = block.layout
    return [BenchRow(f"generator block synthesis ({block.num_paths} paths)", "samples/s", rate, exact_rate,
                     rate / block.sample_rate_hz,
                     f"ref: exact twin; CPU time; blocks of {layout.block_samples}, DFT {layout.window_symbols}/"
                     f"{layout.output_bins}"),
            BenchRow(f"generator exact twin ({exact.num_paths} paths)", "samples/s", exact_rate, n_ref / slow,
                     exact_rate / exact.sample_rate_hz, f"CPU time; pulse span {exact.pulse.span} symbols")]


def bench_simulate(seconds: tuple[float, ...]) -> list[BenchRow]:
    """``dtmbnav simulate park-loop --seconds S`` as a whole process: wall time and peak RSS.

    One job, numba on one thread; the child imports the same ``dtmbnav`` as
    this process and reports its own peak RSS (Linux ``VmHWM``).
    """
    import subprocess
    import tempfile
    from pathlib import Path

    from sim.scenario import load_scenario

    rate_hz = load_scenario("park-loop").receiver.sample_rate_hz
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(
        p for p in (root, os.environ.get("PYTHONPATH", "")) if p)}
    # VmHWM is the peak RSS of the process's own address space; rusage's maxrss would also count the
    # parent's pages that the child held between fork and exec.
    child = ("import sys\nfrom dtmbnav.cli import main\ncode = main(sys.argv[1:])\n"
             "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0])\n"
             "sys.exit(code)")
    rows = []
    for length in seconds:
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            done = subprocess.run([sys.executable, "-c", child, "-q", "simulate", "park-loop", "--seconds",
                                   f"{length:g}", "-o", out], env=env, cwd=root, capture_output=True, text=True,
                                  check=False)
            elapsed = time.perf_counter() - t0
        if done.returncode != 0:
            raise RuntimeError(f"dtmbnav simulate --seconds {length:g} failed (exit {done.returncode}): "
                               f"{done.stderr.strip()[-300:]}")
        rss_mib = int(done.stdout.split()[-1]) / 1024.0  # VmHWM is in KiB
        samples = length * rate_hz
        rows.append(BenchRow(f"simulate park-loop {length:g} s (whole process)", "samples/s", samples / elapsed,
                             None, samples / elapsed / rate_hz,
                             f"{elapsed:.1f} s wall incl. start-up, peak RSS {rss_mib:.0f} MiB"))
    return rows


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
    best: tuple[float, Receiver, int] | None = None
    for _ in range(repeats):
        rx = Receiver(SYMBOL_RATE_HZ, generator.carrier_hz, config)
        t0 = time.perf_counter()
        frames = sum(len(b) for b in receive_stream((x[i:i + (1 << 20)] for i in range(0, len(x), 1 << 20)),
                                                     SYMBOL_RATE_HZ, generator.carrier_hz, receiver=rx))
        elapsed = time.perf_counter() - t0
        if best is None or elapsed < best[0]:
            best = (elapsed, rx, frames)
    assert best is not None
    elapsed, rx, frames = best
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
    for name, fn in [("generator", lambda: bench_generator(seconds / 2)),
                     ("simulate", lambda: bench_simulate((0.5, 1.0) if quick else (5.0, 60.0))),
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
