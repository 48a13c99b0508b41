"""Surveying an SFN's transmit delay offsets once on a walk with GNSS (``dtmbnav towers calibrate``), against truth:
the survey's estimate and its sigma under fix errors correlated in time, the simulator's network identity, the
evaluation's survey on another walk of the network, and the command on a synthetic walk and on bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pymap3d
import pytest
from fusion_synth import exact_paths, park_like_walk

from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_OK, EXIT_USAGE, main
from dtmbnav.evaluation.evaluate import obs_range_source, scenario_transmit_delays, seed_scenario, with_transmit_delays
from dtmbnav.evaluation.seeds import TUNING_SEEDS
from dtmbnav.evaluation.survey import SURVEY_STILL_S, survey_scenario
from dtmbnav.field.towers import read_towers
from dtmbnav_core import schema
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.h5io import read_attrs, read_columns, write_columns
from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS
from dtmbnav_core.records import FRAME_COLUMN_DTYPES, PATH_COLUMN_DTYPES, PathFlag
from fusion.transmit_delays import SurveyFixes, difference_gradient, given_transmit_delays, survey_code_offsets
from sim.gnss import fix_sigma_m
from sim.scenario import GnssConfig, load_scenario

#: The synthetic network's second tower (east, north, height, m) and its c (tx_1 - tx_0), m.
SECOND_TOWER = (-1560.0, -4285.0, 120.0)
OFFSET_M = 0.537e-6 * SPEED_OF_LIGHT_MPS


def _gauss_markov(rng: np.random.Generator, t_s: np.ndarray, tau_s: float) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov errors at increasing times ``t_s`` (two axes)."""
    out = np.empty((len(t_s), 2))
    out[0] = rng.standard_normal(2)
    for i in range(1, len(t_s)):
        phi = np.exp(-(t_s[i] - t_s[i - 1]) / tau_s)
        out[i] = phi * out[i - 1] + np.sqrt(1.0 - phi**2) * rng.standard_normal(2)
    return out


def test_the_survey_recovers_the_offset_within_its_sigma_under_correlated_fix_errors():
    """A two-tower walk whose fixes err as a phone's do (1.5 m per axis, correlated over 30 s): over 40 walks the
    estimate's error divided by its stated sigma spreads by about 1; a sigma of independent fixes (1/sqrt(N))
    would be several times too small. Stated sigmas weigh the fixes: a fix said to be bad hardly counts."""
    walk = park_like_walk(other_towers=(SECOND_TOWER,), laps=2)
    g = walk.geometry
    paths = exact_paths(walk, first_path=False)
    difference = paths.differences[1]
    x, y = (np.interp(difference.t_s, walk.truth.t_s, v) for v in (walk.truth.x_m, walk.truth.y_m))
    t_fix = np.arange(0.0, float(walk.truth.t_s[-1]), 1.0)
    fx, fy = (np.interp(t_fix, walk.truth.t_s, v) for v in (walk.truth.x_m, walk.truth.y_m))
    z, naive = [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        code = g.range_m(x, y, 1) - g.range_m(x, y, 0) + OFFSET_M + 0.3 * rng.standard_normal(len(x))
        coded = {1: type(difference)(**{**difference.__dict__, "code_range_m": code})}
        error = 1.5 * _gauss_markov(rng, t_fix, 30.0)
        fixes = SurveyFixes(t_fix, fx + error[:, 0], fy + error[:, 1], np.full(len(t_fix), 1.5))
        survey = survey_code_offsets(type(paths)(differences=coded), g, fixes)
        assert survey.fixes[0] == len(t_fix) and 1.0 < survey.effective_fixes[0] < len(t_fix) / 10
        z.append((survey.offset_m[0] - OFFSET_M) / survey.sigma_m[0])
        naive.append((survey.offset_m[0] - OFFSET_M) * np.sqrt(len(t_fix))
                      / (1.5 * np.mean(difference_gradient(g, fx, fy, 1))))
    assert 0.7 < np.sqrt(np.mean(np.square(z))) < 1.4
    assert np.sqrt(np.mean(np.square(naive))) > 2.5
    # A fix 40 m off that says it is 40 m off does not move the estimate; its stated sigma keeps it out.
    sigma = np.full(len(t_fix), 1.5)
    sigma[50] = 40.0
    off = fx.copy()
    off[50] += 40.0
    exact = {1: type(difference)(**{**difference.__dict__, "code_range_m": g.range_m(x, y, 1) - g.range_m(x, y, 0)
                                    + OFFSET_M})}
    survey = survey_code_offsets(type(paths)(differences=exact), g, SurveyFixes(t_fix, off, fy, sigma))
    assert survey.offset_m[0] == pytest.approx(OFFSET_M, abs=0.05)
    delays = survey.transmit_delays(0.1e-6)
    assert delays.source == "surveyed" and delays.sigmas_s[0] == 0.0
    assert (delays.delays_s[1] - delays.delays_s[0]) * SPEED_OF_LIGHT_MPS == pytest.approx(OFFSET_M, abs=0.05)


def test_a_network_seed_makes_walks_share_their_offsets():
    scenario = load_scenario("sfn-park")
    assert scenario.network.seed is None and scenario.network_seed == scenario.seed     # as before: per walk
    assert not np.array_equal(scenario.replace(seed=5).transmit_delays_s(), scenario.replace(seed=6).transmit_delays_s())
    network = scenario.replace(network={"seed": 42})
    np.testing.assert_array_equal(network.replace(seed=5).transmit_delays_s(), network.replace(seed=6).transmit_delays_s())
    np.testing.assert_array_equal(network.transmit_delays_s(), scenario.replace(seed=42).transmit_delays_s())
    with pytest.raises(ValueError, match="network.seed"):
        scenario.replace(network={"seed": -3})


def test_the_evaluation_surveys_the_same_network_on_another_walk():
    """The survey walk is another walk (seed) of the same network (its true offsets) and layout; at the
    observation level its estimate of sfn3-park's two differences holds the walk's true offsets within 3 sigma."""
    scenario = seed_scenario(load_scenario("sfn3-park"), 0, TUNING_SEEDS.start)
    survey = survey_scenario(scenario)
    assert survey.seed != scenario.seed and survey.towers == scenario.towers
    assert survey.walk.waypoints_m == scenario.walk.waypoints_m and survey.walk.start_still_s == SURVEY_STILL_S
    np.testing.assert_array_equal(survey.transmit_delays_s(), scenario.transmit_delays_s())
    delays = scenario_transmit_delays(with_transmit_delays(scenario, "surveyed"), obs_range_source)
    assert delays.source == "surveyed" and delays.sigmas_s[0] == 0.0
    true = scenario.transmit_delays_s()
    for k in (1, 2):
        error_s = (delays.delays_s[k] - delays.delays_s[0]) - (true[k] - true[0])
        assert 0.0 < delays.sigmas_s[k] * SPEED_OF_LIGHT_MPS < 2.0
        assert abs(error_s) <= 3.0 * delays.sigmas_s[k]
    with pytest.raises(ValueError, match="towers calibrate"):
        given_transmit_delays("surveyed", [0.0, 0.0], 0.0, list)


# The command, on the tiny walk in a synthetic two-tower network: its receiver file's tower difference holds
# the network's offset, its fixes those of the simulated walk, each stating its accuracy.

ORIGIN = (30.52, 114.36, 24.0)
TOWERS_ENU = ((2000.0, 2200.0, 150.0), SECOND_TOWER)


def _towers_csv(path: Path, count: int = 2) -> Path:
    rows = ["name,lat_deg,lon_deg,height_m,channel_hz,transmit_delay_s"]
    for name, (x, y, up), plan in zip("AB", TOWERS_ENU[:count], (0.0, 0.5e-6)):
        lat, lon, height = (float(v) for v in pymap3d.enu2geodetic(x, y, up, *ORIGIN))
        rows.append(f"{name},{lat!r},{lon!r},{height!r},666e6,{plan!r}")
    path.write_text("\n".join(rows) + "\n")
    return path


def _survey_walk(truth: Path, folder: Path, seed_shift: int = 0) -> tuple[Path, Path]:
    """A sensors file (the tiny walk's, with an origin and stated accuracies) and a receiver file whose first
    paths follow the walk's truth from both towers."""
    sensors = folder / "sensors.h5"
    shutil.copy(truth, sensors)
    with h5py.File(sensors, "a") as f:
        gnss = f[schema.GNSS]
        gnss.attrs.update(dict(zip(schema.ORIGIN_ATTRS, ORIGIN)))
        gnss["accuracy_m"] = ACCURACY_RADIUS_SIGMAS * fix_sigma_m(GnssConfig(), gnss["cn0_dbhz"][()])
    trajectory = read_columns(truth, schema.TRUTH_TRAJECTORY)
    record = read_attrs(truth, schema.TRUTH_FRAMES)
    t = np.arange(0.0, float(trajectory["t_s"][-1] - record[schema.CAPTURE_START_ATTR]), 0.01)
    x, y = (np.interp(t + record[schema.CAPTURE_START_ATTR], trajectory["t_s"], trajectory[v]) for v in ("x_m", "y_m"))
    r0, r1 = (np.sqrt((x - tx) ** 2 + (y - ty) ** 2 + up**2) for tx, ty, up in TOWERS_ENU)
    clock_s = 3e-6 + 1e-7 * t                       # the receiver's clock: cancels in the difference
    n = len(t)
    frames = {name: np.zeros(n, dtype) for name, dtype in FRAME_COLUMN_DTYPES.items()}
    frames.update(t_s=t, frame_index=np.arange(n), range_change_m=r0 - r0[0], snr_db=np.full(n, 20.0),
                  first_path_range_change_m=r0 - r0[0], first_path_delay_s=r0 / SPEED_OF_LIGHT_MPS + clock_s,
                  first_path_snr_db=np.full(n, 20.0), first_path_id=np.ones(n), tower_count=np.full(n, 2),
                  range_difference_change_1_m=(r1 - r0) - (r1 - r0)[0], range_difference_change_2_m=np.full(n, np.nan))
    rows = {name: np.zeros(n, dtype) for name, dtype in PATH_COLUMN_DTYPES.items()}
    rows.update(t_s=t, frame_index=np.arange(n), path_id=np.full(n, 2), tower_id=np.ones(n), snr_db=np.full(n, 20.0),
                delay_s=(r1 + OFFSET_M) / SPEED_OF_LIGHT_MPS + clock_s, flags=np.full(n, int(PathFlag.FIRST_PATH)))
    receiver = folder / "rx.h5"
    with h5py.File(receiver, "w") as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, frames, {
            schema.CAPTURE_SCENARIO_ATTR: "tiny-walk", schema.CAPTURE_SEED_ATTR: int(record["seed"]) + seed_shift})
        write_columns(h5, schema.RECEIVER_PATHS, rows)
    return receiver, sensors


def test_calibrate_writes_the_towers_file_with_the_surveyed_offset(tiny_walk_truth, tmp_path, capsys):
    receiver, sensors = _survey_walk(tiny_walk_truth, tmp_path)
    out = tmp_path / "surveyed.csv"
    code = main(["towers", "calibrate", str(receiver), str(sensors), "--towers", str(_towers_csv(tmp_path / "t.csv")),
                 "-o", str(out)])
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    assert "B - A" in err and "independent" in err
    a, b = read_towers(out)
    assert (a.transmit_delay_s, a.transmit_delay_sigma_s) == (0.0, 0.0) and a.channel_hz == 666e6
    error_m = b.transmit_delay_s * SPEED_OF_LIGHT_MPS - OFFSET_M
    sigma_m = b.transmit_delay_sigma_s * SPEED_OF_LIGHT_MPS
    # The tiny walk is a few seconds of correlated fixes: about one independent fix, seen twice along the gradient.
    assert 0.5 < sigma_m < 2.0 * 1.5 * 2.0 and abs(error_m) <= 3.0 * sigma_m


@pytest.mark.parametrize("case, words", [
    ("one tower", ["two or more", "'A'"]),
    ("no fixes", ["no GNSS fixes"]),
    ("no accuracy", ["states its horizontal accuracy"]),
    ("another walk", ["different walks", "seed"]),
    ("no paths", ["no /receiver/paths", "--no-paths"]),
])
def test_calibrate_refuses_bad_input_naming_it(tiny_walk_truth, tmp_path, capsys, case, words):
    receiver, sensors = _survey_walk(tiny_walk_truth, tmp_path, seed_shift=int(case == "another walk"))
    towers = _towers_csv(tmp_path / "t.csv", 1 if case == "one tower" else 2)
    with h5py.File(receiver if case == "no paths" else sensors, "a") as f:
        if case == "no paths":
            del f[schema.RECEIVER_PATHS]
        elif case == "no accuracy":
            f[schema.GNSS]["accuracy_m"][...] = np.nan
        elif case == "no fixes":
            for name in list(f[schema.GNSS]):
                data = f[schema.GNSS][name]
                del f[schema.GNSS][name]
                f[schema.GNSS].create_dataset(name, data=data[()][:0])
    out = tmp_path / "surveyed.csv"
    assert main(["towers", "calibrate", str(receiver), str(sensors), "--towers", str(towers), "-o", str(out)]) \
        == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert all(word in err for word in words), err
    assert not out.exists()


def test_calibrate_writes_csv_only(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["towers", "calibrate", "rx.h5", "s.h5", "--towers", "t.csv", "-o", str(tmp_path / "out.toml")])
    assert exit_info.value.code == EXIT_USAGE and ".csv" in capsys.readouterr().err
