"""Physical constants, named once."""

GRAVITY = 9.80665  #: standard gravity [m/s^2] (CGPM 1901; ISO 80000-3)
