"""A travel end stop: the force a linkage's hard stop puts on a coordinate driven past its travel (the
steering rack's end stops, a suspension's rebound and bump stops).

Past the travel limit x_max (|x| > x_max, penetration p = |x| - x_max, m or rad) the stop pushes back with

    F = -sign(x) max(0, k p + c min(p / P_RAMP, 1) dp/dt)

k: the stop's contact stiffness (N/m), c: its damping (N s/m). The damping fades in over the first
P_RAMP of penetration, so the force is continuous at contact (no impulse from the damper at the
instant of impact) and the stop never pulls (the max with 0). Inside the travel it is exactly zero:
the model is unchanged wherever the linkage stays within its travel.

Tangent (for the implicit step): dF/dx = -k and dF/d(dx/dt) = -c min(p / P_RAMP, 1) while in contact;
the damper's fade-in term (c/P_RAMP dp/dt) is left out (an under-estimated tangent there only
affects the first few tenths of a millimetre of a contact, where Newton's step control takes over).
"""
from __future__ import annotations

from rtsim.jit import inline_kernel

P_RAMP = 5.0e-4      # m (or rad): penetration over which the stop's damping fades in


@inline_kernel
def end_stop(x, xd, travel, k, c):
    """(F, K, C): the force of two stops at +-travel on x (N, or N m), its stiffness -dF/dx and damping
    -dF/dxd for the tangent (0, 0, 0 within the travel)."""
    return travel_stops(x, xd, -travel, travel, k, c)


@inline_kernel
def travel_stops(x, xd, lo, hi, k, c):
    """(F, K, C) of two stops at lo < hi (end_stop with the limits apart)."""
    if x > hi:
        p = x - hi
        pd = xd
        sgn = 1.0
    elif x < lo:
        p = lo - x
        pd = -xd
        sgn = -1.0
    else:
        return 0.0, 0.0, 0.0
    ramp = p / P_RAMP
    if ramp > 1.0:
        ramp = 1.0
    f = k * p + c * ramp * pd
    if f <= 0.0:
        return 0.0, 0.0, 0.0
    return -sgn * f, k, c * ramp
