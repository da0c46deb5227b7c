"""The rack and pinion, one kit part for both steering systems (rtsim.vehicle.kit.steering, steer-by-wire;
rtsim.vehicle.kit.eps, electric power steering): its parameters as one block of RK_SIZE floats inside the
system's parameter array, packed by `rack_and_pinion`.

The pinion is geared rigidly to the rack, theta_p = x / r_p (x: rack travel, m, positive steers left;
r_p: rack travel per pinion radian, m/rad), so its inertia, and that of whatever turns with the pinion
through a gear of ratio N (an EPS motor on the pinion: N^2 J_motor), sits on the rack coordinate:

    m_rack = m_r + (J_pinion + J_geared) / r_p^2      kg

with viscous friction c_rack (N s/m) on the rack; its travel ends at two end stops at +-travel (m) of
the given contact stiffness (N/m) and damping (N s/m) (rtsim.vehicle.kit.end_stop). The force law on
the rack coordinate (`rack_force`), for both systems:

    F = F_pinion + (-c_rack x' + F_dry) + F_stop(x, x')      N

F_pinion: the pinion's torque over r_p (N), after whatever efficiency the system applies; F_dry: the
system's own dry friction on the rack (N, 0 without one).
"""
from __future__ import annotations

import numpy as np

from rtsim.jit import inline_kernel

from .end_stop import end_stop
from .layout import offsets

(RK_RP,              # m/rad, rack travel per pinion radian
 RK_MASS,            # kg, rack side: rack + (J_pinion + J_geared) / r_p^2
 RK_DAMPING,         # N s/m, rack viscous friction
 RK_TRAVEL,          # m, rack travel from centre to either end stop
 RK_STOP_K,          # N/m, end-stop stiffness
 RK_STOP_C,          # N s/m, end-stop damping
 RK_SIZE) = offsets(*(1,) * 6)


def rack_and_pinion(out: np.ndarray, at: int, *, travel_per_rad: float, rack_mass: float, pinion_inertia: float,
                    damping: float, travel: float, stop_stiffness: float, stop_damping: float,
                    geared_inertia: float = 0.0) -> None:
    """Pack the rack and pinion into out[at:at + RK_SIZE] (units as in the module docstring; geared_inertia:
    N^2 J of what the pinion drives through a gear, kg m^2)."""
    rp = travel_per_rad
    out[at + RK_RP] = rp
    out[at + RK_MASS] = rack_mass + (pinion_inertia + geared_inertia) / (rp * rp)
    out[at + RK_DAMPING] = damping
    out[at + RK_TRAVEL] = travel
    out[at + RK_STOP_K] = stop_stiffness
    out[at + RK_STOP_C] = stop_damping


@inline_kernel
def rack_stops(p, at, x, xd):
    """The end stops of the rack and pinion packed at p[at:], at travel x (m) and rate xd (m/s):
    (force N, stiffness N/m, damping N s/m), zeros between the stops."""
    return end_stop(x, xd, p[at + RK_TRAVEL], p[at + RK_STOP_K], p[at + RK_STOP_C])


@inline_kernel
def rack_force(p, at, x, xd, f_pinion, f_dry):
    """The force on the rack coordinate (module docstring) of the rack and pinion packed at p[at:], at
    travel x (m) and rate xd (m/s). Returns (F, friction, F_stop, k_stop, c_stop): the total (N), its
    friction part -c_rack x' + F_dry (N), the end stops' force (N) and their stiffness (N/m) and damping
    (N s/m) for the tangent (zero off the stops)."""
    f_friction = -p[at + RK_DAMPING] * xd + f_dry
    f_stop, k_stop, c_stop = rack_stops(p, at, x, xd)
    return f_pinion + f_friction + f_stop, f_friction, f_stop, k_stop, c_stop
