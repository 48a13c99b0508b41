"""Physical constants, defined once for every package."""

#: Speed of light in vacuum, m/s (exact, SI).
SPEED_OF_LIGHT_MPS = 299_792_458.0
#: Standard gravity, m/s^2 (exact, CGPM 1901); the IMU simulation and the foot INS share it.
GRAVITY_MPS2 = 9.80665

#: Receiver reference-oscillator presets (docs/paths.md, "Oscillators of common SDRs"): preset -> (max |fractional
#: frequency offset| in ppb, Allan deviation at 1 s of its random-walk frequency wander). The simulator draws its
#: clock from them (sim.oscillator); the fusion's clock state takes its process noise from them
#: (fusion.model.ClockModel).
CLOCK_PRESETS = {"gnss-disciplined": (30.0, 1e-12), "free-running": (500.0, 1e-9)}

#: Weight of each frame in the receiver's SI reference (``receiver/cfo.py``, "Telescoping"; the observation
#: model measures its SI phases the same way). The reference must follow the channel's pattern over the SI
#: carriers, which changes over a fraction of a wavelength of motion, and its own phase wanders by the gain
#: times a frame's phase noise: a memory of 32 frames does both.
SI_REFERENCE_GAIN = 1.0 / 32.0

#: What the fusion can be given of a single-frequency network's transmit delay offsets: nothing (it estimates them
#: at the start fix), the network plan's (with the plan's error as sigma), a survey's on another walk of the network
#: (``dtmbnav towers calibrate``, with the survey's sigma), or the walk's true ones (simulation).
TRANSMIT_DELAY_KNOWLEDGE = ("unknown", "plan", "surveyed", "exact")
