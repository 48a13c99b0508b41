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
