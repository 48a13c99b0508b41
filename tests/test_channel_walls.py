"""Specular wall reflections (image method) in sim.channel, and what they do to the street range error.

Run ``python tests/test_channel_walls.py`` to print the street-out range-error figures.
"""

import numpy as np
import pytest

from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.records import Track
from fusion.metrics import interpolate_track
from sim.channel import WALL_EDGE_TAPER_M, Channel, blocking_loss_db
from sim.obs_range import simulate_obs_range
from sim.scenario import load_scenario
from sim.walk import simulate_walk

TOWER_XY = (-300.0, 3000.0)
WALL_X = 20.0
#: The street scene's previous point scatterers (before the walls), at their gains.
OLD_STREET_SCATTERERS = [{"x_m": 150.0, "y_m": 60.0, "gain_db": -6.0}, {"x_m": 60.0, "y_m": 250.0, "gain_db": -8.0},
                         {"x_m": 260.0, "y_m": 210.0, "gain_db": -10.0}]


def scene(walls, scatterers=(), buildings=()):
    """Tower far to the NNW, no ground ray, no diffuse: paths are direct, scatterers, walls (in that order)."""
    return load_scenario("park-loop-cw").replace(
        tower={"x_m": TOWER_XY[0], "y_m": TOWER_XY[1]},
        channel={"ground_reflection": False, "rician_k_db": None, "scatterers": list(scatterers),
                 "walls": walls, "buildings": list(buildings)})


def straight_walk(x_m, y0_m, y1_m, speed_mps=1.3, rate_hz=100.0):
    t = np.arange(0.0, (y1_m - y0_m) / speed_mps, 1.0 / rate_hz)
    n = len(t)
    return Track(t, np.full(n, x_m), y0_m + speed_mps * t, np.zeros(n), np.full(n, speed_mps))


def wall(y0, y1, gain_db=-3.0):
    return {"start_m": [WALL_X, y0], "end_m": [WALL_X, y1], "gain_db": gain_db}


def test_image_path_length_matches_hand_computation():
    scn = scene([wall(-100.0, 400.0)])
    track = straight_walk(0.0, 0.0, 30.0)
    state = Channel(scn, track, np.random.default_rng(0)).state(track.t_s[::50])
    # Mirror of (-300, 3000) across x = 20 is (340, 3000); height difference 150 - 1.2 m.
    expected_m = np.hypot(np.hypot(340.0 - 0.0, 3000.0 - track.y_m[::50]), 150.0 - 1.2)
    np.testing.assert_allclose(state.delay_s[1] * SPEED_OF_LIGHT_MPS, expected_m, rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.abs(state.coef[1]), 10 ** (-3.0 / 20))


def test_reflection_switches_off_smoothly_when_the_specular_point_leaves_the_wall():
    scn = scene([wall(-100.0, 200.0)])
    track = straight_walk(0.0, 0.0, 50.0)
    amp = np.abs(Channel(scn, track, np.random.default_rng(0)).state(track.t_s).coef[1])
    # Specular point at y_r + 20/340 (3000 - y_r): it reaches the wall's end (y = 200) at y_r = 25 m
    # and the end of the taper (201 m) at y_r = 26.06 m.
    y = track.y_m
    np.testing.assert_allclose(amp[y < 24.9], 10 ** (-3.0 / 20))
    assert np.all(amp[y > 25.0 + 17.0 / 16.0 * WALL_EDGE_TAPER_M + 0.1] == 0.0)
    fading = (y > 25.0) & (y < 26.1)
    assert np.all(np.diff(amp[fading]) <= 0.0) and np.abs(np.diff(amp)).max() < 0.02  # no jump


def test_no_reflection_with_the_tower_behind_the_wall():
    track = straight_walk(30.0, 0.0, 20.0)  # east of the wall, tower west of it
    state = Channel(scene([wall(-100.0, 400.0)]), track, np.random.default_rng(0)).state(track.t_s)
    assert np.all(state.coef[1] == 0.0)


def test_building_between_wall_and_receiver_blocks_the_reflection():
    block = {"polygon_m": [[5.0, -50.0], [15.0, -50.0], [15.0, 300.0], [5.0, 300.0]], "attenuation_db": 20.0}
    track = straight_walk(0.0, 0.0, 20.0)
    state = Channel(scene([wall(-100.0, 400.0)], buildings=[block]), track, np.random.default_rng(0)).state(track.t_s)
    np.testing.assert_allclose(np.abs(state.coef[1]), 10 ** (-23.0 / 20))


def test_walking_along_a_wall_gives_the_direct_paths_doppler():
    # Contrast: a point on the same wall behind the walker, whose path lengthens as the walker
    # closes on the tower.
    scn = scene([wall(-100.0, 400.0)], scatterers=[{"x_m": WALL_X, "y_m": -60.0, "gain_db": -3.0}])
    track = straight_walk(0.0, 0.0, 40.0)
    t = np.linspace(5.0, 25.0, 201)
    delay = Channel(scn, track, np.random.default_rng(0)).state(t).delay_s
    doppler_hz = -scn.tower.carrier_hz * np.gradient(delay, t, axis=1)
    direct, scatterer, reflection = doppler_hz
    assert np.abs(direct).min() > 1.0
    np.testing.assert_allclose(reflection, direct, rtol=0.01)
    assert np.all(np.abs(scatterer - direct) > 0.5 * np.abs(direct))


def test_degenerate_wall_raises():
    scn = scene([{"start_m": [WALL_X, 5.0], "end_m": [WALL_X, 5.0], "gain_db": -3.0}])
    with pytest.raises(ValueError, match="coincide"):
        Channel(scn, straight_walk(0.0, 0.0, 10.0), np.random.default_rng(0))


def blocked_range_error(scn):
    """|range error| of the observation-level range on the scenario's walk, and where LOS is blocked."""
    track = simulate_walk(scn).track
    rs = simulate_obs_range(scn, track)
    at = interpolate_track(track, rs.t_s)
    tower = scn.tower
    true_m = np.hypot(np.hypot(at.x_m - tower.x_m, at.y_m - tower.y_m), tower.height_m - scn.channel.antenna_height_m)
    error = np.abs(rs.range_change_m - (true_m - true_m[0]))
    blocked = blocking_loss_db(at.x_m, at.y_m, tower.x_m, tower.y_m, scn.channel.buildings) > 0.0
    return error, blocked


@pytest.fixture(scope="module")
def street_errors():
    """Range errors on street-out with its walls, and with the walls replaced by the old point scatterers.

    At a C/N of 40 dB: the comparison is of the scenes' geometry, so the receiver noise (whose random
    range jumps in deep fades would otherwise dominate a 350 s walk) is kept out of it.
    """
    walls = load_scenario("street-out").replace(receiver={"cn_db": 40.0})
    points = walls.replace(channel={"walls": [], "scatterers": OLD_STREET_SCATTERERS})
    return blocked_range_error(walls), blocked_range_error(points)


def test_walls_bias_the_blocked_street_range_less_than_point_scatterers(street_errors):
    (wall_err, blocked), (point_err, same_blocked) = street_errors
    assert np.array_equal(blocked, same_blocked) and blocked.mean() > 0.3
    assert np.median(wall_err[blocked]) < np.median(point_err[blocked])
    assert np.percentile(wall_err[blocked], 95) < np.percentile(point_err[blocked], 95)
    assert np.percentile(wall_err, 95) < np.percentile(point_err, 95)


if __name__ == "__main__":
    scn = load_scenario("street-out")
    cases = {"walls (street-out)": scn,
             "old point scatterers, same K": scn.replace(channel={"walls": [], "scatterers": OLD_STREET_SCATTERERS}),
             "old scene (points, K = 6 dB)": scn.replace(channel={"walls": [], "scatterers": OLD_STREET_SCATTERERS,
                                                                  "rician_k_db": 6.0})}
    for label, case in cases.items():
        err, blk = blocked_range_error(case)
        print(f"{label:32s} |range error| all: median {np.median(err):5.1f} m, 95% {np.percentile(err, 95):5.1f} m;"
              f" LOS blocked: median {np.median(err[blk]):5.1f} m, 95% {np.percentile(err[blk], 95):5.1f} m")
