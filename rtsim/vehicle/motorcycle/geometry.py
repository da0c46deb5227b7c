"""The two-wheeler's design geometry and its pose: where every point and unit vector of the assembly is
for given degrees of freedom (rtsim.vehicle.motorcycle.layout DOF_NAMES). Used to build the model, to
set initial states (a lean, a steer, a speed) and by the analyses (the symmetry directions of straight
running). Pure numpy, no kernels."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import MotorcycleConfig
from .layout import D_FORK, D_PITCH, D_ROLL, D_SPIN_F, D_SPIN_R, D_STEER, D_SWING, D_X, D_Y, D_YAW, D_Z, NDOF

EX, EY, EZ = np.eye(3)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about a unit axis by angle (rad), right-handed (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def angle_about(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> float:
    """Angle from u to v about axis (all unit, u and v normal to axis), rad."""
    return math.atan2(float(np.cross(u, v) @ axis), float(u @ v))


def xz(p) -> np.ndarray:
    return np.array([p[0], 0.0, p[1]], dtype=float)


@dataclass(frozen=True)
class Design:
    """The assembly at its design position (design frame, m): the rear frame's origin is the swingarm
    pivot; its axes are e1 (forward, normal to the steering axis), v (left) and h (the steering axis)."""
    pivot: np.ndarray
    e1: np.ndarray
    v: np.ndarray
    h: np.ndarray
    head: np.ndarray
    fork_offset: float          # m, front wheel centre ahead of the steering axis
    fork_length: float          # m, (W_f - head).h = -fork_length + (zeta - zeta0)
    zeta0: float                # m, fork compression at the design position
    swingarm_length: float      # m
    theta0: float               # rad, swingarm angle from e1 about v at the design position
    rear_centre: np.ndarray
    front_centre: np.ndarray


def design(cfg: MotorcycleConfig) -> Design:
    eps = cfg.caster_rad
    h = np.array([-math.sin(eps), 0.0, math.cos(eps)])
    e1 = np.array([math.cos(eps), 0.0, math.sin(eps)])
    wr = np.array([0.0, 0.0, cfg.rear_wheel.radius_m])
    wf = np.array([cfg.geometry.wheelbase_m, 0.0, cfg.front_wheel.radius_m])
    d = cfg.fork_offset
    lf = cfg.geometry.fork_length_m
    head = wf - d * e1 + lf * h
    pivot = xz(cfg.geometry.swingarm_pivot_m)
    arm = wr - pivot
    zeta0 = 0.0 if cfg.suspension.fork is None else cfg.suspension.fork.design_travel_m
    return Design(pivot=pivot, e1=e1, v=EY.copy(), h=h, head=head, fork_offset=d, fork_length=lf, zeta0=zeta0,
                  swingarm_length=float(np.linalg.norm(arm)),
                  theta0=angle_about(e1, arm / np.linalg.norm(arm), EY), rear_centre=wr, front_centre=wf)


def frame_rotation(yaw: float, roll: float, pitch: float) -> np.ndarray:
    """The rear frame's orientation: yaw about z, then roll about the new x, then pitch about the new y."""
    return rotation(EZ, yaw) @ rotation(EX, roll) @ rotation(EY, pitch)


def pose(des: Design, dof: np.ndarray) -> dict[str, np.ndarray]:
    """World positions and unit vectors of every named group (rtsim.vehicle.motorcycle.layout NAMES) for
    the degrees of freedom `dof` (layout D_*: x, y, z of the design origin; yaw, roll, pitch of the rear
    frame about it; steer; fork travel and swingarm rotation from the design position; wheel spins)."""
    rot = frame_rotation(dof[D_YAW], dof[D_ROLL], dof[D_PITCH])
    t = np.array([dof[D_X], dof[D_Y], dof[D_Z]])
    e1, v, h = des.e1, des.v, des.h
    steer = rotation(h, dof[D_STEER])
    f_u, e_u = steer @ e1, steer @ v
    theta = des.theta0 + dof[D_SWING]
    s_u = rotation(v, theta) @ e1
    w_r = des.pivot + des.swingarm_length * s_u
    w_f = des.head + (-des.fork_length + dof[D_FORK]) * h + des.fork_offset * f_u
    b_f = rotation(e_u, dof[D_SPIN_F]) @ f_u
    b_r = rotation(v, dof[D_SPIN_R]) @ e1
    body = {
        "P": des.pivot, "E1": e1, "V": v, "H_AX": h, "HEAD": des.head, "F_U": f_u, "E_U": e_u, "W_F": w_f,
        "B_F": b_f, "C_F": np.cross(b_f, e_u), "W_R": w_r, "S_U": s_u, "B_R": b_r, "C_R": np.cross(b_r, v),
        "N_S": np.cross(s_u, v),
    }
    out = {}
    for k, x in body.items():
        out[k] = rot @ x + (t if k in ("P", "HEAD", "W_F", "W_R") else 0.0)
    out["DELTA"] = np.array([dof[D_STEER]])
    out["ZETA"] = np.array([des.zeta0 + dof[D_FORK]])
    out["THETA"] = np.array([theta])
    out["PHI_F"] = np.array([dof[D_SPIN_F]])
    out["PHI_R"] = np.array([dof[D_SPIN_R]])
    return out


def zero_dof() -> np.ndarray:
    return np.zeros(NDOF)
