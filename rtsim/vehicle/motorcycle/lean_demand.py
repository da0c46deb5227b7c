"""A two-wheeler's lean loop: the handlebar torque that makes it lean to a demanded roll angle.

What a person driving a motorcycle from a keyboard or a gamepad asks for (rtsim.service.user_input):
not a steering torque (nobody balances a motorcycle through a key) but a lean angle, which this loop
holds by counter-steering, as the rider's inner loop does (rtsim.vehicle.motorcycle.rider, with its gains):

    phi_r' = clip((phi_d - phi_r) / h, +-max_roll_rate),  |phi_r| <= max_roll
    tau = p_roll (phi_r - phi) - d_roll phi' + I - d_steer delta',   I' = i_roll (phi_r - phi), |I| <= i_roll_max
    |tau| <= max_torque

Signs as rtsim.vehicle.motorcycle.rider: roll positive leaning right, torque positive steering left (to lean right a
rider first steers left). The reference starts at the measured roll when the loop is switched on, so
taking over a leaning motorcycle does not jerk the bars.
"""
from __future__ import annotations

from rtsim.jit import kernel

from .rider import RiderPar, RV_DELTADOT, RV_PHI, RV_PHIDOT

W_ON, W_REF, W_INT = 0, 1, 2     # the loop's state: switched on (1.0), reference (rad), integral (N m)
NW = 3


@kernel
def lean_torque(par, view, demand, w, h):
    """Handlebar torque (N m) for the lean ``demand`` (rad) over the next step of ``h`` s; ``par`` the
    rider's parameters, ``view`` the rider's view (drivers.rider RV_*), ``w`` the loop's state (W_*)."""
    phi = view[RV_PHI]
    if w[W_ON] < 0.5:
        w[W_ON] = 1.0
        w[W_REF] = phi
        w[W_INT] = 0.0
    step = par[RiderPar.MAX_ROLL_RATE] * h
    dref = demand - w[W_REF]
    if dref > step:
        dref = step
    elif dref < -step:
        dref = -step
    ref = w[W_REF] + dref
    lim = par[RiderPar.MAX_ROLL]
    ref = min(max(ref, -lim), lim)
    w[W_REF] = ref
    e = ref - phi
    imax = par[RiderPar.I_ROLL_MAX]
    w[W_INT] = min(max(w[W_INT] + par[RiderPar.I_ROLL] * e * h, -imax), imax)
    tau = (par[RiderPar.P_ROLL] * e - par[RiderPar.D_ROLL] * view[RV_PHIDOT] + w[W_INT]
           - par[RiderPar.D_STEER] * view[RV_DELTADOT])
    tmax = par[RiderPar.MAX_TORQUE]
    return min(max(tau, -tmax), tmax)
