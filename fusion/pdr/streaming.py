"""The PDR as the walk happens: IMU chunks in, settled steps out (docs/method.md §3).

:class:`StreamingPdr` gives, chunk by chunk, the steps that :func:`fusion.pdr.pipeline.run_pdr`
gives for the whole log, in the same frame (start at (0, 0), heading relative to the rest
before the walk), with memory bounded whatever the walk's length:

- the attitude filter runs sample by sample and carries its state across chunks; the
  gyro bias (from the standstill before the first step) and the rest reference are fixed
  once the walk starts, so the samples before the first step are held until then (at most
  ``prewalk_s`` of them);
- the step detector and the walking direction rerun, every ``update_s`` of new samples,
  on a trailing window of ``trailing_s``: the batch's own functions, so that what they
  decide far enough from the window's ends is what the batch decides;
- a step is given out once later samples can no longer change it: its peak is older than
  the detector's look-ahead (:func:`detector_lookahead_s`), its bout is decided (a bout
  counts from ``min_bout_steps`` steps), and its heading has the steps after it that the
  carriage-change test and the walking direction's running median read (or, when the
  walker has stopped, ``hold_s`` has passed);
- the heading of each new step is the last given step's plus the change between the two
  in the window's run (from the yaw over the last given step's samples where the run no
  longer finds it), and the positions continue the given ones.

Settled steps come out well behind the newest sample (the look-ahead, the bout, the steps a
heading reads, and up to ``update_s``). :meth:`StreamingPdr.provisional` gives, between two
settled batches, the steps the last rerun found after the last settled one, up to the newest
samples: for a live position, to be taken back when the settled steps come.

What the batch decides from the whole walk is decided here from the walk so far, and
said in :attr:`StreamingPdr.notes`: ``heading_source="auto"`` switches to the walking
direction at the step where it is decided (the swing so far, or a change of carriage the
window shows, before or after that step) and never back; the carriage (and so a per-carriage Weinberg gain) is that of the steps so far.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from ahrs.filters import Madgwick
from scipy.spatial.transform import Rotation

from dtmbnav_core.records import ImuLog, PdrSteps
from dtmbnav_core.resampling import check_increasing, is_uniform
from fusion.pdr.attitude import forward_heading, gyro_bias_at_rest, madgwick_attitude
from fusion.pdr.dead_reckoning import dead_reckon, mean_heading_over_windows
from fusion.pdr.pipeline import PdrConfig, check_config, check_imu, has_magnetometer, weinberg_gain
from fusion.pdr.step_length import frequency_length, weinberg_length
from fusion.pdr.steps import (
    DetectedSteps,
    StepCandidates,
    StepDetectorConfig,
    bouts,
    in_bouts,
    step_candidates,
    step_windows,
)
from fusion.pdr.walking_direction import vertical_yaw, walking_direction

#: Steps after a step that the carriage-change test reads (the strides either side, and the peak test over 2 more).
CHANGE_LOOKAHEAD_STEPS = 4


def detector_lookahead_s(config: StepDetectorConfig) -> float:
    """How far ahead of a step's peak the step detector reads, s.

    The dynamic acceleration's centred moving averages (half of each window), then the
    longer of the level's centred percentile window and the period's centred
    autocorrelation window (plus a hop, between whose centres the period is
    interpolated), then one step period for the higher peak that may take a candidate
    out (``spacing_fraction``) and one for the next step that decides whether a gap is
    filled (``bout_tolerance``), at the longest period searched.
    """
    signal = 0.5 * (config.gravity_window_s + config.smoothing_s)
    context = max(0.5 * config.amplitude_window_s, 0.5 * config.period_window_s + config.period_hop_s)
    return signal + context + (config.spacing_fraction + config.bout_tolerance) * config.max_period_s


def _empty_steps() -> PdrSteps:
    empty = np.zeros(0)
    return PdrSteps(t_s=empty, x_m=empty, y_m=empty, heading_rad=empty, speed_mps=empty, step_length_m=empty)


class StreamingPdr:
    """Pedestrian dead reckoning on an IMU stream (module docstring).

    Parameters
    ----------
    config : PdrConfig
        As for :func:`~fusion.pdr.pipeline.run_pdr`.
    trailing_s : float
        Length of the window the detector and the walking direction rerun on, s: the
        look-ahead, ``min_bout_steps`` and ``smoothing_steps`` steps at a slow pace, and
        the detector's reach at the window's start.
    update_s : float
        New samples between two reruns, s (their cost is per rerun, not per chunk).
    lookahead_s : float or None
        Age of a step's peak before the detector's decision on it is final, s
        (None: :func:`detector_lookahead_s`).
    hold_s : float or None
        Age after which a step is given out although the steps after it that its heading
        reads have not come (the walker stopped), s (None: ``lookahead_s + 3``).
    prewalk_s : float
        Most samples held before the first step, s; the attitude then starts that long
        before the walk (the batch starts it at the first sample).
    """

    def __init__(self, config: PdrConfig, trailing_s: float = 30.0, update_s: float = 1.0,
                 lookahead_s: float | None = None, hold_s: float | None = None, prewalk_s: float = 60.0) -> None:
        check_config(config)
        self.config = config
        self.lookahead_s = detector_lookahead_s(config.steps) if lookahead_s is None else float(lookahead_s)
        self.hold_s = self.lookahead_s + 3.0 if hold_s is None else float(hold_s)
        if trailing_s < self.hold_s + 10.0:
            raise ValueError(f"trailing_s must be at least hold_s + 10 s ({self.hold_s + 10.0:g} s), got {trailing_s}")
        self.trailing_s = float(trailing_s)
        self.update_s = float(update_s)
        self.prewalk_s = float(prewalk_s)
        self._t = np.zeros(0)
        self._acc = np.zeros((0, 3))
        self._gyro = np.zeros((0, 3))
        self._mag = np.zeros((0, 3))
        self._quat = np.zeros((0, 4))  # attitude (scipy order x, y, z, w) of the samples since the walk started
        self._still = np.zeros(0, dtype=bool)
        self._since_update = 0
        self._started = False
        self._attitude = config.attitude
        self._bias = np.zeros(3)
        self._filter: Madgwick | None = None
        self._q_wxyz = np.zeros(4)
        self._rate_hz = np.nan
        self._last_t = -np.inf  # peak time of the last step given out
        self._last_start = -np.inf  # start of its window
        self._last_heading = 0.0
        self._x = self._y = 0.0
        self._n_swinging = self._n_steady = 0
        self._walking = config.heading_source == "walking"
        self._notes: list[str] = []
        self._trimmed_prewalk = False
        self._provisional = _empty_steps()

    # ---- what the stream knows so far
    @property
    def walking_used(self) -> bool:
        """Whether the steps' heading is now the walking direction's (else the phone's)."""
        return self._walking

    @property
    def heading_source(self) -> str:
        """``"walking"`` or ``"phone"``: where the heading of the steps now given out comes from."""
        return "walking" if self._walking else "phone"

    @property
    def carriage(self) -> str:
        """How the phone rode over the steps so far (a key of ``CARRIAGE_CLASSES``, or ``"unknown"``)."""
        if self._n_swinging + self._n_steady == 0:
            return "unknown"
        return "swinging" if self._n_swinging > self._n_steady else "steady"

    @property
    def notes(self) -> tuple[str, ...]:
        """What the stream did in place of its settings or of the batch, for the user."""
        return tuple(self._notes)

    @property
    def buffered_samples(self) -> int:
        """IMU samples held (bounded by ``trailing_s``, or ``prewalk_s`` before the walk)."""
        return len(self._t)

    def provisional(self) -> PdrSteps:
        """The steps after the last settled one, as the last rerun found them; not final.

        What a live position shows between two settled batches. They are the last
        rerun's candidates after the last step given out by :meth:`add`, up to the
        newest samples it had, in bouts as the batch keeps them, and the open bout
        at the window's end whatever its length (it may yet reach
        ``min_bout_steps``), its newest candidates taken as periodic while their
        periodicity window still runs past the newest sample (so that setting off
        again after a stop shows at once). Positions continue from the last settled step's; the
        heading is the settled steps' rule (the last settled heading plus the
        change the rerun sees from that step, from the source :attr:`heading_source`
        names now), the lengths the same model's. A later call may move, add or take
        out any of them: the settled steps replace them.

        The newest of them lags the newest sample by up to ``update_s`` (the samples
        since the last rerun), plus the time until the peak after the newest one
        stands out (the smoothing's half-window, a sample or two), plus up to a step
        when the newest peak's neighbourhood is still ambiguous. Empty before the first
        settled step (the attitude and the heading's reference start there) or after
        :meth:`finish`. Nothing is computed here: the rerun in :meth:`add` keeps them.
        """
        return self._provisional

    # ---- input
    def add(self, imu: ImuLog) -> PdrSteps:
        """Take the next chunk of samples and give the steps settled since the last call.

        Raises
        ------
        ValueError
            Malformed samples, times that do not continue the stream's on its uniform grid.
        """
        if len(imu.t_s) == 0:
            return _empty_steps()
        check_imu(imu)
        t = np.asarray(imu.t_s, dtype=np.float64)
        joined = np.concatenate([self._t[-2:], t])
        check_increasing(joined, "imu.t_s")
        if len(joined) >= 3 and not is_uniform(joined):
            raise ValueError("imu.t_s: the stream's samples must lie on one uniform grid (resample uneven "
                             f"times first); the chunk from {t[0]:.3f} s does not continue it")
        self._t = np.concatenate([self._t, t])
        self._acc = np.vstack([self._acc, imu.acc_mps2])
        self._gyro = np.vstack([self._gyro, imu.gyro_radps])
        self._mag = np.vstack([self._mag, imu.mag_ut])
        if self._started:
            self._continue_attitude(len(t))
        self._since_update += len(t)
        if len(self._t) < 2 or self._since_update * (self._t[-1] - self._t[0]) / (len(self._t) - 1) < self.update_s:
            return _empty_steps()
        return self._update(final=False)

    def finish(self) -> PdrSteps:
        """The steps left at the end of the stream."""
        self._provisional = _empty_steps()
        if len(self._t) < 2:
            return _empty_steps()
        return self._update(final=True)

    # ---- attitude
    def _start_walk(self, first_step_t_s: float) -> None:
        """Fix the gyro bias and rest at the first step, and run the attitude over the samples held."""
        attitude = self.config.attitude
        self._rate_hz = (len(self._t) - 1) / (self._t[-1] - self._t[0])
        if attitude.use_magnetometer and not has_magnetometer(ImuLog(self._t, self._acc, self._gyro, self._mag)):
            attitude = dataclasses.replace(attitude, use_magnetometer=False)
            self._notes.append("imu: no magnetometer (mag_ut all zeros): the attitude comes from the gyro and "
                               "accelerometer alone, and the heading drifts with the gyro's bias")
        self._attitude = attitude
        self._bias, self._still = gyro_bias_at_rest(self._t, self._gyro, first_step_t_s, attitude)
        mag = self._mag if attitude.use_magnetometer else None
        rotation = madgwick_attitude(self._gyro - self._bias, self._acc, mag, self._rate_hz, attitude.gain)
        self._quat = rotation.as_quat()
        self._q_wxyz = self._quat[-1, [3, 0, 1, 2]]
        self._filter = Madgwick(frequency=self._rate_hz, gain=attitude.gain)
        self._started = True

    def _continue_attitude(self, n: int) -> None:
        """The attitude of the last ``n`` samples, the filter's state carried from the one before."""
        gyro = self._gyro[-n:] - self._bias
        acc = self._acc[-n:]
        out = np.empty((n, 4))
        q = self._q_wxyz
        if self._attitude.use_magnetometer:
            for k, mag in enumerate(self._mag[-n:]):
                q = out[k] = self._filter.updateMARG(q, gyro[k], acc[k], mag)
        else:
            for k in range(n):
                q = out[k] = self._filter.updateIMU(q, gyro[k], acc[k])
        self._q_wxyz = q
        self._quat = np.vstack([self._quat, out[:, [1, 2, 3, 0]]])
        self._still = np.concatenate([self._still, np.zeros(n, dtype=bool)])

    # ---- the reruns
    def _settled_until(self, t: np.ndarray, peaks: np.ndarray, period: np.ndarray, periodic: np.ndarray,
                       horizon_s: float) -> float:
        """Latest time up to which the bouts of the final candidates are decided, s."""
        config = self.config.steps
        strong, bout = bouts(peaks, period, periodic, config)
        if strong.size == 0:
            return horizon_s
        members = strong[bout == bout[-1]]
        t_last = t[peaks[strong[-1]]]
        # A candidate after the horizon links to the last bout while within bout_tolerance periods of it.
        if horizon_s - t_last < config.bout_tolerance * config.max_period_s:
            return t_last if len(members) >= config.min_bout_steps else t[peaks[members[0]]] - 0.5 / self._rate()
        # A kept bout takes the next step up to last_step_tolerance periods after its last as its closing step.
        if (len(members) >= config.min_bout_steps and strong[-1] + 1 == len(peaks)
                and horizon_s - t_last < config.last_step_tolerance * config.max_period_s):
            return t_last
        return horizon_s

    def _rate(self) -> float:
        return (len(self._t) - 1) / (self._t[-1] - self._t[0])

    def _update(self, final: bool) -> PdrSteps:
        self._since_update = 0
        t, acc = self._t, self._acc
        config = self.config
        candidates = step_candidates(t, acc, config.steps)
        steps = _empty_steps()
        if candidates is not None:
            horizon = np.inf if final else t[-1] - self.lookahead_s
            final_peak = t[candidates.peaks] < horizon
            peaks, period = candidates.peaks[final_peak], candidates.period_samples[final_peak]
            periodic = candidates.periodic[final_peak]
            until = np.inf if final else self._settled_until(t, peaks, period, periodic, horizon)
            kept = in_bouts(peaks, period, periodic, config.steps)
            detected = step_windows(t, candidates.dyn_mps2, kept[t[kept] <= until], candidates.rate_hz,
                                    config.steps)
            if len(detected.t_s):
                if not self._started:
                    self._start_walk(float(detected.t_s[0]))
                steps = self._give_out(detected, final)
        self._provisional = _empty_steps() if final or candidates is None else self._provisional_steps(candidates)
        self._trim()
        return steps

    def _give_out(self, detected: DetectedSteps, final: bool) -> PdrSteps:
        """The detected steps not given out before whose heading is settled, in the PDR frame."""
        t = self._t
        config = self.config
        rotation = Rotation.from_quat(self._quat)
        gyro = self._gyro - self._bias
        phone = mean_heading_over_windows(t, forward_heading(t, rotation, self._still), detected.start_t_s,
                                          detected.t_s)
        walking = walking_direction(t, self._acc, gyro, rotation, self._still, detected.t_s, detected.start_t_s,
                                    self._attitude.gain, config.walking)
        half_sample = 0.5 / self._rate_hz
        new = np.flatnonzero(detected.t_s > self._last_t + half_sample)
        if new.size == 0:
            return _empty_steps()
        n = len(detected.t_s)
        usable_after = np.cumsum(walking.usable[::-1])[::-1] - walking.usable  # usable steps after each
        segment = np.cumsum(walking.carriage_change)
        ready = np.ones(new.size, dtype=bool)
        if not final:
            old = t[-1] - detected.t_s[new] >= self.hold_s
            ready = old | (n - 1 - new >= CHANGE_LOOKAHEAD_STEPS)
            if config.heading_source != "phone":
                # The running median of the walking direction reads half its width of usable steps ahead
                # (in the same carriage: a later change ends the segment).
                later_segment = segment[new] < segment[-1]
                ready &= old | later_segment | (usable_after[new] >= config.walking.smoothing_steps // 2)
            ready = np.logical_and.accumulate(ready)
        new = new[ready]
        if new.size == 0:
            return _empty_steps()
        swinging = walking.swing_rad[new] > np.radians(config.walking.swing_deg)
        self._n_swinging += int(np.count_nonzero(swinging))
        self._n_steady += int(np.count_nonzero(~swinging))
        # A change the run sees after these steps is one the batch sees: it takes the walking direction
        # (which holds the heading across the handling) for the whole walk.
        changed = bool(walking.carriage_change[new[0]:].any())
        if changed or (config.heading_source == "auto" and self.carriage == "swinging"):
            self._switch_to_walking(float(detected.t_s[new[0]]), changed)
        for i in new[walking.carriage_change[new]]:
            self._notes.append(f"pdr: the phone changed carriage (its attitude moved by more than "
                               f"{config.walking.change_deg:g} deg) before the step at {detected.t_s[i]:.2f} s: "
                               "the phone-to-walk offset was estimated afresh after it"
                               + ("" if self._walking else ", but the heading is the phone's "
                                  "(heading_source='phone'), so it may turn there"))
        heading = walking.heading_rad if self._walking else phone
        if np.isfinite(self._last_t):
            base = self._anchor_heading(t, rotation, self._still, detected, heading, int(new[0]))
            step_heading = self._last_heading + heading[new] - base
        else:
            step_heading = heading[new]
        out = self._continue_track(detected, new, step_heading)
        self._x, self._y = float(out.x_m[-1]), float(out.y_m[-1])
        self._last_t = float(detected.t_s[new[-1]])
        self._last_start = float(detected.start_t_s[new[-1]])
        self._last_heading = float(step_heading[-1])
        return out

    def _continue_track(self, detected: DetectedSteps, new: np.ndarray, heading_rad: np.ndarray) -> PdrSteps:
        """The steps ``new`` of ``detected`` with these headings, from the last settled position."""
        if self.config.step_model == "weinberg":
            lengths = weinberg_length(detected.acc_max_mps2[new], detected.acc_min_mps2[new],
                                      weinberg_gain(self.config, self.carriage))
        else:
            lengths = frequency_length(1.0 / detected.duration_s[new])
        out = dead_reckon(detected.t_s[new], detected.start_t_s[new], lengths, heading_rad)
        out.x_m += self._x
        out.y_m += self._y
        return out

    def _provisional_steps(self, candidates: StepCandidates) -> PdrSteps:
        """The last rerun's steps after the last settled one, up to the newest samples (:meth:`provisional`)."""
        if not np.isfinite(self._last_t):
            return _empty_steps()
        t = self._t
        config = self.config.steps
        peaks = candidates.peaks
        # The newest candidates' periodicity is measured on windows that run past the newest sample (after
        # a standstill they hold some of it): taken as periodic until the window is whole.
        periodic = candidates.periodic | (t[peaks] > t[-1] - 0.5 * config.period_window_s - config.period_hop_s)
        kept = in_bouts(peaks, candidates.period_samples, periodic, config)
        strong, bout = bouts(peaks, candidates.period_samples, periodic, config)
        if strong.size and t[-1] - t[peaks[strong[-1]]] < config.bout_tolerance * config.max_period_s:
            kept = np.union1d(kept, peaks[strong[bout == bout[-1]]])  # the open bout may yet be long enough
        half_sample = 0.5 / self._rate_hz
        new = np.flatnonzero(t[kept] > self._last_t + half_sample)
        if new.size == 0:
            return _empty_steps()
        detected = step_windows(t, candidates.dyn_mps2, kept, candidates.rate_hz, config)
        anchor = np.flatnonzero(np.abs(detected.t_s - self._last_t) < half_sample)
        # The heading's change from the anchor on needs only the strides the running median reads before it.
        first = max(0, int(anchor[0] if anchor.size else new[0]) - self.config.walking.smoothing_steps // 2)
        first_sample = int(np.searchsorted(t, min(detected.start_t_s[first], self._last_start)))
        tail = slice(first_sample, len(t))
        t_tail, still = t[tail], self._still[tail]
        rotation = Rotation.from_quat(self._quat[tail])
        steps = DetectedSteps(*(a[first:] for a in (detected.t_s, detected.start_t_s, detected.acc_max_mps2,
                                                     detected.acc_min_mps2)))
        if self._walking:
            heading = walking_direction(t_tail, self._acc[tail], self._gyro[tail] - self._bias, rotation, still,
                                        steps.t_s, steps.start_t_s, self._attitude.gain, self.config.walking).heading_rad
        else:
            heading = mean_heading_over_windows(t_tail, forward_heading(t_tail, rotation, still), steps.start_t_s,
                                                steps.t_s)
        base = self._anchor_heading(t_tail, rotation, still, steps, heading, int(new[0] - first))
        return self._continue_track(detected, new, self._last_heading + heading[new - first] - base)

    def _anchor_heading(self, t: np.ndarray, rotation: Rotation, still: np.ndarray, detected: DetectedSteps,
                        heading: np.ndarray, first_new: int) -> float:
        """The heading this run gives the last step given out, which the new steps' change is counted from, rad.

        A run that no longer finds that step (it lay near the window's start, and the walker stood still
        long after it) counts from it the change of the heading source's yaw between its window and the
        first new step's, while its samples are held; without a turn once they are not.
        """
        anchor = np.flatnonzero(np.abs(detected.t_s - self._last_t) < 0.5 / self._rate_hz)
        if anchor.size:
            return float(heading[anchor[0]])
        if self._last_start < t[0]:
            return float(heading[first_new])
        yaw = vertical_yaw(rotation, np.zeros(0, dtype=int)) if self._walking else forward_heading(t, rotation, still)
        before, after = mean_heading_over_windows(t, yaw, np.array([self._last_start, detected.start_t_s[first_new]]),
                                                  np.array([self._last_t, detected.t_s[first_new]]))
        return float(heading[first_new] - (after - before))

    def _switch_to_walking(self, t_s: float, changed: bool) -> None:
        if self._walking or self.config.heading_source != "auto":
            return
        self._walking = True
        why = "the phone changed carriage" if changed else "the phone's attitude swings over a stride on the steps so far"
        self._notes.append(f"pdr (live): the heading is the walking direction from the step at {t_s:.2f} s on ({why}); "
                           "the batch decides this from the whole walk")

    def _trim(self) -> None:
        """Drop the samples older than the trailing window (before the walk: than ``prewalk_s``)."""
        if self._started and not np.isfinite(self._last_t):
            return  # the rest before the walk is the heading's reference until the first step is given out
        keep_s = self.trailing_s if self._started else self.prewalk_s
        first = int(np.searchsorted(self._t, self._t[-1] - keep_s, side="left"))
        if first == 0:
            return
        if not self._started and not self._trimmed_prewalk:
            self._trimmed_prewalk = True
            self._notes.append(f"pdr (live): more than {self.prewalk_s:g} s before the first step; the attitude "
                               "starts from the last of it")
        self._t, self._acc, self._gyro, self._mag = (a[first:] for a in (self._t, self._acc, self._gyro, self._mag))
        if self._started:
            self._quat, self._still = self._quat[first:], self._still[first:]
