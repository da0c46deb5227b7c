"""The two-wheeler's applied forces for the linearisation: the vehicle file's force elements
(rtsim.vehicle.motorcycle.step.two_wheeler_forces: tyres, suspension springs and dampers, steering
damper and stops, chain, brakes, aero) evaluated by the compiled kernel at any state (q, qd) with the
tyres' contact deflections z, and the rates dz/dt of those deflections from the tyre kit's relaxation
law (rtsim.vehicle.kit.tyre.two_wheel.two_wheel_slip_rates, the equation advance_two_wheel_slip
integrates over a step).

A drive torque at the rear wheel holds the speed against rolling resistance and drag: through the chain
when the vehicle has one (so its squat and anti-squat act), else between the rear wheel and the swingarm
(a hub motor)."""
from __future__ import annotations

import numpy as np

from rtsim.mbs.model import make_data
from rtsim.vehicle.kit.tyre.two_wheel import TW_N_SLIP_STATES, two_wheel_slip_rates
from rtsim.vehicle.motorcycle.build import MotorcycleModel
from rtsim.vehicle.motorcycle.layout import K_PHI_R, K_THETA
from rtsim.vehicle.motorcycle.parts import make_parts
from rtsim.vehicle.motorcycle.step import (TO_FZ, TO_GAMMA, TO_OMEGA, TO_RE, TO_VSY, TO_VX, U_DRIVE_TORQUE,
                                           two_wheeler_forces)

SLIP_NAMES = ("u_front", "v_front", "u_rear", "v_rear")   # contact deflections, m (kit TW_S_U, TW_S_V)


class AppliedForces:
    """The force elements of `mm`'s vehicle file at a state, for offline analyses (a scratch copy of the
    model's data; not for the real-time loop). `n_slip` contact-deflection states (0 with knife-edge
    wheels, else 2 per wheel in the order of SLIP_NAMES)."""

    def __init__(self, mm: MotorcycleModel, mu: float = 1.0):
        self.mm = mm
        self.parts = make_parts(mm, mu)
        self.model = mm.mech.model
        self.data = make_data(self.model, mm.mech.q0)
        self.n_slip = 0 if mm.knife_edge else 2 * TW_N_SLIP_STATES
        self.chain = mm.config.chain is not None
        self.drive = 0.0          # N m, drive torque at the rear wheel

    def __call__(self, q: np.ndarray, qd: np.ndarray, slip: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Q, dz/dt): generalized forces (N, N m per coordinate) and the rates of the contact deflections
        z = `slip` (m/s)."""
        m, d, p = self.model, self.data, self.parts
        d.q[:] = q
        d.qd[:] = qd
        d.force[:] = 0.0
        p.u[:] = 0.0
        if self.n_slip:
            p.slip[:] = np.reshape(slip, p.slip.shape)
        if self.chain:
            p.u[U_DRIVE_TORQUE] = self.drive
        bad = two_wheeler_forces(m, d, p.idx, p.par, p.tab, p.u, p.tp, p.slip, p.tyre, False, 0.0, 0.0)
        if bad >= 0:
            raise FloatingPointError(f"non-finite applied force on coordinate {bad}")
        force = d.force.copy()
        if not self.chain and self.drive != 0.0:
            force[p.idx[K_PHI_R]] += self.drive
            force[p.idx[K_THETA]] -= self.drive
        return force, self.slip_rates()

    def slip_rates(self) -> np.ndarray:
        """d(slip)/dt (m/s) at the state of the last call, from the contact quantities the force kernel
        computed there; a wheel off the road has none (zero rates)."""
        p = self.parts
        out = np.zeros(self.n_slip)
        for w in range(self.n_slip // TW_N_SLIP_STATES):
            t = p.tyre[w]
            if t[TO_FZ] > 0.0:
                out[2 * w:2 * w + 2] = two_wheel_slip_rates(p.tp[w], t[TO_FZ], t[TO_GAMMA], t[TO_VX], t[TO_VSY],
                                                            t[TO_OMEGA], t[TO_RE], p.slip[w, 0], p.slip[w, 1])
        return out

    def loads(self) -> np.ndarray:
        """Tyre loads (N, front and rear) at the state of the last call."""
        return self.parts.tyre[:, TO_FZ].copy()


def slip_rates(applied: AppliedForces, q: np.ndarray, qd: np.ndarray, slip: np.ndarray) -> np.ndarray:
    """d(slip)/dt (m/s) of the tyres' contact deflections (SLIP_NAMES) at the state (q, qd, slip): the
    relaxation law that advance_two_wheel_slip integrates over a step."""
    return applied(q, qd, slip)[1]
