"""The seed paper's "basic linearized" tyre: linear in the slips, saturated on the friction ellipse.

    Fx = Cx kappa,    Fy = -C_alpha alpha,    then scaled by 1/n when
    n = sqrt((Fx/(mu_x mu Fz))^2 + (Fy/(mu_y mu Fz))^2) > 1          (a circle when mu_x = mu_y)

Signs are ISO (as in `magic_formula`): positive kappa drives (Fx > 0); a positive slip angle (contact
point sliding to the left of the heading) gives Fy < 0. Cx = Kxk(FNOMIN), C_alpha = -Kya(FNOMIN) > 0,
mu_x = PDX1 LMUX, mu_y = |PDY1| LMUY come from the same .tir (packed at load time in the P_LIN_* slots
of the parameter array), so that this model and the Magic Formula agree in the linear range at
Fz = FNOMIN. The stiffnesses do not vary with load (the "basic" model); camber is ignored.
Mz = -t0 Fy (t0: MF pneumatic trail at zero slip and FNOMIN), My as in the MF (QSY1..QSY4), both with
the same low-speed factors as `mf52_forces`, so the two kernels are interchangeable, including with
the transient-slip states of `magic_formula`.
"""
from __future__ import annotations

from math import sqrt

from rtsim.jit import kernel

from .low_speed import low_speed_fade
from .magic_formula import _rolling_moment
from .tir import P_LIN_CALPHA, P_LIN_CX, P_LIN_MUX, P_LIN_MUY, P_LIN_TRAIL, P_VXLOW


@kernel
def linear_forces(p, fz, kappa, alpha, gamma, vx, mu):
    """(Fx, Fy, Mz, My) of the linearised tyre; same arguments as `mf52_forces` (gamma unused)."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    if mu < 0.0:
        mu = 0.0
    fx = p[P_LIN_CX] * kappa
    fy = -p[P_LIN_CALPHA] * alpha
    fmx = p[P_LIN_MUX] * mu * fz
    fmy = p[P_LIN_MUY] * mu * fz
    if fmx <= 0.0 or fmy <= 0.0:
        fx = 0.0
        fy = 0.0
    else:
        n2 = (fx / fmx) ** 2 + (fy / fmy) ** 2
        if n2 > 1.0:
            n = sqrt(n2)
            fx /= n
            fy /= n
    _, s_low = low_speed_fade(vx, p[P_VXLOW])
    mz = -s_low * p[P_LIN_TRAIL] * fy
    my = _rolling_moment(p, fz, fx, vx, s_low)
    return fx, fy, mz, my
