"""The IFToMM / A Coruna multibody benchmark problems (A01-A05), declared with the builder.

Each problem gives its mechanism, the step a real-time user would choose, the end time, and the
compared quantities read from the coordinates. Problem data follow the benchmark library's problem
statements; the references they are checked against live in tests/references.py.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from rtsim.mbs import Mechanism, MechanismBuilder

G = 9.81


@dataclass(frozen=True)
class Problem:
    name: str
    title: str
    build: Callable[[], Mechanism]
    dt: float                     # default step, s (what a real-time user would pick for 1e-3 accuracy)
    t_end: float                  # s
    compared: Callable[[Mechanism, np.ndarray], dict[str, float]]


# ---- A01 simple pendulum -------------------------------------------------------------------------
def pendulum() -> Mechanism:
    """Point mass 1 kg on a massless 1 m link pivoted at the origin, released from rest horizontal."""
    b = MechanismBuilder(dim=2, name="pendulum")
    o = b.fixed_point((0.0, 0.0), "O")
    p1 = b.point("P1", (1.0, 0.0), velocity=(0.0, None))
    b.point_mass(p1, 1.0)
    b.distance(o, p1)
    b.gravity((0.0, -G))
    return b.compile()


def _xy(name_x: str, name_y: str, point: str):
    def read(mech: Mechanism, q: np.ndarray) -> dict[str, float]:
        return {name_x: float(q[mech.coordinate(point + ".x")]), name_y: float(q[mech.coordinate(point + ".y")])}
    return read


# ---- A02 N-four-bar ------------------------------------------------------------------------------
def fourbar(n: int) -> Mechanism:
    """N+1 cranks (1 m, 1 kg uniform rods) pivoted at (i, 0), tips B_i joined by N couplers (1 m,
    1 kg); cranks start vertical, B0 moves at +1 m/s in x; gravity -y. Passes through singular
    (all-horizontal) positions twice per revolution."""
    b = MechanismBuilder(dim=2, name=f"fourbar{n}" if n != 1 else "fourbar")
    tips = []
    for i in range(n + 1):
        a = b.fixed_point((float(i), 0.0), f"A{i}")
        tip = b.point(f"B{i}", (float(i), 1.0), velocity=(1.0, None) if i == 0 else None)
        b.rod(f"crank{i}", a, tip, 1.0)
        tips.append(tip)
    for i in range(n):
        b.rod(f"coupler{i}", tips[i], tips[i + 1], 1.0)
    b.gravity((0.0, -G))
    return b.compile()


# ---- A03 Andrews' squeezer -------------------------------------------------------------------------
ANDREWS = dict(
    m1=0.04325, m2=0.00365, m3=0.02373, m4=0.00706, m5=0.07050, m6=0.00706, m7=0.05498,
    i1=2.194e-6, i2=4.410e-7, i3=5.255e-6, i4=5.667e-7, i5=1.169e-5, i6=5.667e-7, i7=1.912e-5,
    xa=-0.06934, ya=-0.00227, xb=-0.03635, yb=0.03273, xc=0.014, yc=0.072,
    d=0.028, da=0.0115, e=0.02, ea=0.01421, rr=0.007, ra=0.00092, l0=0.07785, ss=0.035,
    sa=0.01874, sb=0.01043, sc=0.018, sd=0.02, ta=0.02308, tb=0.00916, u=0.04, ua=0.01228,
    ub=0.00449, zf=0.02, zt=0.04, fa=0.01421, c0=4530.0, mom=0.033,
)
# Consistent initial angles (beta, Theta, gamma, Phi, delta, Omega, epsilon), rad, from the
# Hairer-Wanner test set; the mechanism starts at rest.
ANDREWS_Q0 = (-0.0617138900142764496358948458001, 0.0, 0.455279819163070380255912382449,
              0.222668390165885884674473185609, 0.487364979543842550225598953530,
              -0.222668390165885884674473185609, 1.23054744454982119249735015568)


def _rot(v, ang):
    c, s = np.cos(ang), np.sin(ang)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def andrews() -> Mechanism:
    """Andrews' squeezing mechanism: seven planar bodies, a driving torque of 0.033 N m on the crank
    and a stiff spring (4530 N/m); no gravity. Natural coordinates: points F, E, G, H, D and the
    crank angle beta (a mixed coordinate, so beta is measured cumulatively)."""
    p = ANDREWS
    be, th, ga, ph, de, om, ep = ANDREWS_Q0
    e_ = lambda a: np.array([np.cos(a), np.sin(a)])  # noqa: E731
    f_pos = p["rr"] * e_(be)
    e_pos = f_pos - p["d"] * e_(be + th)
    o_pos, a_pos = np.zeros(2), np.array([p["xa"], p["ya"]])
    b_pos, c_pos = np.array([p["xb"], p["yb"]]), np.array([p["xc"], p["yc"]])
    g_pos = a_pos + p["zt"] * e_(de)
    h_pos = a_pos + p["u"] * np.array([np.sin(ep), -np.cos(ep)])
    # body 3 frame: x along (cos gamma, sin gamma), y along (sin gamma, -cos gamma) rotated
    x3, y3 = e_(ga), np.array([np.sin(ga), -np.cos(ga)])
    d_pos = b_pos + p["sd"] * x3 + p["sc"] * y3

    b = MechanismBuilder(dim=2, name="andrews")
    O = b.fixed_point(o_pos, "O")
    A = b.fixed_point(a_pos, "A")
    B = b.fixed_point(b_pos, "B")
    C = b.fixed_point(c_pos, "C")
    F = b.point("F", f_pos, velocity=(0.0, 0.0))
    E = b.point("E", e_pos)
    Gp = b.point("G", g_pos)
    H = b.point("H", h_pos)
    D = b.point("D", d_pos)
    beta = b.angle("beta", be, velocity=0.0)
    b.angle2d(beta, F, O)

    def along(p0, p1, dist):
        return p0 + dist * (p1 - p0) / np.linalg.norm(p1 - p0)

    # body 1: crank O-F, centre of mass at ra from O
    b.body("K1", O, [(F, O)], p["m1"], along(o_pos, f_pos, p["ra"]), p["i1"])
    # body 2: rod F-E, centre of mass at da from F
    b.body("K2", F, [(E, F)], p["m2"], along(f_pos, e_pos, p["da"]), p["i2"])
    # body 3: rotates about B, carries E and the spring point D; centre of mass at (sa, sb)
    b.body("K3", B, [(E, B)], p["m3"], b_pos + p["sa"] * x3 + p["sb"] * y3, p["i3"])
    b.body_point("K3", B, [(E, B)], D)
    # body 4: G-E, centre of mass at (e - ea) from G ; body 5: rotates about A, carries G
    b.body("K4", Gp, [(E, Gp)], p["m4"], along(g_pos, e_pos, p["e"] - p["ea"]), p["i4"])
    u5 = (g_pos - a_pos) / p["zt"]
    b.body("K5", A, [(Gp, A)], p["m5"], a_pos + p["ta"] * u5 + p["tb"] * np.array([-u5[1], u5[0]]), p["i5"])
    # body 6: H-E, centre of mass at (zf - fa) from H ; body 7: rotates about A, carries H
    b.body("K6", H, [(E, H)], p["m6"], along(h_pos, e_pos, p["zf"] - p["fa"]), p["i6"])
    u7 = (h_pos - a_pos) / p["u"]
    b.body("K7", A, [(H, A)], p["m7"], a_pos + p["ua"] * u7 + p["ub"] * np.array([-u7[1], u7[0]]), p["i7"])
    b.spring(D, C, p["c0"], rest_length=p["l0"], name="spring C-D")
    b.coordinate_force(beta, constant=p["mom"], name="drive torque")
    return b.compile()


def _andrews_compared(mech: Mechanism, q: np.ndarray) -> dict[str, float]:
    return {"beta": float(q[mech.coordinate("beta")])}


# ---- A04 Bricard mechanism -----------------------------------------------------------------------
BRICARD_JOINTS = ((0, 0, 0), (1, 0, 0), (1, -1, 0), (1, -1, 1), (0, -1, 1), (0, 0, 1))
BRICARD_AXES = ((0, 1, 0), (0, 0, 1), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 0))


def bricard() -> Mechanism:
    """Bricard's mechanism: five uniform 1 m, 1 kg bars in a closed loop of six revolute joints
    (two of them on the ground); Gruebler's count gives zero mobility, yet it moves with one degree
    of freedom: one constraint is redundant. Released from rest, gravity -y. Natural coordinates:
    the four moving joint points and four moving joint axes."""
    b = MechanismBuilder(dim=3, name="bricard")
    pts, axes = [], []
    for j, (pos, ax) in enumerate(zip(BRICARD_JOINTS, BRICARD_AXES)):
        fixed = j in (0, 5)
        pts.append(b.fixed_point(pos, f"P{j + 1}") if fixed else b.point(f"P{j + 1}", pos, velocity=(0, 0, 0)))
        axes.append(b.fixed_point(ax, f"u{j + 1}") if fixed else b.unit_vector(f"u{j + 1}", ax, velocity=(0, 0, 0)))
    for i in range(5):
        pa, pb = np.array(BRICARD_JOINTS[i], float), np.array(BRICARD_JOINTS[i + 1], float)
        d = (pb - pa) / np.linalg.norm(pb - pa)
        it = 1.0 / 12.0                                    # transverse, about the centre, kg m^2
        inertia = it * (np.eye(3) - np.outer(d, d))        # slender bar: no axial inertia
        b.body(f"bar{i + 1}", pts[i], [(pts[i + 1], pts[i]), axes[i], axes[i + 1]], 1.0,
               0.5 * (pa + pb), inertia)
    b.gravity((0.0, -G, 0.0))
    return b.compile()


def _bricard_compared(mech: Mechanism, q: np.ndarray) -> dict[str, float]:
    return {f"{c}_P3": float(q[mech.coordinate(f"P3.{c}")]) for c in "xyz"}


# ---- A05 stiff flyball governor ------------------------------------------------------------------
FLYBALL = dict(m_shaft=0.3, m_slider=3.0, m_rod=0.3, m_ball=5.0, rod_length=1.0, rod_width=0.01,
               slider_side=0.1, shaft_length=1.0, shaft_width=0.01, k=8e5, c=4e4, l0=0.5,
               x_pivot=0.05, z_pivot=1.0, x_slider=0.05, s0=0.5, rod_angle0=np.radians(30.0),
               omega0=2 * np.pi)


def flyball() -> Mechanism:
    """Stiff flyball governor: a free vertical shaft spinning at 2 pi rad/s, two 1 m rods hinged at its
    top with 5 kg balls at their ends, and a 3 kg slider on the shaft tied to the rod mid-points by
    stiff spring-dampers (8e5 N/m, 4e4 N s/m, rest length 0.5 m); gravity -z. Natural coordinates:
    the shaft frame's unit vectors u, v (z is fixed), slider, pivot, ball, mid-rod and spring points."""
    p = FLYBALL
    w = p["omega0"]
    b = MechanismBuilder(dim=3, name="flyball")
    spin = lambda r: (-w * r[1], w * r[0], 0.0)  # noqa: E731  rigid rotation about z
    O = b.fixed_point((0, 0, 0), "O")
    z = b.fixed_point((0, 0, 1), "z")
    u = b.unit_vector("u", (1, 0, 0), velocity=spin((1, 0, 0)))
    v = b.unit_vector("v", (0, 1, 0), velocity=spin((0, 1, 0)))
    frame = [z, u, v]
    ls, ws = p["shaft_length"], p["shaft_width"]
    i_shaft = p["m_shaft"] * np.diag([(ls ** 2 + ws ** 2) / 12, (ls ** 2 + ws ** 2) / 12, 2 * ws ** 2 / 12])
    b.body("shaft", O, frame, p["m_shaft"], (0, 0, 0.5 * ls), i_shaft)
    s_pos = np.array([0.0, 0.0, p["s0"]])
    S = b.point("S", s_pos, velocity=(0, 0, 0))
    b.linear([(1.0, S, 0)], name="slider on axis x")
    b.linear([(1.0, S, 1)], name="slider on axis y")
    a = p["slider_side"]
    b.body("slider", S, frame, p["m_slider"], s_pos, p["m_slider"] * a * a / 6 * np.eye(3))
    lr, wr, al = p["rod_length"], p["rod_width"], p["rod_angle0"]
    for side, sign in (("1", 1.0), ("2", -1.0)):
        e_pos = s_pos + sign * p["x_slider"] * np.array([1.0, 0, 0])
        E = b.point(f"E{side}", e_pos, velocity=spin(e_pos))
        b.body_point("slider", S, frame, E)
        a_pos = np.array([sign * p["x_pivot"], 0.0, p["z_pivot"]])
        A = b.point(f"A{side}", a_pos, velocity=spin(a_pos))
        b.body_point("shaft", O, frame, A)
        b_pos = a_pos + lr * np.array([sign * np.cos(al), 0.0, -np.sin(al)])
        P = b.point(f"P{side}", b_pos, velocity=spin(b_pos))
        b.rod3d(f"rod{side}", A, P, p["m_rod"], p["m_rod"] * (lr ** 2 + wr ** 2) / 12)
        b.point_mass(P, p["m_ball"])
        b.dot((P, A), v, 0.0, name=f"hinge{side}: rod normal to v")
        m_pos = 0.5 * (a_pos + b_pos)
        Mid = b.point(f"M{side}", m_pos, velocity=spin(m_pos))
        for c in range(3):
            b.linear([(1.0, Mid, c), (-0.5, A, c), (-0.5, P, c)], name=f"rod{side}: mid-point {'xyz'[c]}")
        b.spring(Mid, E, p["k"], p["c"], rest_length=p["l0"], name=f"spring{side}")
    b.gravity((0.0, 0.0, -G))
    return b.compile()


def _flyball_compared(mech: Mechanism, q: np.ndarray) -> dict[str, float]:
    return {"s": float(q[mech.coordinate("S.z")])}


PROBLEMS: dict[str, Problem] = {
    "pendulum": Problem("pendulum", "A01 simple pendulum", pendulum, 1e-3, 10.0, _xy("x_P1", "y_P1", "P1")),
    "fourbar": Problem("fourbar", "A02 four-bar (N = 1)", lambda: fourbar(1), 1e-3, 20.0, _xy("x_B0", "y_B0", "B0")),
    "fourbar2": Problem("fourbar2", "A02 N-four-bar, N = 2", lambda: fourbar(2), 1e-3, 20.0, _xy("x_B0", "y_B0", "B0")),
    "fourbar40": Problem("fourbar40", "A02 N-four-bar, N = 40", lambda: fourbar(40), 1e-3, 20.0, _xy("x_B0", "y_B0", "B0")),
    "andrews": Problem("andrews", "A03 Andrews' squeezer", andrews, 1e-5, 0.03, _andrews_compared),
    "bricard": Problem("bricard", "A04 Bricard mechanism", bricard, 1e-3, 10.0, _bricard_compared),
    "flyball": Problem("flyball", "A05 stiff flyball governor", flyball, 1e-3, 10.0, _flyball_compared),
}
