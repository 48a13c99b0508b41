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
  of 3 runs): end to end including acquisition (one thread and
  ``jobs = 2``), steady state (acquisition left out) and per stage
  (acquisition, sync, channel estimate, body recovery, SI DFT, estimators,
  path tracking), against the per-frame numpy pipeline
  (:mod:`receiver.reference`), which starts from a finished acquisition;
  and end to end once more with the path tracker switched off
  (``ReceiverConfig.track_paths``), the rate it is measured against;
- receive command: ``dtmbnav receive`` as a user runs it, a child process
  on generated ci8 captures at 7.56 Msps (20 s and 60 s), pinned to one
  core (two for ``--jobs 2``): wall time including interpreter start-up,
  imports, reading and writing, next to the in-memory figure, and the
  two-core rate over the one-core rate; the same with path tracking off;
  the start-up (a 0.2 s capture) and the receive path's import time; the
  children import from bytecode as an installed copy does, even where the
  environment sets ``PYTHONDONTWRITEBYTECODE``; the child's peak RSS for a
  short and a long capture (flat memory); and, when the ``dtmb-sdr``
  package is installed, its front end on the same capture and core;
- phone log import: ``dtmbnav sensors`` (read, resample, the sensors file) on a GnssLogger log of an
  hour (a minute with ``--quick``) written by the simulator's writer, CPU time on one core;
- particle filter: particle-updates/s at Np = 1k, 10k, 100k.
"""

from __future__ import annotations

import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numba
import numpy as np

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ
from receiver.capture import CaptureSource, open_capture


@dataclass(frozen=True)
class BenchRow:
    """One kernel: its rate and the numpy reference's, in ``unit``."""

    kernel: str
    unit: str
    rate: float
    reference_rate: float | None
    realtime_factor: float | None
    note: str = ""


def _best_time(fn, repeats: int, clock=time.perf_counter) -> float:
    """Fewest seconds of ``clock`` over ``repeats`` calls of ``fn``.

    With ``clock=time.process_time`` (:func:`_best_cpu_time`) it is the CPU
    time of this process: for work on one thread that is what a quiet core
    would take, and unlike the wall time it does not grow when other processes
    share the core.
    """
    best = np.inf
    for _ in range(repeats):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best


def _best_cpu_time(fn, repeats: int) -> float:
    """Fewest CPU seconds of this process over ``repeats`` calls of a single-threaded ``fn``."""
    return _best_time(fn, repeats, clock=time.process_time)


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
    from sim.scenario import load_scenario

    rate_hz = load_scenario("park-loop").receiver.sample_rate_hz
    root = str(Path(__file__).resolve().parents[1])
    # VmHWM is the peak RSS of the process's own address space; rusage's maxrss would also count the
    # parent's pages that the child held between fork and exec.
    child = ("import sys\nfrom dtmbnav.cli import main\ncode = main(sys.argv[1:])\n"
             "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0])\n"
             "sys.exit(code)")
    rows = []
    with tempfile.TemporaryDirectory(prefix="dtmbnav-bench-") as tmp:
        env = _child_env(Path(tmp), NUMBA_NUM_THREADS="1")
        # Untimed: writes the bytecode the timed runs import (_child_env).
        subprocess.run([sys.executable, "-c", "import dtmbnav.cli, sim.simulate"], env=env, cwd=root, check=True)
        for length in seconds:
            with tempfile.TemporaryDirectory(dir=tmp) as out:
                t0 = time.perf_counter()
                done = subprocess.run([sys.executable, "-c", child, "-q", "simulate", "park-loop", "--seconds",
                                       f"{length:g}", "-o", out], env=env, cwd=root, capture_output=True,
                                      text=True, check=False)
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
    from the first chunk to the last frame, acquisition included, on one
    thread and with ``jobs = 2``; "steady state" leaves out the acquisition
    stage (a one-off cost per lock) and is the rate the receiver sustains
    once locked, comparable with the reference pipeline, which starts from a
    finished acquisition.
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
    # Warm-up on a separate receiver: numba cache loads are not part of the rate.
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
        if best[2] == 0:
            raise RuntimeError("benchmark receiver produced no frames")
        return best

    elapsed, rx, frames = fastest(config)
    elapsed_2, _, _ = fastest(replace(config, jobs=2))
    elapsed_off, _, frames_off = fastest(replace(config, track_paths=False))
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
            BenchRow("receiver end to end, jobs 2", "samples/s", len(x) / elapsed_2, None,
                     len(x) / elapsed_2 / SYMBOL_RATE_HZ, "the same, per-frame work on 2 threads"),
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


#: Front-end stages of dtmb-sdr's ``dtmb-decode`` pipeline (rate conversion and frame extraction; the
#: demapping and LDPC stages after them have no counterpart in this receiver).
DTMB_SDR_FRONT_END = ("dtmb_core_ci8_resample", "dtmb_core_c3780_extract")


#: Runs argv[2:] as a child of this small process and writes the child's peak RSS (kB) to argv[1]. A
#: child started straight from the benchmark (vfork) would count the benchmark's own memory as its peak.
_RSS_LAUNCHER = """import os, sys
pid = os.fork()
if pid == 0:
    os.execv(sys.argv[2], sys.argv[2:])
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as out:
    out.write(f"{usage.ru_maxrss} {os.waitstatus_to_exitcode(status)}")
"""


def _child_env(folder: Path, **extra: str) -> dict[str, str]:
    """Environment of a timed child: this package first on its path, imports from bytecode as installed.

    An installed package imports from its compiled bytecode; an environment
    with ``PYTHONDONTWRITEBYTECODE`` (some containers and CI images set it)
    would make every child compile the project's sources again, about 0.4 s
    of each run on the bench machine, a cost no installed copy pays. The
    children write their bytecode under ``folder`` instead
    (``PYTHONPYCACHEPREFIX``), never into the installation, and the first
    (untimed) run of each command leaves it there for the timed ones.
    """
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))
    env["PYTHONPYCACHEPREFIX"] = str(folder / "pycache")
    return {**env, **extra}


def _run_child(commands: list[list[str]], cpus: list[int], env: dict[str, str] | None = None) -> tuple[float, int]:
    """Run ``commands`` as a pipeline (each one's stdout into the next) pinned to ``cpus``: wall time, exit code."""
    t0 = time.perf_counter()
    procs: list[subprocess.Popen] = []
    previous = None
    for i, command in enumerate(commands):
        last = i == len(commands) - 1
        procs.append(subprocess.Popen(command, stdin=previous, stdout=subprocess.DEVNULL if last else subprocess.PIPE,
                                      stderr=subprocess.DEVNULL, env=env))
        if cpus and hasattr(os, "sched_setaffinity"):   # pinned from here (not preexec_fn: this process has threads)
            os.sched_setaffinity(procs[-1].pid, cpus)
        if previous is not None:
            previous.close()
        previous = procs[-1].stdout
    codes = [proc.wait() for proc in procs]
    return time.perf_counter() - t0, next((c for c in codes if c), 0)


def _peak_rss_mb(command: list[str], env: dict[str, str], folder: Path) -> float:
    """Peak resident memory of ``command`` (Linux ``ru_maxrss``), MB."""
    report = folder / "rss.txt"
    subprocess.run([sys.executable, "-c", _RSS_LAUNCHER, str(report), *command], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kilobytes, code = (int(v) for v in report.read_text().split())
    if code:
        raise RuntimeError(f"{' '.join(command)} exited {code}")
    return kilobytes / 1024


def _capture_prefix(capture: Path, seconds: float, folder: Path) -> Path:
    """The first ``seconds`` of a raw capture with its sidecar, as a capture of its own."""
    meta = json.loads(capture.with_name(capture.name + ".json").read_text())
    samples = int(seconds * meta["sample_rate_hz"])
    bytes_per_sample = capture.stat().st_size // meta["num_samples"]
    out = folder / f"{capture.stem}-{seconds:g}s{capture.suffix}"
    with open(capture, "rb") as src, open(out, "wb") as dst:
        shutil.copyfileobj(src, dst)
        dst.truncate(samples * bytes_per_sample)
    out.with_name(out.name + ".json").write_text(json.dumps({**meta, "num_samples": samples}))
    return out


#: Capture length whose whole-process receive time is the command's start-up, s.
START_UP_CAPTURE_S = 0.2


def bench_receive_command(lengths: tuple[float, ...], rss_seconds: tuple[float, float],
                          repeats: int) -> list[BenchRow]:
    """``dtmbnav receive`` as a user runs it: whole process on generated ci8 captures, against in-memory.

    A park-loop ci8 capture at 7.56 Msps is generated once (raw + sidecar)
    and cut to the lengths used. The peak RSS of the child for a short and a
    long capture shows memory flat with length (these runs also load numba's
    cache and put the file in the page cache). Then, for each of ``lengths``
    (seconds), the command runs in a child process pinned to one core and
    with ``--jobs 2`` on two; its wall time counts interpreter start-up,
    imports (from bytecode, as installed: :func:`_child_env`), reading,
    conversion and writing. Next to each, the same samples through
    :class:`receiver.pipeline.Receiver` in this process (kernels only,
    reading left out), and the two-core rate over the one-core rate. On the
    first length, the command once more with ``--no-paths`` (the rate the
    path tracker is measured against) and with ``--keep-dc --no-correct-iq``
    (the front-end corrector's stage off); the command on a
    :data:`START_UP_CAPTURE_S` capture (its start-up); and the import of
    :mod:`receiver.pipeline` in a fresh interpreter. When dtmb-sdr is
    installed, its front end (:data:`DTMB_SDR_FRONT_END`) runs on the longest
    capture on one core too.
    """
    from sim.scenario import load_scenario
    from sim.simulate import simulate

    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    rows: list[BenchRow] = []
    with tempfile.TemporaryDirectory(prefix="dtmbnav-bench-") as tmp:
        folder = Path(tmp)
        env = _child_env(folder)   # the child runs this package, wherever it was imported from
        longest = max(*lengths, *rss_seconds)
        result = simulate(load_scenario("park-loop"), folder / "sim", seconds=longest, sample_format="ci8",
                          container="raw")
        assert result.capture_path is not None
        captures = {sec: _capture_prefix(Path(result.capture_path), sec, folder) if sec < longest
                    else Path(result.capture_path) for sec in {*lengths, START_UP_CAPTURE_S, *rss_seconds}}

        def command(sec: float, jobs: int, *options: str) -> list[str]:
            return [sys.executable, "-m", "dtmbnav.cli", "-q", "receive", str(captures[sec]), "-o",
                    str(folder / "rx.h5"), "--jobs", str(jobs), *options]

        def receive(sec: float, jobs: int, *options: str) -> float:
            seconds_taken, code = _run_child([command(sec, jobs, *options)], cpus[:jobs], env)
            if code:
                raise RuntimeError(f"dtmbnav receive --jobs {jobs} {' '.join(options)} on {captures[sec]} exited "
                                   f"{code}")
            return seconds_taken

        # Peak RSS first: the short run also warms numba's cache and the page cache for the timed runs.
        rss_rows = [BenchRow(f"receive command peak RSS, {sec:g} s capture", "MB",
                             _peak_rss_mb(command(sec, 1), env, folder), None, None, "the child's ru_maxrss")
                    for sec in sorted(rss_seconds)]
        one_core: dict[float, float] = {}
        for seconds in lengths:
            capture = open_capture(captures[seconds])
            whole_process: dict[int, float] = {}
            for jobs in (1, 2):
                best = whole_process[jobs] = min(receive(seconds, jobs) for _ in range(repeats))
                in_memory = seconds / _receiver_seconds(capture, jobs)
                rows.append(BenchRow(f"receive command, {seconds:g} s, --jobs {jobs}", "samples/s",
                                     capture.num_samples / best, None, seconds / best,
                                     f"ci8 7.56 Msps {seconds:g} s capture on {min(jobs, len(cpus) or jobs)} "
                                     f"core(s), incl. start-up; in memory {in_memory:.1f}x real time"))
            one_core[seconds] = whole_process[1]
            rows.append(BenchRow(f"receive command, {seconds:g} s, 2 cores / 1 core", "ratio",
                                 whole_process[1] / whole_process[2], None, None,
                                 "the --jobs 2 rate over the one-core rate, same capture"))
        seconds = lengths[0]
        capture = open_capture(captures[seconds])
        off = min(receive(seconds, 1, "--no-paths") for _ in range(repeats))
        rows.append(BenchRow(f"receive command, {seconds:g} s, tracking off", "samples/s",
                             capture.num_samples / off, None, seconds / off,
                             f"the same on 1 core with --no-paths; with tracking {off / one_core[seconds]:.0%} of "
                             "this speed"))
        raw = min(receive(seconds, 1, "--keep-dc", "--no-correct-iq") for _ in range(repeats))
        rows.append(BenchRow(f"receive command, {seconds:g} s, front-end stage off", "samples/s",
                             capture.num_samples / raw, None, seconds / raw,
                             f"the same on 1 core with --keep-dc --no-correct-iq (no front-end corrector); with "
                             f"the stage {raw / one_core[seconds]:.0%} of this speed"))
        start_up = min(receive(START_UP_CAPTURE_S, 1) for _ in range(repeats))
        rows.append(BenchRow(f"receive command start-up ({START_UP_CAPTURE_S:g} s capture)", "s", start_up, None, None,
                             "whole process on 1 core: interpreter, imports, numba cache, acquisition, files"))
        rows.append(BenchRow("import receiver.pipeline", "s", _import_seconds("receiver.pipeline", env, cpus[:1]),
                             None, None, "child process on 1 core, best of 5; the receive path's imports"))
        rows.extend(rss_rows)
        if importlib.util.find_spec("dtmb") is not None:
            seconds = max(lengths)
            rows.extend(_bench_dtmb_sdr(captures[seconds], seconds, one_core[seconds], cpus[:1]))
    return rows


def _import_seconds(module: str, env: dict[str, str], cpus: list[int], repeats: int = 5) -> float:
    """Seconds a fresh interpreter takes to import ``module`` (best of ``repeats``; the interpreter's own start-up
    left out)."""
    child = f"import time; t = time.perf_counter(); import {module}; print(time.perf_counter() - t)"
    best = np.inf
    for _ in range(repeats):
        proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True, env=env)
        if cpus and hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(proc.pid, cpus)
        out, _ = proc.communicate()
        if proc.returncode:
            raise RuntimeError(f"import {module} exited {proc.returncode}")
        best = min(best, float(out.split()[-1]))
    return best


def _receiver_seconds(capture: CaptureSource, jobs: int) -> float:
    """Seconds :meth:`Receiver.process` and :meth:`Receiver.finish` take over ``capture`` (reading left out).

    A warm-up receiver first loads numba's cache (and starts its threads).
    """
    from receiver.pipeline import Receiver, ReceiverConfig

    config = ReceiverConfig(jobs=jobs)
    warm = Receiver(capture.sample_rate_hz, capture.center_hz, config)
    warm.process(next(capture.chunks(1 << 20)))
    warm.finish()
    rx = Receiver(capture.sample_rate_hz, capture.center_hz, config)
    spent = 0.0
    for chunk in capture.chunks(1 << 20):
        t0 = time.perf_counter()
        rx.process(chunk)
        spent += time.perf_counter() - t0
    t0 = time.perf_counter()
    rx.finish()
    return spent + time.perf_counter() - t0


def _bench_dtmb_sdr(capture: Path, seconds: float, ours_s: float, cpus: list[int]) -> list[BenchRow]:
    """dtmb-sdr's front end on ``capture`` (PN420, one worker, one core), next to our ``ours_s`` on the same file."""
    from importlib.metadata import version

    from dtmb.decode import build_commands, build_parser

    meta = json.loads(capture.with_name(capture.name + ".json").read_text())
    args = build_parser().parse_args(["--input", str(capture), "--input-rate", str(int(meta["sample_rate_hz"])),
                                      "--pn-mode", "pn420", "--output", os.devnull, "--workers", "1",
                                      "--pipeline-buffer-mib", "0"])
    front = [c for c in build_commands(args) if Path(c[0]).stem in DTMB_SDR_FRONT_END]
    front[-1] = [*front[-1][:-1], os.devnull]     # its output (the extracted bodies) is not needed
    theirs_s, code = _run_child(front, cpus)
    if code:
        print(f"dtmb-sdr front end exited {code}; left out", file=sys.stderr)
        return []
    return [BenchRow(f"dtmb-sdr {version('dtmb-sdr')} front end (for comparison)", "samples/s",
                     seconds * meta["sample_rate_hz"] / theirs_s, None, seconds / theirs_s,
                     f"same {seconds:g} s ci8 capture, 1 core; dtmbnav receive (whole process) is "
                     f"{theirs_s / ours_s:.1f}x its rate")]


def bench_phone_log_import(seconds: float) -> BenchRow:
    """``dtmbnav sensors`` on a GnssLogger log of ``seconds``: its rows read per CPU second (one core).

    The log, written by the simulator's writer (``sim/phone_log_writer.py``), holds the accelerometer,
    gyroscope and magnetometer at 100 Hz (a phone's sway at a walker's step rate and noise, to the
    micro-unit as a phone's float32 readings are logged) and a fix a second; the whole import is timed:
    reading, resampling and writing the sensors file (:func:`dtmbnav.field.sensors_import.import_phone_log`).
    """
    from dtmbnav.field.sensors_import import import_phone_log
    from dtmbnav_core.phone import PhoneClock
    from dtmbnav_core.records import ImuLog
    from dtmbnav_core.records import GeodeticFixes
    from sim.phone_log_writer import gnsslogger_log

    t = np.arange(0.0, seconds, 0.01)
    rng = np.random.default_rng(1)
    sway = np.sin(2.0 * np.pi * 1.8 * t)[:, None]
    imu = ImuLog(t, *(np.round(np.add(mean, 0.5 * sway + 0.05 * rng.standard_normal((len(t), 3))), 6)
                      for mean in ([0.1, 0.2, 9.8], [0.0, 0.0, 0.0], [-18.0, 2.0, -42.0])))
    fix_t = np.arange(0.0, seconds, 1.0)
    n = len(fix_t)
    fixes = GeodeticFixes(fix_t, 30.52 + 1e-5 * np.sin(fix_t / 60.0), 114.36 + 1e-5 * np.cos(fix_t / 60.0),
                       np.full(n, 25.0), np.full(n, 3.5), np.full(n, 35.0))
    rows = 3 * len(t) + 2 * n  # a row per sample of each sensor, a Fix and a Status row per fix
    with tempfile.TemporaryDirectory(prefix="dtmbnav-bench-") as tmp:
        log = Path(tmp) / "gnss_log.txt"
        log.write_text(gnsslogger_log(imu, fixes, PhoneClock(), 1_767_225_600_000_000_000))
        megabytes = log.stat().st_size / 1e6
        spent = _best_cpu_time(lambda: import_phone_log([log], Path(tmp) / "sensors.h5"), 1)
    return BenchRow(f"sensors: GnssLogger log, {seconds / 60:g} min", "rows/s", rows / spent, None, seconds / spent,
                    f"{rows} rows ({megabytes:.0f} MB) read, resampled and written in {spent:.2f} s CPU, one core")


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
                     ("receive command", lambda: bench_receive_command((0.5, 1.0) if quick else (20.0, 60.0),
                                                                       (0.25, 1.0) if quick else (5.0, 60.0),
                                                                       1 if quick else 2)),
                     ("phone log import", lambda: [bench_phone_log_import(60.0 if quick else 3600.0)]),
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
