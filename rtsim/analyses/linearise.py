"""Numerical linearisation of a compiled multibody model about a motion, in its own coordinates.

The model's equations of motion are those its kernels evaluate: the constant mass matrix M, the
constraint rows (position rows Phi(q) = 0 and velocity rows B(q) qd = 0 of rolling without slip; all
of them as C(q) qd = 0 at the velocity level) and the applied forces Q(q, qd). For any state
x = (q, qd) the accelerations follow from

    [M  C^T] [qdd   ]   [Q(q, qd)           ]
    [C  0  ] [lambda] = [-(d/dt C) qd        ],

so f(x) = (qd, qdd) is the model's own vector field, defined on and off the constraint manifold.
Force elements with first-order states of their own (a tyre's contact deflections) extend the state:
x = (q, qd, z) with dz/dt = g(q, qd, z) from the same call that gives their forces (`Equations.aux`).
The Jacobian J of f is taken by fourth-order central differences (error ~1e-12 for smooth forces; at a
kink, such as a damper with different compression and rebound rates at zero speed, the stencil gives
the mean of the two slopes).

The motion is a steady one, not an equilibrium: straight running moves the state along the model's
symmetries (translation along the ground, the wheels' spin), x(t) = exp(t xi) x0, with f(x0) = xi(x0)
for the generator field xi of that motion. Perturbations seen in the frame that moves with it obey
dy/dt = (J - D xi(x0)) y (the variational equation of a relative equilibrium); this matrix maps the
constraint manifold's tangent space T into itself and the symmetry directions S (translations, yaw,
spins) into S. The eigenvalues that matter are those on T/S: with N' an orthonormal basis of T
orthogonal to S, A = N'^T (J - D xi) N' (rtsim.analyses.eigen).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from rtsim.mbs import Mechanism
from rtsim.mbs.constraints import eval_constraints, eval_drivers, eval_hqd
from rtsim.mbs.forces import eval_forces
from rtsim.mbs.model import VELOCITY_KINDS, make_data
from rtsim.mbs.simulation import dense_jacobian

FD_STEP = 1e-4       # relative finite-difference step of the fourth-order stencil


@dataclass
class Equations:
    """The equations of motion of `mech`, with optional extra applied forces `extra(q, qd) -> Q` (N, N m),
    or applied forces with `n_aux` first-order states z of their own: `aux(q, qd, z) -> (Q, dz/dt)`."""
    mech: Mechanism
    extra: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    aux: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
    n_aux: int = 0

    def __post_init__(self):
        m = self.model = self.mech.model
        self.data = make_data(m, self.mech.q0)     # dt = 0: velocity rows give their plain coefficients
        self.nq = m.nq
        self.velocity_rows = np.isin(m.con_kind, VELOCITY_KINDS)
        self.mass = self.mech.mass_dense
        if self.n_aux and self.aux is None:
            raise ValueError("n_aux states need their aux(q, qd, z) rates")

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.nq
        return x[:n], x[n:2 * n], x[2 * n:]

    def constraint_matrix(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Phi of the position rows, C (all rows' velocity coefficients), (d/dt C) qd)."""
        m, d = self.model, self.data
        d.qd[:] = qd
        eval_drivers(m, d, 0.0)
        eval_constraints(m, d, q)
        c = dense_jacobian(m, d)
        eval_hqd(m, d, q, qd)
        return d.phi[~self.velocity_rows].copy(), c, d.hqd.copy()

    def forces(self, q: np.ndarray, qd: np.ndarray, z: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(Q, dz/dt): the generalized forces at (q, qd, z) and the rates of the force elements' states."""
        m, d = self.model, self.data
        d.q_ext[:] = 0.0
        eval_forces(m, d, q, qd, False, 0.0, 0.0)
        out = d.force.copy()
        if self.extra is not None:
            out += self.extra(q, qd)
        zd = np.zeros(self.n_aux)
        if self.aux is not None:
            f, zd = self.aux(q, qd, np.zeros(0) if z is None else z)
            out += f
        return out, zd

    def accelerations(self, q: np.ndarray, qd: np.ndarray, z: np.ndarray | None = None) -> np.ndarray:
        return self._solve(q, qd, self.forces(q, qd, z)[0])

    def _solve(self, q, qd, force):
        _phi, c, hqd = self.constraint_matrix(q, qd)
        n, k = self.nq, c.shape[0]
        kkt = np.zeros((n + k, n + k))
        kkt[:n, :n] = self.mass
        kkt[:n, n:] = c.T
        kkt[n:, :n] = c
        rhs = np.concatenate([force, -hqd])
        return np.linalg.solve(kkt, rhs)[:n]

    def rates(self, x: np.ndarray) -> np.ndarray:
        q, qd, z = self.split(x)
        force, zd = self.forces(q, qd, z)
        return np.concatenate([qd, self._solve(q, qd, force), zd])

    def manifold(self, x: np.ndarray) -> np.ndarray:
        """The state constraints g(x) = (Phi(q), C(q) qd): zero on the manifold of consistent states (the
        force elements' states z are free)."""
        q, qd, _z = self.split(x)
        phi, c, _ = self.constraint_matrix(q, qd)
        return np.concatenate([phi, c @ qd])


def jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, step: float = FD_STEP) -> np.ndarray:
    """d fun / dx by the fourth-order central difference, column by column."""
    cols = []
    for i in range(x.size):
        hi = step * max(1.0, abs(x[i]))
        e = np.zeros_like(x)
        e[i] = hi
        cols.append((8.0 * (fun(x + e) - fun(x - e)) - (fun(x + 2 * e) - fun(x - 2 * e))) / (12.0 * hi))
    return np.array(cols).T


def null_space(a: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis of the null space of a (columns)."""
    if a.shape[0] == 0:
        return np.eye(a.shape[1])
    _u, s, vt = np.linalg.svd(a)
    rank = int(np.sum(s > rtol * max(s[0], 1.0)))
    return vt[rank:].T


def reduced_matrix(eqs: Equations, x0: np.ndarray, symmetries: np.ndarray,
                   motion: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(A, N'): the state matrix on T/S in the orthonormal basis N' (columns in x-space); `motion(x)` is
    the generator field xi of the steady motion (None: x0 is an equilibrium)."""
    tangent = null_space(jacobian(eqs.manifold, x0))
    s_in_t = tangent.T @ symmetries
    off = np.linalg.norm(symmetries - tangent @ s_in_t) / max(1.0, np.linalg.norm(symmetries))
    if off > 1e-6:
        raise ValueError(f"the symmetry directions leave the constraint manifold (residual {off:.2g})")
    basis = tangent @ null_space(s_in_t.T)
    jac = jacobian(eqs.rates, x0)
    if motion is not None:
        jac = jac - jacobian(motion, x0)
    return basis.T @ jac @ basis, basis
