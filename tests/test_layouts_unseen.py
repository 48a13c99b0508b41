"""Street layouts no setting was tuned on (``tests/data/layouts/``): eq. 15's heading and its stated sigma.

The packaged scenarios' streets are the ones the tuning walks vary; these two are not: three sides of a city
block with a PN945 tower to the north-east that the block hides, and an avenue across the line of sight to a
constant-phase PN420 tower to the south. Run ``python tests/test_layouts_unseen.py`` to print more walks.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from dtmbnav.evaluation.evaluate import run_walk, simulated_chain
from fusion.heading_init import UNCERTAIN_HEADING_RAD
from fusion.run import FusionConfig
from sim.channel import blocking_loss_db
from sim.scenario import load_scenario
from sim.walk import simulate_walk

LAYOUTS = sorted((Path(__file__).parent / "data" / "layouts").glob("*.toml"))


@pytest.mark.parametrize("path", LAYOUTS, ids=lambda p: p.stem)
def test_layout_is_a_street_whose_buildings_hide_the_tower(path):
    """Each layout loads, and its buildings cut the line of sight on part of the walk but not all of it."""
    scn = load_scenario(path)
    assert scn.channel.buildings
    track = simulate_walk(scn).track
    blocked = blocking_loss_db(track.x_m[::100], track.y_m[::100], scn.tower.x_m, scn.tower.y_m,
                               scn.channel.buildings) > 0
    assert 0.1 < blocked.mean() < 0.9


@pytest.mark.parametrize("path", LAYOUTS, ids=lambda p: p.stem)
def test_initial_heading_is_within_5_deg_or_says_it_may_not_be(path):
    """Observation level, tuning walk 100 of each layout: eq. 15's heading is within 5 deg of the truth, or its
    stated sigma (twice it) covers the error, or the solution is flagged uncertain."""
    result = run_walk(load_scenario(path), 0, 100, True, ("ukf",), FusionConfig(), "obs", None, simulated_chain)
    error = result.heading_error_rad
    assert (error <= UNCERTAIN_HEADING_RAD or error <= 2.0 * result.heading_sigma_rad or result.heading_uncertain), \
        (np.rad2deg(error), np.rad2deg(result.heading_sigma_rad))


if __name__ == "__main__":
    walks = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    for path in LAYOUTS:
        for k in range(walks):
            r = run_walk(load_scenario(path), k, 100, True, ("ukf",), FusionConfig(), "obs", None, simulated_chain)
            print(f"{path.stem:16s} walk {100 + k}: heading error {np.rad2deg(r.heading_error_rad):5.2f} deg, "
                  f"sigma {np.rad2deg(r.heading_sigma_rad):5.2f} deg, uncertain {r.heading_uncertain}")
