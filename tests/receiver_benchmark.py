"""Receiver throughput at 7.56 Msps cf32 input on one core, per stage, against the numpy reference.

Run ``python tests/receiver_benchmark.py [seconds]`` from the repository root.
It builds a PN420 test signal (5 kHz CFO, 15 dB SNR, an echo, 0.5 ppm
sampling offset), lets the receiver acquire and warm up on its first 0.3 s
(acquisition, FFTW planning, numba cache loads), then times the rest fed in
2**20-sample chunks; the plain-numpy per-frame pipeline
(:mod:`receiver.reference`) runs over the same frames for comparison.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from receiver.gb20600 import SYMBOL_RATE_HZ  # noqa: E402
from receiver.pipeline import STAGES, Receiver, ReceiverConfig  # noqa: E402
from receiver.reference import receive_reference  # noqa: E402
from receiver_signals import make_signal  # noqa: E402

CHUNK = 1 << 20


def main(seconds: float = 2.0, reference_frames: int = 400) -> None:
    n = int(seconds * SYMBOL_RATE_HZ)
    x = make_signal(n, cfo_hz=5000.0, snr_db=15, start_symbol=123_457, echo=(4.3, 0.3j), sampling_offset_ppm=0.5)
    warm = int(0.3 * SYMBOL_RATE_HZ)
    rx = Receiver(SYMBOL_RATE_HZ, 666e6, ReceiverConfig(clock_offset_hz=5000.0))
    frames = sum(len(b) for b in rx.process(x[:warm]))
    rx.stage_seconds = dict.fromkeys(STAGES, 0.0)
    t0 = time.perf_counter()
    timed = 0
    for i in range(warm, n, CHUNK):
        timed += sum(len(b) for b in rx.process(x[i:i + CHUNK]))
    timed += sum(len(b) for b in rx.finish())
    elapsed = time.perf_counter() - t0
    rate = (n - warm) / elapsed
    print(f"streaming receiver: {rate / 1e6:.1f} Msps = {rate / SYMBOL_RATE_HZ:.1f}x real time, "
          f"{elapsed / timed * 1e6:.1f} us/frame over {timed} frames ({frames} in warm-up)")
    print("  per stage, us/frame: " + ", ".join(f"{k} {v / timed * 1e6:.1f}" for k, v in rx.stage_seconds.items())
          + f", other (buffering, records, ranging) {(elapsed - sum(rx.stage_seconds.values())) / timed * 1e6:.1f}")
    t0 = time.perf_counter()
    receive_reference(x, rx.acquisitions[0], reference_frames)
    ref_elapsed = time.perf_counter() - t0
    per_frame = ref_elapsed / reference_frames
    print(f"numpy reference (per-frame loop): {per_frame * 1e6:.0f} us/frame = "
          f"{4200 / per_frame / SYMBOL_RATE_HZ:.2f}x real time ({per_frame / (elapsed / timed):.0f}x slower)")


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:2]))
