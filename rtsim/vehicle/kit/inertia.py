"""A rigid body's inertia tensor checked as physics (the vehicle files' mass properties): its principal
moments are positive (non-negative for a point mass) and each at most the sum of the other two (the
triangle inequality: I1 = integral of (y^2 + z^2) dm <= I2 + I3 = integral of (x^2 + 2 y^2 + z^2) dm ...).
The files give bodies symmetric about their x-z plane: Ixx, Iyy, Izz and the product ixz = integral of
x z dm (the tensor's xz entry is -ixz)."""
from __future__ import annotations

import math


def principal_moments(ixx: float, iyy: float, izz: float, ixz: float) -> tuple[float, float, float]:
    """The principal moments (kg m^2) of the tensor [[ixx, 0, -ixz], [0, iyy, 0], [-ixz, 0, izz]] (a body
    symmetric about its x-z plane): iyy and the eigenvalues of the x-z block."""
    mean, half = 0.5 * (ixx + izz), math.hypot(0.5 * (ixx - izz), ixz)
    return mean + half, iyy, mean - half


def inertia_problem(inertia: tuple[float, float, float], ixz: float, strict: bool) -> tuple[str, str] | None:
    """(key, why) if an inertia tensor (Ixx, Iyy, Izz and the product ixz, kg m^2) is not a rigid body's,
    else None; the key is "ixz_kgm2" when the moments alone would do. A body's principal moments are
    positive (strict) or non-negative (a point mass: zero) and obey the triangle inequalities (each at most
    the sum of the other two: I1 = integral of y^2 + z^2 dm, ...)."""
    p = principal_moments(*inertia, ixz)
    tol = 1e-9 * max(1e-12, sum(p))
    if min(p) < (tol if strict else -tol):
        why = (f"principal moments {p[0]:.6g}, {p[1]:.6g}, {p[2]:.6g} kg m^2: a rigid body's are "
               f"{'positive' if strict else 'non-negative'} (need Ixx, Iyy, Izz > 0 and ixz^2 < Ixx Izz)")
    elif p[0] + p[1] < p[2] - tol or p[1] + p[2] < p[0] - tol or p[2] + p[0] < p[1] - tol:
        why = (f"principal moments {p[0]:.6g}, {p[1]:.6g}, {p[2]:.6g} kg m^2 violate the triangle inequality "
               "(each at most the sum of the other two)")
    else:
        return None
    return ("ixz_kgm2" if ixz and inertia_problem(inertia, 0.0, strict) is None else "inertia_kgm2"), why
