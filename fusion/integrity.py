"""Range integrity: fall back on the PDR where a range channel stops agreeing with the motion.

A reflection with its own Doppler, a drifting clock or a tracker on the
wrong path bends an integrated range by a steady fraction of a metre per
second (docs/paths.md). A filter follows such a bend (it turns and speeds up
its track, and its innovations stay small), but the PDR does not. This
monitor, shared by every filter (:mod:`fusion.particle_filter`,
:mod:`fusion.kalman`), sets each range channel
(:class:`fusion.model.ObservationLayout`) against the PDR (docs/method.md §8).

**Open-loop prediction.** The posterior ``(x_m, P_m)`` of each of the last
``window`` epochs (:meth:`IntegrityMonitor.posterior`) is carried forward
with the PDR's steps alone (:func:`fusion.model.propagate`,
:func:`fusion.model.transition_jacobian`): ``x_n|m``, ``P_n|m = Phi P_m
Phi^T + Q_acc`` and ``C = Phi P_m``.

**Consistency test.** A channel's observation ``z_n`` is set against that of
the oldest kept epoch m of its window that has one:

    d = (z_n - z_m) - (g(x_n|m) - g(x_m))
    Var(d) = 2 e^2 + (r (t_n - t_m))^2 + J_n P_n|m J_n^T + J_m P_m J_m^T - 2 J_n C J_m^T
             + k range_offset_m^2

with ``g`` the channel's model (:func:`fusion.model.observe`, the origin
cancelling), ``J`` its Jacobian and ``k`` the epochs in between without the
channel (:class:`fusion.model.ModelNoise`). ``e`` (``change_noise_m``) and
``r`` (``rate_sigma_mps``) are the noise of a *change* of a carrier-phase
range, not the filters' sigma (:mod:`fusion.observations`): that sigma is
mostly an offset a change cancels, inflated on weak paths, and counted at
both ends it would hide the bends of the very paths that need testing. The
channel agrees while ``d^2 <= chi2_1(1 - false_alarm) Var(d)``, ``chi2_1(p)``
the p quantile of the chi-square distribution with one degree of freedom.

**Fallback.** A failing channel is dropped, and the filter's state is
replaced by the open-loop prediction from the oldest kept epoch, undoing
what the ranges did to the track since: not only from epoch m, because a
channel's test restarts at each new origin but the track it dragged does
not. The kept epochs after it belong to the abandoned track and are
forgotten.

**Return.** A dropped channel is tested again once ``readmit_window``
observations are in, against the far stricter ``return_quantile`` (the
median by default): a biased channel taken back drags the track again, a
good one kept out a little longer only leaves the filter on the PDR. It
comes back as a new origin: the filter re-anchors it and takes only changes
from there. A channel whose data restart from a new origin (a slip, a
re-acquired path) is re-anchored by the filter, and its window restarts.

**Late first path.** A reflection taken for the first path while its range
changes as the truth's (walking along a wall) passes that test. Its code
range (:class:`dtmbnav_core.records.PathRangeSeries`) is absolute up to a
constant ``b``, and a reflection only ever arrives *late*. ``b`` is the
median of ``code - g(x)`` over the first ``code_calibration_epochs`` epochs
with a code, ``x`` the filter's prior (the walker starts at the fix); from
then on a first path whose excess ``code - b - g(x)`` exceeds ``code_late_m``
is kept from the filters that epoch (:attr:`IntegrityMonitor.late_epochs`).
The bound is a distance, not a multiple of the prior's ``J P J^T``, which a
particle cloud makes metres wide even where its mean is right; and an early
code does not move ``b``, since no path arrives before the direct one. Eq.
15 keeps every first path: reflections along the street serve it.

**Two references.** A filter that is off along the line of sight sees the
direct path late by its own error and would drop the one range that brings
it back. With ``code_pdr_reference`` the excess is also taken against the
PDR alone from the first posterior (its clock columns the prior's), with a
constant of its own, and a path is late only when late against both: the
PDR's error is its own drift, which no decision of the gate moves.

The defaults were chosen on the tuning walks (docs/decisions.md, D24-D28).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy.stats import chi2

from fusion.model import (STATE_SIZE, ClockModel, Geometry, ModelNoise, ObservationLayout, StepControl,
                          observation_jacobian, observe, process_covariance, propagate, transition_jacobian)


@dataclass(frozen=True)
class IntegrityConfig:
    """Settings of the range integrity monitor (module docstring).

    Attributes
    ----------
    enabled : bool
        Off: every present range is used (the filters' own outlier handling only).
    window : int
        Epochs over which a channel's change is set against the PDR's
        (about two per second while walking).
    false_alarm : float
        Probability that a test of a consistent channel fails.
    readmit_window : int
        Observations a dropped channel needs after the drop before it may come back.
    return_quantile : float
        The return test passes below this quantile of the consistency
        statistic's chi-square distribution: a consistent channel passes it
        this often, a biased one far less (module docstring).
    change_noise_m : float
        White error of one epoch's range in a change, m (``e``).
    rate_sigma_mps : float
        Range-rate error a consistent channel may carry, m/s (``r``). A
        carrier-phase range of the path it claims to follow errs by
        millimetres per second, a first path that follows a wall reflection
        round a corner by tenths of a metre per second; the default lies
        between (chosen on the tuning walks; docs/decisions.md, D25).
    code_gate : bool
        Whether a late first path (module docstring) is kept from the filters.
    code_calibration_epochs : int
        Epochs with a code range the constant ``b`` is calibrated on.
    code_late_m : float
        Excess of the code range over the prior's range beyond which the
        first path is late, m: above the IQ receiver's code error on a
        street's diffracted direct path (docs/paths.md) plus the prior's
        range error where the filter is right (chosen on the tuning walks;
        docs/decisions.md, D27).
    code_change_m : float or None
        A late first path is kept while its excess stays within this of its
        value where the late stretch began (a reflection off a wall along the
        walk changes its range as the direct path does), and dropped from the
        first epoch it does not until the stretch ends, m; None: dropped
        throughout.
    code_pdr_reference : bool
        Whether a first path counts as late only when it is also late against
        the PDR alone (module docstring, "Two references").
    """

    enabled: bool = True
    window: int = 20
    false_alarm: float = 1e-3
    readmit_window: int = 20
    return_quantile: float = 0.5
    change_noise_m: float = 0.05
    rate_sigma_mps: float = 0.02
    code_gate: bool = True
    code_calibration_epochs: int = 10
    code_late_m: float = 3.0
    code_change_m: float | None = None
    code_pdr_reference: bool = True

    def __post_init__(self) -> None:
        if self.window < 2 or not 2 <= self.readmit_window <= self.window:
            raise ValueError(f"integrity windows: need 2 <= readmit_window <= window, got {self.readmit_window}, "
                             f"{self.window}")
        if not 0.0 < self.false_alarm < 1.0 or not 0.0 < self.return_quantile < 1.0:
            raise ValueError(f"integrity false_alarm and return_quantile must be in (0, 1), got {self.false_alarm}, "
                             f"{self.return_quantile}")
        if self.change_noise_m < 0.0 or self.rate_sigma_mps < 0.0:
            raise ValueError(f"integrity change_noise_m and rate_sigma_mps must be >= 0, got {self.change_noise_m}, "
                             f"{self.rate_sigma_mps}")
        if self.code_calibration_epochs < 1 or self.code_late_m < 0.0:
            raise ValueError(f"integrity code gate: need code_calibration_epochs >= 1 and code_late_m >= 0, got "
                             f"{self.code_calibration_epochs}, {self.code_late_m}")


@dataclass
class KeptEpochs:
    """The epochs the monitor keeps, oldest first: each row one epoch (module docstring).

    Attributes
    ----------
    index : ndarray of int, (K,)
        Epoch index.
    t_s : ndarray, (K,)
        Epoch time since the first control, s.
    z : ndarray, (K, n_channels)
        The epoch's observations (NaN: none), m.
    x, P : ndarray, (K, S), (K, S, S)
        The filter's posterior state and covariance at the epoch.
    x_open, P_open : ndarray
        Their open-loop prediction (PDR only) from the epoch to now.
    cross : ndarray, (K, S, S)
        ``Phi P_m``: the covariance of the prediction with the posterior.
    """

    index: np.ndarray
    t_s: np.ndarray
    z: np.ndarray
    x: np.ndarray
    P: np.ndarray
    x_open: np.ndarray
    P_open: np.ndarray
    cross: np.ndarray

    @classmethod
    def single(cls, index: int, t_s: float, z: np.ndarray, x: np.ndarray, P: np.ndarray) -> KeptEpochs:
        """One epoch, whose open-loop prediction starts at its posterior."""
        return cls(np.array([index]), np.array([t_s]), z[None], x[None], P[None], x[None].copy(), P[None].copy(),
                   P[None].copy())

    def appended(self, epoch: KeptEpochs, window: int) -> KeptEpochs:
        """The last ``window - 1`` of these epochs, then ``epoch``."""
        keep = -(window - 1)
        return KeptEpochs(*(np.concatenate([getattr(self, f.name)[keep:], getattr(epoch, f.name)])
                            for f in fields(self)))

    def oldest(self) -> KeptEpochs:
        """Only the oldest epoch."""
        return KeptEpochs(*(getattr(self, f.name)[:1] for f in fields(self)))


class IntegrityMonitor:
    """Decides per epoch which range channels a filter uses (module docstring).

    The filter calls :meth:`predict` with each control, :meth:`assess`
    before it weighs the epoch's ranges, and :meth:`posterior` with its
    state after the update.

    Parameters
    ----------
    geometry : Geometry
    noise : ModelNoise
        The process noise of the open-loop prediction.
    clock : ClockModel
        With a free-running clock the states carry the clock (7 columns).
    config : IntegrityConfig

    Attributes
    ----------
    dropped_epochs : ndarray of int
        Per channel, how many of its observations were not used.
    fallbacks : int
        How often the filter was sent back to an open-loop prediction.
    late_epochs : ndarray of int
        Per channel, how many of its observations the code range found late.
    """

    def __init__(self, geometry: Geometry, noise: ModelNoise, clock: ClockModel = ClockModel(),
                 config: IntegrityConfig = IntegrityConfig()) -> None:
        self.geometry = geometry
        self.noise = noise
        self.clock = clock
        self.config = config
        self.layout = ObservationLayout(geometry.n_towers)
        n = self.layout.n_channels
        self._rows = self.layout.rows()
        self._in_use = np.ones(n, dtype=bool)
        self._since = np.full(n, -1)  # a channel's tests start after this epoch (a drop or a new origin)
        self._drop_limit = float(chi2.ppf(1.0 - config.false_alarm, 1))
        self._return_limit = float(chi2.ppf(config.return_quantile, 1))
        self._index = -1
        self._t_s = 0.0
        self._z = np.full(n, np.nan)
        self._kept: KeptEpochs | None = None
        self.dropped_epochs = np.zeros(n, dtype=np.int64)
        self.fallbacks = 0
        self.late_epochs = np.zeros(n, dtype=np.int64)
        # Per channel and reference (the filter's prior, then the PDR alone if used): code - g(x) while
        # calibrating, then the constant b.
        self._references = 2 if config.code_pdr_reference else 1
        self._code_offsets: list[list[np.ndarray]] = [[] for _ in range(n)]
        self._code_origin = np.full((n, self._references), np.nan)
        self._late_excess = np.full(n, np.nan)                            # excess where a late stretch began
        self._late_dropped = np.zeros(n, dtype=bool)                      # the stretch's path has been dropped
        self._pdr_x: np.ndarray | None = None                             # the PDR alone from the first epoch

    def predict(self, control: StepControl) -> None:
        """Carry every kept epoch's open-loop prediction over one more control."""
        self._index += 1
        self._t_s += control.elapsed_s
        if self._pdr_x is not None:
            self._pdr_x = propagate(self._pdr_x, control)
        kept = self._kept
        if not self.config.enabled or kept is None:
            return
        f = transition_jacobian(kept.x_open, control)
        kept.x_open = propagate(kept.x_open, control)
        kept.P_open = f @ kept.P_open @ np.swapaxes(f, -1, -2) + process_covariance(self.noise, control, self.clock)
        kept.cross = f @ kept.cross

    def assess(self, z: np.ndarray, new_origin: np.ndarray, code_m: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
        """Which channels to use this epoch, which come back as a new origin, and any fallback state.

        Parameters
        ----------
        z : ndarray
            Observation per range channel, m (NaN: none this epoch).
        new_origin : ndarray of bool
            Channels whose data restart from a new origin this epoch: the
            filter re-anchors them when they are in use, and their windows
            start afresh.
        code_m : ndarray, optional
            Code range per range channel, m (NaN: none;
            :meth:`fusion.model.EpochObservation.code_channels`): a channel
            whose code range is late is treated as absent this epoch.

        Returns
        -------
        use : ndarray of bool
            Observations the filter may use.
        reanchor : ndarray of bool
            Channels coming back after being dropped, to be re-anchored on
            this observation rather than weighed.
        fallback : (x, P) or None
            Where a channel was dropped: the open-loop state and covariance
            from the oldest kept epoch, which the filter is to take instead
            of its own.
        """
        if self.config.enabled and code_m is not None:
            late = self._late(np.asarray(code_m, dtype=np.float64)) & np.isfinite(z)
            self.late_epochs += late
            z = np.where(late, np.nan, z)
        present = np.isfinite(z)
        self._z = z.copy()
        use = present.copy()
        reanchor = np.zeros(len(z), dtype=bool)
        if not self.config.enabled:
            return use, reanchor, None
        dropped = False
        for j in np.flatnonzero(present):
            if new_origin[j]:
                self._since[j] = self._index
                continue
            candidates = (np.empty(0, dtype=np.int64) if self._kept is None else
                          np.flatnonzero((self._kept.index > self._since[j]) & np.isfinite(self._kept.z[:, j])))
            if self._in_use[j]:
                if len(candidates) and not self._agrees(candidates[0], j, z[j], self._drop_limit):
                    self._in_use[j] = False
                    self._since[j] = self._index
                    dropped = True
            elif (len(candidates) + 1 >= self.config.readmit_window
                  and self._agrees(candidates[0], j, z[j], self._return_limit)):
                self._in_use[j] = True
                self._since[j] = self._index
                reanchor[j] = True
            if not self._in_use[j]:
                use[j] = False
                self.dropped_epochs[j] += 1
        if not dropped:
            return use, reanchor, None
        self.fallbacks += 1
        fallback = (self._kept.x_open[0].copy(), self._kept.P_open[0].copy())
        # The filter falls back to the oldest kept epoch, so the later posteriors are abandoned.
        self._kept = self._kept.oldest()
        return use, reanchor, fallback

    def posterior(self, x: np.ndarray, P: np.ndarray) -> None:
        """Keep the filter's state after this epoch's update as a start of later tests (the first also starts the
        PDR reference of the late-first-path gate)."""
        if not self.config.enabled:
            return
        epoch = KeptEpochs.single(self._index, self._t_s, self._z, np.array(x, dtype=np.float64),
                                  np.array(P, dtype=np.float64))
        self._kept = epoch if self._kept is None else self._kept.appended(epoch, self.config.window)
        if self._pdr_x is None and self._references == 2:
            self._pdr_x = np.array(x, dtype=np.float64)

    def _late(self, code_m: np.ndarray) -> np.ndarray:
        """Channels whose code range says the tracked path arrives late (module docstring, "Late first path")."""
        config = self.config
        late = np.zeros(len(code_m), dtype=bool)
        if not config.code_gate or self._kept is None:
            return late
        references = np.repeat(self._kept.x_open[-1:], self._references, axis=0)
        if self._references == 2:
            references[1, :STATE_SIZE] = self._pdr_x[:STATE_SIZE]   # its clock columns stay the prior's
        offsets = code_m[:, None] - observe(references, self.geometry, 0.0)[:, self._rows].T
        for j in np.flatnonzero(np.isfinite(code_m)):
            if np.isnan(self._code_origin[j, 0]):
                self._code_offsets[j].append(offsets[j])
                if len(self._code_offsets[j]) == config.code_calibration_epochs:
                    self._code_origin[j] = np.median(self._code_offsets[j], axis=0)
                continue
            excess = float(np.min(offsets[j] - self._code_origin[j]))
            if excess <= config.code_late_m:
                self._late_excess[j], self._late_dropped[j] = np.nan, False
                continue
            if np.isnan(self._late_excess[j]):
                self._late_excess[j] = excess
            self._late_dropped[j] |= (config.code_change_m is None
                                      or abs(excess - self._late_excess[j]) > config.code_change_m)
            late[j] = self._late_dropped[j]
        return late

    def _agrees(self, start: int, channel: int, z: float, limit: float) -> bool:
        """Consistency test of ``channel`` from kept epoch ``start`` to now (module docstring): ``d^2 <= limit Var(d)``."""
        row = self._rows[channel]
        kept = self._kept
        x_then, x_now = kept.x[start], kept.x_open[start]
        g = observe(np.stack([x_then, x_now]), self.geometry, 0.0)[:, row]
        j_then = observation_jacobian(x_then, self.geometry)[row]
        j_now = observation_jacobian(x_now, self.geometry)[row]
        d = (z - kept.z[start, channel]) - (g[1] - g[0])
        gaps = np.count_nonzero(~np.isfinite(kept.z[start + 1:, channel]))
        span_s = self._t_s - kept.t_s[start]
        variance = (2.0 * self.config.change_noise_m**2 + (self.config.rate_sigma_mps * span_s) ** 2
                    + j_now @ kept.P_open[start] @ j_now
                    + j_then @ kept.P[start] @ j_then - 2.0 * j_now @ kept.cross[start] @ j_then
                    + gaps * self.noise.range_offset_m**2)
        return d * d <= limit * variance
