"""``dtmbnav live``'s fusion side (dtmbnav.chain.live): a phone's HTTP push replayed at pace and the receiver's
range handed in as it comes give positions all along the walk, a now-cast that keeps up with the newest samples,
a final track as good as the batch fusion of the same inputs, and a recording ``fuse`` reads again.

The receiver is the observation-level model here (the rtl_tcp source and the receiver on it are tested in
tests/test_rtl_tcp.py, and the whole chain over IQ by ``python -m dtmbnav.evaluation.live_check``).
"""

from __future__ import annotations

import csv
import subprocess
import sys
import threading

import h5py
import numpy as np
import pytest

from dtmbnav.chain.live import LiveSetup, LiveWalk, output_paths
from dtmbnav.evaluation.evaluate import obs_range_source
from dtmbnav.field.live_positions import LivePositionWriter
from dtmbnav.field.phone_stream import SensorLoggerPush
from dtmbnav.field.towers import read_towers, towers_about
from dtmbnav.simulation.phone_replay import replay_push
from dtmbnav_core.records import ELLIPSE_95_CHI2, FrameFlag, ImuLog
from dtmbnav_core.sensors import read_imu, read_walk_truth
from fusion.metrics import position_errors_m
from fusion.pdr import PdrConfig, run_pdr
from fusion.run import FusionConfig, fuse
from sim.scenario import load_scenario

#: Replay pace: the walk's 100 s in about 5 s.
PACE = 10.0
#: The Weinberg gain the simulated walker's calibration walk gives (its truth file's weinberg_k_m).
PDR = PdrConfig(weinberg_k_m=0.4751489132109989)


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """A simulated park walk's phone log (Sensor Logger export) and its observation-level range."""
    folder = tmp_path_factory.mktemp("walk")
    subprocess.run([sys.executable, "-m", "dtmbnav.cli", "simulate", "park-loop", "--no-iq", "--phone-log",
                    "sensorlogger", "-o", str(folder), "-q"], check=True)
    truth = read_walk_truth(folder / "truth.h5")
    scenario = load_scenario("park-loop")
    ranges = obs_range_source(scenario, truth.track).ranges
    return folder, next(folder.glob("2026-*")), truth, scenario, ranges


def _frames(ranges, first: int, stop: int) -> dict[str, np.ndarray]:
    """Receiver frame columns of range rows ``first:stop`` (what the receiver's batches carry)."""
    rows = slice(first, stop)
    flags = np.where(ranges.valid[rows], 0, int(FrameFlag.LOW_QUALITY)).astype(np.uint32)
    return {"t_s": ranges.t_s[rows], "range_change_m": ranges.range_change_m[rows], "flags": flags,
            "snr_db": ranges.snr_db[rows], "si_snr_db": ranges.snr_db[rows], "segment_id": ranges.segment_id[rows]}


@pytest.fixture(scope="module")
def live_run(walk, tmp_path_factory):
    """The walk through LiveWalk: the phone pushed at PACE, the range handed in as its time comes."""
    folder, phone_log, truth, scenario, ranges = walk
    out = tmp_path_factory.mktemp("live")
    phone = SensorLoggerPush(host="127.0.0.1", port=0)
    setup = LiveSetup(towers=read_towers(folder / "towers.csv"), filters=("ukf",), pdr=PDR,
                      fusion=FusionConfig(), tick_s=0.05)
    lags = []
    with LivePositionWriter(output_paths(out)["csv"]) as writer:
        live = LiveWalk(phone, setup, writer, None, progress=False,
                        capture_start_utc_ns=lambda: phone.t0_utc_ns)   # the simulated capture starts with the log
        pusher = threading.Thread(target=replay_push, args=([phone_log], phone.url, PACE), daemon=True)
        live.start()
        pusher.start()
        sent = 0
        while pusher.is_alive():
            # Hand in the frames up to the phone's newest sample, as a receiver keeping pace would.
            stop = int(np.searchsorted(ranges.t_s, live.status.walk_s)) if np.isfinite(live.status.walk_s) else 0
            if stop > sent:
                live.on_frames(_frames(ranges, sent, stop))
                sent = stop
            lags.append((live.status.walk_s, live.status.step_lag_s, live.status.lag_s))
            pusher.join(0.05)
        live.on_frames(_frames(ranges, sent, len(ranges.t_s)))
        result = live.stop()
    live.write_recording(output_paths(out)["live"], result)
    return out, live, result, np.array(lags)


def test_positions_keep_up_with_the_walk(walk, live_run):
    """Positions at least once a second, at the newest sample, holding the motion up to 1.5 s before it."""
    _, _, truth, _, _ = walk
    _, live, result, lags = live_run
    assert result.fusion is not None and live.fusion.heading is not None
    assert 0.0 < result.status.longest_silence_s <= 1.0
    walk_s, step_lag_s, lag_s = (np.array(column) for column in zip(*lags))
    ticks = np.isfinite(walk_s) & np.isfinite(step_lag_s) & np.isfinite(lag_s)
    assert np.nanmax(lag_s[ticks]) < 0.05 * PACE   # at most one update's samples behind
    # Every true step taken more than 1.5 s before the newest sample is in the position (found by the PDR,
    # settled or provisional, to within a tenth of a second of its time).
    now_s, newest_step_s = walk_s[ticks], walk_s[ticks] - step_lag_s[ticks]
    due = np.searchsorted(truth.step_t_s, now_s - 1.5) - 1
    walking = (due >= 0) & (now_s > truth.step_t_s[0] + 5.0)
    assert walking.sum() > 50
    assert np.all(newest_step_s[walking] >= truth.step_t_s[due[walking]] - 0.1)


def test_final_track_is_the_batch_fusions(walk, live_run):
    """The live UKF's 95 % error is within 10 % of the batch fusion's of the same IMU, range and start fix."""
    _, _, truth, scenario, ranges = walk
    out, live, result, _ = live_run
    imu = read_imu(output_paths(out)["live"])
    batch = fuse(run_pdr(imu, PDR).steps, ranges, (live.start_fix.fix.x_m, live.start_fix.fix.y_m),
                 live.layout.tower_xy_m, ("ukf",), tower_height_m=live.layout.tower_height_m,
                 start_sigma_m=live.start_fix.fix.sigma_m)
    moved = _truth_in_live_frame(truth, scenario, live)
    p95 = {name: float(np.percentile(position_errors_m(track, moved), 95))
           for name, track in (("live", result.fusion.tracks["ukf"]), ("batch", batch.tracks["ukf"]))}
    assert p95["live"] <= 1.1 * p95["batch"], p95
    assert p95["batch"] < 5.0, p95   # and the batch itself works on this walk


def _truth_in_live_frame(truth, scenario, live):
    """The truth about the phone's first fix: shifted by where the tower lands in that frame."""
    shift = np.subtract(live.layout.tower_xy_m, (scenario.tower.x_m, scenario.tower.y_m))
    return type(truth.track)(t_s=truth.track.t_s, x_m=truth.track.x_m + shift[0], y_m=truth.track.y_m + shift[1],
                             heading_rad=truth.track.heading_rad, speed_mps=truth.track.speed_mps)


def test_nowcast_states_an_error_that_holds(walk, live_run):
    """The rows written ahead of the settled track (now-cast, held) hold the truth in their 95 % ellipse."""
    _, _, truth, scenario, _ = walk
    out, live, _, _ = live_run
    rows = list(csv.DictReader(output_paths(out)["csv"].open()))
    now = [r for r in rows if r["stage"] == "nowcast" and r["var_x_m2"]]
    t = np.array([float(r["t_s"]) for r in now])
    moved = _truth_in_live_frame(truth, scenario, live)
    d = np.column_stack([[float(r["east_m"]) for r in now] - np.interp(t, moved.t_s, moved.x_m),
                         [float(r["north_m"]) for r in now] - np.interp(t, moved.t_s, moved.y_m)])
    cov = np.array([[[float(r["var_x_m2"]), float(r["cov_xy_m2"])], [float(r["cov_xy_m2"]), float(r["var_y_m2"])]]
                    for r in now])
    nees = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov), d)
    assert len(now) > 100
    assert np.mean(nees <= ELLIPSE_95_CHI2) >= 0.9


def test_recording_is_a_walk_fuse_reads(live_run):
    out, live, result, _ = live_run
    with h5py.File(output_paths(out)["live"]) as f:
        assert {"imu", "gnss", "pdr", "fusion"} <= set(f)
        assert len(f["fusion/ukf/t_s"]) == len(result.fusion.tracks["ukf"]) > 100
        assert f["gnss"].attrs["start_fix_sigma_m"] == pytest.approx(live.start_fix.fix.sigma_m)
    rows = output_paths(out)["csv"].read_text().splitlines()
    stages = {row.split(",")[3] for row in rows[1:]}
    assert stages == {"heading", "filtered", "nowcast"} and len(rows) > 200


def test_a_phone_gap_is_bridged_onto_one_grid():
    """Grid times a phone gap left out (inside a chunk, or between two) are put back, linear across the gap."""
    def imu(t):
        t = np.asarray(t, dtype=np.float64)
        values = np.column_stack([t, 2 * t, -t])
        return ImuLog(t_s=t, acc_mps2=values, gyro_radps=values.copy(), mag_ut=values.copy())

    live = LiveWalk(None, LiveSetup(towers=(), pdr=PDR), LivePositionWriter(), None, progress=False)
    first = live._bridged(imu([0.0, 0.01, 0.02, 0.05, 0.06]))
    np.testing.assert_allclose(first.t_s, np.arange(7) * 0.01)
    np.testing.assert_allclose(first.acc_mps2[:, 1], 2 * first.t_s)
    live._last_imu = first
    second = live._bridged(imu([0.1, 0.11]))
    np.testing.assert_allclose(second.t_s, [0.07, 0.08, 0.09, 0.1, 0.11])
    np.testing.assert_allclose(second.gyro_radps[:, 2], -second.t_s)
    live._last_imu = second
    assert live._bridged(imu([0.12, 0.13])).t_s.tolist() == [0.12, 0.13]   # no gap: as it came
