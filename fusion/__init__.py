"""Fusion of PDR and DTMB range: initial heading, particle filter and Kalman-family filters.

Consumes typed records (:mod:`dtmbnav_core.records`) and knows nothing of IQ.
This module holds only the names and defaults that callers need without
importing the numba kernels (the command line's parser uses them).
"""

#: The fusion filters, in table order ("pf" is the paper's particle filter, "rb-pf" the marginalised one that
#: samples only the heading); ``fusion.run.FILTERS`` maps each to its runner.
FILTER_NAMES = ("pf", "ukf", "wt-ukf", "adaptive-kf", "rank-kf", "rb-pf")
#: The filters that can be streamed (:mod:`fusion.streaming`): built from the first step alone, each epoch seen
#: once, in order (the WT-UKF and the adaptive EKF read their whole epoch history when they are built).
STREAMING_FILTERS = ("pf", "ukf", "rank-kf")
#: Particle-filter Np unless a caller says otherwise: enough particles that the filter's own random draws
#: move a walk's error little next to what the ranges and the PDR decide, so that whether a walk ends worse
#: than its PDR does not turn on the filter's seed (chosen on the tuning walks; docs/decisions.md, D18).
DEFAULT_PARTICLES = 40_000
#: Np of the marginalised particle filter (``fusion.rb_particle_filter``): it samples the heading and its rate
#: only, position and step-length scale are exact per particle (chosen on the tuning walks; docs/decisions.md, D59).
DEFAULT_RB_PARTICLES = 4_000
#: Lag of the particle filter's fixed-lag smoother, epochs (``fusion.particle_filter``): each particle carries
#: this many of its ancestors' states, so its memory is Np x lag states.
DEFAULT_SMOOTHING_LAG = 30
#: Row name of the foot-mounted ZUPT INS (:mod:`fusion.foot_ins`) in evaluations: it runs on its own
#: IMU, not on the range/PDR epochs the filters share.
FOOT_INS = "zupt-ins"
#: The receiver clock models (:class:`fusion.model.ClockModel`): a GNSS-disciplined clock, whose
#: offset the static window measures once, and a free-running one, which the filters carry as a state.
CLOCK_MODELS = ("disciplined", "free-running")
#: The clock model unless a caller says otherwise.
DEFAULT_CLOCK_MODEL = "disciplined"
#: The range eq. 15's initial heading is solved on with a disciplined clock (``fusion.run.initial_heading``):
#: the SI-carrier range (the paper's), or tower 0's first-path range where the path tracker gives one.
HEADING_RANGES = ("si", "first-path")
#: The heading range unless a caller says otherwise: the first path, which is the direct path's range
#: where the SI carriers follow a reflection (a blocked street) and the same range in the open (docs/method.md §4).
#: Without a path tracker (the observation level, ``--no-paths``) eq. 15 falls back to the SI carriers.
DEFAULT_HEADING_RANGE = "first-path"
#: When the filters take the SI-carrier range (``fusion.observations.si_range_epochs``): at every epoch it
#: passes its rules, or only at epochs without a first-path observation (the SI carriers measure the
#: power-weighted mix of all paths, so where the path tracker holds the direct path they add a reflection's
#: bias, not information).
SI_RANGE_USES = ("always", "without-first-path")
#: The SI range's use unless a caller says otherwise. Without a path tracker both are the same.
DEFAULT_SI_RANGE_USE = "without-first-path"
