"""Capture-to-phone time alignment (fusion/time_alignment.py; dtmbnav.chain.fuse's coarse/fine choice)."""

from __future__ import annotations

import numpy as np
import pytest

from dtmbnav.chain.fuse import fine_time_offset
from dtmbnav_core.records import PathRangeSeries, RangeSeries, Track
from fusion.time_alignment import AlignmentConfig, TimeAlignment, align_range_to_pdr, coarse_offset_s, range_rate

TOWER_XY_M = np.array([1500.0, 2500.0])


def _walk(rate_hz: float = 100.0) -> Track:
    """A walk with stops and turns: stand 5 s, then legs of 12 s at 1.3 m/s, each turned 90 deg after a 2 s
    stop, speed ramped over 1 s at each start and stop (ENU, m)."""
    t = np.arange(0.0, 80.0, 1.0 / rate_hz)
    speed = np.zeros_like(t)
    heading = np.zeros_like(t)
    start = 5.0
    for leg in range(5):
        ramp_up = np.clip(t - start, 0.0, 1.0)
        ramp_down = np.clip(start + 12.0 - t, 0.0, 1.0)
        inside = (t >= start) & (t <= start + 12.0)
        speed[inside] = 1.3 * np.minimum(ramp_up, ramp_down)[inside]
        heading[t >= start - 1.0] = np.radians(90.0 * leg + 10.0)
        start += 14.0
    heading = np.convolve(np.pad(heading, 50, mode="edge"), np.ones(101) / 101, mode="valid")  # turns of 1 s
    x = np.cumsum(speed * np.sin(heading)) / rate_hz
    y = np.cumsum(speed * np.cos(heading)) / rate_hz
    return Track(t_s=t, x_m=x, y_m=y, heading_rad=heading, speed_mps=speed)


def _ranges(track: Track, offset_s: float, noise_m: float, rng: np.random.Generator) -> RangeSeries:
    """The receiver's range change at 1800 frames/s on a clock starting ``offset_s`` after the track's."""
    t_rx = np.arange(0.0, track.t_s[-1] - offset_s - 0.1, 1.0 / 1800.0)
    x, y = np.interp(t_rx + offset_s, track.t_s, track.x_m), np.interp(t_rx + offset_s, track.t_s, track.y_m)
    r = np.hypot(x - TOWER_XY_M[0], y - TOWER_XY_M[1])
    r = r - r[0] + 0.02 * t_rx + noise_m * rng.standard_normal(len(t_rx))   # an oscillator's leftover slope
    n = len(t_rx)
    return RangeSeries(t_s=t_rx, range_change_m=r, snr_db=np.full(n, 15.0), valid=np.ones(n, bool),
                       segment_id=np.zeros(n, np.int32))


def _pdr_frame(track: Track, turn_rad: float, scale: float) -> Track:
    """The track as a PDR with an unknown initial heading and step-length scale sees it."""
    c, s = np.cos(turn_rad), np.sin(turn_rad)
    return Track(t_s=track.t_s, x_m=scale * (c * track.x_m - s * track.y_m),
                 y_m=scale * (s * track.x_m + c * track.y_m), heading_rad=track.heading_rad + turn_rad,
                 speed_mps=scale * track.speed_mps)


@pytest.mark.parametrize("offset_s, coarse_error_s", [(2.5, 0.7), (0.0, -1.2), (7.25, 2.0)])
def test_fine_alignment_recovers_the_offset_whatever_the_pdr_heading(offset_s, coarse_error_s):
    rng = np.random.default_rng(4)
    truth = _walk()
    ranges = _ranges(truth, offset_s, 0.005, rng)
    pdr = _pdr_frame(truth, np.radians(-123.0), 1.07)
    found, sigma = align_range_to_pdr(ranges, pdr, offset_s + coarse_error_s)
    assert found == pytest.approx(offset_s, abs=0.005)
    assert AlignmentConfig().step_timing_sigma_s <= sigma < 0.03
    assert abs(found - offset_s) < 4 * sigma + 0.002


def test_fine_alignment_sigma_grows_when_the_motion_says_little():
    """A straight walk at constant speed holds no timing information: the uncertainty says so."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 60.0, 0.01)
    straight = Track(t_s=t, x_m=1.3 * t, y_m=0.0 * t, heading_rad=np.full_like(t, np.pi / 2),
                     speed_mps=np.full_like(t, 1.3))
    _, sigma_straight = align_range_to_pdr(_ranges(straight, 1.0, 0.005, rng), straight, 1.0)
    _, sigma_turns = align_range_to_pdr(_ranges(_walk(), 1.0, 0.005, rng), _walk(), 1.0)
    assert sigma_straight > 10 * sigma_turns


def _wandering_bias(ranges: RangeSeries, rate_sigma_mps: float, correlation_s: float,
                    rng: np.random.Generator) -> RangeSeries:
    """The range with a range-rate bias that wanders (first-order Gauss-Markov, ``correlation_s``), as a
    reflected range's does where the walls the walker passes change, integrated into the range (m)."""
    t = ranges.t_s[::90]   # 20 Hz
    keep = np.exp(-np.diff(t, prepend=t[0]) / correlation_s)
    bias = np.zeros(len(t))
    kicks = rate_sigma_mps * np.sqrt(1.0 - keep ** 2) * rng.standard_normal(len(t))
    for i in range(1, len(t)):
        bias[i] = keep[i] * bias[i - 1] + kicks[i]
    drift = np.interp(ranges.t_s, t, np.concatenate([[0.0], np.cumsum(0.5 * (bias[1:] + bias[:-1]) * np.diff(t))]))
    return RangeSeries(t_s=ranges.t_s, range_change_m=ranges.range_change_m + drift, snr_db=ranges.snr_db,
                       valid=ranges.valid, segment_id=ranges.segment_id)


@pytest.mark.parametrize("seed", [0, 2, 3, 6])
def test_stated_sigma_covers_a_wandering_range_rate_bias(seed):
    """A range rate biased by 0.3 m/s wandering over 10 s (a street's reflections) moves the offset by far more
    than its residuals' curvature says: the stated sigma covers the error at 2 sigma, well above a clean walk's."""
    rng = np.random.default_rng(seed)
    truth = _walk()
    ranges = _wandering_bias(_ranges(truth, 2.5, 0.005, rng), 0.3, 10.0, rng)
    found, sigma = align_range_to_pdr(ranges, _pdr_frame(truth, np.radians(-123.0), 1.07), 2.8)
    assert abs(found - 2.5) <= 2.0 * sigma
    assert sigma > 2.0 * AlignmentConfig().step_timing_sigma_s


def _first_path(ranges: RangeSeries) -> PathRangeSeries:
    n = len(ranges.t_s)
    return PathRangeSeries(t_s=ranges.t_s, range_change_m=ranges.range_change_m, snr_db=ranges.snr_db,
                           valid=ranges.valid, slip=np.zeros(n, bool), path_age_s=ranges.t_s.copy())


def test_the_first_paths_range_rate_is_preferred_to_the_si_carriers():
    """The SI carriers follow a wandering reflection, the first path the direct path: aligned on the first path,
    the offset is as good as on a clean walk; where the first path slips, the windows across the slip are left to
    the SI carriers."""
    rng = np.random.default_rng(0)
    truth = _walk()
    direct = _ranges(truth, 2.5, 0.005, rng)
    reflected = _wandering_bias(direct, 0.3, 10.0, rng)
    pdr = _pdr_frame(truth, np.radians(-123.0), 1.07)
    alone, alone_sigma = align_range_to_pdr(reflected, pdr, 2.8)
    first_path = _first_path(direct)
    first_path.slip[len(direct.t_s) // 2] = True
    found, sigma = align_range_to_pdr(reflected, pdr, 2.8, first_path=first_path)
    assert abs(alone - 2.5) > 0.05 and alone_sigma > 0.08
    assert found == pytest.approx(2.5, abs=0.01) and sigma < 0.05


def _frames(ranges: RangeSeries) -> dict[str, np.ndarray]:
    """``/receiver/frames`` columns of a range series (no path tracker)."""
    return {"t_s": ranges.t_s, "range_change_m": ranges.range_change_m, "flags": np.zeros(len(ranges.t_s), np.int64),
            "snr_db": ranges.snr_db, "segment_id": ranges.segment_id}


def test_fuse_keeps_the_utc_stamps_where_the_motion_says_less_and_warns():
    """A straight walk at constant speed fixes no offset: fuse keeps the UTC stamps' and its line says why."""
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 60.0, 0.01)
    straight = Track(t_s=t, x_m=1.3 * t, y_m=0.0 * t, heading_rad=np.full_like(t, np.pi / 2),
                     speed_mps=np.full_like(t, 1.3))
    config = AlignmentConfig()
    coarse = TimeAlignment(1.2, config.coarse_sigma_s, "coarse", coarse_offset_s=1.2,
                           coarse_sigma_s=config.coarse_sigma_s)
    kept = fine_time_offset(_frames(_ranges(straight, 1.0, 0.005, rng)), straight, coarse, config)
    assert kept.source == "coarse" and kept.offset_s == 1.2 and kept.too_little
    assert kept.fine_sigma_s >= config.coarse_sigma_s
    assert "too little to align on" in kept.describe() and "UTC stamps' offset is kept" in kept.describe()
    # A walk with stops and turns is aligned, with no warning.
    fine = fine_time_offset(_frames(_ranges(_walk(), 1.0, 0.005, rng)), _walk(), coarse, config)
    assert fine.source == "fine" and not fine.too_little and "WARNING" not in fine.describe()
    assert fine.offset_s == pytest.approx(1.0, abs=0.005)


def test_range_rate_leaves_out_windows_across_a_gap():
    rng = np.random.default_rng(6)
    ranges = _ranges(_walk(), 0.0, 0.0, rng)
    valid = ranges.valid.copy()
    valid[(ranges.t_s > 30.0) & (ranges.t_s < 30.5)] = False
    gapped = RangeSeries(t_s=ranges.t_s, range_change_m=ranges.range_change_m, snr_db=ranges.snr_db, valid=valid,
                         segment_id=ranges.segment_id)
    grid = np.array([20.0, 29.8, 30.2, 30.9, 40.0])
    rate = range_rate(gapped, grid, AlignmentConfig(velocity_window_s=1.0))
    assert np.isfinite(rate[[0, 4]]).all() and np.isnan(rate[[1, 2, 3]]).all()


def test_too_little_overlap_is_an_error():
    rng = np.random.default_rng(7)
    truth = _walk()
    ranges = _ranges(truth, 0.0, 0.0, rng)
    with pytest.raises(ValueError, match="overlap"):
        align_range_to_pdr(ranges, truth, 200.0)


def test_coarse_offset_and_disagreement():
    assert coarse_offset_s(1_700_000_012_500_000_000, 1_700_000_010_000_000_000) == pytest.approx(2.5)
    agree = TimeAlignment(2.6, 0.01, "fine", coarse_offset_s=2.5, coarse_sigma_s=1.0, fine_offset_s=2.6,
                          fine_sigma_s=0.01)
    far = TimeAlignment(9.0, 0.01, "fine", coarse_offset_s=2.5, coarse_sigma_s=1.0, fine_offset_s=9.0,
                        fine_sigma_s=0.01)
    assert not agree.disagrees and far.disagrees
    assert "UTC stamps say +2.500 s" in far.describe()


def test_receive_records_the_start_time_of_a_raw_capture(tiny_sim, tmp_path):
    """A raw capture records no start time: ``--start-time`` gives it, and the output carries it for fuse."""
    import shutil

    from dtmbnav.cli import EXIT_OK, EXIT_USAGE, main
    from dtmbnav_core import schema
    from dtmbnav_core.h5io import read_attrs

    raw = tmp_path / "walk.ci8"
    shutil.copy(tiny_sim / "tiny-walk.sigmf-data", raw)
    options = ["--format", "ci8", "--rate", "7.56e6", "--center", "666e6"]
    assert main(["-q", "receive", str(raw), *options, "--start-time", "2026-12-05T10:00:00.25Z", "-o",
                 str(tmp_path / "rx.h5")]) == EXIT_OK
    assert read_attrs(tmp_path / "rx.h5", schema.RECEIVER_FRAMES)[schema.START_UTC_NS_ATTR] == (
        1_796_464_800_250_000_000)
    # The SigMF capture states its own start (core:datetime): another one is refused before any work.
    assert main(["-q", "receive", str(tiny_sim / "tiny-walk.sigmf-meta"), "--start-time", "2026-12-05T10:00:00Z",
                 "-o", str(tmp_path / "rx2.h5")]) == EXIT_USAGE
    assert not (tmp_path / "rx2.h5").exists()
