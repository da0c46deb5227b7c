"""Suspension kinematics from hardpoints: double wishbone (steered, tie rod to the rack), MacPherson strut
(unsteered, toe link to the body) and vertical slider (the wheel slides along the body's vertical axis;
steered about a vertical kingpin through a steering arm and a tie rod to the rack, or unsteered).

At build time the real linkage is solved for the knuckle pose over a grid of wheel travel z (m, wheel
centre rise relative to the body, positive in bump) and, for the steered front, rack displacement s
(m, positive steers left; see rack_direction). The results -- wheel-centre position, spin
axis, the knuckle's rotation rates with z and s, and the spring/damper length -- are fitted with
smooth polynomials in (z, s) whose first and second derivatives the multibody constraint needs. The
vehicle's corner then moves exactly along its linkage path (to the fit accuracy, reported), so camber,
toe, track and steer angles change with travel and rack as the hardpoints dictate.

Frames: the body (chassis) frame of the vehicle model, ISO 8855 (x forward, y left, z up); all points
in metres in that frame. Every knuckle point X moves as X = W0 + t + R (X0 - W0).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from rtsim.errors import ModelError

# Outputs fitted per corner, each a 3-vector except the spring length.
OUT_CENTRE = 0       # wheel centre W(z, s) in the body frame
OUT_AXIS = 1         # spin axis unit vector a(z, s) (points to the vehicle's left on every wheel)
OUT_ROT_Z = 2        # knuckle rotation per unit z: omega = OUT_ROT_Z * zdot + OUT_ROT_S * sdot (rad/m)
OUT_ROT_S = 3
N_VEC_OUT = 4


@dataclass(frozen=True)
class DoubleWishbone:
    lower_front: np.ndarray   # lower arm inner pivots (body)
    lower_rear: np.ndarray
    upper_front: np.ndarray   # upper arm inner pivots (body)
    upper_rear: np.ndarray
    lower_ball: np.ndarray    # lower ball joint (knuckle)
    upper_ball: np.ndarray    # upper ball joint (knuckle)
    tie_outer: np.ndarray     # tie rod outer end (knuckle)
    tie_inner: np.ndarray     # tie rod inner end on the rack at s = 0 (moves with the rack, see rack_direction)
    spring_lower: np.ndarray  # spring/damper lower mount, on the lower arm
    spring_upper: np.ndarray  # spring/damper upper mount (body)
    wheel_centre: np.ndarray
    spin_axis: np.ndarray


@dataclass(frozen=True)
class MacPherson:
    lower_front: np.ndarray   # lower arm inner pivots (body)
    lower_rear: np.ndarray
    lower_ball: np.ndarray    # lower ball joint (knuckle)
    strut_top: np.ndarray     # strut top mount (body)
    strut_lower: np.ndarray   # a point on the strut axis fixed to the knuckle
    toe_outer: np.ndarray     # toe link outer end (knuckle)
    toe_inner: np.ndarray     # toe link inner end (body)
    wheel_centre: np.ndarray
    spin_axis: np.ndarray


@dataclass(frozen=True)
class VerticalSlider:
    """The knuckle slides along the body's z axis (wheel travel z is the slide); a steered one also
    turns about the vertical kingpin axis through `kingpin`, its steering arm's end `tie_outer` held by
    a tie rod from `tie_inner` on the rack (crank-rod kinematics). Unsteered: the tie points are None."""
    wheel_centre: np.ndarray
    spring_lower: np.ndarray  # spring/damper mount on the slider (moves with z)
    spring_upper: np.ndarray  # spring/damper mount on the body
    spin_axis: np.ndarray
    kingpin: np.ndarray | None = None     # a point of the vertical steering axis (knuckle)
    tie_outer: np.ndarray | None = None   # steering arm end (knuckle)
    tie_inner: np.ndarray | None = None   # tie rod inner end on the rack at s = 0


def is_steered(geom) -> bool:
    """A linkage with a tie rod to the rack."""
    return isinstance(geom, DoubleWishbone) or (isinstance(geom, VerticalSlider) and geom.tie_outer is not None)


@dataclass
class CornerKinematics:
    """Polynomial fits p(z, s) = sum_j c_j z^ez_j s^es_j of one corner's kinematic outputs."""
    exponents: np.ndarray     # (nterm, 2) int
    vec_coef: np.ndarray      # (N_VEC_OUT, 3, nterm)
    spring_coef: np.ndarray   # (nterm,) spring/damper length, m
    z_range: tuple[float, float]
    s_range: tuple[float, float]
    fit_error: float          # max |fit - linkage| over the grid, m (or rad for the axis)
    steered: bool

    def evaluate(self, out: int, z: float, s: float = 0.0) -> np.ndarray:
        return self.vec_coef[out] @ (z ** self.exponents[:, 0] * s ** self.exponents[:, 1])

    def spring_length(self, z: float, s: float = 0.0) -> float:
        return float(self.spring_coef @ (z ** self.exponents[:, 0] * s ** self.exponents[:, 1]))


def _pose_points(x: np.ndarray, pts: np.ndarray, w0: np.ndarray) -> np.ndarray:
    rot = Rotation.from_rotvec(x[:3]).as_matrix()
    return w0 + x[3:] + (pts - w0) @ rot.T


def rack_direction(g: DoubleWishbone | VerticalSlider) -> np.ndarray:
    """Unit rack motion for positive s: steering arms ahead of the axle pull the rack to the left
    (+y) to steer left, arms behind push it to the right (-y)."""
    return np.array([0.0, 1.0 if g.tie_outer[0] > g.wheel_centre[0] else -1.0, 0.0])


def _solve_double_wishbone(g: DoubleWishbone, z: float, s: float, x0: np.ndarray) -> np.ndarray:
    pts = np.array([g.lower_ball, g.upper_ball, g.tie_outer, g.wheel_centre])
    w0 = g.wheel_centre
    d_lf, d_lr = np.linalg.norm(g.lower_ball - g.lower_front), np.linalg.norm(g.lower_ball - g.lower_rear)
    d_uf, d_ur = np.linalg.norm(g.upper_ball - g.upper_front), np.linalg.norm(g.upper_ball - g.upper_rear)
    d_tie = np.linalg.norm(g.tie_outer - g.tie_inner)
    tie_inner = g.tie_inner + s * rack_direction(g)

    def res(x):
        lb, ub, to, wc = _pose_points(x, pts, w0)
        return [np.linalg.norm(lb - g.lower_front) - d_lf, np.linalg.norm(lb - g.lower_rear) - d_lr,
                np.linalg.norm(ub - g.upper_front) - d_uf, np.linalg.norm(ub - g.upper_rear) - d_ur,
                np.linalg.norm(to - tie_inner) - d_tie, wc[2] - w0[2] - z]
    sol = least_squares(res, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    if np.max(np.abs(sol.fun)) > 1e-10:
        raise ModelError(f"double wishbone cannot reach travel z = {z:.3f} m, rack s = {s:.3f} m "
                         f"(residual {np.max(np.abs(sol.fun)):.2e} m): check the hardpoints and travel range")
    return sol.x


def _solve_macpherson(g: MacPherson, z: float, x0: np.ndarray) -> np.ndarray:
    pts = np.array([g.lower_ball, g.strut_lower, g.toe_outer, g.wheel_centre])
    w0 = g.wheel_centre
    d_lf, d_lr = np.linalg.norm(g.lower_ball - g.lower_front), np.linalg.norm(g.lower_ball - g.lower_rear)
    d_toe = np.linalg.norm(g.toe_outer - g.toe_inner)
    axis0 = (g.strut_top - g.strut_lower) / np.linalg.norm(g.strut_top - g.strut_lower)
    # two directions normal to the strut axis at the design position, carried by the knuckle
    n1 = np.cross(axis0, [1.0, 0.0, 0.0])
    n1 /= np.linalg.norm(n1)
    n2 = np.cross(axis0, n1)

    def res(x):
        lb, sl, to, wc = _pose_points(x, pts, w0)
        rot = Rotation.from_rotvec(x[:3]).as_matrix()
        rel = g.strut_top - sl
        return [np.linalg.norm(lb - g.lower_front) - d_lf, np.linalg.norm(lb - g.lower_rear) - d_lr,
                rel @ (rot @ n1), rel @ (rot @ n2),
                np.linalg.norm(to - g.toe_inner) - d_toe, wc[2] - w0[2] - z]
    sol = least_squares(res, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    if np.max(np.abs(sol.fun)) > 1e-10:
        raise ModelError(f"MacPherson strut cannot reach travel z = {z:.3f} m "
                         f"(residual {np.max(np.abs(sol.fun)):.2e} m): check the hardpoints and travel range")
    return sol.x


def _solve_vertical_slider(g: VerticalSlider, z: float, s: float, x0: np.ndarray,
                           steer_angle: bool = False) -> np.ndarray:
    """Pose (rotation vector, translation) of the knuckle: slide z along the body z axis, and for a
    steered one the turn delta about the vertical kingpin that keeps the tie rod's length (s: rack
    travel), or the turn s itself (steer_angle: s is the knuckle's own steer coordinate, rad)."""
    if g.tie_outer is None:
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, z])
    if steer_angle:
        return _kingpin_pose(g, z, s)
    kp = g.kingpin
    arm = (g.tie_outer - kp)[:2]
    d_tie = np.linalg.norm(g.tie_outer - g.tie_inner)
    tie_inner = g.tie_inner + s * rack_direction(g)

    def outer(delta):
        c, sn = np.cos(delta), np.sin(delta)
        return np.array([kp[0] + c * arm[0] - sn * arm[1], kp[1] + sn * arm[0] + c * arm[1], g.tie_outer[2] + z])

    sol = least_squares(lambda x: [np.linalg.norm(outer(x[0]) - tie_inner) - d_tie], [x0[2]],
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    if abs(sol.fun[0]) > 1e-10:
        raise ModelError(f"vertical slider cannot reach rack s = {s:.3f} m (residual {abs(sol.fun[0]):.2e} m): "
                         "check the steering arm and tie rod hardpoints")
    return _kingpin_pose(g, z, float(sol.x[0]))


def _kingpin_pose(g: VerticalSlider, z: float, delta: float) -> np.ndarray:
    """The knuckle turned by delta (rad, positive left) about the vertical kingpin, slid by z."""
    kp = g.kingpin
    rot = Rotation.from_rotvec([0.0, 0.0, delta]).as_matrix()
    r = kp - g.wheel_centre
    t = r - rot @ r + np.array([0.0, 0.0, z])
    return np.array([0.0, 0.0, delta, *t])


def _spring_length_dw(g: DoubleWishbone, x: np.ndarray) -> float:
    """The spring's lower mount rides on the lower arm: rotate it about the arm's pivot axis by the
    arm's rotation, found from the lower ball joint's motion."""
    lb = _pose_points(x, g.lower_ball[None, :], g.wheel_centre)[0]
    axis = g.lower_rear - g.lower_front
    axis /= np.linalg.norm(axis)

    def radial(p):
        v = p - g.lower_front
        return v - (v @ axis) * axis
    r0, r1 = radial(g.lower_ball), radial(lb)
    ang = np.arctan2(np.cross(r0, r1) @ axis, r0 @ r1)
    rot = Rotation.from_rotvec(axis * ang).as_matrix()
    mount = g.lower_front + (g.spring_lower - g.lower_front) @ rot.T
    return float(np.linalg.norm(g.spring_upper - mount))


def _rotation_rates(poses: np.ndarray, step: float, axis: int) -> np.ndarray:
    """Angular velocity per unit coordinate from poses sampled along grid `axis` (central differences)."""
    rots = Rotation.from_rotvec(poses[..., :3].reshape(-1, 3)).as_matrix().reshape(poses.shape[:-1] + (3, 3))
    drot = np.gradient(rots, step, axis=axis, edge_order=2)
    omega_hat = np.einsum("...ij,...kj->...ik", drot, rots)   # dR/dz R^T, skew
    return np.stack([omega_hat[..., 2, 1], omega_hat[..., 0, 2], omega_hat[..., 1, 0]], axis=-1)


def _exponents(deg_z: int, deg_s: int) -> np.ndarray:
    return np.array([(i, j) for i in range(deg_z + 1) for j in range(deg_s + 1)], dtype=np.int64)


def _fit(zs: np.ndarray, ss: np.ndarray, values: np.ndarray, exps: np.ndarray) -> tuple[np.ndarray, float]:
    basis = (zs[:, None] ** exps[None, :, 0]) * (ss[:, None] ** exps[None, :, 1])
    coef, *_ = np.linalg.lstsq(basis, values, rcond=None)
    err = float(np.max(np.abs(basis @ coef - values)))
    return coef, err


def solve_corner(geom: DoubleWishbone | MacPherson | VerticalSlider, z_range=(-0.08, 0.08),
                 s_range=(-0.07, 0.07), nz: int = 33, ns: int = 29, deg_z: int = 5, deg_s: int = 7,
                 steer_angle: bool = False) -> CornerKinematics:
    """Solve the linkage over the travel (and rack) grid and fit the polynomials. steer_angle (a steered
    vertical slider only): the second variable is the knuckle's steer angle about its kingpin (rad,
    s_range in rad) instead of the rack travel; the tie rod then joins it to the rack as a constraint of
    the multibody model (crank_rod_constants)."""
    steered = is_steered(geom)
    if steer_angle and not (isinstance(geom, VerticalSlider) and steered):
        raise ModelError("a steer-angle corner needs a steered vertical slider (kingpin, tie rod)")
    zg = np.linspace(*z_range, nz)
    sg = np.linspace(*s_range, ns) if steered else np.zeros(1)
    poses = np.zeros((nz, sg.size, 6))
    spring = np.zeros((nz, sg.size))
    iz0 = int(np.argmin(np.abs(zg)))
    # continuation from the design position outwards keeps the solver on the assembled branch
    order_z = list(range(iz0, nz)) + list(range(iz0 - 1, -1, -1))
    is0 = int(np.argmin(np.abs(sg)))
    order_s = list(range(is0, sg.size)) + list(range(is0 - 1, -1, -1))
    for j in order_s:
        for i in order_z:
            if i == iz0:
                guess = poses[iz0, j - 1 if j > is0 else min(j + 1, sg.size - 1)] if j != is0 else np.zeros(6)
            else:
                guess = poses[i - 1 if i > iz0 else i + 1, j]
            if isinstance(geom, VerticalSlider):
                x = _solve_vertical_slider(geom, zg[i], sg[j], guess, steer_angle)
                spring[i, j] = float(np.linalg.norm(geom.spring_upper - geom.spring_lower - [0.0, 0.0, zg[i]]))
            elif steered:
                x = _solve_double_wishbone(geom, zg[i], sg[j], guess)
                spring[i, j] = _spring_length_dw(geom, x)
            else:
                x = _solve_macpherson(geom, zg[i], guess)
                sl = _pose_points(x, geom.strut_lower[None, :], geom.wheel_centre)[0]
                spring[i, j] = float(np.linalg.norm(geom.strut_top - sl))
            poses[i, j] = x
    w0 = geom.wheel_centre
    centre = w0 + poses[..., 3:]
    rots = Rotation.from_rotvec(poses[..., :3].reshape(-1, 3)).as_matrix().reshape(nz, sg.size, 3, 3)
    axis = np.einsum("...ij,j->...i", rots, geom.spin_axis / np.linalg.norm(geom.spin_axis))
    rot_z = _rotation_rates(poses, zg[1] - zg[0], 0)
    rot_s = _rotation_rates(poses, sg[1] - sg[0], 1) if steered else np.zeros_like(rot_z)
    exps = _exponents(deg_z, deg_s if steered else 0)
    zz, ssg = np.meshgrid(zg, sg, indexing="ij")
    zf, sf = zz.ravel(), ssg.ravel()
    vec = np.zeros((N_VEC_OUT, 3, exps.shape[0]))
    err = 0.0
    for out, data in ((OUT_CENTRE, centre), (OUT_AXIS, axis), (OUT_ROT_Z, rot_z), (OUT_ROT_S, rot_s)):
        for c in range(3):
            coef, e = _fit(zf, sf, data[..., c].ravel(), exps)
            vec[out, c] = coef
            if out in (OUT_CENTRE, OUT_AXIS):
                err = max(err, e)
    spring_coef, e = _fit(zf, sf, spring.ravel(), exps)
    err = max(err, e)
    return CornerKinematics(exps, vec, spring_coef, tuple(z_range), tuple(s_range) if steered else (0.0, 0.0),
                            err, steered)


def crank_rod_constants(g: VerticalSlider) -> dict:
    """The steering arm and tie rod of a steered vertical slider, in the body's horizontal plane, as
    rtsim.mbs MechanismBuilder.crank_rod takes them: kingpin (pivot), arm (tie_outer - kingpin), the
    rack end of the tie rod at zero travel, the rack's direction for positive (leftward) steer, and the
    tie rod's length in that plane (the arm and the rack end at one height: no bump steer)."""
    return dict(pivot=g.kingpin[:2], arm=(g.tie_outer - g.kingpin)[:2], rod_end=g.tie_inner[:2],
                direction=float(rack_direction(g)[1]),
                length=float(np.linalg.norm((g.tie_outer - g.tie_inner)[:2])))


def mirror(geom):
    """The right-hand corner from a left-hand one: y -> -y for every point; the mirrored spin axis is
    negated so that it still points to the vehicle's left."""
    flip = np.array([1.0, -1.0, 1.0])
    kw = {name: None if val is None else val * flip for name, val in geom.__dict__.items()}
    kw["spin_axis"] = -kw["spin_axis"]
    return type(geom)(**kw)
