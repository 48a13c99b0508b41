"""Streaming fusion (fusion.streaming) against the batch fuse, the truth and its own bounds."""

import numpy as np
import pytest
from fusion_synth import exact_ranges, park_like_walk

from dtmbnav_core.records import ELLIPSE_95_CHI2, RangeSeries
from fusion.metrics import position_errors_m
from fusion.observations import AggregationConfig
from fusion.run import FusionConfig, fuse
from fusion.streaming import DEFAULT_STEP_LAG_S, LivePositions, StreamingFusion

TOWER = ((2000.0, 2200.0), 150.0)
#: How far the settled steps trail the ranges in the streamed fixture, s (the streaming PDR settles a step 7-12 s
#: after its samples); the steps in between are passed to nowcast as provisional.
STEP_LAG_S = 8.0


def hard_ranges(walk) -> RangeSeries:
    """Exact ranges with what the batch rule carries across epochs: an SNR dip (rule 5's deficit), a blocked
    stretch after which the receiver restarts its range from a new origin (a new segment, rule 7; settle_s)."""
    r = exact_ranges(walk)
    t = r.t_s
    snr = np.where((t > 40.0) & (t < 46.0), 12.0, 20.0)
    blocked = (t > 60.0) & (t < 64.0)
    segment = (t >= 64.0).astype(np.int64)
    return RangeSeries(t, r.range_change_m + np.where(segment > 0, 3.0, 0.0), snr, ~blocked, segment)


def feed(sf: StreamingFusion, pdr, ranges, chunk_s: float = 0.5, step_lag_s: float = 1.0, check=None):
    """Feed the walk in chunks of ``chunk_s`` (steps ``step_lag_s`` behind the ranges), polling after each."""
    t, si, ri, polled = float(ranges.t_s[0]), 0, 0, []
    while ri < len(ranges) or si < len(pdr):
        t += chunk_s
        sj = int(np.searchsorted(pdr.t_s, t - step_lag_s, "right")) if ri < len(ranges) else len(pdr)
        rj = int(np.searchsorted(ranges.t_s, t, "right"))
        if sj > si:
            sf.add_steps(pdr.select(slice(si, sj)))
        if rj > ri:
            sf.add_ranges(ranges.select(slice(ri, rj)))
        si, ri = sj, rj
        polled.append(sf.poll())
        if check is not None:
            check(sf, polled, t, si)
    return sf.finish(), polled


@pytest.fixture(scope="module")
def walk():
    return park_like_walk(gain=1.1, drift_dps=0.02, seed=3)


def stream(walk, ranges, filters=("ukf",), config=FusionConfig(), **kw):
    sf = StreamingFusion((0.0, 0.0), TOWER[0], filters, tower_height_m=TOWER[1], config=config)
    return feed(sf, walk.pdr, ranges, **kw)


@pytest.mark.parametrize("filters", [("ukf",)])
def test_streamed_track_is_the_batch_track(walk, filters):
    """With the batch rule's whole-walk SNR level left out (the one rule a stream cannot apply) the streamed
    epochs, heading and track are the batch's to rounding; with it, the 95 % error stays within 10 %."""
    ranges = hard_ranges(walk)
    config = FusionConfig(n_particles=500, aggregation=AggregationConfig(max_snr_deficit_db=None))
    batch = fuse(walk.pdr, ranges, (0.0, 0.0), TOWER[0], filters, tower_height_m=TOWER[1], config=config)
    live, _ = stream(walk, ranges, filters, config)
    assert live.heading.heading_rad == batch.heading.heading_rad
    for column in ("range_change_m", "range_sigma_m", "range_new_origin", "pdr_heading_rad", "dt_s"):
        np.testing.assert_allclose(getattr(live.epochs, column), getattr(batch.epochs, column), atol=1e-9)
    assert np.isnan(batch.epochs.range_change_m).sum() > 20 and batch.epochs.range_new_origin.any()
    name = filters[0]
    for column in ("x_m", "y_m", "var_x_m2", "var_y_m2", "cov_xy_m2"):
        np.testing.assert_allclose(getattr(live.tracks[name], column), getattr(batch.tracks[name], column),
                                   atol=1e-6)
    if name == "ukf":
        batch = fuse(walk.pdr, ranges, (0.0, 0.0), TOWER[0], filters, tower_height_m=TOWER[1])
        live, _ = stream(walk, ranges, filters)
        p95 = [np.percentile(position_errors_m(r.tracks[name], walk.truth), 95) for r in (batch, live)]
        assert abs(p95[1] - p95[0]) <= 0.1 * p95[0]


@pytest.fixture(scope="module")
def streamed(walk):
    """One streamed walk (0.5 s chunks, settled steps STEP_LAG_S behind the ranges) with, after each poll, the
    frames held, the steps due but not given, and the now-cast of the steps held back (up to the newest frame)."""
    given, held, late, filtered_at, nowcasts = set(), [], [], [], []

    def check(sf, polled, t, n_steps):
        p = polled[-1]
        given.update(p.t_s[p.filtered].tolist())
        held.append(sf.buffered_frames)
        newest = min(t, float(walk.truth.t_s[-1]))
        if sf.heading is not None:
            filtered_at.append(t)
            due = walk.pdr.t_s[:n_steps][walk.pdr.t_s[:n_steps] <= newest - sf.reach_s]
            late.extend(set(due.tolist()) - given)
        provisional = walk.pdr.select(slice(n_steps, int(np.searchsorted(walk.pdr.t_s, newest, "right"))))
        nowcasts.append((newest, sf.nowcast(provisional)))

    result, polled = stream(walk, hard_ranges(walk), check=check, step_lag_s=STEP_LAG_S)
    return result, polled, held, late, filtered_at, nowcasts


def test_chunking_does_not_change_the_track(walk, streamed):
    """Nor do the now-casts (the fixture's, after every poll): they never enter the filters."""
    coarse, _ = stream(walk, hard_ranges(walk), chunk_s=2.7, step_lag_s=3.0)
    np.testing.assert_allclose(streamed[0].tracks["ukf"].x_m, coarse.tracks["ukf"].x_m, atol=1e-6)
    np.testing.assert_allclose(streamed[0].tracks["ukf"].y_m, coarse.tracks["ukf"].y_m, atol=1e-6)


def test_every_complete_epoch_is_given_by_the_next_poll_and_the_buffer_stays_bounded(walk, streamed):
    """Latency: once the heading is confident, every step whose windows the ranges cover is in the polls so far,
    long before the end. Memory: the frames held stay within lag + chunk + reach + a step, whatever the walk's
    length (50 Hz frames here)."""
    _, _, held, late, filtered_at, _ = streamed
    assert filtered_at and filtered_at[0] < walk.pdr.t_s[-1] - 30.0
    assert not late
    assert max(held) <= 50.0 * (DEFAULT_STEP_LAG_S + 0.5 + 1.0)       # before the first step: the lag's worth
    walking = held[int((walk.pdr.t_s[0] + STEP_LAG_S) / 0.5) + 4:]   # once the first step is taken
    assert max(walking) <= 50.0 * (STEP_LAG_S + 0.5 + 1.0 + 1.0)


def test_the_unconfident_stage_states_an_error_that_holds(walk, streamed):
    """Before the heading is confident the rows are the PDR turned by the best heading so far: the truth lies
    inside each row's stated 95 % ellipse."""
    rows = [p.select(~p.filtered) for p in streamed[1] if len(p)]
    t = np.concatenate([r.t_s for r in rows])
    assert len(t) > 50
    x, y = np.concatenate([r.x_m for r in rows]), np.concatenate([r.y_m for r in rows])
    cov = np.concatenate([r.position_covariance_m2() for r in rows])
    error = np.stack([x - np.interp(t, walk.truth.t_s, walk.truth.x_m),
                      y - np.interp(t, walk.truth.t_s, walk.truth.y_m)], axis=1)
    nees = np.einsum("ni,nij,nj->n", error, np.linalg.inv(cov), error)
    assert np.all(nees <= ELLIPSE_95_CHI2)


def nowcast_rows(streamed, filtered: bool) -> LivePositions:
    """The fixture's now-cast rows of one stage."""
    rows = [n.select(n.filtered == filtered) for _, n in streamed[5]]
    rows = [n for n in rows if len(n)]
    return LivePositions(**{k: np.concatenate([getattr(n, k) for n in rows]) for k in rows[0].columns()})


def nees(x_m, y_m, reference_x_m, reference_y_m, covariance_m2):
    """Normalised squared distance of the reference from each row under its stated covariance."""
    error = np.stack([x_m - reference_x_m, y_m - reference_y_m], axis=1)
    return np.einsum("ni,nij,nj->n", error, np.linalg.inv(covariance_m2), error)


def test_nowcast_is_close_to_the_settled_filter_and_states_an_error_that_holds(walk, streamed):
    """Once the heading is confident the now-cast of the held-back steps lies within its stated 95 % ellipse of
    the filter's row for the same step once settled, and of the truth, on nearly every row; its newest row is at
    most 1.5 s behind the newest frame while walking."""
    rows = nowcast_rows(streamed, filtered=True)
    assert np.all(rows.nowcast) and len(rows) > 500
    settled = streamed[0].tracks["ukf"]
    i = np.searchsorted(settled.t_s, rows.t_s)
    np.testing.assert_array_equal(settled.t_s[i], rows.t_s)
    cov = rows.position_covariance_m2()
    to_settled = nees(rows.x_m, rows.y_m, settled.x_m[i], settled.y_m[i], cov) <= ELLIPSE_95_CHI2
    to_truth = nees(rows.x_m, rows.y_m, np.interp(rows.t_s, walk.truth.t_s, walk.truth.x_m),
                    np.interp(rows.t_s, walk.truth.t_s, walk.truth.y_m), cov) <= ELLIPSE_95_CHI2
    assert to_settled.mean() >= 0.95 and to_truth.mean() >= 0.9
    # The filter's speed over the PDR's takes out the PDR's 10 % step-length gain (unscaled: 0.5 m median).
    assert np.median(np.hypot(rows.x_m - settled.x_m[i], rows.y_m - settled.y_m[i])) <= 0.25
    last = [(t, n.t_s[-1]) for t, n in streamed[5] if len(n) and walk.pdr.t_s[0] + 1.0 < t < walk.pdr.t_s[-1]]
    assert len(last) > 100 and max(t - s for t, s in last) <= 1.5


def test_nowcast_before_the_heading_is_confident_is_the_provisional_stage(walk, streamed):
    """Before the heading is confident the now-cast is the provisional stage's rule on the held-back steps: the
    truth lies inside each row's stated 95 % ellipse."""
    rows = nowcast_rows(streamed, filtered=False)
    assert np.all(rows.nowcast) and len(rows) > 100
    error = nees(rows.x_m, rows.y_m, np.interp(rows.t_s, walk.truth.t_s, walk.truth.x_m),
                 np.interp(rows.t_s, walk.truth.t_s, walk.truth.y_m), rows.position_covariance_m2())
    assert np.all(error <= ELLIPSE_95_CHI2)


def test_bad_input_is_refused_and_loses_nothing(walk):
    with pytest.raises(ValueError, match="cannot stream"):
        StreamingFusion((0.0, 0.0), TOWER[0], ("wt-ukf",))
    sf = StreamingFusion((0.0, 0.0), TOWER[0], ("ukf",))
    ranges = exact_ranges(walk)
    sf.add_ranges(ranges.select(slice(0, 100)))
    with pytest.raises(ValueError, match="increase"):
        sf.add_ranges(ranges.select(slice(50, 150)))
    assert sf.buffered_frames == 100
    sf.add_steps(walk.pdr.select(slice(0, 5)))
    assert not len(sf.nowcast(walk.pdr.select(slice(5, 5))))
    for held_back in (slice(4, 8), slice(6, 4, -1)):   # not after the last settled step; not increasing
        with pytest.raises(ValueError, match="increase past"):
            sf.nowcast(walk.pdr.select(held_back))
    assert len(sf.nowcast(walk.pdr.select(slice(5, 8)))) == 3
