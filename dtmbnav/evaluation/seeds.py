"""The evaluation's seed protocol: which Monte Carlo walks tune defaults, which are reported.

Walk k of a scenario whose file gives seed s runs scenario seed
``SEED_STRIDE * s + k``; k is the *Monte Carlo index*. Defaults (noise
levels, thresholds, particle count, the observation model's calibration) are
chosen on :data:`TUNING_SEEDS` only, and the README reports
:data:`REPORTING_SEEDS`, on which nothing was chosen (docs/evaluation.md,
"Tuning and reporting seeds"). This module imports nothing heavy, so the
command line can show the ranges in its help.
"""

from __future__ import annotations

#: Monte Carlo indices on which defaults are chosen (``--first-seed 100``, up to 50 walks).
TUNING_SEEDS = range(100, 150)
#: Monte Carlo indices the README reports, on which no default was chosen and no walk was opened for diagnosis
#: (``--first-seed 600``, up to 50 walks). Sealed: a walk of it opened to find a failure burns the range, which
#: then moves to a fresh one (docs/evaluation.md, "Tuning and reporting seeds").
REPORTING_SEEDS = range(600, 650)
#: Former reporting ranges, burned: defaults were chosen or failures diagnosed on their walks (0-19 before the
#: ranges were named; 200-249 until defaults were found on its walks, CHANGELOG). Neither tuning nor reporting.
BURNED_SEEDS = (range(0, 20), range(200, 250))
#: Monte Carlo indices per scenario seed: walk k of a scenario with file seed s runs seed ``SEED_STRIDE * s + k``.
SEED_STRIDE = 1000
#: Where the receiver range comes from: the observation-level model, the IQ transmitter, channel and receiver,
#: or the exact range change of the direct path (the filters' bound with a perfect receiver).
LEVELS = ("obs", "iq", "exact")
#: Default Monte Carlo walks per scenario at the IQ and the observation level (``dtmbnav results``).
IQ_SEEDS = 10
OBS_SEEDS = 50
#: Walks of each scenario a fusion section's check (``dtmbnav results --check``) runs again, unless told otherwise.
CHECK_SEEDS = 3
#: Every section of ``dtmbnav results``, in the file's order.
RESULT_SECTIONS = ("fusion-iq", "fusion-obs", "fusion-exact", "receiver", "paths", "frontends", "field", "weak-signal",
                   "pdr", "steps", "live", "bench")


def monte_carlo_seed(scenario_seed: int, k: int, first_seed: int = REPORTING_SEEDS.start) -> int:
    """Scenario seed of Monte Carlo walk ``k``: ``SEED_STRIDE * scenario_seed + first_seed + k``.

    Raises
    ------
    ValueError
        When ``first_seed + k`` leaves ``[0, SEED_STRIDE)`` (it would run another scenario seed's walks).
    """
    index = first_seed + k
    if not 0 <= index < SEED_STRIDE:
        raise ValueError(f"evaluate: Monte Carlo index first_seed + k = {index} must lie in [0, {SEED_STRIDE})")
    return SEED_STRIDE * scenario_seed + index


def seed_range_name(first_seed: int, seeds: int) -> str:
    """Which named range the Monte Carlo indices ``first_seed .. first_seed + seeds - 1`` lie in."""
    last = first_seed + seeds - 1
    named_ranges = [("reporting range", REPORTING_SEEDS), ("tuning range", TUNING_SEEDS)]
    named_ranges += [(f"burned range {r.start}-{r[-1]}", r) for r in BURNED_SEEDS]
    for name, named in named_ranges:
        if first_seed in named and last in named:
            return name
    return "neither named range"
