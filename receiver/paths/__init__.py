"""Path tracking from the PN-header channel estimate: each path's delay and carrier phase (``docs/paths.md``).

The SI-carrier CFO (eq. 5-8) sees the sum of all paths; in a street it follows
the strongest reflection. The PN header gives, every frame, the channel
impulse response (CIR) over the header's cyclic extension
(:meth:`receiver.channel_estimate.ChannelEstimator.span_taps`: inside it no
previous body and no header tail reach the correlation window, so nothing
needs removing), and, where the header phase rotates, over shifted windows up
to the guard interval (``PathConfig.guard_span``, :mod:`receiver.paths.tracking`,
step 5); this package
separates the paths in it and tracks each one:

1. **Fit** (:mod:`receiver.paths.fit`). The CIR is a sum of known pulses (the
   GB 20600 SRRC through the header correlation and the resampler), one per
   path with its complex amplitude and fractional delay. Over runs of frames
   the delays are held and the amplitudes are the least-squares fit, so
   paths closer than a chip are separated by the pulse shape; every
   ``block_frames`` frames a Gauss-Newton step corrects each path's delay: a
   delay-locked loop per path, with a rate for the receiver clock's drift
   and the walker's motion.
2. **Detection** (:mod:`receiver.paths.detection`). What the paths leave
   unexplained, over the noise floor, is tested against a threshold of known
   false-alarm probability; the strongest peak that stands out like a pulse
   is a new path, fitted with the others from the next batch on (so a
   strong path's sidelobes are never taken for paths).
3. **Tracking** (:mod:`receiver.paths.tracking`). A path is reported once its
   delay holds still and dropped when it fades or merges with an older one;
   its frequency is its amplitude's phase step from frame to frame, with
   outliers bridged and cycle slips flagged. Paths are grouped into towers
   by delay; each tower's earliest mature path is its first path, the
   direct-path candidate, and the towers' first-path phase differences give
   clock-free range differences. An optional Doppler check
   (:class:`receiver.delay_doppler.FirstPathDoppler`) handles a first path
   that is a pair closer than a third of a chip.

The public names of the three modules are importable from here.
"""

from receiver.paths.detection import RING, detect_paths, detection_threshold, erlang_log_survival
from receiver.paths.fit import (
    PULSE_OVERSAMPLING,
    fit_paths_kernel,
    fit_paths_reference,
    fit_views_kernel,
    model_residual_kernel,
    pulse_tables,
    resampler_response,
    srrc_spectrum,
)
from receiver.paths.tracking import (
    RANGE_DIFFERENCE_TOWERS,
    PathConfig,
    PathTracker,
    PathUpdate,
    slip_kernel,
    slip_reference,
    step_paths_kernel,
)

__all__ = [
    "PULSE_OVERSAMPLING",
    "RANGE_DIFFERENCE_TOWERS",
    "RING",
    "PathConfig",
    "PathTracker",
    "PathUpdate",
    "detect_paths",
    "detection_threshold",
    "erlang_log_survival",
    "fit_paths_kernel",
    "fit_paths_reference",
    "fit_views_kernel",
    "model_residual_kernel",
    "pulse_tables",
    "resampler_response",
    "slip_kernel",
    "slip_reference",
    "srrc_spectrum",
    "step_paths_kernel",
]
