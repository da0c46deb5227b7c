"""Index tables of the two-wheeler assembly, declared once: which coordinates hold which point, unit
vector or relative coordinate. Kernels read them from `TwoWheeler.idx` by the constants below; a
point or vector occupies three consecutive coordinates starting at its index."""
from __future__ import annotations

# Named coordinate groups (TwoWheeler.idx[K_*]): points and unit vectors (start of 3 coordinates) and
# scalars. K_N_S is -1 for a massless swingarm (no third vector needed).
NAMES = (
    "P",      # swingarm pivot: the rear frame's origin (point)
    "E1",     # rear frame: forward unit vector normal to the steering axis
    "V",      # rear frame: lateral unit vector (left); also the swingarm pivot and rear axle
    "H_AX",   # rear frame: steering axis, upwards
    "HEAD",   # head point on the steering axis (top of the fork)
    "F_U",    # upper fork: forward unit vector normal to the steering axis
    "E_U",    # upper fork: lateral unit vector, the front axle
    "DELTA",  # steer angle, rad (positive steering left)
    "W_F",    # front wheel centre (point)
    "ZETA",   # fork compression from full extension, m
    "B_F", "C_F",   # front wheel in-plane unit vectors
    "PHI_F",  # front wheel spin angle relative to the fork, rad
    "W_R",    # rear wheel centre (point)
    "S_U",    # swingarm: unit vector from pivot to rear axle
    "THETA",  # swingarm angle from E1 about V, rad
    "B_R", "C_R",   # rear wheel in-plane unit vectors
    "PHI_R",  # rear wheel spin angle relative to the rear frame, rad
    "N_S",    # swingarm: third unit vector (massive swingarm only)
)
(K_P, K_E1, K_V, K_H, K_HEAD, K_F_U, K_E_U, K_DELTA, K_W_F, K_ZETA, K_B_F, K_C_F, K_PHI_F, K_W_R, K_S_U,
 K_THETA, K_B_R, K_C_R, K_PHI_R, K_N_S) = range(len(NAMES))
NK = len(NAMES)
POINTS = ("P", "HEAD", "W_F", "W_R")
VECTORS = ("E1", "V", "H_AX", "F_U", "E_U", "B_F", "C_F", "S_U", "B_R", "C_R", "N_S")
SCALARS = ("DELTA", "ZETA", "PHI_F", "THETA", "PHI_R")

# Degrees of freedom of the pose (rtsim.vehicle.motorcycle.pose), in this order.
DOF_NAMES = ("x", "y", "z", "yaw", "roll", "pitch", "steer", "fork_travel", "swingarm", "spin_rear", "spin_front")
(D_X, D_Y, D_Z, D_YAW, D_ROLL, D_PITCH, D_STEER, D_FORK, D_SWING, D_SPIN_R, D_SPIN_F) = range(len(DOF_NAMES))
NDOF = len(DOF_NAMES)
