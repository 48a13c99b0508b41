"""A simulated network's transmit delay offsets surveyed on another walk of it (``[network] known = "surveyed"``).

Signal-of-opportunity navigation measures the offsets a network's operator
does not publish once, on a walk where GNSS works, and navigates later walks
with them (``dtmbnav towers calibrate``; :func:`fusion.transmit_delays.survey_code_offsets`).
Here the survey walk of a Monte Carlo walk is the same network
(:attr:`sim.scenario.Scenario.network_seed`: the same true offsets) and the
same layout, walked again on another seed (:func:`survey_scenario`): its own
walker noise, receiver clock, code errors and GNSS fix errors. The surveyor
stands :data:`SURVEY_STILL_S` at the start before walking the route, as a
survey should (``docs/cli.md``, "Surveying a network"): the fixes' errors are
correlated over tens of seconds, so minutes of them are what lowers the
survey's sigma. Its fixes state their accuracy as a phone's do
(:func:`sim.gnss.fix_sigma_m`).
"""

from __future__ import annotations

from collections.abc import Callable

from dtmbnav_core.records import Observations, Track
from fusion.model import Geometry
from fusion.transmit_delays import SurveyFixes, TransmitDelays, survey_code_offsets
from sim.gnss import fix_sigma_m, simulate_gnss
from sim.scenario import Scenario
from sim.walk import simulate_walk

#: Added to a walk's seed for the walk that surveys its network: past every Monte Carlo walk's seed
#: (:func:`dtmbnav.evaluation.seeds.monte_carlo_seed`, below a million for any scenario file's seed under a
#: thousand), so a survey walk is never a walk of a table.
SURVEY_SEED_OFFSET = 10**9
#: How long the survey walk stands at its start before walking the route, s: five minutes under the walk's sky,
#: about five independent fixes' worth (``dtmbnav_core.start_fix``).
SURVEY_STILL_S = 300.0


def scenario_towers(scenario: Scenario) -> tuple[tuple[float, float], float, tuple[tuple[float, float, float], ...]]:
    """The scenario's towers as the fusion takes them: tower 0's east and north (m), its height above the
    receiver's antenna (m), and the further towers of an SFN (east, north, height above the antenna, m)."""
    antenna_m = scenario.channel.antenna_height_m
    tower = scenario.tower
    others = tuple((site.x_m, site.y_m, site.height_m - antenna_m) for site in scenario.sites[1:])
    return (tower.x_m, tower.y_m), tower.height_m - antenna_m, others


def survey_scenario(scenario: Scenario) -> Scenario:
    """The walk that surveys ``scenario``'s network: its network (seed), layout and route, on seed
    ``seed + SURVEY_SEED_OFFSET``, standing at least :data:`SURVEY_STILL_S` before it walks, told nothing of
    the offsets."""
    return scenario.replace(seed=scenario.seed + SURVEY_SEED_OFFSET,
                            network={"seed": scenario.network_seed, "known": "unknown"},
                            walk={"start_still_s": max(scenario.walk.start_still_s, SURVEY_STILL_S)},
                            name=f"{scenario.name} (survey)")


def survey_transmit_delays(scenario: Scenario,
                           range_source: Callable[[Scenario, Track], Observations]) -> TransmitDelays | None:
    """The offsets of ``scenario``'s network as its survey walk (:func:`survey_scenario`) measures them, with the
    survey's sigmas, from ``range_source``'s tower differences at the walk's GNSS fixes; None where the source has
    no path tracker (nor has the walk it is for, which then uses no tower difference)."""
    survey = survey_scenario(scenario)
    walk = simulate_walk(survey)
    observed = range_source(survey, walk.track)
    if observed.paths is None:
        return None
    gnss = simulate_gnss(survey, walk)
    tower_xy, height, others = scenario_towers(survey)
    start = (float(walk.track.x_m[0]), float(walk.track.y_m[0]))
    geometry = Geometry(*start, *tower_xy, height, others)
    fixes = SurveyFixes(gnss.t_s, gnss.x_m, gnss.y_m, fix_sigma_m(survey.gnss, gnss.cn0_dbhz))
    return survey_code_offsets(observed.paths, geometry, fixes).transmit_delays(scenario.sites[0].transmit_delay_s)
