"""Dimension-specific shared-control arbitration: numpy and numba, no I/O, no clock.

Everything here takes arrays and frozen dataclasses and returns the same; `dt` is always an
argument. The maths is stated once, in the docstring of the module that implements it, with
the paper's equation numbers (docs/METHOD.md gathers them):

    jit          how the maths is compiled (numba, cached on disk)
    se3          poses, rotations, differences, integration: the only SO(3) maths
    policy       U_robot, U_human, eq (2) on the bounded reference
    allocation   eq (3)-(8)
    arbiters     one tick of any mode, on a batch of any size
    modes        the modes (plug-ins: one module each) and their registry, `Mode`
    history      the operator's previous attempts (eq 6, last term)
    metrics      the paper's Section IV-D metrics and statistics

Conventions (written down once):
    * Poses are in the robot base frame: position [m], rotation as a 3x3 matrix, finger
      openness in [0, 1] (1 = fully open), one value per robot finger.
    * A dimension vector has 6 + F entries: x, y, z [m], rx, ry, rz [rad] (components in the
      base frame of a rotation vector), then the F fingers.
    * Actions U are velocities: m/s, rad/s (base-frame angular velocity), openness/s.
    * Public functions accept a leading batch shape on all of their arrays. The maths itself
      is written once, per state and per dimension, in compiled functions (`jit.kernel`)
      that the tick's kernels (`arbiters._shared`, the modes' rules, `arbiters._finish`) run
      over every row of a batch.
"""

from dsteleop.arbitration.arbiters import (
    STEP_ARRAYS,
    Arbiter,
    ArbitrationInput,
    ArbitrationStep,
    FilterState,
    RowModes,
    make_arbiter,
)
from dsteleop.arbitration.config import ArbitrationConfig, InvalidConfig
from dsteleop.arbitration.history import OperatorHistory
from dsteleop.arbitration.modes import Mode, ModeSpec, Quantities, register, registered, unregister
from dsteleop.arbitration.se3 import (
    HandState,
    diff,
    dim_names,
    integrate,
    log_relative,
    saturate,
    so3_exp,
    so3_log,
)

__all__ = [
    "STEP_ARRAYS",
    "Arbiter",
    "ArbitrationConfig",
    "ArbitrationInput",
    "ArbitrationStep",
    "FilterState",
    "HandState",
    "InvalidConfig",
    "Mode",
    "ModeSpec",
    "OperatorHistory",
    "Quantities",
    "RowModes",
    "diff",
    "dim_names",
    "integrate",
    "log_relative",
    "make_arbiter",
    "register",
    "registered",
    "saturate",
    "so3_exp",
    "so3_log",
    "unregister",
]
