"""Pedestrian dead reckoning (docs/method.md §3, eq. 12-13): steps, step lengths, heading, positions.

``run_pdr(imu, config)`` (:mod:`fusion.pdr.pipeline`) turns an :class:`~dtmbnav_core.records.ImuLog`
into per-step positions in the PDR's own frame (start at (0, 0), heading
relative to the initial one) and a fixed-rate track.
"""

from fusion.pdr.pipeline import PdrConfig, PdrResult, calibrate_weinberg_k_from_walk, run_pdr

__all__ = ["PdrConfig", "PdrResult", "run_pdr", "calibrate_weinberg_k_from_walk"]
