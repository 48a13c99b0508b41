"""Every track states its error: the covariance against truth, its metrics, its file round trip."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from fusion_synth import exact_ranges, park_like_walk, ranges_with_blockage

from dtmbnav_core import schema
from dtmbnav_core.h5io import read_fused_track, write_columns
from dtmbnav_core.records import ELLIPSE_95_CHI2, FusedTrack, Track
from fusion.driver import drive_filter
from fusion.metrics import position_nees, stated_error_stats
from fusion.observations import aggregate_ranges, build_epochs
from fusion.run import FILTER_BUILDERS, FusionConfig, fuse


def constant_velocity_runs(runs: int = 20, steps: int = 100, seed: int = 1) -> tuple[list[FusedTrack], list[Track]]:
    """A linear Kalman filter on simulated constant-velocity walks seen in position: its tracks and the truths."""
    rng = np.random.default_rng(seed)
    dt, q, r = 1.0, 0.05, 1.0
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    Q = q * np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), np.eye(2))[[0, 2, 1, 3]][:, [0, 2, 1, 3]]
    H = np.eye(2, 4)
    R = r * np.eye(2)
    tracks, truths = [], []
    for _ in range(runs):
        P = np.diag([4.0, 4.0, 1.0, 1.0])
        truth = rng.multivariate_normal([0.0, 0.0, 1.0, 0.5], P)
        x = np.array([0.0, 0.0, 1.0, 0.5])
        rows, true_rows, covariances = [], [], []
        for _ in range(steps):
            truth = F @ truth + rng.multivariate_normal(np.zeros(4), Q)
            x, P = F @ x, F @ P @ F.T + Q
            gain = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
            x = x + gain @ (truth[:2] + rng.normal(0.0, np.sqrt(r), 2) - H @ x)
            P = (np.eye(4) - gain @ H) @ P
            rows.append(x.copy())
            true_rows.append(truth.copy())
            covariances.append(P[:2, :2])
        rows, true_rows = np.array(rows), np.array(true_rows)
        t = np.arange(steps, dtype=np.float64)
        zeros = np.zeros(steps)
        tracks.append(FusedTrack.from_track(Track(t, rows[:, 0], rows[:, 1], zeros, zeros), np.array(covariances)))
        truths.append(Track(t, true_rows[:, 0], true_rows[:, 1], zeros, zeros))
    return tracks, truths


def test_a_right_covariance_holds_the_truth_95_percent_and_its_nees_is_2():
    """Linear-Gaussian case where the answer is known: NEES mean 2, 95 % of the truths inside the ellipse."""
    tracks, truths = constant_velocity_runs()
    stats = [stated_error_stats(track, truth) for track, truth in zip(tracks, truths)]
    assert np.mean([s.mean_nees for s in stats]) == pytest.approx(2.0, abs=0.2)
    assert np.mean([s.in_ellipse_95 for s in stats]) == pytest.approx(0.95, abs=0.02)
    # A covariance stated twice too small puts the NEES at 4 and the coverage near 78 %.
    halved = [FusedTrack.from_track(t, t.position_covariance_m2() / 2) for t in tracks]
    assert np.mean([stated_error_stats(t, truth).in_ellipse_95 for t, truth in zip(halved, truths)]) < 0.85


def test_nees_of_one_row_and_the_95_radius():
    track = FusedTrack.from_track(Track(*(np.zeros(1),) * 5), np.array([[[4.0, 1.0], [1.0, 2.0]]]))
    truth = Track(np.array([-1.0, 1.0]), np.array([1.0, 1.0]), np.array([2.0, 2.0]), np.zeros(2), np.zeros(2))
    e = np.array([1.0, 2.0])
    assert position_nees(track, truth)[0] == pytest.approx(e @ np.linalg.solve([[4.0, 1.0], [1.0, 2.0]], e))
    largest = np.linalg.eigvalsh([[4.0, 1.0], [1.0, 2.0]]).max()
    assert track.accuracy_radius_m()[0] == pytest.approx(np.sqrt(ELLIPSE_95_CHI2 * largest))
    assert ELLIPSE_95_CHI2 == pytest.approx(5.991, abs=1e-3)


@pytest.fixture(scope="module")
def synthetic_run():
    walk = park_like_walk(gain=1.1, drift_dps=0.3, seed=5)
    epochs = build_epochs(walk.pdr, aggregate_ranges(exact_ranges(walk), walk.pdr.t_s), walk.initial_heading_rad)
    return walk, epochs


@pytest.mark.parametrize("name", ["ukf", "adaptive-kf", "rank-kf"])
def test_kalman_cross_covariance_is_the_linearised_one(name, synthetic_run):
    """What each Kalman-type filter hands the smoother, Cov(x before, x after) of its prediction, is P F^T to
    first order (the sigma-point filters' from their propagated points)."""
    walk, epochs = synthetic_run
    kf = FILTER_BUILDERS[name](epochs, walk.geometry, FusionConfig())
    for n in range(20):
        kf.predict(epochs.control(n))
        kf.update(epochs.observation(n))
    x, P = np.array(kf.x), np.array(kf.P)
    expected = P @ kf.model_transition_jacobian(x, epochs.control(20)).T
    np.testing.assert_allclose(kf.time_update(epochs.control(20)), expected, atol=1e-3 * np.abs(expected).max())


def test_recorded_joint_covariance_holds_through_a_clone_reanchoring():
    """What the RTS smoother takes, the joint covariance of an epoch's filtered state and the next prior, is a
    covariance (positive semi-definite) at every epoch, also where a range lost in a 70 s blockage comes back and
    is re-anchored by cloning: the clone's cross-covariance column is carried with it (fusion.kalman's base class,
    shown on the EKF)."""
    walk = park_like_walk(gain=1.15, seed=4, laps=2)
    epochs = build_epochs(walk.pdr, aggregate_ranges(ranges_with_blockage(walk, 30.0, 100.0, 8.0), walk.pdr.t_s),
                          walk.initial_heading_rad)
    kf = FILTER_BUILDERS["adaptive-kf"](epochs, walk.geometry, FusionConfig())
    drive_filter(kf, epochs, smooth=True)
    h = kf.history
    for k in range(1, len(h.post_P)):
        joint = np.block([[h.post_P[k - 1], h.cross[k]], [h.cross[k].T, h.prior_P[k]]])
        scale = np.sqrt(np.diag(joint))
        assert np.linalg.eigvalsh(joint / np.outer(scale, scale)).min() > -1e-6, k


@pytest.mark.parametrize("name", ["pf", "ukf", "adaptive-kf"])
def test_filters_state_their_error_and_smooth(name, synthetic_run):
    """Each filter's track states a covariance that holds the truth on a walk with exact ranges; the smoothed
    track has one row per step, ends where the filter ends, and the RTS smoother's is nowhere less certain."""
    walk, epochs = synthetic_run
    run = drive_filter(FILTER_BUILDERS[name](epochs, walk.geometry, FusionConfig(n_particles=1000)), epochs,
                       smooth=True)
    assert run.track.has_stated_error() and run.smoothed.has_stated_error()
    filtered, smoothed = stated_error_stats(run.track, walk.truth), stated_error_stats(run.smoothed, walk.truth)
    assert filtered.in_ellipse_95 > 0.9 and smoothed.in_ellipse_95 > 0.9
    assert 0.05 < filtered.mean_nees < 5.0
    np.testing.assert_allclose(run.smoothed.t_s, run.track.t_s)
    trace = lambda t: t.var_x_m2 + t.var_y_m2  # noqa: E731
    assert trace(run.smoothed)[-1] == pytest.approx(trace(run.track)[-1], rel=1e-3)
    if name != "pf":    # the particles' ancestry is a Monte Carlo estimate: no bound row by row
        assert np.all(trace(run.smoothed) <= trace(run.track) + 1e-9)


def test_fused_track_round_trip_and_an_old_file(tmp_path):
    """The covariance goes to /fusion/<filter> and back; a group written before it reads as stating no error,
    and a group with only part of it is refused."""
    track = FusedTrack.from_track(Track(*(np.arange(3.0),) * 5), np.tile([[2.0, 0.5], [0.5, 1.0]], (3, 1, 1)))
    path = tmp_path / "results.h5"
    with h5py.File(path, "w") as f:
        write_columns(f, schema.fusion_group("ukf"), track)
        write_columns(f, schema.fusion_group("ukf", smoothed=True), track)
        write_columns(f, schema.fusion_group("old"), {k: getattr(track, k) for k in schema.TRACK_COLUMNS})
        write_columns(f, schema.fusion_group("broken"), {**{k: getattr(track, k) for k in schema.TRACK_COLUMNS},
                                                         "var_x_m2": track.var_x_m2})
    read = read_fused_track(path, schema.fusion_group("ukf"))
    np.testing.assert_array_equal(read.position_covariance_m2(), track.position_covariance_m2())
    assert read_fused_track(path, schema.fusion_group("ukf", smoothed=True)).has_stated_error()
    old = read_fused_track(path, schema.fusion_group("old"))
    assert not old.has_stated_error() and np.all(np.isnan(old.accuracy_radius_m()))
    np.testing.assert_array_equal(old.x_m, track.x_m)
    assert np.isnan(stated_error_stats(old, track).mean_nees)
    with pytest.raises(ValueError, match="var_x_m2"):
        read_fused_track(path, schema.fusion_group("broken"))


def test_map_files_carry_each_points_95_radius():
    """GeoJSON: an ``accuracy_m`` per line coordinate (null where not stated, left out where a point is not
    finite); GPX: a dtmbnav:accuracy_m extension per track point; a track without stated error has neither."""
    import gpxpy

    from dtmbnav.field.maps import MapTrack, tracks_to_geojson, tracks_to_gpx

    stated = MapTrack("ukf", "filter", np.array([1.0, 1.1, np.nan, 1.2]), np.array([2.0, 2.1, 2.2, 2.3]),
                      accuracy_m=np.array([3.0, np.nan, 5.0, 6.0]))
    plain = MapTrack("truth", "truth", np.array([1.0, 1.1]), np.array([2.0, 2.1]))
    features = tracks_to_geojson([stated, plain], [])["features"]
    assert features[0]["properties"]["accuracy_m"] == [3.0, None, 6.0]
    assert "accuracy_m" not in features[1]["properties"]
    gpx = gpxpy.parse(tracks_to_gpx([stated, plain], []).to_xml())
    points = gpx.tracks[0].segments[0].points
    assert [[e.text for e in p.extensions] for p in points] == [["3.000"], [], ["6.000"]]
    assert not any(p.extensions for p in gpx.tracks[1].segments[0].points)


def test_report_ellipse_axes_and_table_columns():
    """The drawn ellipse is the stated 95 % one; the table shows coverage and NEES for a stated track only."""
    from dtmbnav.chain.report import SummaryRow, ellipse_axes, ellipse_rows, format_rows

    width, height, angle = ellipse_axes(np.array([[9.0, 0.0], [0.0, 1.0]]))
    assert (width, height, angle % 180.0) == pytest.approx((6.0 * np.sqrt(ELLIPSE_95_CHI2), 2.0 * np.sqrt(
        ELLIPSE_95_CHI2), 0.0))
    assert ellipse_axes(np.array([[1.0, 0.0], [0.0, 9.0]]))[2] % 180.0 == pytest.approx(90.0)
    np.testing.assert_array_equal(ellipse_rows(np.arange(0.0, 25.0, 0.5), every_s=10.0), [0, 20, 40])
    table = format_rows([SummaryRow("ukf", 1.0, 2.0, 3.0, 0.5, None, 0.93, 2.1),
                         SummaryRow("pdr", 1.0, 2.0, 3.0, None, None)])
    assert "in 95 % ellipse | NEES" in table and "| 93 % | 2.10 |" in table


def test_the_start_fixs_sigma_is_the_filters_first_stated_error(synthetic_run):
    """A start fix stating 6 m (a blocked sky) starts every filter four times wider than one stating 1.5 m:
    the first epoch's stated variance across the range follows the fix's, where the range says nothing."""
    walk, _ = synthetic_run
    g = walk.geometry
    start, tower = (g.start_x_m, g.start_y_m), (g.tower_x_m, g.tower_y_m)
    first_var = {}
    for sigma in (1.5, 6.0):
        track = fuse(walk.pdr, exact_ranges(walk), start, tower, ("ukf",), tower_height_m=g.tower_height_m,
                     start_sigma_m=sigma).tracks["ukf"]
        first_var[sigma] = np.linalg.eigvalsh(np.array([[track.var_x_m2[0], track.cov_xy_m2[0]],
                                                        [track.cov_xy_m2[0], track.var_y_m2[0]]])).max()
    assert first_var[6.0] / first_var[1.5] == pytest.approx(16.0, rel=0.25)
    with pytest.raises(ValueError, match="sigma"):
        fuse(walk.pdr, exact_ranges(walk), start, tower, ("ukf",), start_sigma_m=0.0)
