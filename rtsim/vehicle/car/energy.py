"""The power audit of a car run: the bond-graph view of the model. Every force element is a port whose
generalized forces (VehicleData.pf: each force stage's record, rtsim.vehicle.car.forces, the last one
of a step written at its converged state) do work on the coordinates, so the audit is a sum over the
stages' records after the step and nothing inside the force stages depends on it; the stored
energies (kinetic, gravity, suspension springs, anti-roll bars, torsion bar, the motor's inductance)
are functions of the state. The balance

    stored(t) - stored(t0) = sum of the ports' work + supply - winding losses

holds without quadrature error when the ports' work is paired with the step exactly as the
trapezoidal rule integrates it: W += (Q_n + Q_n+1) / 2 . (q_n+1 - q_n) for each port, so what is left
(`residual`) is the integrator's own energy error (Newton and projection tolerances).
The constraint forces (-Phi_q^T lambda) are two ports of their own: the driver's imposed steering-wheel
angle (an input) and the joints (zero work in exact arithmetic).

The audit starts at the end of the first step after it is switched on. Values are cumulative
energies in J (positive: work done on the vehicle); `summarise` derives the ports' peak powers from the
recorded cumulative work. The compiled part is rtsim.vehicle.car.energy_kernels.
"""
from __future__ import annotations

import numpy as np

from rtsim.channels import ENERGY, ENERGY_FLOWS, ENERGY_STORED

from ..kit.eps import (EO_ASSIST_TORQUE, EO_CURRENT, EO_MOTOR_ANGLE, EO_MOTOR_SPEED, EO_POWER, EO_SW_TORQUE,
                       EO_TB_TORQUE, EO_VOLTAGE, PORT_MOTOR_EM, PORT_TORSION_BAR)
from .energy_kernels import A_DRIVER_ANGLE, A_EMF, A_JOINTS, A_SIZE, A_STORED, A_STORED0, A_SUPPLY, A_WINDING, NSTORED
from .layout import CAR_PORT_NAMES, NPORT, PORT_ARB, PORT_EPS, PORT_SPRING
from .step import AUDIT_SIZE

EPS_PORT_NAMES = ("driver_torque", "torsion_bar", "column_friction", "motor_em", "motor_friction", "gear_loss",
                  "pinion_friction", "rack_loss", "rack_friction")
PORT_NAMES = CAR_PORT_NAMES + EPS_PORT_NAMES
STORED_NAMES = ENERGY_STORED
assert len(PORT_NAMES) == NPORT and len(STORED_NAMES) == NSTORED and A_SIZE <= AUDIT_SIZE
# stored elements: their port work is the negative change of their stored energy (not in the balance)
STORED_PORTS = (PORT_SPRING, PORT_ARB, PORT_EPS + PORT_TORSION_BAR)


#: the names of Balance.flows, in its order: the ports that store nothing (but the motor's electromagnetic
#: one), then the driver's angle, the joints and the motor's supply, winding and conversion
FLOW_KEYS = (*(n for i, n in enumerate(PORT_NAMES) if i not in STORED_PORTS and i != PORT_EPS + PORT_MOTOR_EM),
             "driver_angle", "joints", "motor_supply", "motor_winding", "motor_conversion")
_FLOW_PORTS = np.array([PORT_NAMES.index(n) for n in FLOW_KEYS[:-5]] + [A_DRIVER_ANGLE, A_JOINTS], dtype=np.int64)
_ROW_FLOWS = np.array([FLOW_KEYS.index(n) for n in ENERGY_FLOWS], dtype=np.int64)   # the row's order


def flow_values(a: np.ndarray, e_base: np.ndarray) -> np.ndarray:
    """Balance.flows of the audit array `a` as an array in FLOW_KEYS order (J)."""
    out = np.empty(len(FLOW_KEYS))
    n = _FLOW_PORTS.size
    out[:n] = a[_FLOW_PORTS]
    out[n] = a[A_SUPPLY] - e_base[0]
    out[n + 1] = -(a[A_WINDING] - e_base[1])
    # the motor's conversion: mechanical work of Kt i less the electrical energy converted (0 exactly)
    out[n + 2] = a[PORT_EPS + PORT_MOTOR_EM] - (a[A_EMF] - e_base[2])
    return out


def stored_values(a: np.ndarray) -> np.ndarray:
    """The stored energies' change since the audit's start (J), STORED_NAMES order."""
    return a[A_STORED:A_STORED + NSTORED] - a[A_STORED0:A_STORED0 + NSTORED]


class Balance:
    """The audit's summary from its array (VehicleData.audit_e, or a recorded row of energy columns)."""

    def __init__(self, a: np.ndarray, e_base: np.ndarray):
        self.ports = {n: float(a[i]) for i, n in enumerate(PORT_NAMES)}
        self.driver_angle = float(a[A_DRIVER_ANGLE])
        self.joints = float(a[A_JOINTS])
        self.supply = float(a[A_SUPPLY] - e_base[0])
        self.winding = float(a[A_WINDING] - e_base[1])
        self.emf = float(a[A_EMF] - e_base[2])
        self.stored = dict(zip(STORED_NAMES, stored_values(a).tolist()))
        self._flows = dict(zip(FLOW_KEYS, flow_values(a, e_base).tolist()))

    @property
    def flows(self) -> dict[str, float]:
        """Work done on the vehicle by every non-storing port (J): inputs positive, losses negative."""
        return dict(self._flows)

    @property
    def stored_change(self) -> float:
        return sum(self.stored.values())

    @property
    def exchanged(self) -> float:
        """The energy exchanged in the run (J): the sum of the magnitudes of all non-storing flows."""
        return sum(abs(v) for v in self.flows.values()) + abs(self.emf)

    @property
    def residual(self) -> float:
        """stored change - (inputs - dissipation), J."""
        return self.stored_change - sum(self.flows.values())


ENERGY_NAMES = tuple(c.name for c in ENERGY)
#: the EPS outputs of the audit's row, in its order
_EPS_OUT = np.array([EO_CURRENT, EO_VOLTAGE, EO_POWER, EO_MOTOR_SPEED, EO_MOTOR_ANGLE, EO_TB_TORQUE, EO_SW_TORQUE,
                     EO_ASSIST_TORQUE], dtype=np.int64)


def energy_row(sim, out: np.ndarray) -> None:
    """The audit's channels (rtsim.channels.ENERGY order) of a VehicleSim at its present step: the
    flows, the stored energies' changes, the residual (Balance.residual, summed in the same order) and,
    with EPS, the EPS's outputs."""
    a = sim.vd.audit_e
    flows = flow_values(a, sim.vd.e_base)
    stored = stored_values(a)
    nf = _ROW_FLOWS.size
    out[:nf] = flows[_ROW_FLOWS]
    out[nf:nf + NSTORED] = stored
    out[nf + NSTORED] = sum(stored.tolist()) - sum(flows.tolist())
    k = nf + NSTORED + 1
    if sim.has_eps:
        out[k:k + _EPS_OUT.size] = sim.io.eps_out[_EPS_OUT]
    else:
        out[k:] = 0.0


def summarise(t: np.ndarray, series: dict[str, np.ndarray]) -> str:
    """The audit of a run as text: every port's energy (J) and peak power (W), the stored energies'
    change, and the balance with its residual relative to the energy exchanged."""
    def peak(w):
        p = np.diff(w) / np.maximum(np.diff(t), 1e-12)
        return float(p[np.argmax(np.abs(p))]) if p.size else 0.0
    flows = {n: series[f"work_{n}"] for n in ENERGY_FLOWS}
    stored = {n: series[f"stored_{n}"] for n in ENERGY_STORED}
    lines = [f"power audit over {t[0]:.3f} .. {t[-1]:.3f} s (J: energy into the vehicle through each port; "
             "W: largest power)"]
    lines.append(f"  {'port':<22} {'energy J':>14} {'peak W':>12}")
    for n, w in flows.items():
        if np.any(w != 0.0):
            lines.append(f"  {n:<22} {w[-1] - w[0]:>14.4f} {peak(w):>12.2f}")
    lines.append(f"  {'stored':<22} {'change J':>14}")
    for n, e in stored.items():
        if np.any(e != 0.0):
            lines.append(f"  {n:<22} {e[-1] - e[0]:>14.4f}")
    d_stored = sum(e[-1] - e[0] for e in stored.values())
    inputs = sum(w[-1] - w[0] for w in flows.values())
    exchanged = sum(abs(w[-1] - w[0]) for w in flows.values())
    res = d_stored - inputs
    lines.append(f"  balance: stored change {d_stored:.4f} J = inputs - dissipation {inputs:.4f} J; residual "
                 f"{res:.3e} J, {res / max(exchanged, 1e-300):.2e} of the {exchanged:.1f} J exchanged")
    return "\n".join(lines)
