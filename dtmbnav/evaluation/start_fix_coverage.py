"""Whether the simulated start fix's stated sigma holds the truth: the coverage of its 95 % circle over walks.

For each Monte Carlo walk (the walk ``dtmbnav evaluate`` runs: :func:`dtmbnav.evaluation.evaluate.seed_scenario`)
the start fix P0 is made of the walk's own GNSS fixes over the standstill (:func:`sim.gnss.simulate_start_fix`)
and compared with the true start. For a circular normal error of sigma per axis the squared distance over
sigma^2 is chi-square with two degrees of freedom, so the 95 % circle has the radius
``sqrt(-2 ln 0.05) sigma`` (:data:`CIRCLE_95_SIGMAS`); a stated sigma that holds the truth puts about 95 % of
the walks inside it. The walks of one scenario share its error model, so their coverage is a binomial count.

``python -m dtmbnav.evaluation.start_fix_coverage SCENARIO... --first-seed N [--seeds M]`` prints each scenario's
coverage and the pooled one.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dtmbnav.evaluation.evaluate import seed_scenario
from dtmbnav.evaluation.seeds import OBS_SEEDS
from dtmbnav_core.records import ELLIPSE_95_CHI2
from sim.gnss import simulate_gnss, simulate_start_fix
from sim.scenario import Scenario, load_scenario
from sim.walk import simulate_walk

#: Radius of the 95 % circle of a circular normal error, in per-axis sigmas (chi-square, 2 degrees of freedom):
#: the stated 95 % ellipse's bound for equal variances.
CIRCLE_95_SIGMAS = math.sqrt(ELLIPSE_95_CHI2)


@dataclass(frozen=True)
class StartFixCoverage:
    """The start fix's errors over a scenario's walks against their stated sigmas.

    Attributes
    ----------
    scenario : str
    error_m : ndarray
        Horizontal distance of each walk's start fix from the true start, m.
    sigma_m : ndarray
        Each start fix's stated 1-sigma error per axis, m.
    """

    scenario: str
    error_m: np.ndarray
    sigma_m: np.ndarray

    @property
    def inside(self) -> int:
        """Walks whose start fix lies within its 95 % circle."""
        return int(np.sum(self.error_m <= CIRCLE_95_SIGMAS * self.sigma_m))

    @property
    def coverage(self) -> float:
        """Fraction of the walks inside their 95 % circle."""
        return self.inside / len(self.error_m)


def start_fix_error(scenario: Scenario) -> tuple[float, float]:
    """One walk's start fix: its distance from the true start (m) and its stated sigma per axis (m)."""
    walk = simulate_walk(scenario)
    fix = simulate_start_fix(scenario, walk, simulate_gnss(scenario, walk))
    return float(np.hypot(fix.x_m - walk.track.x_m[0], fix.y_m - walk.track.y_m[0])), fix.sigma_m


def start_fix_coverage(scenario: Scenario, seeds: int, first_seed: int,
                       vary_geometry: bool = True) -> StartFixCoverage:
    """The start fix's errors on Monte Carlo walks ``first_seed .. first_seed + seeds - 1`` of ``scenario``."""
    pairs = np.array([start_fix_error(seed_scenario(scenario, k, first_seed, vary_geometry)) for k in range(seeds)])
    return StartFixCoverage(scenario.name, pairs[:, 0], pairs[:, 1])


def pooled_coverage(rows: Sequence[StartFixCoverage]) -> float:
    """Fraction of all the rows' walks inside their 95 % circle."""
    return sum(row.inside for row in rows) / sum(len(row.error_m) for row in rows)


def coverage_lines(rows: Sequence[StartFixCoverage]) -> list[str]:
    """A line per scenario and the pooled one: walks inside the 95 % circle, and the median sigma and error."""
    lines = [f"{'scenario':<16} walks  inside 95 % circle  median sigma m  median error m"]
    for row in rows:
        lines.append(f"{row.scenario:<16} {len(row.error_m):5d}  {row.inside:5d} ({row.coverage:6.1%})     "
                     f"{np.median(row.sigma_m):10.2f}  {np.median(row.error_m):14.2f}")
    lines.append(f"{'pooled':<16} {sum(len(r.error_m) for r in rows):5d}  {pooled_coverage(rows):14.1%}")
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    """Print the start fix's coverage on the given scenarios' walks (module docstring)."""
    parser = argparse.ArgumentParser(description="coverage of the simulated start fix's 95 % circle")
    parser.add_argument("scenarios", nargs="+", help="scenario names or files")
    parser.add_argument("--first-seed", type=int, required=True, help="first Monte Carlo index")
    parser.add_argument("--seeds", type=int, default=OBS_SEEDS, help=f"walks per scenario (default {OBS_SEEDS})")
    args = parser.parse_args(argv)
    rows = [start_fix_coverage(load_scenario(name), args.seeds, args.first_seed) for name in args.scenarios]
    print("\n".join(coverage_lines(rows)))


if __name__ == "__main__":
    main()
