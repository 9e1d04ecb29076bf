"""Physical constants shared by the numerical core."""

# Standard gravity (CGPM 1901, exact by definition); the data sheet's "g".
STANDARD_GRAVITY_MPS2 = 9.80665

# Timer ticks per second of the reference board: 11.0592 MHz crystal / 12.
# Only a default for simulation; the gateway uses the rate the board reports.
DEFAULT_TICK_HZ = 921_600

SEQ_MODULUS = 65_536
