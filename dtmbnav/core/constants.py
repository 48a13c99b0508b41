"""Physical constants, defined once for every package."""

#: Speed of light in vacuum, m/s (exact, SI).
SPEED_OF_LIGHT_MPS = 299_792_458.0
#: Standard gravity, m/s^2 (exact, CGPM 1901); the IMU simulation and the foot INS share it.
GRAVITY_MPS2 = 9.80665
