"""Stability of a two-wheeler in straight running: eigenvalues, mode shapes and names against speed,
from the full nonlinear model linearised numerically (rtsim.analyses.linearise).

At each speed the motorcycle (or bicycle) runs upright and straight; its state matrix on the constraint
manifold, less the symmetries of straight running (translation, yaw, wheel spins), gives the modes.
Each mode is read out in physical quantities (roll, steer, yaw, lateral, pitch, bounce, the suspension
travels and the forward speed) and named:

- out of plane (roll, steer, yaw): *weave* (oscillatory, roll and yaw with the steer, below ~5 Hz),
  *wobble* (oscillatory, steer-dominated, above it), *capsize* (real, roll-dominated), *castering*
  (real, steer-dominated);
- in plane: *speed* (the forward speed), *bounce* and *pitch* of the frame, *front hop* and *rear hop*
  (a wheel on its tyre), and the tyre's *relaxation* states.
A mode changes stability where its real part changes sign; those speeds are refined by bisection.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rtsim.vehicle.motorcycle.build import MotorcycleModel, straight_running_velocity
from rtsim.vehicle.motorcycle.layout import NAMES, POINTS, VECTORS

from .linearise import Equations, reduced_matrix

EZ = np.array([0.0, 0.0, 1.0])
OUT_OF_PLANE = ("roll", "steer", "yaw", "lateral")
IN_PLANE = ("pitch", "bounce", "fork", "swingarm", "speed")
WOBBLE_HZ = 5.0


@dataclass
class Mode:
    name: str
    eigenvalue: complex
    shape: dict[str, complex]          # physical quantities, normalised to the largest angle-like entry

    @property
    def frequency_hz(self) -> float:
        return abs(self.eigenvalue.imag) / (2 * np.pi)


@dataclass
class SpeedResult:
    speed: float
    modes: list[Mode] = field(default_factory=list)

    def eigenvalues(self, exclude=("speed",)) -> np.ndarray:
        return np.array([m.eigenvalue for m in self.modes if m.name not in exclude])


class TwoWheelerLinearisation:
    """Linearise `mm` about straight running; `extra_forces(q, qd)` adds the vehicle's applied forces."""

    def __init__(self, mm: MotorcycleModel, extra_forces=None):
        self.mm = mm
        self.eqs = Equations(mm.mech, extra_forces)
        self.nq = mm.mech.model.nq

    # ---- the operating point and its symmetries ----------------------------------------------------
    def operating_point(self, speed: float, q: np.ndarray | None = None) -> np.ndarray:
        q = self.mm.coordinates(np.zeros(11)) if q is None else q
        return np.concatenate([q, straight_running_velocity(self.mm, q, speed)])

    def _slices(self, names):
        for n in names:
            k = self.mm.bike.idx[NAMES.index(n)]
            if k >= 0:
                yield n, slice(k, k + 3)

    def symmetries(self, x0: np.ndarray) -> np.ndarray:
        """Columns: translation x, y; yaw about the vertical; each wheel's spin about its axle."""
        n = self.nq
        q, qd = x0[:n], x0[n:]
        cols = []
        for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
            s = np.zeros(2 * n)
            for _name, sl in self._slices(POINTS):
                s[sl] = axis
            cols.append(s)
        s = np.zeros(2 * n)
        for _name, sl in self._slices(POINTS + VECTORS):
            s[sl] = np.cross(EZ, q[sl])
            s[n:][sl] = np.cross(EZ, qd[sl])
        cols.append(s)
        for axle, vecs, spin in (("E_U", ("B_F", "C_F"), "PHI_F"), ("V", ("B_R", "C_R"), "PHI_R")):
            s = np.zeros(2 * n)
            ka = self.mm.bike.idx[NAMES.index(axle)]
            a, ad = q[ka:ka + 3], qd[ka:ka + 3]
            for _name, sl in self._slices(vecs):
                s[sl] = np.cross(a, q[sl])
                s[n:][sl] = np.cross(ad, q[sl]) + np.cross(a, qd[sl])
            s[self.mm.bike.idx[NAMES.index(spin)]] = 1.0
            cols.append(s)
        return np.array(cols).T

    # ---- physical read-out of a state perturbation -------------------------------------------------
    def readout(self, x0: np.ndarray, dx: np.ndarray) -> dict[str, complex]:
        """Linear read-out of a (complex) state perturbation in physical quantities: rear-frame roll, yaw,
        pitch (rad), steer (rad), lateral and bounce displacement of the pivot (m), fork and swingarm
        travel, forward speed (m/s)."""
        mm, n = self.mm, self.nq
        g = lambda x, name: x[mm.bike.idx[NAMES.index(name)]:][:3]   # noqa: E731
        dq, dqd = dx[:n], dx[n:]
        eps = mm.config.caster_rad
        x_axis = np.cos(eps) * g(dq, "E1") - np.sin(eps) * g(dq, "H_AX")
        return {
            "roll": g(dq, "V")[2], "yaw": -g(dq, "V")[0], "pitch": -x_axis[2],
            "steer": g(dq, "DELTA")[0], "lateral": g(dq, "P")[1], "bounce": g(dq, "P")[2],
            "fork": g(dq, "ZETA")[0], "swingarm": g(dq, "THETA")[0] * mm.design.swingarm_length,
            "speed": g(dqd, "P")[0],
        }

    # ---- modes -------------------------------------------------------------------------------------
    def modes(self, speed: float, q: np.ndarray | None = None) -> SpeedResult:
        x0 = self.operating_point(speed, q)
        sym = self.symmetries(x0)
        n = self.nq
        rates = np.array([speed, x0[n + self.mm.bike.idx[NAMES.index("PHI_R")]],
                          x0[n + self.mm.bike.idx[NAMES.index("PHI_F")]]])
        # straight running = translation along x at `speed` and the two wheels' spins (symmetry columns
        # 0, 3 and 4 of rtsim.analyses.eigen symmetries, front spin before rear)
        motion = lambda x: self.symmetries(x)[:, [0, 4, 3]] @ rates   # noqa: E731
        a, basis = reduced_matrix(self.eqs, x0, sym, motion)
        lam, vec = np.linalg.eig(a)
        out = SpeedResult(speed)
        for k in np.argsort(lam.real):
            if lam[k].imag < -1e-9 * max(1.0, abs(lam[k])):
                continue            # one of each conjugate pair
            shape = self.readout(x0, basis @ vec[:, k])
            out.modes.append(Mode(_name(lam[k], shape), complex(lam[k]), _normalise(shape)))
        return out


def _normalise(shape: dict[str, complex]) -> dict[str, complex]:
    angles = max(abs(shape[k]) for k in ("roll", "steer", "yaw", "pitch"))
    ref = max(angles, 1e-300)
    return {k: complex(v / ref) for k, v in shape.items()}


def _name(lam: complex, shape: dict[str, complex]) -> str:
    """Name a mode from its eigenvalue and its physical shape (see the module's docstring)."""
    mag = {k: abs(v) for k, v in shape.items()}
    out_plane = max(mag["roll"], mag["steer"], mag["yaw"])
    in_plane = max(mag["pitch"], mag["bounce"] / 0.3, mag["fork"] / 0.3, mag["swingarm"] / 0.3)
    if mag["speed"] > 10 * max(out_plane, in_plane, 1e-300) * max(1.0, abs(lam)):
        return "speed"
    if out_plane >= in_plane:
        oscillating = abs(lam.imag) > 1e-6 * max(1.0, abs(lam))
        steer_led = mag["steer"] > 3.0 * mag["roll"]
        if oscillating:
            return "wobble" if steer_led and abs(lam.imag) / (2 * np.pi) > WOBBLE_HZ else "weave"
        return "castering" if steer_led else "capsize"
    if mag["fork"] > 3 * max(mag["bounce"], 1e-300) and mag["fork"] > mag["swingarm"]:
        return "front hop"
    if mag["swingarm"] > 3 * max(mag["bounce"], 1e-300):
        return "rear hop"
    return "pitch" if mag["pitch"] * 0.7 > mag["bounce"] else "bounce"
