"""Declare a mechanism in natural and mixed coordinates; compile it into a `Model`.

Coordinates are the Cartesian components of basic points and unit vectors (natural coordinates) plus
optional scalar relative angles and distances (mixed coordinates). Rigid bodies are declared by an
origin point and directions (a difference of two points, or a unit vector); the builder derives their
constant mass matrix, their gravity force and their rigid-body constraints. Joints are topology: two
bodies sharing a point form a spherical (3D) or revolute (2D) joint, sharing a point and a unit vector
forms a 3D revolute joint. Ground points and fixed directions are constants, not coordinates.

    b = MechanismBuilder(dim=2)
    o = b.fixed_point((0, 0))
    p = b.point("P1", (1, 0))
    b.point_mass(p, 1.0)
    b.distance(o, p)
    b.gravity((0, -9.81))
    mech = b.compile()
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from rtsim.errors import ModelError

from . import envelope, sparse
from .model import (
    CON_ANGLE2D, CON_ANGLE3D, CON_CRANK_ROD, CON_DISC_CONTACT, CON_DISC_ROLL, CON_DOT, CON_LINEAR, CON_POLY_POINT, SCALAR2, DRV_EXTERNAL, DRV_POLY, DRV_SINE, FRC_COORD,
    FRC_SPRING, FS_REUSE_RATE, FS_TOL_ACC, FS_TOL_ACC_FAIL, FS_TOL_DQ, FS_TOL_PHI, FS_TOL_VEL,
    FS_TOL_VEL_FAIL, FS_STALL_RATE, FS_MIN_STEP, FS_GRAVITY, NFSET, IS_ERROR_TEST, IS_MAX_ITER, IS_PREDICTOR, IS_ABSOLUTE_DQ, IS_FINISH_FORCES, NISET, IS_MAX_PROJ, IS_PROJECTION_FACTOR, IS_REUSE_STEPS, IS_TANGENT_FORCES, NSLOT, SCALAR, Model,
)


def _structural_slots(kind: int, idx: np.ndarray, par) -> np.ndarray:
    """Slots of a row whose Jacobian entry can be nonzero: those with a coordinate, and for a poly
    point only the row's own component of each vector reference plus its scalars."""
    slots = np.nonzero(idx >= 0)[0]
    if kind == CON_DISC_CONTACT:
        return np.array([k for k in slots if k in (2, 5)], dtype=np.int64)
    if kind == CON_DISC_ROLL:
        comp = int(par[1])
        return np.array([k for k in slots if k in (comp, 6 + comp, 9 + comp)], dtype=np.int64)
    if kind == CON_POLY_POINT:
        comp = int(par[1])
        keep = {3 * r + comp for r in range(5)} | {SCALAR, SCALAR2}
        slots = np.array([k for k in slots if k in keep], dtype=np.int64)
    return slots


#: _row_structure's results by (kind, slot indices, par[1]): the rows of the models a worker builds repeat
_ROWS: dict = {}


def _lower_pairs(used) -> np.ndarray:
    """(a, b) for a, b in the sorted coordinates ``used`` with b <= a, as an (n, 2) int64 array."""
    return np.array([(a, b) for a in used for b in used if b <= a], dtype=np.int64).reshape(-1, 2)


def _row_structure(kind: int, idx: np.ndarray, par) -> tuple[np.ndarray, np.ndarray]:
    """(the row's structural slots, the lower pairs of the coordinates they hold), kept per process
    (read only): functions of the row's kind, slot indices and component (par[1]) alone."""
    key = (int(kind), idx.tobytes(), float(par[1]))
    hit = _ROWS.get(key)
    if hit is None:
        act = _structural_slots(kind, idx, par)
        hit = (act, _lower_pairs(np.unique(idx[act])))
        if len(_ROWS) >= 4096:
            _ROWS.clear()
        _ROWS[key] = hit
    return hit


def _factor_layout(nq: int, pairs: np.ndarray, perm, pinv, first, ptr) -> dict:
    """The Cholesky factor's layout (rtsim.mbs.sparse) on the cheaper of minimum degree and the envelope's
    ordering, with the envelope slot of W for each of its positions."""
    fac = min((sparse.symbolic(nq, pairs, p) for p in (sparse.minimum_degree(nq, pairs), perm)),
              key=lambda f: f["macs"])
    w_map = -np.ones(fac["rowidx"].size, dtype=np.int64)
    for p in range(w_map.size):
        i, j = fac["perm"][fac["rowidx"][p]], fac["perm"][fac["pcol"][p]]
        r, c = max(pinv[i], pinv[j]), min(pinv[i], pinv[j])
        if c >= first[r]:
            w_map[p] = ptr[r] + c - first[r]
    fac["w_map"] = w_map
    return fac


_ASM_FIELDS = ("asm_row", "asm_s", "asm_u", "asm_pos", "asm_mult")


def _structure_digest(nq: int, pairs: np.ndarray, con_idx, con_act, con_nact) -> str:
    """SHA-256 of what the symbolic analysis (envelope, factor layout, assembly lists) is computed from."""
    import hashlib

    h = hashlib.sha256(np.int64(nq).tobytes())
    for a in (pairs, con_idx, con_act, con_nact):
        a = np.ascontiguousarray(a, dtype=np.int64)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _assembly(fac: dict, con_idx, con_act, con_nact) -> dict:
    """Each constraint row's contributions to the factor's pattern: pairs of active slots s <= u (a pair on
    one coordinate through two slots counts twice; off-diagonal pairs are stored once)."""
    where = {(int(r), int(c)): p for p, (r, c) in enumerate(zip(fac["rowidx"], fac["pcol"]))}
    out = {k: [] for k in _ASM_FIELDS}
    for i in range(con_idx.shape[0]):
        act = con_act[i, :con_nact[i]]
        for a in range(act.size):
            for b in range(a, act.size):
                s_, u = int(act[a]), int(act[b])
                js, ju = con_idx[i, s_], con_idx[i, u]
                r, c = fac["pinv"][js], fac["pinv"][ju]
                out["asm_row"].append(i)
                out["asm_s"].append(s_)
                out["asm_u"].append(u)
                out["asm_pos"].append(where[(int(max(r, c)), int(min(r, c)))])
                out["asm_mult"].append(2.0 if u != s_ and ju == js else 1.0)
    return {k: np.array(v, dtype=float if k == "asm_mult" else np.int64) for k, v in out.items()}


@dataclass(frozen=True)
class Ref:
    """A vector reference: component c is q[idx[c]] (if idx[c] >= 0) plus cst[c]."""
    name: str
    idx: tuple[int, int, int]
    cst: tuple[float, float, float]

    @property
    def is_fixed(self) -> bool:
        return all(i < 0 for i in self.idx)


@dataclass(frozen=True)
class Scalar:
    """A scalar coordinate (relative angle in rad or relative distance in m)."""
    name: str
    index: int


ZERO = Ref("zero", (-1, -1, -1), (0.0, 0.0, 0.0))
Direction = Ref | tuple[Ref, Ref]  # a unit-vector ref, or (head, tail) points: head - tail


@dataclass
class Settings:
    """Integrator settings. Tolerances are in coordinate units (m, rad) and their rates."""
    max_iter: int = 30                # Newton iterations per step before ConvergenceError
    max_proj_iter: int = 100          # CG iterations (Newton multipliers), multiplier iterations (projections)
    tol_dq: float = 1e-8              # Newton increment, relative to max(1, max|q|) (absolute: absolute_tol_dq)
    tol_phi: float = 1e-10            # max |Phi| for Newton to stop
    tol_vel: float = 1e-10            # target max |Phi_q qd + Phi_t| of the velocity projection
    tol_acc: float = 1e-8             # target max |Phi''| of the acceleration projection
    tol_vel_fail: float = 1e-6        # velocity projection fails above this (near singular positions
    #                                   the regularised projection may stop between target and this)
    tol_acc_fail: float = np.inf      # acceleration consistency is reported (stats), never fatal
    reuse_rate: float = 0.2           # refresh the Newton factor when |dq| shrinks by less than this
    penalty_ratio: float = 1e4        # p in alpha_i = p (4/dt^2) m_i / |Phi_q,i|^2
    reuse_across_steps: bool = False  # keep the factor into the next step (pays off for large dense models)
    error_test: bool = False          # Newton stops on the estimated error of the new iterate (contraction
    #                                   rate) and its constraints, not on the last increment and the
    #                                   constraints it started from (which costs an iteration that only
    #                                   confirms; the default keeps it for problems through singular positions)
    finish_forces: bool = True        # evaluate the forces again at the converged q for what reads them after
    #                                   the step; False keeps the last Newton evaluation's (made one increment,
    #                                   within tol_dq, before the converged q). A model whose projections
    #                                   refactor (projection_factor) always evaluates them: its W needs them
    projection_factor: bool = True    # refactor at the converged q for the projections (needed at
    #                                   singular positions; a model without them may save it)
    absolute_tol_dq: bool = False     # tol_dq in coordinate units, not relative to max(1, max|q|): where some
    #                                   coordinates grow without bound (distance travelled, wheel spin angles)
    #                                   the relative test loosens as they grow, while the increments that matter
    #                                   (a wheel's spin, hence its tyre's slip) need the same tolerance all along
    stall_rate: float = 0.8           # Newton step control: an increment that turns back on the last one and is
    #                                   >= stall_rate x its size (a cycle across a kink of the forces) halves
    #                                   the fraction of the increment applied next, down to min_step; any other
    #                                   iteration doubles it back (to 1). Convergence is always tested on
    #                                   the full increment, so the solution accepted is the same.
    min_step: float = 1.0 / 16.0
    extrapolate: bool = False         # Newton starts from the trapezoidal rule with the end-of-step qdd
    #                                   extrapolated from the last two steps (error O(h^4 d4q/dt4) instead of the
    #                                   Taylor predictor's O(h^3 d3q/dt3)) plus Newton's corrections of the last
    #                                   four steps extrapolated by a cubic (rtsim.mbs.integrator.step_begin):
    #                                   fewer iterations where bodies spin fast


@dataclass(frozen=True)
class BodyFrame:
    """A body's share of the mass matrix apart from its mass and inertia (MechanismBuilder._body_frame):
    x the basis of its directions and r0 its origin at the initial configuration (m), cg its centre of
    mass (m), maps the coordinate maps of its origin and each direction (read only)."""
    name: str
    dim: int
    x: np.ndarray
    r0: np.ndarray
    cg: np.ndarray
    maps: tuple


@dataclass(frozen=True)
class MassParts:
    """The mass matrix and gravity vector of a compile before its bodies were added (every point mass,
    scalar inertia and rod summed, read only), the gravity (m/s^2) and its bodies' frames in the order the
    compile added them: Mechanism.with_bodies adds the bodies again with other masses and inertias, the
    same sums in the same order, so its matrix equals a compile's with those values bit for bit."""
    mass: np.ndarray
    qg: np.ndarray
    g: np.ndarray
    bodies: tuple
    values: tuple       # each body's (mass in kg, inertia in kg m^2) in this mechanism


def _add_body(mass: np.ndarray, qg: np.ndarray, g: np.ndarray, frame: BodyFrame, m: float, inertia: np.ndarray) -> None:
    """Add a rigid body of mass `m` (kg) and `inertia` (kg m^2, about its centre of mass in global axes;
    2D: the polar moment) with `frame` to the mass matrix and gravity vector, in place."""
    dim, x, r0 = frame.dim, frame.x, frame.r0
    cbar = np.linalg.solve(x, frame.cg[:dim] - r0)
    rel = frame.cg[:dim] - r0
    if dim == 3:
        i_g = inertia.reshape(3, 3)
        j_g = 0.5 * np.trace(i_g) * np.eye(3) - i_g
    else:
        j_g = 0.5 * float(inertia.ravel()[0]) * np.eye(2)
    j0 = j_g + m * np.outer(rel, rel)
    xi = np.linalg.inv(x)
    jc = xi @ j0 @ xi.T
    mbar = np.zeros((dim + 1, dim + 1))
    mbar[0, 0] = m
    mbar[0, 1:] = mbar[1:, 0] = m * cbar
    mbar[1:, 1:] = jc
    maps = frame.maps
    for a in range(dim + 1):
        qg += mbar[0, a] * maps[a].T @ g
        for c in range(dim + 1):
            mass += mbar[a, c] * maps[a].T @ maps[c]


@dataclass
class Mechanism:
    """A compiled mechanism: the model arrays plus the names and initial guesses that go with them."""
    name: str
    model: Model
    q0: np.ndarray
    qd0: np.ndarray
    qd_given: np.ndarray          # bool mask: prescribed initial velocity components
    coordinate_names: list[str]
    constraint_names: list[str]
    force_names: list[str]
    mass_dense: np.ndarray
    settings: Settings
    conservative: bool
    structure: str = ""           # digest of the topology the symbolic analysis depends on (compile's reuse)
    mass_parts: MassParts | None = None   # the compile's sums before its bodies (with_bodies)

    def with_bodies(self, values: dict[str, tuple[float, np.ndarray]]) -> "Mechanism":
        """This mechanism with other masses (kg) and inertias (kg m^2, as MechanismBuilder.body takes them)
        of the named bodies: a new Mechanism whose mass matrix, its envelope and the gravity vector are new
        arrays, summed as a compile sums them (so equal to a compile's with those values bit for bit),
        every other array shared with this one (the model's arrays are read only)."""
        parts = self.mass_parts
        if parts is None:
            raise ModelError(f"{self.name}: compiled without its mass parts")
        unknown = set(values) - {f.name for f in parts.bodies}
        if unknown:
            raise ModelError(f"{self.name}: no body named {sorted(unknown)[0]!r}")
        mass, qg = parts.mass.copy(), parts.qg.copy()
        new = []
        for frame, kept in zip(parts.bodies, parts.values):
            m, inertia = values.get(frame.name, kept)
            m, inertia = float(m), np.atleast_2d(np.asarray(inertia, dtype=float))
            _add_body(mass, qg, parts.g, frame, m, inertia)
            new.append((m, inertia))
        mass = 0.5 * (mass + mass.T)
        md = self.model
        model = md._replace(q_grav=qg, m_env=envelope.to_envelope(mass, md.first, md.ptr, md.perm))
        return replace(self, model=model, mass_dense=mass, mass_parts=replace(parts, values=tuple(new)))

    def coordinate(self, name: str) -> int:
        try:
            return self.coordinate_names.index(name)
        except ValueError:
            raise ModelError(f"{self.name}: no coordinate named {name!r}") from None


@dataclass
class _Body:
    name: str
    origin: Ref
    directions: list[Direction]
    mass: float
    cg: np.ndarray
    inertia: np.ndarray


@dataclass
class MechanismBuilder:
    dim: int = 3
    name: str = "mechanism"
    settings: Settings = field(default_factory=Settings)

    def __post_init__(self):
        if self.dim not in (2, 3):
            raise ModelError(f"{self.name}: dim must be 2 or 3, got {self.dim}")
        self._names: list[str] = []
        self._q0: list[float] = []
        self._qd0: list[float] = []
        self._qd_given: list[bool] = []
        self._bodies: list[_Body] = []
        self._point_masses: list[tuple[Ref, float]] = []
        self._rods: list[tuple[Ref, Ref, float, float]] = []
        self._polys: list[np.ndarray] = []
        self._scalar_inertia: list[tuple[int, float]] = []
        self._coupled: list[list[int]] = []
        self._poly_exp = None
        self._cons: list[dict] = []
        self._con_keys: set = set()
        self._drivers: list[tuple[int, tuple[float, ...]]] = []
        self._forces: list[dict] = []
        self._gravity = np.zeros(3)
        self._conservative = True

    @property
    def constraint_count(self) -> int:
        """Constraint rows declared so far (a row's index in the compiled model is its order)."""
        return len(self._cons)

    # ---- coordinates ---------------------------------------------------------------------------
    def _coord(self, name: str, value: float, velocity: float | None) -> int:
        if name in self._names:
            raise ModelError(f"{self.name}: coordinate {name!r} declared twice")
        self._names.append(name)
        self._q0.append(float(value))
        self._qd0.append(0.0 if velocity is None else float(velocity))
        self._qd_given.append(velocity is not None)
        return len(self._names) - 1

    def _vec(self, value) -> np.ndarray:
        v = np.zeros(3)
        value = np.asarray(value, dtype=float).ravel()
        if value.size != self.dim:
            raise ModelError(f"{self.name}: expected {self.dim} components, got {value.size}")
        v[: self.dim] = value
        return v

    def point(self, name: str, position, velocity=None) -> Ref:
        """A moving basic point (m); `velocity` prescribes initial velocity components (m/s, None = free)."""
        p = self._vec(position)
        vel = [None] * self.dim if velocity is None else list(velocity)
        axes = "xyz"
        idx = [-1, -1, -1]
        for c in range(self.dim):
            idx[c] = self._coord(f"{name}.{axes[c]}", p[c], vel[c])
        return Ref(name, tuple(idx), (0.0, 0.0, 0.0))

    def unit_vector(self, name: str, direction, velocity=None) -> Ref:
        """A moving unit vector (normalised here); its |u| = 1 constraint comes with the body using it."""
        u = self._vec(direction)
        u = u / np.linalg.norm(u)
        return self.point(name, u[: self.dim], velocity)

    def fixed_point(self, position, name: str = "ground") -> Ref:
        return Ref(name, (-1, -1, -1), tuple(self._vec(position)))

    def angle(self, name: str, value: float, velocity: float | None = None) -> Scalar:
        """A relative angle coordinate (rad); tie it to the points with angle2d/angle3d."""
        return Scalar(name, self._coord(name, value, velocity))

    def length(self, name: str, value: float, velocity: float | None = None) -> Scalar:
        """A relative distance coordinate (m)."""
        return Scalar(name, self._coord(name, value, velocity))

    # ---- inertia ---------------------------------------------------------------------------------
    def point_mass(self, p: Ref, mass: float) -> None:
        self._point_masses.append((p, float(mass)))

    def scalar_inertia(self, s: Scalar, inertia: float) -> None:
        """Inertia (kg or kg m^2) on a scalar coordinate, e.g. a wheel's spin angle."""
        self._scalar_inertia.append((s.index, float(inertia)))

    def couple(self, *coords: Scalar | Ref) -> None:
        """Declare that forces added outside the builder (a vehicle's tyres) couple these coordinates
        in the tangent matrix, so its sparsity pattern has room for them."""
        idx = []
        for c in coords:
            idx.extend([c.index] if isinstance(c, Scalar) else [i for i in c.idx if i >= 0])
        self._coupled.append(sorted(set(idx)))

    def body(self, name: str, origin: Ref, directions: list[Direction], mass: float, cg,
             inertia, rigid: bool = True) -> None:
        """A rigid body: origin point plus directions (2D: one; 3D: three independent), all at their
        initial values; `cg` (m) in global coordinates and `inertia` (kg m^2) about the centre of mass
        in global axes (3D: 3x3 tensor; 2D: the polar moment I_zz) at that configuration.
        With rigid=True the constant-dot-product constraints between the directions are added."""
        need = 1 if self.dim == 2 else 3
        if len(directions) != need:
            raise ModelError(f"{self.name}: body {name!r} needs {need} directions in {self.dim}D")
        cg = self._vec(cg)
        inertia = np.atleast_2d(np.asarray(inertia, dtype=float))
        self._bodies.append(_Body(name, origin, list(directions), float(mass), cg, inertia))
        if rigid:
            for k in range(need):
                for l in range(k, need):
                    self.dot(directions[k], directions[l], name=f"{name}: rigid d{k + 1}.d{l + 1}")

    def rod(self, name: str, a: Ref, b: Ref, mass: float) -> None:
        """A slender uniform rod between points a and b (2D only: the planar bar)."""
        if self.dim != 2:
            raise ModelError(f"{self.name}: rod() is planar; use body() in 3D")
        pa, pb = self._value(a), self._value(b)
        length = np.linalg.norm(pb - pa)
        self.body(name, a, [(b, a)], mass, 0.5 * (pa + pb)[:2], mass * length ** 2 / 12.0)

    def rod3d(self, name: str, a: Ref, b: Ref, mass: float, transverse_inertia: float | None = None) -> None:
        """A rod between points a and b in 3D whose spin about its own axis carries no inertia (a slender
        bar): mass matrix m [[1/3, 1/6], [1/6, 1/3]] (x) I3 for a uniform rod, generalised to a transverse
        inertia about the centre of mass I_t (default m L^2 / 12), plus |a - b| = L."""
        if self.dim != 3:
            raise ModelError(f"{self.name}: rod3d() is for 3D mechanisms")
        pa, pb = self._value(a), self._value(b)
        length = float(np.linalg.norm(pb - pa))
        it = mass * length ** 2 / 12.0 if transverse_inertia is None else float(transverse_inertia)
        self._rods.append((a, b, float(mass), it / (mass * length ** 2)))
        self.distance(a, b, name=f"{name}: length")

    # ---- constraints -----------------------------------------------------------------------------
    def _value(self, r: Ref) -> np.ndarray:
        v = np.array(r.cst, dtype=float)
        for c in range(3):
            if r.idx[c] >= 0:
                v[c] += self._q0[r.idx[c]]
        return v

    def _dir_value(self, d: Direction) -> np.ndarray:
        if isinstance(d, tuple):
            return self._value(d[0]) - self._value(d[1])
        return self._value(d)

    @staticmethod
    def _dir_refs(d: Direction) -> tuple[Ref, Ref]:
        return d if isinstance(d, tuple) else (d, ZERO)

    def _add_con(self, kind, refs, scalar, par, name, drv=-1, key=None):
        if key is not None:
            if key in self._con_keys:
                return
            self._con_keys.add(key)
        self._cons.append(dict(kind=kind, refs=refs, scalar=scalar, par=par, name=name, drv=drv))

    def dot(self, a: Direction, b: Direction, value: float | None = None, name: str | None = None,
            scalar: Scalar | None = None, linear: float = 0.0, quadratic: float = 0.0) -> None:
        """(a).(b) = value + linear * s + quadratic * s^2 (value defaults to the initial one).
        Identical constraints declared twice (shared joints) are kept once."""
        ra, rb = self._dir_refs(a)
        rc, rd = self._dir_refs(b)
        if value is None:
            value = float(self._dir_value(a) @ self._dir_value(b))
            if scalar is not None:
                s = self._q0[scalar.index]
                value -= linear * s + quadratic * s * s
        if all(r.is_fixed for r in (ra, rb, rc, rd)) and scalar is None:
            return  # a relation between constants (two ground directions): nothing to constrain
        key = (CON_DOT, frozenset([(ra, rb), (rc, rd)]), None if scalar is None else scalar.index,
               round(value, 12), linear, quadratic)
        nm = name or f"dot({ra.name}-{rb.name}, {rc.name}-{rd.name})"
        self._add_con(CON_DOT, (ra, rb, rc, rd), scalar, (value, linear, quadratic, 0.0), nm, key=key)

    def distance(self, a: Ref, b: Ref, length: float | None = None, name: str | None = None) -> None:
        """|a - b| = length (m; default: the initial distance)."""
        value = None if length is None else length ** 2
        self.dot((a, b), (a, b), value, name=name or f"distance({a.name}, {b.name})")

    def distance_coordinate(self, a: Ref, b: Ref, s: Scalar, name: str | None = None) -> None:
        """|a - b| = s, with s a distance coordinate."""
        self.dot((a, b), (a, b), 0.0, scalar=s, quadratic=1.0, name=name or f"distance({a.name}, {b.name}) = {s.name}")

    def linear(self, terms: list[tuple[float, Ref | Scalar, int]], const: float = 0.0,
               name: str = "linear", driver: int = -1) -> None:
        """sum coeff * component + const = f(t): terms are (coeff, ref, component) or (coeff, scalar, 0)."""
        self._add_con(CON_LINEAR, terms, None, (const, 0.0, 0.0, 0.0), name, drv=driver)

    def angle2d(self, theta: Scalar, head: Ref, tail: Ref, name: str | None = None) -> None:
        """theta is the angle of (head - tail) from the x axis (planar, rad)."""
        if self.dim != 2:
            raise ModelError(f"{self.name}: angle2d() is planar")
        self._add_con(CON_ANGLE2D, (head, tail, ZERO, ZERO), theta, (0.0,) * 4,
                      name or f"angle({theta.name})")

    def angle3d(self, theta: Scalar, u: Ref, v: Ref, axis: Ref, name: str | None = None) -> None:
        """theta is the angle from u to v about `axis` (all unit vectors, u and v normal to axis)."""
        self._add_con(CON_ANGLE3D, (u, v, axis, ZERO), theta, (0.0,) * 4, name or f"angle({theta.name})")

    def rolling_disc(self, centre: Ref, axle: Ref, b: Ref, c: Ref, radius: float, height: float = 0.0,
                     name: str = "disc") -> None:
        """A knife-edge disc of `radius` (m) rolling without slip on the plane z = height: its lowest
        point on the plane (one position row) and zero material velocity there along x and y (two
        velocity rows). `axle` is the disc's unit axle, b and c its in-plane unit vectors."""
        if self.dim != 3:
            raise ModelError(f"{self.name}: rolling_disc() is for 3D mechanisms")
        self._add_con(CON_DISC_CONTACT, (centre, axle), None, (float(radius), float(height), 0.0, 0.0),
                      f"{name}: contact")
        for comp in (0, 1):
            self._add_con(CON_DISC_ROLL, (centre, axle, b, c), None, (float(radius), float(comp), 0.0, 0.0),
                          f"{name}: no slip {'xy'[comp]}")

    def body_point(self, name: str, origin: Ref, directions: list[Direction], p: Ref) -> None:
        """Tie point p rigidly to a body given by origin and directions (linear constraints)."""
        self._body_member(name, origin, directions, p, is_point=True)

    def body_vector(self, name: str, directions: list[Direction], u: Ref) -> None:
        """Tie unit vector u rigidly to a body given by its directions (linear constraints)."""
        self._body_member(name, ZERO, directions, u, is_point=False)

    def _body_member(self, name, origin, directions, p, is_point):
        x = self._basis_values(origin if is_point else ZERO, directions)
        rel = self._value(p) - (self._value(origin) if is_point else 0.0)
        coeff = np.linalg.solve(x, rel[: self.dim])
        for c in range(self.dim):
            terms = [(1.0, p, c)]
            if is_point:
                terms.append((-1.0, origin, c))
            for k, ck in enumerate(coeff):
                for sign, r, comp in self._basis_component(directions, k, c):
                    terms.append((-ck * sign, r, comp))
            self.linear(terms, 0.0, name=f"{name}: {p.name}.{'xyz'[c]}")

    def _basis_values(self, origin, directions) -> np.ndarray:
        cols = [self._dir_value(d)[: self.dim] for d in directions]
        if self.dim == 2:
            d1 = cols[0]
            cols.append(np.array([-d1[1], d1[0]]))
        x = np.column_stack(cols)
        if abs(np.linalg.det(x)) < 1e-12:
            raise ModelError(f"{self.name}: body directions are not independent")
        return x

    def _basis_component(self, directions, k, c):
        """Terms (sign, ref, comp) of component c of basis direction k (2D: k = 1 is R90 d1)."""
        if self.dim == 2 and k == 1:
            head, tail = self._dir_refs(directions[0])
            comp, sign = (1, -1.0) if c == 0 else (0, 1.0)   # (R d)_x = -d_y, (R d)_y = d_x
            return [(sign, head, comp), (-sign, tail, comp)]
        head, tail = self._dir_refs(directions[k])
        return [(1.0, head, c), (-1.0, tail, c)]

    def poly_point(self, p: Ref, origin: Ref, frame: tuple[Ref, Ref, Ref], path: np.ndarray,
                   exponents: np.ndarray, z: Scalar, s: Scalar | None = None, name: str = "poly_point") -> None:
        """p = origin + sum_k path_k(z, s) frame_k: a point moving in a body frame (unit vectors
        `frame`) along a polynomial path of one or two scalar coordinates; `path` is (3, nterm)
        coefficients over `exponents` (nterm, 2). Three constraint rows."""
        exponents = np.asarray(exponents, dtype=np.int64)
        na, nb = exponents[:, 0].max() + 1, exponents[:, 1].max() + 1
        grid = np.array([(a, b) for a in range(na) for b in range(nb)], dtype=np.int64)
        if exponents.shape != grid.shape or not np.array_equal(exponents, grid):
            raise ModelError(f"{self.name}: polynomial exponents must be the full grid a = 0..{na - 1}, "
                             f"b = 0..{nb - 1}, a-major")
        if self._poly_exp is None:
            self._poly_exp = exponents
        elif not np.array_equal(self._poly_exp, exponents):
            raise ModelError(f"{self.name}: all polynomial paths of a model share one exponent table")
        self._polys.append(np.asarray(path, dtype=float).reshape(3, -1))
        k = len(self._polys) - 1
        for c in range(3):   # consecutive rows, component 0 first: the kernels share p(z, s) among them
            self._add_con(CON_POLY_POINT, (p, origin, frame[0], frame[1], frame[2]), (z, s),
                          (float(k), float(c), 0.0, 0.0), f"{name}.{'xyz'[c]}")

    def crank_rod(self, theta: Scalar, x: Scalar, pivot, arm, rod_end, direction: float, length: float,
                  name: str = "crank_rod") -> None:
        """Planar crank and rod (a steering arm and its tie rod): the crank turns by the angle
        coordinate `theta` (rad) about `pivot`, its end at pivot + R(theta) `arm`; the rod of `length` (m)
        joins it to `rod_end`, which slides by `direction` * x along the plane's second axis with the
        travel coordinate `x` (m). Points are 2-vectors in the plane of motion (a body's x, y). One row."""
        c = np.asarray(pivot, dtype=float)[:2] - np.asarray(rod_end, dtype=float)[:2]
        a = np.asarray(arm, dtype=float)[:2]
        ra = Ref(f"{name}.c", (-1, -1, -1), (float(c[0]), float(c[1]), float(a[0])))
        rb = Ref(f"{name}.l", (-1, -1, -1), (float(a[1]), float(direction), float(length)))
        self._add_con(CON_CRANK_ROD, (ra, rb), (theta, x), (0.0,) * 4, name)

    def _poly_coef(self) -> np.ndarray:
        if not self._polys:
            return np.zeros((0, 3, 1))
        return np.array(self._polys)

    def drive(self, s: Scalar | tuple[Ref, int], poly=None, sine=None, external: bool = False,
              name: str | None = None) -> int:
        """Rheonomic constraint coordinate = f(t): poly=(c0, c1, c2, c3), sine=(offset, amplitude,
        omega, phase) or external (value, rate, acceleration written into data.drv_ext). Returns the
        driver index."""
        if poly is not None:
            kind, par = DRV_POLY, tuple(poly) + (0.0,) * (4 - len(poly))
        elif sine is not None:
            kind, par = DRV_SINE, tuple(sine)
        elif external:
            kind, par = DRV_EXTERNAL, (0.0,) * 4
        else:
            raise ModelError(f"{self.name}: drive() needs poly, sine or external")
        self._drivers.append((kind, par))
        k = len(self._drivers) - 1
        term = (1.0, s, 0) if isinstance(s, Scalar) else (1.0, s[0], s[1])
        self.linear([term], 0.0, name=name or f"drive {k}", driver=k)
        self._conservative = False
        return k

    # ---- forces ----------------------------------------------------------------------------------
    def gravity(self, g) -> None:
        self._gravity = self._vec(g)

    def spring(self, a: Ref, b: Ref, stiffness: float, damping: float = 0.0, rest_length: float | None = None,
               preload: float = 0.0, name: str | None = None) -> None:
        """Point-to-point spring-damper: tension = k (L - L0) + c L' + F0 (N)."""
        if rest_length is None:
            rest_length = float(np.linalg.norm(self._value(a) - self._value(b)))
        if damping:
            self._conservative = False
        self._forces.append(dict(kind=FRC_SPRING, refs=(a, b), scalar=None, drv=-1,
                                 par=(stiffness, damping, rest_length, preload, 0.0, 0.0),
                                 name=name or f"spring({a.name}, {b.name})"))

    def coordinate_force(self, s: Scalar, constant: float = 0.0, stiffness: float = 0.0, rest: float = 0.0,
                         damping: float = 0.0, name: str | None = None) -> None:
        """Generalized force on a scalar coordinate: F = constant - k (s - rest) - c s' (N or N m)."""
        if damping or constant:
            self._conservative = False
        self._forces.append(dict(kind=FRC_COORD, refs=(ZERO, ZERO), scalar=s, drv=-1,
                                 par=(constant, stiffness, rest, damping, 0.0, 0.0),
                                 name=name or f"force({s.name})"))

    # ---- compilation -----------------------------------------------------------------------------
    def _affine(self, r: Ref, nq: int) -> tuple[np.ndarray, np.ndarray]:
        p = np.zeros((self.dim, nq))
        for c in range(self.dim):
            if r.idx[c] >= 0:
                p[c, r.idx[c]] = 1.0
        return p, np.array(r.cst[: self.dim])

    def _mass_and_gravity(self, nq: int) -> tuple[np.ndarray, np.ndarray]:
        mass = np.zeros((nq, nq))
        qg = np.zeros(nq)
        g = self._gravity[: self.dim]
        for p, mp in self._point_masses:
            a, _ = self._affine(p, nq)
            mass += mp * a.T @ a
            qg += mp * a.T @ g
        for k, inertia in self._scalar_inertia:
            mass[k, k] += inertia
        for a, b, mr, k in self._rods:
            # r(xi) = a + xi (b - a), xi in [-1/2, 1/2] about the centre: M from m and k = I_t / (m L^2)
            pa, _ = self._affine(a, nq)
            pb, _ = self._affine(b, nq)
            mid = 0.5 * (pa + pb)
            dif = pb - pa
            mass += mr * (mid.T @ mid + k * dif.T @ dif)
            qg += mr * mid.T @ g
        parts = MassParts(mass.copy(), qg.copy(), g.copy(), tuple(self._body_frame(b, nq) for b in self._bodies),
                          tuple((b.mass, b.inertia) for b in self._bodies))
        for frame, b in zip(parts.bodies, self._bodies):
            _add_body(mass, qg, g, frame, b.mass, b.inertia)
        self._mass_parts = parts
        return 0.5 * (mass + mass.T), qg

    def _body_frame(self, b: _Body, nq: int) -> "BodyFrame":
        """What a body's share of the mass matrix and gravity vector depends on besides its mass and
        inertia: its name, the basis of its directions and its origin at the initial configuration, its
        centre of mass, the coordinate maps of its origin and directions (functions of the topology and
        the initial values alone)."""
        x = self._basis_values(b.origin, b.directions)
        r0 = self._value(b.origin)[: self.dim]
        maps = [self._affine(b.origin, nq)[0]]
        for k in range(self.dim):
            if self.dim == 2 and k == 1:
                d1 = maps[1]
                maps.append(np.vstack([-d1[1], d1[0]]))
            else:
                h, t = self._dir_refs(b.directions[k])
                maps.append(self._affine(h, nq)[0] - self._affine(t, nq)[0])
        return BodyFrame(b.name, self.dim, x, r0, b.cg, tuple(maps))

    def _row_slots(self, refs, scalar, terms=None):
        """Slot indices and constants of a row: from linear `terms`, or from vector refs + scalar."""
        idx = -np.ones(NSLOT, dtype=np.int64)
        cst = np.zeros(NSLOT)
        if terms is not None:
            coeffs: dict[int, float] = {}
            const = 0.0
            for coeff, r, comp in terms:
                if isinstance(r, Scalar):
                    coeffs[r.index] = coeffs.get(r.index, 0.0) + coeff
                else:
                    const += coeff * r.cst[comp]
                    if r.idx[comp] >= 0:
                        coeffs[r.idx[comp]] = coeffs.get(r.idx[comp], 0.0) + coeff
            items = [(k, v) for k, v in coeffs.items() if v != 0.0]
            if len(items) > NSLOT:
                raise ModelError(f"{self.name}: a linear constraint has more than {NSLOT} terms")
            for s, (k, v) in enumerate(items):
                idx[s] = k
                cst[s] = v
            return idx, cst, const
        for s, r in enumerate(refs):
            for c in range(3):
                idx[3 * s + c] = r.idx[c] if c < self.dim else -1
                cst[3 * s + c] = r.cst[c]
        if isinstance(scalar, tuple):
            for slot, sc in zip((SCALAR, SCALAR2), scalar):
                if sc is not None:
                    idx[slot] = sc.index
        elif scalar is not None:
            idx[SCALAR] = scalar.index
        return idx, cst, 0.0

    def compile(self, reuse: Mechanism | None = None) -> Mechanism:
        """The model's arrays. ``reuse``: a mechanism compiled before; when this one has its topology (the
        same coordinates, the same pattern of the mass matrix, constraints, forces and couplings: the
        ``structure`` digest) its symbolic analysis -- orderings, the envelope's and the factor's layout, the
        constraint rows' assembly lists, all functions of the topology alone -- is taken instead of being
        computed again; every value (mass matrix, gravity, constraint and force parameters) is computed
        here as always, so the model equals a fresh compile's bit for bit."""
        nq = len(self._names)
        if nq == 0:
            raise ModelError(f"{self.name}: no coordinates")
        nc = len(self._cons)
        mass, qg = self._mass_and_gravity(nq)
        con_kind = np.zeros(nc, dtype=np.int64)
        con_idx = -np.ones((nc, NSLOT), dtype=np.int64)
        con_cst = np.zeros((nc, NSLOT))
        con_par = np.zeros((nc, 4))
        con_drv = -np.ones(nc, dtype=np.int64)
        con_act = np.zeros((nc, NSLOT), dtype=np.int64)
        con_nact = np.zeros(nc, dtype=np.int64)
        pairs = [np.array(np.nonzero(mass)).T]
        for i, con in enumerate(self._cons):
            idx, cst, const = self._row_slots(con["refs"], con["scalar"],
                                              con["refs"] if con["kind"] == CON_LINEAR else None)
            con_kind[i] = con["kind"]
            con_idx[i], con_cst[i] = idx, cst
            con_par[i] = con["par"]
            if con["kind"] == CON_LINEAR:
                con_par[i, 0] = con["par"][0] + const   # the declared constant plus fixed refs
            con_drv[i] = con["drv"]
            act, row_pairs = _row_structure(con["kind"], idx, con_par[i])
            con_nact[i] = act.size
            con_act[i, :act.size] = act
            pairs.append(row_pairs)
        nf = len(self._forces)
        frc_kind = np.zeros(nf, dtype=np.int64)
        frc_idx = -np.ones((nf, NSLOT), dtype=np.int64)
        frc_cst = np.zeros((nf, NSLOT))
        frc_par = np.zeros((nf, 6))
        tangent = 0
        for f, frc in enumerate(self._forces):
            refs = tuple(frc["refs"]) + (ZERO, ZERO)
            idx, cst, _ = self._row_slots(refs, frc["scalar"])
            frc_kind[f], frc_idx[f], frc_cst[f], frc_par[f] = frc["kind"], idx, cst, frc["par"]
            used = np.unique(idx[idx >= 0])
            pairs.append(_lower_pairs(used))
            tangent = 1
        for used in self._coupled:
            pairs.append(_lower_pairs(used))
        allpairs = np.vstack(pairs)
        structure = _structure_digest(nq, allpairs, con_idx, con_act, con_nact)
        if reuse is not None and reuse.structure == structure:
            m0 = reuse.model                 # the same topology: its symbolic analysis, shared (immutable)
            perm, pinv, first, ptr = m0.perm, m0.pinv, m0.first, m0.ptr
            fac = {"perm": m0.fperm, "pinv": m0.fpinv, "colptr": m0.fcolptr, "rowidx": m0.frowidx,
                   "uptr": m0.fuptr, "upos": m0.fupos, "uend": m0.fuend, "w_map": m0.fw_map}
            asm = {k: getattr(m0, k) for k in _ASM_FIELDS}
        else:
            perm, pinv, first, ptr = envelope.symbolic(nq, allpairs)
            fac = _factor_layout(nq, allpairs, perm, pinv, first, ptr)
            asm = _assembly(fac, con_idx, con_act, con_nact)
        nd = len(self._drivers)
        drv_kind = np.array([k for k, _ in self._drivers], dtype=np.int64)
        drv_par = np.array([p for _, p in self._drivers], dtype=float).reshape(nd, 4)
        s = self.settings
        iset = np.zeros(NISET, dtype=np.int64)
        iset[IS_PROJECTION_FACTOR] = int(s.projection_factor)
        iset[IS_MAX_ITER], iset[IS_MAX_PROJ] = s.max_iter, s.max_proj_iter
        iset[IS_TANGENT_FORCES], iset[IS_REUSE_STEPS] = tangent, int(s.reuse_across_steps)
        iset[IS_ERROR_TEST] = int(s.error_test)
        iset[IS_PREDICTOR] = int(s.extrapolate)
        iset[IS_ABSOLUTE_DQ] = int(s.absolute_tol_dq)
        iset[IS_FINISH_FORCES] = int(s.finish_forces)
        fset = np.zeros(NFSET)
        fset[FS_TOL_DQ], fset[FS_TOL_PHI], fset[FS_TOL_VEL], fset[FS_TOL_ACC] = s.tol_dq, s.tol_phi, s.tol_vel, s.tol_acc
        fset[FS_TOL_VEL_FAIL], fset[FS_TOL_ACC_FAIL] = s.tol_vel_fail, s.tol_acc_fail
        fset[FS_REUSE_RATE] = s.reuse_rate
        fset[FS_STALL_RATE], fset[FS_MIN_STEP] = s.stall_rate, s.min_step
        fset[FS_GRAVITY:FS_GRAVITY + 3] = self._gravity
        model = Model(
            nq=nq, nc=nc, dim=self.dim,
            con_kind=con_kind, con_idx=con_idx, con_cst=con_cst, con_par=con_par, con_drv=con_drv,
            con_nact=con_nact, con_act=con_act,
            drv_kind=drv_kind, drv_par=drv_par,
            frc_kind=frc_kind, frc_idx=frc_idx, frc_cst=frc_cst, frc_par=frc_par,
            frc_drv=-np.ones(nf, dtype=np.int64),
            q_grav=qg, poly_coef=self._poly_coef(),
            poly_exp=self._poly_exp if self._poly_exp is not None else np.zeros((1, 2), dtype=np.int64),
            perm=perm, pinv=pinv, first=first, ptr=ptr,
            m_env=envelope.to_envelope(mass, first, ptr, perm),
            fperm=fac["perm"], fpinv=fac["pinv"], fcolptr=fac["colptr"], frowidx=fac["rowidx"], fuptr=fac["uptr"],
            fupos=fac["upos"], fuend=fac["uend"], fw_map=fac["w_map"], **asm,
            iset=iset, fset=fset,
        )
        return Mechanism(
            name=self.name, model=model, q0=np.array(self._q0), qd0=np.array(self._qd0),
            qd_given=np.array(self._qd_given), coordinate_names=list(self._names),
            constraint_names=[c["name"] for c in self._cons], force_names=[f["name"] for f in self._forces],
            mass_dense=mass, settings=s, conservative=self._conservative, structure=structure,
            mass_parts=self._mass_parts,
        )
