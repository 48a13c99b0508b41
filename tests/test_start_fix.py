"""The start fix from the whole standstill (dtmbnav_core.start_fix): its weights, its sigma against a Monte Carlo of
Gauss-Markov errors, the importer's rule at its edges, and the simulator's start fix made of its own fixes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import TINY_WALK
from scipy.stats import chi2

from dtmbnav.evaluation.start_fix_coverage import CIRCLE_95_SIGMAS, StartFixCoverage, start_fix_coverage
from dtmbnav.field.sensors_import import choose_start_fix
from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS
from dtmbnav_core.records import GnssLog
from dtmbnav_core.start_fix import FIX_ERROR_TAU_S, combine_fixes, standstill_fixes, standstill_start_fix
from sim.gnss import fix_sigma_m, simulate_gnss, simulate_start_fix
from sim.scenario import load_scenario
from sim.walk import simulate_walk


def _gauss_markov(rng: np.random.Generator, t_s: np.ndarray, trials: int, tau_s: float) -> np.ndarray:
    """Unit-variance Gauss-Markov samples at irregular times ``t_s``, trials x len(t_s): z_k = phi_k z_{k-1} +
    sqrt(1 - phi_k^2) n_k with phi_k = exp(-(t_k - t_{k-1}) / tau), stationary from the first."""
    z = np.empty((trials, len(t_s)))
    z[:, 0] = rng.standard_normal(trials)
    for k in range(1, len(t_s)):
        phi = math.exp(-(t_s[k] - t_s[k - 1]) / tau_s)
        z[:, k] = phi * z[:, k - 1] + math.sqrt(1.0 - phi**2) * rng.standard_normal(trials)
    return z


def test_the_combined_sigma_holds_gauss_markov_errors_at_their_coverage():
    """Fixes of different accuracies at irregular times over a window about the correlation time, their errors
    Gauss-Markov: the weighted mean's stated sigma puts 95 % of the trials in its 95 % circle, where the
    independent-error sigma would put far fewer."""
    rng = np.random.default_rng(58)
    t_s = np.cumsum(rng.uniform(0.5, 1.5, 40))
    sigma = rng.uniform(1.0, 3.0, 40)
    trials = 4000
    ex = sigma * _gauss_markov(rng, t_s, trials, FIX_ERROR_TAU_S)
    ey = sigma * _gauss_markov(rng, t_s, trials, FIX_ERROR_TAU_S)
    combined = combine_fixes(t_s, np.zeros(40), np.zeros(40), sigma)
    w = sigma**-2 / np.sum(sigma**-2)
    distance = np.hypot(ex @ w, ey @ w)
    coverage = np.mean(distance <= CIRCLE_95_SIGMAS * combined.fix.sigma_m)
    assert 0.935 <= coverage <= 0.965  # about 4 binomial standard deviations of 4000 trials
    independent_sigma = np.sum(sigma**-2) ** -0.5
    assert np.mean(distance <= CIRCLE_95_SIGMAS * independent_sigma) < 0.7
    assert 1.0 < combined.n_effective < 40 / 4


def test_weights_follow_the_stated_accuracy():
    """Two fixes of sigma 1 and 2 m weigh 4:1. Far apart in time their errors are independent and the sigma is the
    inverse-variance one; at the same moment they are one error and the sigma is the weighted sum of theirs. Equal
    fixes at one moment count as one."""
    x, y = np.array([0.0, 5.0]), np.array([10.0, 0.0])
    sigma = np.array([1.0, 2.0])
    apart = combine_fixes(np.array([0.0, 1e6]), x, y, sigma)
    assert (apart.fix.x_m, apart.fix.y_m) == pytest.approx((1.0, 8.0))
    assert apart.fix.sigma_m == pytest.approx(1.0 / math.sqrt(1.25))
    assert apart.n_effective == pytest.approx(2.0)
    together = combine_fixes(np.array([3.0, 3.0]), x, y, sigma)
    assert together.fix.sigma_m == pytest.approx(0.8 * 1.0 + 0.2 * 2.0)
    # As many fixes of their mean inverse variance (1.25 / 2 m^-2) as give 1.2 m: 1.6 / 1.44 of them.
    assert together.n_effective == pytest.approx(1.6 / 1.44)
    assert together.fix.t_s == 3.0
    assert combine_fixes(np.zeros(5), np.zeros(5), np.zeros(5), np.full(5, 2.0)).n_effective == pytest.approx(1.0)


@pytest.mark.parametrize("spacing_s", [1.0, 0.05])
def test_equal_fixes_count_as_the_effective_number_of_an_exponential_autocorrelation(spacing_s):
    """Equal sigmas every ``spacing_s`` over T = 20 s: n_eff = N^2 / sum_ij rho^|i-j| exactly; densely sampled it
    tends to Bayley and Hammersley's (T/tau)^2 / (2 (T/tau - 1 + exp(-T/tau)))."""
    n = int(round(20.0 / spacing_s)) + 1
    t_s = np.arange(n) * spacing_s
    combined = combine_fixes(t_s, np.zeros(n), np.zeros(n), np.full(n, 2.0))
    rho = np.exp(-spacing_s / FIX_ERROR_TAU_S)
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    assert combined.n_effective == pytest.approx(n**2 / np.sum(rho**lags), rel=1e-9)
    assert combined.fix.sigma_m == pytest.approx(2.0 / math.sqrt(combined.n_effective), rel=1e-9)
    if spacing_s < 0.1:
        x = 20.0 / FIX_ERROR_TAU_S
        assert combined.n_effective == pytest.approx(x**2 / (2.0 * (x - 1.0 + math.exp(-x))), rel=0.01)


def test_the_window_keeps_the_standstills_last_seconds():
    t_s = np.array([-2.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    assert list(standstill_fixes(t_s, 0.0, 3.5)) == [1, 2, 3, 4]
    assert list(standstill_fixes(t_s, 0.0, 3.5, window_s=1.0)) == [3, 4]
    assert list(standstill_fixes(t_s, 0.0, 3.5, window_s=0.0)) == [4]
    assert standstill_start_fix(t_s, t_s, t_s, np.ones(7), 0.0, -1.0) is None
    with pytest.raises(ValueError, match="window"):
        standstill_fixes(t_s, 0.0, 3.5, window_s=-1.0)


def _log(t_s: list[float]) -> GnssLog:
    t = np.array(t_s)
    return GnssLog(t_s=t, x_m=10.0 * t, y_m=-t, cn0_dbhz=np.full(len(t), np.nan))


def test_a_standstill_of_one_fix_gives_the_one_fix_rule():
    """One usable fix in the standstill (the others state no accuracy): P0 is that fix, sigma accuracy / 1.51."""
    accuracy = np.array([np.nan, 3.0, np.nan, 4.0])
    notes: list[str] = []
    combined = choose_start_fix(_log([0.0, 1.0, 2.0, 5.0]), accuracy, 2.5, "log", notes)
    assert combined.fix == pytest.approx(combined.fix.__class__(1.0, 10.0, -1.0, 3.0 / ACCURACY_RADIUS_SIGMAS))
    assert (combined.n_fixes, combined.n_effective, notes) == (1, 1.0, [])


def test_fixes_only_after_the_walk_start_give_the_first_as_before():
    notes: list[str] = []
    combined = choose_start_fix(_log([4.0, 5.0]), np.array([3.0, 2.0]), 2.5, "log", notes)
    assert (combined.fix.t_s, combined.fix.x_m, combined.n_fixes) == (4.0, 40.0, 1)
    assert len(notes) == 1 and "the first, at 4.00 s" in notes[0]


def test_fixes_only_before_the_motion_sensors_give_the_last_before_the_walk():
    notes: list[str] = []
    combined = choose_start_fix(_log([-3.0, -1.0, 4.0]), np.array([3.0, 2.0, 2.0]), 2.5, "log", notes)
    assert (combined.fix.t_s, combined.n_fixes) == (-1.0, 1)
    assert len(notes) == 1 and "the last before it" in notes[0]


def test_the_simulators_start_fix_is_the_rule_on_its_own_fixes():
    """P0 of a simulated walk: its own fixes from t = 0 to the walk's start, weighted by their stated sigma, with the
    sigma of their mean under the Gauss-Markov errors they were drawn with (an N x N covariance here)."""
    scenario = load_scenario(TINY_WALK)
    walk = simulate_walk(scenario)
    gnss = simulate_gnss(scenario, walk)
    fix = simulate_start_fix(scenario, walk, gnss)
    i = np.flatnonzero(gnss.t_s <= walk.walk_start_t_s)
    assert len(i) > 2 and i[0] == 0
    sigma = fix_sigma_m(scenario.gnss, gnss.cn0_dbhz[i])
    w = sigma**-2 / np.sum(sigma**-2)
    covariance = np.outer(sigma, sigma) * np.exp(-np.abs(np.subtract.outer(gnss.t_s[i], gnss.t_s[i])) / FIX_ERROR_TAU_S)
    assert fix.t_s == gnss.t_s[i[-1]]
    assert (fix.x_m, fix.y_m) == pytest.approx((w @ gnss.x_m[i], w @ gnss.y_m[i]), abs=1e-12)
    assert fix.sigma_m == pytest.approx(np.sqrt(w @ covariance @ w), rel=1e-12)


def test_the_coverage_counts_the_walks_inside_the_95_percent_circle():
    assert CIRCLE_95_SIGMAS == pytest.approx(math.sqrt(chi2.ppf(0.95, 2)), rel=1e-12)
    row = StartFixCoverage("s", np.array([0.0, 2.44, 2.45, 10.0]), np.ones(4))
    assert (row.inside, row.coverage) == (2, 0.5)
    walks = start_fix_coverage(load_scenario(TINY_WALK), 3, 100, vary_geometry=False)
    assert len(walks.error_m) == 3 and np.all(walks.sigma_m > 0) and len(set(walks.error_m)) == 3
