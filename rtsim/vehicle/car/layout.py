"""Array layouts of the four-wheel car assembly (no imports of its builder or config, so the kernels,
the effects and the config can all use them without an import cycle): the Vehicle tuple of model
arrays the kernels read, and the index tables into it."""
from __future__ import annotations

from collections import namedtuple

G = 9.81
WHEELS = ("fl", "fr", "rl", "rr")   # corner order of every per-wheel array: front axle first, left first
FRONT_AXLE, REAR_AXLE = (0, 1), (2, 3)

# Corner coordinate index table (Vehicle.corner_idx[w, :]).
CI_WX, CI_WY, CI_WZ, CI_Z, CI_PHI, CI_S = range(6)
# Chassis coordinate index table (Vehicle.chassis_idx): r (0..2), u (3..5), v (6..8), w (9..11).

# Per-corner suspension parameters (Vehicle.susp[w, :]).
SP_K, SP_FREE, SP_BS_LEN, SP_BS_K, SP_C_BUMP, SP_C_REB, SP_ARB, SP_PARTNER = range(8)
NSP = 8

Vehicle = namedtuple("Vehicle", [
    "chassis_idx",     # (12,) int
    "corner_idx",      # (4, 6) int, CI_*
    "axis_coef", "rotz_coef", "rots_coef",   # (4, 3, nterm) polynomials in (z, s), body frame
    "spring_coef",     # (4, nterm) spring/damper length polynomial, m
    "susp",            # (4, NSP) float
    "steer_idx",       # (2,) int coordinate indices of the steering column angle and the rack travel
    "imu_local",       # (3,) IMU position in the body frame relative to the CG, m
    "aero",            # (2,) drag area m^2, air density kg/m^3
    "tyre_model",      # (1,) int: TYRE_MAGIC_FORMULA or TYRE_LINEAR
    "driven",          # (2,) int corners of the driven axle, left then right
    "drive_slot",      # (4,) int per corner: its index in `driven`, or -1
    "side",            # (4,) float per corner: +1 left, -1 right (mirrors the tyre property file)
])
TYRE_MAGIC_FORMULA, TYRE_LINEAR = 0, 1
STEER_COLUMN, STEER_RACK = 0, 1     # Vehicle.steer_idx
