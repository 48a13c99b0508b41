"""Parity of the path tracker's batched code with its readable per-path reference (issue 47).

:func:`receiver.paths.step_paths_kernel` runs every path's slip detector and
steadiness in one call, and :meth:`PathTracker._rows` builds a batch's rows
from ``(F, n)`` columns without a loop over paths. Here each is checked
against the per-path code it replaced, written out below as the readable
reference: the outputs must be bit-identical (``np.array_equal``, NaN-aware),
not merely close.
"""

from __future__ import annotations

import numpy as np
import pytest

from dtmbnav_core.gb20600 import SYMBOL_RATE_HZ, PnMode
from dtmbnav_core.records import PathBatch, PathFlag
from receiver.paths import PathConfig, PathTracker, slip_reference, step_paths_kernel
from receiver.paths.tracking import _Path

RNG = np.random.default_rng(47)
FRAME_S = 5.556e-4


def _batch(count: int, n: int) -> dict[str, np.ndarray]:
    """A batch of ``n`` paths' frequencies with bursts, lasting steps and missing frames, and their state."""
    cfo = 3.0 + 0.2 * RNG.standard_normal((count, n))
    cfo[RNG.random((count, n)) < 0.02] = np.nan
    for i in range(n):
        at = RNG.integers(0, count)
        cfo[at:at + 4, i] += RNG.choice([0.25, -0.3, 0.1]) / FRAME_S     # a burst: a slip or an outlier run
        cfo[RNG.integers(0, count):, i] += RNG.choice([0.0, 150.0, -400.0])   # a lasting step
    return {"cfo": cfo, "dt": np.full(count, FRAME_S) * (1.0 + 0.01 * RNG.random(count)),
            "sigma": 0.01 * (1.0 + RNG.random((count, n))),
            "smooth": np.where(RNG.random(n) < 0.3, np.nan, 3.0 + RNG.standard_normal(n)),
            "run_cycles": np.where(RNG.random(n) < 0.5, 0.0, 0.2 * RNG.standard_normal(n)),
            "run_s": np.where(RNG.random(n) < 0.5, 0.0, 0.01 * RNG.random(n)),
            "moved": 0.05 * RNG.standard_normal(n), "power": RNG.random(n) * 10.0, "noise": RNG.random(n),
            "steady": RNG.integers(0, 5, n), "confirmed": RNG.random(n) < 0.5}


def _step_paths_reference(b: dict[str, np.ndarray], alpha: float, steady_move: float, survival: float,
                          confirm_batches: int) -> tuple:
    """The per-path loop :func:`step_paths_kernel` replaced: :func:`slip_reference`, then steadiness, per path."""
    count, n = b["cfo"].shape
    bridged, slips = np.empty((count, n)), np.zeros((count, n), bool)
    state = np.empty((n, 3))
    steady, confirmed = b["steady"].copy(), b["confirmed"].copy()
    for i in range(n):
        bridged[:, i], slips[:, i], *state[i] = slip_reference(b["cfo"][:, i], b["dt"], b["sigma"][:, i],
                                                               b["smooth"][i], b["run_cycles"][i], b["run_s"][i],
                                                               alpha, 6.0, 0.05)
        ok = abs(b["moved"][i]) < steady_move and b["power"][i] >= survival * b["noise"][i]
        steady[i] = steady[i] + 1 if ok else 0
        confirmed[i] = confirmed[i] or steady[i] >= confirm_batches
    return bridged, slips, state, steady, confirmed


@pytest.mark.parametrize("n", [0, 1, 3, 12])
def test_step_paths_kernel_is_bit_identical_to_the_per_path_loop(n):
    for _ in range(20):
        b = _batch(128, n)
        ref = _step_paths_reference(b, 10.0, 0.05, 4.0, 3)
        smooth, run_cycles, run_s = b["smooth"].copy(), b["run_cycles"].copy(), b["run_s"].copy()
        steady, confirmed = b["steady"].copy(), b["confirmed"].copy()
        bridged, slips = np.empty((128, n)), np.zeros((128, n), bool)
        step_paths_kernel(b["cfo"], b["dt"], b["sigma"], smooth, run_cycles, run_s, 10.0, 6.0, 0.05, b["moved"],
                          b["power"], b["noise"], 0.05, 4.0, 3, steady, confirmed, bridged, slips)
        assert np.array_equal(bridged, ref[0], equal_nan=True)
        assert np.array_equal(slips, ref[1])
        assert np.array_equal(np.column_stack([smooth, run_cycles, run_s]), ref[2], equal_nan=True)
        assert np.array_equal(steady, ref[3]) and np.array_equal(confirmed, ref[4])


def _rows_reference(tracker: PathTracker, paths: list[_Path], amplitudes, lags, rate, bridged, slips, noise, t_s,
                    frame_index) -> PathBatch:
    """The per-path construction :meth:`PathTracker._rows` replaced (one column set per path, then frame-major)."""
    confirmed = [i for i, p in enumerate(paths) if p.confirmed]
    count = len(t_s)
    if len(confirmed) == 0:
        return PathBatch.concatenate([])
    noise_sample = noise * tracker.header_gain
    cols = {name: [] for name in ("t_s", "frame_index", "path_id", "tower_id", "delay_s", "delay_rate", "cfo_hz",
                                  "snr_db", "flags")}
    for i in confirmed:
        p = paths[i]
        flags = np.zeros(count, np.uint8)
        flags[slips[:, i]] |= np.uint8(PathFlag.CYCLE_SLIP)
        if p.first:
            flags |= np.uint8(PathFlag.FIRST_PATH)
        if p.fading:
            flags |= np.uint8(PathFlag.FADING)
        if p.born:
            flags[0] |= np.uint8(PathFlag.BORN)
        with np.errstate(divide="ignore"):
            snr = 10.0 * np.log10(np.abs(amplitudes[:, i]) ** 2 / noise_sample[:, i])
        for name, column in (("t_s", t_s), ("frame_index", frame_index), ("path_id", np.full(count, p.path_id)),
                             ("tower_id", np.full(count, p.tower_id)), ("delay_s", lags[:, i] / SYMBOL_RATE_HZ),
                             ("delay_rate", np.full(count, rate[i] / tracker.mode.value.frame_length)),
                             ("cfo_hz", bridged[:, i]), ("snr_db", snr), ("flags", flags)):
            cols[name].append(column)
    order = np.argsort(np.tile(np.arange(count), len(confirmed)), kind="stable")
    out = {k: np.concatenate(v)[order] for k, v in cols.items()}
    nan = np.full(len(order), np.nan)
    return PathBatch(doppler_hz=nan, range_change_m=nan.copy(), **out)


def _paths(n: int) -> list[_Path]:
    return [_Path(path_id=10 + i, tower_id=int(RNG.integers(0, 3)), delay=float(RNG.uniform(-80, 80)),
                  rate=0.0, confirmed=bool(RNG.random() < 0.7), fading=int(RNG.integers(0, 3)),
                  born=bool(RNG.random() < 0.3), first=bool(RNG.random() < 0.3)) for i in range(n)]


@pytest.mark.parametrize("n", [0, 1, 4, 12])
def test_rows_are_bit_identical_to_the_per_path_construction(n):
    tracker = PathTracker(PnMode.PN420, 666e6, PathConfig())
    count = 128
    for _ in range(10):
        paths = _paths(n)
        amplitudes = (RNG.standard_normal((count, n)) + 1j * RNG.standard_normal((count, n))) * 10.0 ** RNG.uniform(-6, 2)
        amplitudes[RNG.random((count, n)) < 0.01] = 0.0            # a zero amplitude: -inf dB, as before
        noise = np.broadcast_to(RNG.random(count)[:, None] + 1e-3, (count, n))   # the span's per-frame noise
        args = (amplitudes, RNG.uniform(-80, 80, (count, n)), 1e-3 * RNG.standard_normal(n),
                np.where(RNG.random((count, n)) < 0.02, np.nan, RNG.standard_normal((count, n))),
                RNG.random((count, n)) < 0.05, noise, 0.1 + np.arange(count) * FRAME_S, 1000 + np.arange(count))
        born = [p.born for p in paths]
        ref = _rows_reference(tracker, paths, *args)
        for p, b in zip(paths, born):
            p.born = b
        rows = tracker._rows(paths, *args)
        for name, want in ref.columns().items():
            got = getattr(rows, name)
            assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=got.dtype.kind == "f"), name
        assert not any(p.born for p in paths if p.confirmed)
