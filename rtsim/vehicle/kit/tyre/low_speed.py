"""The tyre models' low-speed factors, one kernel each for every tyre model (rtsim.vehicle.kit.tyre:
magic_formula, linear, two_wheel).

- Fade: r = sin(pi/2 |Vx|/V_low) in [0, 1] and s = sin(pi/2 Vx/V_low) in [-1, 1], both saturated beyond
  V_low (m/s): smooth fade-ins of the force offsets and of the moments that change sign with the direction
  of travel (rolling resistance, aligning moment), so that they vanish at standstill.
- Contact damping: the damping time d (s) of the contact deflections, ``residual`` above V_low and
  ``residual + low 0.5 (1 + cos(pi |Vx|/V_low))`` below (keeps a slow or standing tyre from ringing).
"""
from __future__ import annotations

from math import cos, pi, sin

from rtsim.jit import inline_kernel


@inline_kernel
def low_speed_fade(vx, v_low):
    """(r, s) at forward speed vx (m/s) and blending speed v_low (m/s): r = sin(pi/2 |vx|/v_low) in
    [0, 1], s = sin(pi/2 vx/v_low) in [-1, 1], saturated beyond v_low."""
    x = vx / v_low
    if x >= 1.0:
        return 1.0, 1.0
    if x <= -1.0:
        return 1.0, -1.0
    s = sin(0.5 * pi * x)
    return abs(s), s


@inline_kernel
def low_speed_damping(residual, low, vxlow, vx):
    """Damping time d [s] of the contact deflections: ``residual`` + ``low`` 0.5 (1 + cos(pi |Vx|/vxlow))
    below ``vxlow`` [m/s] (the relaxation lengths' damping that keeps a slow or standing tyre from
    ringing), ``residual`` above."""
    avx = abs(vx)
    d = residual
    if avx < vxlow:
        d += low * 0.5 * (1.0 + cos(pi * avx / vxlow))
    return d
