"""End to end on the simulator's captures (sim.rf), truth from its per-frame truth.

Locks in every header mode, with constant and rotating phase, at several input
rates and sample formats with a 5 kHz tuner offset, and names the SI word; on
a park-loop segment (line of sight, C/N 15 dB, GNSS-disciplined clock) the
radial velocity and the integrated range, SI carriers and first path, meet the
brief's accuracy; on an sfn-park segment (two towers, free-running TCXO) the
tower-differenced range does. The 60 s and whole-walk figures come from
``python -m dtmbnav.evaluation.accuracy``.
"""

import h5py
import numpy as np
import pytest
from dtmbnav.evaluation.accuracy import accuracy, match_truth, path_accuracy, run_capture

from dtmbnav_core.records import FrameFlag
from receiver.capture import open_capture
from receiver.pipeline import ReceiverConfig, receive_file
from sim.scenario import load_scenario
from sim.simulate import simulate

BULK_CFO_HZ = 5000.0


@pytest.mark.slow
@pytest.mark.parametrize("rate,fmt,mode,rotating", [
    (7.56e6, "cf32", "PN420", True),
    (10e6, "ci8", "PN945", True),
    (16e6, "ci16", "PN595", False),
    (20e6, "cu8", "PN420", False),
    (10e6, "cf32", "PN945", False),
])
def test_locks_at_rates_formats_and_modes(rate, fmt, mode, rotating):
    scn = load_scenario("park-loop-cw").replace(tower={"rotating_phase": rotating})
    run = run_capture(scn, start_s=3.0, seconds=0.12, config=ReceiverConfig(clock_offset_hz=0.0),
                      sample_rate_hz=rate, sample_format=fmt, pn_mode=mode, bulk_cfo_hz=BULK_CFO_HZ)
    f, tr, rx = run.frames, run.truth, run.receiver
    assert rx.pn_mode.name == mode and rx.acquisitions[0].rotating == (rotating and mode != "PN595")
    assert len(rx.acquisitions) == 1 and rx.si_index == 15
    assert len(f) >= len(tr.t_s) - 20                           # acquisition uses the first ~17 frames
    j = match_truth(f, tr)
    assert np.max(np.abs(f.t_s - tr.t_s[j])) < 2e-6              # frame times on the capture clock
    if rotating and mode != "PN595":
        assert np.all((tr.frame_number[j] - f.frame_index) % rx.pn_mode.value.frames_per_superframe == 0)
    truth_cfo = tr.doppler_hz[j] + tr.clock_offset_hz[j] + BULK_CFO_HZ
    err = f.cfo_hz - truth_cfo
    assert abs(np.nanmean(err)) < 3.0 and np.nanstd(err) < 25.0
    assert abs(np.nanmean(f.cfo_pn_hz - truth_cfo)) < 3.0
    assert np.nanmedian(f.snr_db) > 10.0


@pytest.mark.slow
def test_park_loop_segment_velocity_and_range_accuracy():
    """16 s of park-loop (4 s still for f_s, then 12 s of walking): the brief's accuracy figures."""
    scn = load_scenario("park-loop-cw")
    still = scn.walk.start_still_s
    start = still - 4.0
    run = run_capture(scn, start_s=start, seconds=16.0, config=ReceiverConfig(static_window_s=3.5))
    acc = accuracy(run, still - start, 16.0)
    assert acc.velocity_rmse_1s_mps < 0.05
    assert acc.range_error_p95_m < 0.5
    assert abs(acc.clock_offset_error_hz) < 0.05
    assert not np.any(run.frames.flags & (FrameFlag.GAP | FrameFlag.LOW_QUALITY))
    # The first path is the direct path (line of sight): its range change meets the park-loop target.
    paths = path_accuracy(run, still - start, 16.0)
    assert paths.first_path_share == 1.0 and paths.first_path_error_p95_m < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("plan_error_s", [0.0, None])
def test_sfn_segment_tower_difference_cancels_the_free_running_clock(plan_error_s):
    """sfn-park, 4 s still then 6 s of walking, free-running TCXO: the two towers' range difference; the towers
    at the plan's offsets, and at the scenario's own drawn ones (``plan_error_s`` None)."""
    scn = load_scenario("sfn-park")
    if plan_error_s is not None:
        scn = scn.replace(network={"plan_error_s": plan_error_s})
    still = scn.walk.start_still_s
    start = still - 4.0
    run = run_capture(scn, start_s=start, seconds=10.0, config=ReceiverConfig(static_window_s=3.5))
    acc = path_accuracy(run, still - start, 10.0)
    assert np.all(run.frames.tower_count[run.frames.t_s > still - start] == 2)
    assert acc.difference_error_p95_m < 0.1


@pytest.mark.slow
def test_receive_file_from_simulated_sigmf(tmp_path):
    scn = load_scenario("park-loop-cw")
    sim = simulate(scn, tmp_path / "sim", seconds=0.1, start_s=1.0)
    capture = open_capture(sim.capture_path)
    sink, attrs = receive_file(capture, tmp_path / "rx.h5", ReceiverConfig(clock_offset_hz=0.0),
                               csv_path=tmp_path / "rx.csv", progress=False)
    assert sink.frames > 150
    with h5py.File(tmp_path / "rx.h5", "r") as f:
        group = f["receiver/frames"]
        assert group.attrs["pn_mode"] == "PN420" and group.attrs["si_index"] == 15
        assert group.attrs["sample_rate_hz"] == capture.sample_rate_hz
        assert group.attrs["carrier_hz"] == scn.tower.carrier_hz
        assert len(group["frame_index"]) == sink.frames
        assert np.all(np.diff(group["frame_index"][()]) == 1)
        paths = f["receiver/paths"]
        assert paths.attrs["taps_before"] == 83 and len(paths["t_s"]) == sink.paths
    assert len((tmp_path / "rx.csv").read_text().splitlines()) == sink.frames + 1
    with pytest.raises(ValueError, match="carrier_hz"):
        capture.center_hz = None
        receive_file(capture, None, progress=False)
