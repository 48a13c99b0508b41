"""Initial heading from the DTMB range constraint (docs/method.md §4, eq. 14-15).

The PDR track is relative: it starts at (0, 0) with an unknown heading offset.
Rotating it by a candidate ``phi0`` and placing it at P0 predicts a range
change to the tower at every step (eq. 14); the initial heading is the
``phi0`` whose prediction best matches the measured range change in the L1
sense (eq. 15). A walk symmetric about the line P0-P_b has two equally good
solutions (the true one and its mirror), so the solver reports every local
minimum of the cost with its value, and a confidence from how much better
the best one is than the runner-up. After an epoch without a range
observation (a gap, a fade, a multipath stretch: :mod:`fusion.observations`)
the integrated range may carry an error it picked up there, so each later
run of observed epochs gets a free offset (its median mismatch, the L1
optimum); only the run that starts at P0 is tied to zero. A coarse 1-degree grid finds the minima;
each is then refined to a fraction of a degree. The chosen minimum carries a
standard uncertainty (:func:`heading_sigma`: the residuals, the start fix's
error and the PDR's heading drift), and a solution that may be more than a
few degrees off says so (:meth:`HeadingSolution.uncertain`); the filters
start with at least that spread (:func:`fusion.run.with_heading_spread`).

In a single-frequency network the same equations hold for the difference of
two towers' ranges (``difference_tower``, docs/paths.md): it changes with the
walker's position as eq. 14 predicts for each tower, and the receiver clock's
drift, which a single tower's range cannot tell from motion, cancels in it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from fusion.model import Geometry

#: Coarse grid spacing, rad (the refinement brings it to a fraction of a degree).
COARSE_STEP_RAD = np.deg2rad(1.0)

#: Costs closer than this are indistinguishable for the confidence, m.
COST_FLOOR_M = 0.05

#: A heading whose two-sigma interval is wider than this, or whose mirror is nearly as good, is reported as
#: uncertain (:meth:`HeadingSolution.uncertain`), rad.
UNCERTAIN_HEADING_RAD = np.deg2rad(5.0)

#: Confidence below which the mirror minimum is nearly as good as the chosen one (:func:`solve_initial_heading`).
MIN_CONFIDENCE = 0.3

#: The first window eq. 15 is solved over, s (:func:`solve_initial_heading`'s ``max_duration_s``): doubled
#: while the solution's confidence stays below :data:`MIN_CONFIDENCE`.
HEADING_WINDOW_S = 45.0

#: Epochs a window needs beyond the free offsets of its runs (each run after a gap spends one on its offset);
#: with no more of them than solved parameters the window's solution has no confidence.
MIN_CONSTRAINING_EPOCHS = 2


@dataclass(frozen=True)
class HeadingSolution:
    """Result of the initial-heading search.

    Attributes
    ----------
    minima_rad : ndarray
        Headings of the local minima of the cost, clockwise from north, rad in
        [0, 2 pi), best first.
    costs_m : ndarray
        Eq. 15 cost at each minimum: mean |predicted - measured| range
        change, m (a mean rather than the sum so it reads as metres).
    scales : ndarray
        PDR distance scale at each minimum (1 when the scale is not solved).
    heading_rad : float
        Chosen initial heading (the lowest-cost minimum), rad.
    confidence : float
        ``(c_second - c_best) / c_second`` in [0, 1] with each cost raised to
        :data:`COST_FLOOR_M` first: 0 when the mirror solution is as good as
        the best, 1 when there is a single minimum. Costs below the floor (a
        few centimetres, the integrated range's noise) count as equally good:
        on a straight leg walked across the line to the tower the mirror and
        the truth both fit to within that noise, and the ratio of two such
        costs would otherwise read as a confident choice of whichever is
        lower, the mirror as often as not (180 deg off).
    n_used : int
        Number of epochs with a range observation that entered the cost.
    sigma_rad : float
        Standard uncertainty of the chosen heading about its own minimum
        (:func:`heading_sigma`), rad; it does not cover the mirror minimum,
        which ``confidence`` speaks for.
    """

    minima_rad: np.ndarray
    costs_m: np.ndarray
    scales: np.ndarray
    heading_rad: float
    confidence: float
    n_used: int
    sigma_rad: float = 0.0

    def uncertain(self, limit_rad: float = UNCERTAIN_HEADING_RAD, min_confidence: float = MIN_CONFIDENCE) -> bool:
        """Whether the heading may be more than ``limit_rad`` off: twice its sigma past it, or a near-equal mirror."""
        return 2.0 * self.sigma_rad > limit_rad or self.confidence < min_confidence

    def describe(self) -> str:
        """One line for a person: chosen heading, confidence and the other minima, degrees."""
        others = ", ".join(f"{np.rad2deg(h):.1f} deg ({c:.2f} m)"
                           for h, c in zip(self.minima_rad[1:], self.costs_m[1:]))
        line = (f"{np.rad2deg(self.heading_rad):.1f} +- {np.rad2deg(self.sigma_rad):.1f} deg (cost "
                f"{self.costs_m[0]:.2f} m, confidence {self.confidence:.2f}"
                + (f"; other minima: {others})" if others else ")"))
        if self.uncertain():
            line += (f"; WARNING: the range may leave this heading more than "
                     f"{np.rad2deg(UNCERTAIN_HEADING_RAD):.0f} deg off")
        return line


def rotate_pdr(x_m: np.ndarray, y_m: np.ndarray, heading_rad: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate PDR-frame displacements clockwise by ``heading_rad``.

    A PDR step ``(L sin psi, L cos psi)`` becomes ``(L sin(psi + phi0), L cos(psi + phi0))``.
    Broadcasts ``heading_rad`` of shape (K, 1) against points of shape (N,).
    """
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    return x_m * c + y_m * s, y_m * c - x_m * s


def predicted_range_change(heading_rad: float | np.ndarray, pdr_x_m: np.ndarray, pdr_y_m: np.ndarray,
                           geometry: Geometry, difference_tower: int = 0) -> np.ndarray:
    """Eq. 14: range change predicted by the PDR track rotated by ``heading_rad``, m.

    With ``difference_tower`` k > 0, the change of the range difference tower k minus tower 0.
    """
    dx, dy = rotate_pdr(pdr_x_m, pdr_y_m, heading_rad)
    x, y = geometry.start_x_m + dx, geometry.start_y_m + dy
    change = geometry.range_m(x, y) - geometry.start_range_m()
    if difference_tower:
        change = geometry.range_m(x, y, difference_tower) - geometry.start_range_m(difference_tower) - change
    return change


def heading_cost(heading_rad: float | np.ndarray, pdr_x_m: np.ndarray, pdr_y_m: np.ndarray,
                 range_change_m: np.ndarray, geometry: Geometry, scale: float = 1.0,
                 free_runs: list[np.ndarray] | None = None, difference_tower: int = 0) -> np.ndarray:
    """Eq. 15 cost (mean absolute range mismatch, m) of candidate headings for a PDR scaled by ``scale``.

    ``free_runs`` lists index arrays of epochs whose range shares an unknown
    offset (module docstring): their mismatch is taken about its median.
    ``difference_tower``: as :func:`predicted_range_change`.
    """
    predicted = predicted_range_change(np.asarray(heading_rad)[..., None], scale * pdr_x_m, scale * pdr_y_m, geometry,
                                       difference_tower)
    return np.mean(np.abs(centred_mismatch(predicted, range_change_m, free_runs)), axis=-1)


def centred_mismatch(predicted_m: np.ndarray, range_change_m: np.ndarray,
                     free_runs: list[np.ndarray] | None = None) -> np.ndarray:
    """Predicted minus measured range change (last axis: epochs), each free run's median taken out, m."""
    mismatch = predicted_m - range_change_m
    for run in free_runs or ():
        mismatch[..., run] -= np.median(mismatch[..., run], axis=-1, keepdims=True)
    return mismatch


def free_offset_runs(observed: np.ndarray) -> list[np.ndarray]:
    """Index arrays (into the observed epochs) of each run of observed epochs that follows a missing one."""
    observed = np.asarray(observed, dtype=bool)
    run_id = np.cumsum(observed & ~np.concatenate([[False], observed[:-1]]))[observed]
    first_tied = bool(observed[0]) if len(observed) else False
    return [np.nonzero(run_id == r)[0] for r in np.unique(run_id) if not (first_tied and r == 1)]


def solve_initial_heading(pdr_t_s: np.ndarray, pdr_x_m: np.ndarray, pdr_y_m: np.ndarray,
                          range_change_m: np.ndarray, geometry: Geometry, *,
                          scale_bounds: tuple[float, float] | None = (0.8, 1.25),
                          max_duration_s: float | None = HEADING_WINDOW_S, min_confidence: float = MIN_CONFIDENCE,
                          difference_tower: int = 0, start_sigma_m: float = 0.0,
                          heading_rate_sigma_radps: float = 0.0) -> HeadingSolution:
    """Solve eq. 15 for the initial heading.

    Three options extend the paper's eq. 15, aimed at the PDR errors that
    bias it (docs/scenarios.md: a step-length gain 10-20 % off, a heading that
    drifts late in the walk) and at the mirror ambiguity of a straight start:

    - ``scale_bounds``: the PDR's distance scale is solved jointly as a
      nuisance parameter (a too-long step stretches the predicted range
      change, which a rotation would otherwise absorb); None keeps it at 1,
      the literal eq. 15.
    - ``max_duration_s``: only the epochs within this time of the first one
      enter the cost, before the PDR heading has drifted far; None uses
      them all.
    - ``min_confidence``: a straight leg fits its mirror image about the line
      P0-P_b exactly as well as the truth (a street walk's first turn may
      come minutes after the start), so while the confidence stays below
      this value the window is doubled, up to the whole walk. A longer window
      lets more PDR drift into the cost, but a wrong mirror costs far more.

    Parameters
    ----------
    pdr_t_s, pdr_x_m, pdr_y_m : ndarray
        PDR epoch times (s) and positions (PDR frame, relative to the start, m).
    range_change_m : ndarray
        Measured range change since P0 at the same epochs, m; NaN entries
        (no observation) are left out.
    geometry : Geometry
        P0 and the tower(s).
    scale_bounds : (float, float) or None
    max_duration_s : float or None
    min_confidence : float
    difference_tower : int
        0: ``range_change_m`` is the range to tower 0 (eq. 14-15); k > 0:
        it is the change of the range difference tower k minus tower 0
        (module docstring).
    start_sigma_m : float
        Standard deviation of the start fix P0 per axis, m, for the
        solution's ``sigma_rad`` (:func:`heading_sigma`).
    heading_rate_sigma_radps : float
        Standard deviation of the PDR heading's rate error, rad/s, for the
        same.

    Returns
    -------
    HeadingSolution
        The solution of the first window that reaches ``min_confidence``
        (or of the whole walk).

    Raises
    ------
    ValueError
        If the inputs differ in length, or the range constrains no heading
        even over the whole walk (fewer than :data:`MIN_CONSTRAINING_EPOCHS`
        epochs beyond the runs' free offsets, or a cost flat to within
        :data:`COST_FLOOR_M`).
    """
    arrays = [np.asarray(a, dtype=np.float64) for a in (pdr_t_s, pdr_x_m, pdr_y_m, range_change_m)]
    if len({a.shape for a in arrays}) != 1:
        raise ValueError("solve_initial_heading: pdr_t_s, pdr_x_m, pdr_y_m and range_change_m differ in length")
    t, x, y, rc = arrays
    observed = np.isfinite(rc)
    duration = max_duration_s
    while True:
        used = observed if duration is None else observed & (t <= t[0] + duration)
        solution = None
        if used.any():
            free_runs = free_offset_runs(observed[: int(np.nonzero(used)[0][-1]) + 1])
            # A run with a free offset spends one epoch on it: isolated epochs after gaps constrain nothing.
            constraining = int(used.sum()) - len(free_runs)
            if constraining >= MIN_CONSTRAINING_EPOCHS:
                solution = _solve_window(x[used], y[used], rc[used], geometry, scale_bounds, free_runs,
                                         difference_tower, start_sigma_m, t[used], heading_rate_sigma_radps)
            solved_parameters = 1 if scale_bounds is None else 2
            if solution is not None and constraining <= solved_parameters:
                # As many epochs as unknowns (heading, scale): some heading fits them exactly, whatever the
                # noise; its minimum is no evidence against the others, so the window must grow.
                solution = replace(solution, confidence=0.0)
        whole_walk = duration is None or t[-1] <= t[0] + duration
        if solution is not None and (solution.confidence >= min_confidence or whole_walk):
            return solution
        if whole_walk:
            raise ValueError(f"solve_initial_heading: the range does not constrain the heading ({observed.sum()} "
                             "epochs with a range observation, too few or all in isolated runs)")
        duration *= 2.0


def _solve_window(x: np.ndarray, y: np.ndarray, rc: np.ndarray, geometry: Geometry,
                  scale_bounds: tuple[float, float] | None, free_runs: list[np.ndarray],
                  difference_tower: int = 0, start_sigma_m: float = 0.0, t: np.ndarray | None = None,
                  heading_rate_sigma_radps: float = 0.0) -> HeadingSolution | None:
    """Eq. 15 over the given epochs: coarse grid, then every local minimum refined.

    None when the cost is flat to within :data:`COST_FLOOR_M` over the whole
    circle: the range does not tell the headings apart (e.g. a few runs of
    epochs, each with its own free offset), and a minimum of it, alone or
    not, would be a heading picked by rounding, not by the range.
    """
    grid = np.arange(0.0, 2.0 * np.pi, COARSE_STEP_RAD)
    scales = (np.array([1.0]) if scale_bounds is None
              else np.clip(np.arange(scale_bounds[0], scale_bounds[1] + 0.01, 0.01), *scale_bounds))
    costs = np.stack([heading_cost(grid, x, y, rc, geometry, k, free_runs, difference_tower)
                      for k in scales])  # (scales, headings)
    profile = costs.min(axis=0)
    if np.ptp(profile) < COST_FLOOR_M:
        return None   # every heading explains the range as well as any other: its minima would be noise
    best_scale = scales[costs.argmin(axis=0)]
    # Local minima on the circle (a flat stretch counts once: <= before, < after).
    is_min = (profile <= np.roll(profile, 1)) & (profile < np.roll(profile, -1))

    def cost(params: np.ndarray) -> float:
        return float(heading_cost(params[0], x, y, rc, geometry, params[1], free_runs, difference_tower))

    found = []
    for i in np.nonzero(is_min)[0]:
        bracket = (grid[i] - COARSE_STEP_RAD, grid[i] + COARSE_STEP_RAD)
        if scale_bounds is None:
            # A bounded scalar search over the grid cell: Nelder-Mead's default first step (5 % of x0) is
            # clipped at the cell's edge and can stall at the grid point on this piecewise-linear cost.
            res = minimize_scalar(lambda h: cost(np.array([h, 1.0])), bounds=bracket, method="bounded",
                                  options={"xatol": 1e-6})
            heading, scale = res.x, 1.0
        else:
            # An explicit first simplex inside the cell, for the same reason.
            start = np.array([grid[i], best_scale[i]])
            simplex = np.array([start, start + [0.5 * COARSE_STEP_RAD, 0.0], start + [0.0, 0.01]])
            res = minimize(cost, x0=start, method="Nelder-Mead", bounds=[bracket, scale_bounds],
                           options={"xatol": 1e-5, "fatol": 1e-7, "initial_simplex": simplex})
            heading, scale = res.x
        found.append((float(res.fun), float(heading % (2.0 * np.pi)), float(scale)))
    if not found:
        return None
    found.sort()
    costs_m, minima_rad, solved_scales = (np.array(v) for v in zip(*found))
    floored = np.maximum(costs_m, COST_FLOOR_M)
    confidence = float((floored[1] - floored[0]) / floored[1]) if len(costs_m) > 1 else 1.0
    sigma = heading_sigma(minima_rad[0], solved_scales[0], x, y, rc, geometry, free_runs, difference_tower,
                          solve_scale=scale_bounds is not None, start_sigma_m=start_sigma_m, pdr_t_s=t,
                          heading_rate_sigma_radps=heading_rate_sigma_radps)
    return HeadingSolution(minima_rad=minima_rad, costs_m=costs_m, scales=solved_scales,
                           heading_rad=float(minima_rad[0]), confidence=confidence, n_used=len(rc), sigma_rad=sigma)


def heading_sigma(heading_rad: float, scale: float, pdr_x_m: np.ndarray, pdr_y_m: np.ndarray,
                  range_change_m: np.ndarray, geometry: Geometry, free_runs: list[np.ndarray] | None = None,
                  difference_tower: int = 0, solve_scale: bool = True, start_sigma_m: float = 0.0,
                  pdr_t_s: np.ndarray | None = None, heading_rate_sigma_radps: float = 0.0) -> float:
    """Standard uncertainty of an eq. 15 heading about its minimum, rad.

    Eq. 15 is a least-absolute-deviations fit. With Laplace residuals of mean
    absolute value ``b`` (the cost at the minimum, raised to
    :data:`COST_FLOOR_M`) its parameters' covariance is ``b^2 (G^T G)^-1``,
    ``G`` the derivatives of the predicted range change (eq. 14) by heading
    and, where solved, PDR scale: a heading that the walk's geometry barely
    moves the range with is poorly known however small the cost. Consecutive
    epochs' residuals are not independent (the PDR drifts, the range error
    wanders), so ``G^T G`` counts ``n_eff = n (1 - rho) / (1 + rho)`` epochs
    instead of ``n``, ``rho`` the residuals' lag-one autocorrelation. Each
    free run's offset (:func:`free_offset_runs`) takes its mean out of the
    derivatives, as it takes its median out of the mismatch.

    The start fix's error is no residual: every epoch's prediction is made
    from the same P0, so its error moves the minimum as a whole. Its share is
    the least-squares solution's response to the predicted change's
    derivatives by P0 (east and north), each with ``start_sigma_m``. Nor is
    the PDR's heading drift over the window, the AHRS's residual gyro bias:
    a rate error turns each later step further, and the minimum follows it
    with the least-squares response to the track turned at
    ``heading_rate_sigma_radps``.

    Parameters
    ----------
    heading_rad, scale : float
        The minimum: heading (rad) and PDR distance scale.
    pdr_x_m, pdr_y_m, range_change_m : ndarray
        The epochs that entered the cost (NaN-free), m.
    geometry : Geometry
    free_runs : list of ndarray, optional
    difference_tower : int
        As :func:`predicted_range_change`.
    solve_scale : bool
        Whether the scale was solved with the heading (it then shares the
        range's information).
    start_sigma_m : float
        Standard deviation of the start fix P0 per axis, m.
    pdr_t_s : ndarray, optional
        The epochs' times, s (needed with ``heading_rate_sigma_radps``).
    heading_rate_sigma_radps : float
        Standard deviation of the PDR heading's rate error, rad/s.

    Returns
    -------
    float
        The heading's standard deviation, rad (pi where the range does not
        move with the heading at all).
    """
    def predicted(h: float, k: float, dx_m: float = 0.0, dy_m: float = 0.0) -> np.ndarray:
        start = replace(geometry, start_x_m=geometry.start_x_m + dx_m, start_y_m=geometry.start_y_m + dy_m)
        return predicted_range_change(h, k * pdr_x_m, k * pdr_y_m, start, difference_tower)

    step_rad, step_scale, step_m = 1e-4, 1e-4, 0.1
    columns = [(predicted(heading_rad + step_rad, scale) - predicted(heading_rad - step_rad, scale)) / (2 * step_rad)]
    if solve_scale:
        columns.append((predicted(heading_rad, scale + step_scale) - predicted(heading_rad, scale - step_scale))
                       / (2 * step_scale))
    jacobian = np.stack(columns, axis=1)
    at_minimum = predicted(heading_rad, scale)
    # Systematic errors, one column each, scaled by their sigma: P0 east and north, the PDR heading's rate.
    systematic = [(predicted(heading_rad, scale, step_m * east, step_m * north)
                   - predicted(heading_rad, scale, -step_m * east, -step_m * north)) / (2 * step_m) * start_sigma_m
                  for east, north in ((1.0, 0.0), (0.0, 1.0))]
    if pdr_t_s is not None:
        # The track with every step turned by a rate error of step_rate rad/s since the first epoch.
        step_rate = 1e-4
        dx, dy = np.diff(pdr_x_m, prepend=0.0), np.diff(pdr_y_m, prepend=0.0)
        tx, ty = rotate_pdr(dx, dy, step_rate * (pdr_t_s - pdr_t_s[0]))
        turned = predicted_range_change(heading_rad, scale * np.cumsum(tx), scale * np.cumsum(ty), geometry,
                                        difference_tower)
        systematic.append((turned - at_minimum) / step_rate * heading_rate_sigma_radps)
    by_error = np.stack(systematic, axis=1)
    mismatch = centred_mismatch(at_minimum, range_change_m, free_runs)
    for run in free_runs or ():
        jacobian[run] -= jacobian[run].mean(axis=0)
        by_error[run] -= by_error[run].mean(axis=0)
    n = len(mismatch)
    rho = 0.0
    if n > 2 and np.std(mismatch[:-1]) > 0 and np.std(mismatch[1:]) > 0:
        rho = float(np.clip(np.corrcoef(mismatch[:-1], mismatch[1:])[0, 1], 0.0, 1.0 - 1e-6))
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), 1.0)
    information = (jacobian.T @ jacobian) * n_eff / n
    b = max(float(np.mean(np.abs(mismatch))), COST_FLOOR_M)
    try:
        variance = b**2 * np.linalg.inv(information)[0, 0]
        # The systematic errors' share: how the least-squares heading follows each of them at one sigma.
        response = np.linalg.solve(jacobian.T @ jacobian, jacobian.T @ by_error)[0]
    except np.linalg.LinAlgError:
        return float(np.pi)
    variance += float(response @ response)
    return float(min(np.sqrt(max(variance, 0.0)), np.pi))
