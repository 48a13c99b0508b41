"""``dtmbnav evaluate --level iq``: the Monte Carlo through the IQ transmitter, channel and receiver."""

from pathlib import Path

import numpy as np
import pytest

from dtmbnav.evaluation import evaluate as ev
from dtmbnav.cli import EXIT_OK, main
from dtmbnav.simulation.iq_range import iq_observations, iq_ranges
from fusion.run import FusionConfig
from sim.walk import simulate_walk

TINY = str(Path(__file__).parent / "data" / "tiny-walk.toml")


@pytest.mark.slow
def test_iq_level_table_on_the_tiny_walk(capsys):
    assert main(["-q", "evaluate", TINY, "--level", "iq", "--seeds", "1", "--filters", "ukf", "--workers", "0"]) \
        == EXIT_OK
    table = capsys.readouterr().out
    assert "iq level, a layout per walk" in table.splitlines()[0]
    assert [line.split()[1] for line in table.splitlines()[3:]] == ["pdr", "pdr@fix", "ukf"]


@pytest.mark.slow
def test_iq_range_follows_the_walk():
    """The receiver's range of the tiny walk's varied layout against the true distance change.

    The channel here has the direct path, the ground reflection and no diffuse
    scattering. With the tiny walk's diffuse scattering (Rician K = 10 dB,
    Doppler spread 3 Hz about the receiver) the SI-carrier frequency (eq. 8) is
    the power-weighted mean of the direct path's and the scattering's, so it
    shrinks the Doppler by up to 1 / (1 + K) = 9 %: a physical bias of the
    estimator, not the chain's (0.25 m on this walk), which the observation
    level models and ``test_obs_vs_iq`` compares.
    """
    scn = ev.seed_scenario(ev.load_scenario(TINY), 0).replace(channel={"rician_k_db": None})
    truth = simulate_walk(scn).track
    ranges = iq_ranges(scn, truth)
    assert ranges.t_s[0] < 0.1 and ranges.t_s[-1] > truth.t_s[-1] - 0.1  # the whole walk, frame by frame
    assert np.median(np.diff(ranges.t_s)) == pytest.approx(1.0 / 1800.0, rel=1e-3)
    x, y = np.interp(ranges.t_s, truth.t_s, truth.x_m), np.interp(ranges.t_s, truth.t_s, truth.y_m)
    tower = scn.tower
    d = np.hypot(np.hypot(x - tower.x_m, y - tower.y_m), tower.height_m - scn.channel.antenna_height_m)
    error = ranges.range_change_m - (d - d[0])
    assert ranges.valid.mean() > 0.95
    # Line of sight over a 12 m walk: the range change follows the geometry to a fifth of a wavelength.
    assert np.percentile(np.abs(error), 95) < 0.1 and np.ptp(d) > 3.0  # the L is at least 4 m wide


@pytest.mark.slow
def test_iq_level_hands_the_first_path_to_the_fusion():
    """The IQ level gives the fusion the path tracker's first-path range, as ``dtmbnav fuse`` does.

    On the tiny walk's channel with its diffuse scattering (2 chips behind the
    direct path on average) the first path is the direct path alone: its range
    follows the geometry far closer than the SI carriers', which the scattering
    biases (0.20 m here).
    """
    scn = ev.seed_scenario(ev.load_scenario(TINY), 0)
    truth = simulate_walk(scn).track
    observed = iq_observations(scn, truth)
    assert observed.paths is not None and not observed.paths.differences  # one tower: no differences
    first = observed.paths.first_path[0]
    assert first.valid.mean() > 0.9
    x, y = np.interp(first.t_s, truth.t_s, truth.x_m), np.interp(first.t_s, truth.t_s, truth.y_m)
    tower = scn.tower
    d = np.hypot(np.hypot(x - tower.x_m, y - tower.y_m), tower.height_m - scn.channel.antenna_height_m)
    error = (first.range_change_m - (d - d[0]))[first.valid]
    assert np.percentile(np.abs(error), 95) < 0.1


def test_iq_source_is_the_level_source():
    assert ev.level_range_source("iq").__module__ == "dtmbnav.simulation.iq_range"
    assert ev.level_range_source("obs") is ev.obs_range_source
    with pytest.raises(ValueError, match="level"):
        ev.level_range_source("rf")
    assert FusionConfig().seed == 0  # every walk's filters use the same seed: a walk depends on its own seed only
