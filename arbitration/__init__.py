"""Dimension-specific shared-control arbitration: pure numpy, no I/O, no clock.

Everything here takes arrays and frozen dataclasses and returns the same; `dt` is always an
argument. The maths is stated once, in the docstring of each module, with the paper's
equation numbers (`../shared/paper`, eq. 1-8) and the reading fixed in DESIGN.md.

Conventions (written down once):
    * Poses are in the robot base frame: position [m], rotation as a 3x3 matrix, finger
      openness in [0, 1] (1 = fully open), one value per robot finger.
    * A dimension vector has 6 + F entries: x, y, z [m], rx, ry, rz [rad] (components in the
      base frame of a rotation vector), then the F fingers.
    * Actions U are velocities: m/s, rad/s (base-frame angular velocity), openness/s.
    * Every function accepts a leading batch axis on all of its arrays.
"""

from dsteleop.arbitration.arbiters import (
    ARBITERS,
    STEP_ARRAYS,
    Arbiter,
    ArbitrationInput,
    ArbitrationStep,
    Autonomous,
    DimensionSpecific,
    Manual,
    Mode,
    Standard,
    make_arbiter,
)
from dsteleop.arbitration.config import ArbitrationConfig, InvalidConfig
from dsteleop.arbitration.history import OperatorHistory
from dsteleop.arbitration.se3 import (
    HandState,
    diff,
    dim_names,
    integrate,
    saturate,
    so3_exp,
    so3_log,
)

__all__ = [
    "ARBITERS",
    "STEP_ARRAYS",
    "Arbiter",
    "ArbitrationConfig",
    "ArbitrationInput",
    "ArbitrationStep",
    "Autonomous",
    "DimensionSpecific",
    "HandState",
    "InvalidConfig",
    "Manual",
    "Mode",
    "OperatorHistory",
    "Standard",
    "diff",
    "dim_names",
    "integrate",
    "make_arbiter",
    "saturate",
    "so3_exp",
    "so3_log",
]
