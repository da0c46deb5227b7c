"""Building the two-wheeler's multibody model from its vehicle file.

Six bodies in mixed natural coordinates, eleven degrees of freedom (rtsim.vehicle.motorcycle.layout):
- rear frame (engine, tank and the rider rigidly attached): the swingarm pivot P and three unit vectors
  e1, v, h, h along the steering axis (6 dof);
- upper fork with the handlebars: the head point on the steering axis (fixed in the frame) and two unit
  vectors f_U, e_U normal to the axis; the steer angle delta measures e_U from v about h (1 dof);
- lower fork: the front wheel centre W_f, sliding along the axis with the compression zeta (1 dof); its
  axes are the upper fork's;
- swingarm: the rear wheel centre W_r = P + L s_U, s_U normal to v; the angle theta measures s_U from e1
  about v (1 dof); a massive swingarm has a third unit vector n_S for its inertia;
- the wheels: each the centre and axle of its carrier (a revolute joint shares a point and a vector)
  plus two in-plane unit vectors b, c; the spin angle phi measures b from the carrier (1 dof each).
Every body's mass matrix is constant in these coordinates, so the gyroscopic couplings of the spinning
wheels, the steer and the frame are exact, which the self-stability of a two-wheeler depends on.

Contact: with knife-edge tyres each wheel rolls without slip on the ground (rtsim.mbs rolling_disc: one
position row, two velocity rows); with tyre models the tyre forces of the vehicle kernel act instead.
A locked suspension fixes zeta and theta by linear rows.
"""
from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtsim.mbs import Mechanism, MechanismBuilder, Settings
from rtsim.mbs.model import EARTH_GRAVITY, IS_TANGENT_FORCES

from .config import Body, MotorcycleConfig
from .geometry import Design, design, pose
from .layout import NAMES, NK, POINTS, SCALARS, VECTORS, K_N_S

TwoWheeler = namedtuple("TwoWheeler", [
    "idx",        # (NK,) int: first coordinate of each named group (layout K_*), -1 if absent
])


@dataclass
class MotorcycleModel:
    config: MotorcycleConfig
    base: Path
    mech: Mechanism
    bike: TwoWheeler
    design: Design
    knife_edge: bool

    def coordinates(self, dof: np.ndarray) -> np.ndarray:
        """q for the degrees of freedom `dof` (layout D_*), starting from the model's initial q."""
        q = self.mech.q0.copy()
        for name, x in pose(self.design, np.asarray(dof, dtype=float)).items():
            k = self.bike.idx[NAMES.index(name)]
            if k >= 0:
                q[k:k + x.size] = x
        return q

    def group(self, q: np.ndarray, name: str) -> np.ndarray:
        k = self.bike.idx[NAMES.index(name)]
        return q[k:k + (1 if name in SCALARS else 3)]


def _tensor(b: Body) -> np.ndarray:
    ixx, iyy, izz = b.inertia_kgm2
    return np.array([[ixx, 0.0, -b.ixz_kgm2], [0.0, iyy, 0.0], [-b.ixz_kgm2, 0.0, izz]])


def combine(*bodies: Body) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass (kg), centre of mass (3,) and inertia tensor about it (3x3) of rigidly joined bodies."""
    bodies = [b for b in bodies if b is not None and b.mass_kg > 0]
    m = sum(b.mass_kg for b in bodies)
    if m == 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    cg = sum(b.mass_kg * np.array([b.cg_m[0], 0.0, b.cg_m[1]]) for b in bodies) / m
    inertia = np.zeros((3, 3))
    for b in bodies:
        r = np.array([b.cg_m[0], 0.0, b.cg_m[1]]) - cg
        inertia += _tensor(b) + b.mass_kg * (r @ r * np.eye(3) - np.outer(r, r))
    return m, cg, inertia


def build_motorcycle(cfg: MotorcycleConfig, base: Path, gravity=(0.0, 0.0, -EARTH_GRAVITY),
                     reuse: MotorcycleModel | None = None) -> MotorcycleModel:
    """The compiled two-wheeler; `gravity` (m/s^2, design frame): tilted for a road grade (rtsim.validate).
    ``reuse``: a model built before, whose symbolic analysis compile takes when the topology is the same
    (rtsim.mbs.builder); every value is computed here, so the model equals a fresh build's bit for bit."""
    des = design(cfg)
    p0 = pose(des, np.zeros(11))
    # the projections refactor at the converged q: reusing the Newton factor for them feeds energy into
    # fast-spinning bodies in natural coordinates (a wheel at 17 rad/s gained 0.3 %/s at 1 ms; correcting
    # the stale factor by defect iterations instead costs as much as the factorization it saves). With the
    # projections solved for the correction (rtsim.mbs.integrator.project) the knife-edge run of
    # tests/test_motorcycle.py still gained 0.2 J (the bar: 0.034 J) in its first steps, and reusing the
    # Newton factor only where it was made within 1e-8 of the converged q (1e-10 at 20 m/s) took Newton
    # from 1.02 to 1.8 iterations a step there (the projections' metric error enters the predictor).
    # Newton's error test is the plain one, with an absolute increment tolerance: relative to max|q| it
    # loosened as the wheels' spin angles grew (to 4e-5 rad after 24 s at 55 m/s) and the slip errors it
    # let through moved the top speed by +0.10 m/s off the fully converged solution (54.93 m/s, found
    # with tol_dq = 1e-14); the contraction-rate test (Settings.error_test) moved it by +2.4 m/s. The
    # extrapolating predictor starts Newton close enough that 1.02 iterations a step meet it at 20 m/s
    # (its first increment about 1e-10 rad), with steps closer to the fully converged ones than 2 did.
    b = MechanismBuilder(dim=3, name=cfg.id, settings=Settings(projection_factor=True, error_test=False, extrapolate=True,
                                                              absolute_tol_dq=True, tol_phi=2e-9))
    refs: dict = {}
    for name in NAMES:
        if name == "N_S" and cfg.swingarm.mass_kg == 0:
            continue
        if name in POINTS:
            refs[name] = b.point(name.lower(), p0[name])
        elif name in VECTORS:
            refs[name] = b.unit_vector(name.lower(), p0[name])
        else:
            refs[name] = (b.angle if name != "ZETA" else b.length)(name.lower(), float(p0[name][0]))
    P, e1, v, h, head = refs["P"], refs["E1"], refs["V"], refs["H_AX"], refs["HEAD"]
    f_u, e_u, w_f, w_r, s_u = refs["F_U"], refs["E_U"], refs["W_F"], refs["W_R"], refs["S_U"]
    b_f, c_f, b_r, c_r = refs["B_F"], refs["C_F"], refs["B_R"], refs["C_R"]
    # rear frame with the rider: the frame's three axes are rigid (six rows)
    m, cg, inertia = combine(cfg.rear_frame, cfg.rider)
    b.body("rear frame", P, [e1, v, h], m, cg, inertia)
    b.body_point("head", P, [e1, v, h], head)
    # upper fork: f_U, e_U orthonormal and normal to the steering axis; the steer angle
    _orthonormal(b, f_u, e_u, h, "upper fork")
    b.angle3d(refs["DELTA"], v, e_u, h, name="steer angle")
    _body(b, "upper fork", head, [f_u, e_u, h], cfg.upper_fork)
    # lower fork: the front wheel centre slides along the axis, offset ahead of it
    b.dot((w_f, head), f_u, des.fork_offset, name="fork offset")
    b.dot((w_f, head), e_u, 0.0, name="fork plane")
    b.dot((w_f, head), h, -des.fork_length - des.zeta0, scalar=refs["ZETA"], linear=1.0, name="fork travel")
    _body(b, "lower fork", w_f, [f_u, e_u, h], cfg.lower_fork)
    # swingarm
    b.dot(s_u, s_u, 1.0, name="swingarm: unit")
    b.dot(s_u, v, 0.0, name="swingarm: plane")
    for c in range(3):
        b.linear([(1.0, w_r, c), (-1.0, P, c), (-des.swingarm_length, s_u, c)], name=f"swingarm: axle {'xyz'[c]}")
    b.angle3d(refs["THETA"], e1, s_u, v, name="swingarm angle")
    if "N_S" in refs:
        n_s = refs["N_S"]
        b.dot(n_s, n_s, 1.0, name="swingarm: n unit")
        b.dot(n_s, s_u, 0.0, name="swingarm: n.s")
        b.dot(n_s, v, 0.0, name="swingarm: n.v")
        _body(b, "swingarm", P, [s_u, v, n_s], cfg.swingarm)
    # wheels: in-plane unit vectors normal to the carrier's axle; spin angles
    _orthonormal(b, b_f, c_f, e_u, "front wheel")
    b.angle3d(refs["PHI_F"], f_u, b_f, e_u, name="front wheel spin")
    _orthonormal(b, b_r, c_r, v, "rear wheel")
    b.angle3d(refs["PHI_R"], e1, b_r, v, name="rear wheel spin")
    for name, centre, axle, bb, cc, wheel in (("front wheel", w_f, e_u, b_f, c_f, cfg.front_wheel),
                                               ("rear wheel", w_r, v, b_r, c_r, cfg.rear_wheel)):
        if wheel.mass_kg > 0:
            a0 = p0["E_U" if name == "front wheel" else "V"]
            tensor = wheel.diametral_inertia_kgm2 * (np.eye(3) - np.outer(a0, a0)) + wheel.spin_inertia_kgm2 * np.outer(a0, a0)
            b.body(name, centre, [bb, axle, cc], wheel.mass_kg, p0["W_F" if name == "front wheel" else "W_R"],
                   tensor, rigid=False)
    if cfg.suspension.locked:
        b.linear([(1.0, refs["ZETA"], 0)], const=-des.zeta0, name="fork locked")
        b.linear([(1.0, refs["THETA"], 0)], const=-des.theta0, name="swingarm locked")
    knife = cfg.tyres.model == "knife_edge"
    if knife:
        b.rolling_disc(w_r, v, b_r, c_r, cfg.rear_wheel.radius_m, name="rear wheel")
        b.rolling_disc(w_f, e_u, b_f, c_f, cfg.front_wheel.radius_m, name="front wheel")
    b.gravity(tuple(float(g) for g in gravity))
    # the rear brake acts on the wheel's spin relative to the swingarm: its damping couples the two
    b.couple(refs["PHI_R"], refs["THETA"])
    mech = b.compile(reuse=None if reuse is None else reuse.mech)
    # the step's own forces (rtsim.vehicle.motorcycle.step) add stiffness and damping: the finishing stage
    # rebuilds W = M before they add theirs for the projections (otherwise they would be added twice)
    mech.model.iset[IS_TANGENT_FORCES] = 1
    idx = -np.ones(NK, dtype=np.int64)
    for k, name in enumerate(NAMES):
        if name in refs:
            r = refs[name]
            idx[k] = r.index if name in SCALARS else r.idx[0]
    assert idx[K_N_S] >= 0 or cfg.swingarm.mass_kg == 0
    return MotorcycleModel(cfg, base, mech, TwoWheeler(idx=idx), des, knife)


def _orthonormal(b: MechanismBuilder, x, y, axis, name: str) -> None:
    """x, y unit, orthogonal to each other and to `axis` (five rows: a rotation about the axis)."""
    b.dot(x, x, 1.0, name=f"{name}: |x|")
    b.dot(y, y, 1.0, name=f"{name}: |y|")
    b.dot(x, y, 0.0, name=f"{name}: x.y")
    b.dot(x, axis, 0.0, name=f"{name}: x.axis")
    b.dot(y, axis, 0.0, name=f"{name}: y.axis")


def _body(b: MechanismBuilder, name: str, origin, directions, body: Body) -> None:
    if body.mass_kg > 0:
        b.body(name, origin, directions, body.mass_kg, np.array([body.cg_m[0], 0.0, body.cg_m[1]]),
               _tensor(body), rigid=False)


def straight_running_velocity(mm: MotorcycleModel, q: np.ndarray, speed: float) -> np.ndarray:
    """qd of the upright two-wheeler at q rolling straight ahead at `speed` (m/s) along its heading:
    every point moves with the frame, each wheel spins at speed / radius about its axle."""
    qd = np.zeros_like(q)
    fwd = np.cross(mm.group(q, "V"), np.array([0.0, 0.0, 1.0]))
    fwd /= np.linalg.norm(fwd)
    for name in POINTS:
        k = mm.bike.idx[NAMES.index(name)]
        qd[k:k + 3] = speed * fwd
    for axle, vecs, spin, wheel in (("E_U", ("B_F", "C_F"), "PHI_F", mm.config.front_wheel),
                                    ("V", ("B_R", "C_R"), "PHI_R", mm.config.rear_wheel)):
        omega = speed / wheel.radius_m * mm.group(q, axle)
        for name in vecs:
            k = mm.bike.idx[NAMES.index(name)]
            qd[k:k + 3] = np.cross(omega, q[k:k + 3])
        qd[mm.bike.idx[NAMES.index(spin)]] = speed / wheel.radius_m
    return qd
