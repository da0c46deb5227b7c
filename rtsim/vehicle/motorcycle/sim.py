"""Running the two-wheeler: its state, its force-element arrays and the compiled step, with read-outs of
the quantities riders and analyses use (ISO 8855: roll positive right side down, steer positive left)
and a fall detector. A fall (roll past a limit, both tyres off the road) ends a run with a status,
never a NaN."""
from __future__ import annotations

import math
import weakref

import numpy as np

from rtsim.errors import SimulationError
from rtsim.mbs.model import OK
from rtsim.mbs.simulation import Simulation

from .build import MotorcycleModel, straight_running_velocity
from .layout import NAMES, NDOF
from .parts import make_parts
from .step import TO_FZ, two_wheeler_step

FALL_ROLL = math.radians(70.0)     # rad: a lean past this is a fall


class Fall(SimulationError):
    """The two-wheeler fell (roll past FALL_ROLL or both tyres off the road)."""

    def __init__(self, msg: str, t: float):
        super().__init__(msg, 0, t)


class TwoWheelerSim:
    def __init__(self, mm: MotorcycleModel, dt: float = 1e-3, speed: float = 0.0, dof=None,
                 q: np.ndarray | None = None, mu: float = 1.0):
        self.mm = mm
        self.dt = float(dt)
        q = mm.coordinates(np.zeros(NDOF) if dof is None else dof) if q is None else q.copy()
        qd = straight_running_velocity(mm, q, speed)
        self.sim = Simulation(mm.mech, dt, q0=q, qd0=qd)
        self.parts = make_parts(mm, mu)
        self.model, self.data = self.sim.model, self.sim.data

    # ---- stepping ------------------------------------------------------------------------------------
    def step(self) -> None:
        p = self.parts
        status = two_wheeler_step(self.model, self.data, self.dt, p.idx, p.par, p.tab, p.u, p.tp, p.slip, p.tyre)
        if status != OK:
            self.sim._raise(status, int(self.data.stats[0]) + 1)
        if abs(self.roll) > FALL_ROLL:
            raise Fall(f"{self.mm.config.id}: fell at t = {self.time:.3f} s (roll {math.degrees(self.roll):.0f} deg)",
                       self.time)
        if not self.mm.knife_edge and p.tyre[0, TO_FZ] <= 0.0 and p.tyre[1, TO_FZ] <= 0.0 and self.time > 0.5:
            raise Fall(f"{self.mm.config.id}: fell at t = {self.time:.3f} s (both tyres off the road)", self.time)

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / self.dt))):
            self.step()

    # ---- read-outs ---------------------------------------------------------------------------------
    def _g(self, x, name):
        k = self.mm.bike.idx[NAMES.index(name)]
        return x[k] if name in ("DELTA", "ZETA", "THETA", "PHI_F", "PHI_R") else x[k:k + 3]

    @property
    def time(self) -> float:
        return float(self.data.t[0])

    @property
    def roll(self) -> float:
        """Rear frame roll, rad (asin of the lateral axis' height)."""
        return math.asin(max(-1.0, min(1.0, self._g(self.data.q, "V")[2])))

    @property
    def yaw(self) -> float:
        v = self._g(self.data.q, "V")
        return math.atan2(-v[0], v[1])

    @property
    def steer(self) -> float:
        return float(self._g(self.data.q, "DELTA"))

    @property
    def steer_rate(self) -> float:
        return float(self._g(self.data.qd, "DELTA"))

    def angular_velocity(self) -> np.ndarray:
        q, qd = self.data.q, self.data.qd
        w = np.zeros(3)
        for name in ("E1", "V", "H_AX"):
            w += 0.5 * np.cross(self._g(q, name), self._g(qd, name))
        return w

    @property
    def yaw_rate(self) -> float:
        return float(self.angular_velocity()[2])

    @property
    def roll_rate(self) -> float:
        """Rate of the roll angle, rad/s: the angular velocity about the heading."""
        w = self.angular_velocity()
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return float(w[0] * c + w[1] * s)

    @property
    def position(self) -> np.ndarray:
        """The swingarm pivot's position on the ground plane (x, y), m (`rear_contact` for the road point)."""
        return self._g(self.data.q, "P")[:2].copy()

    @property
    def velocity(self) -> tuple[float, float]:
        """(forward, lateral) speed of the pivot in the heading frame, m/s."""
        v = self._g(self.data.qd, "P")
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return float(v[0] * c + v[1] * s), float(-v[0] * s + v[1] * c)


_POSES: dict = {}      # static_pose's results by (model, seconds, dt): a weak reference to the model, q, loads


def static_pose(mm: MotorcycleModel, seconds: float = 1.5, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """The two-wheeler standing upright at rest with the rider on, settled by its own suspension and tyre
    damping: (q, tyre loads front and rear, N). Straight running starts from this pose. The settling
    (`seconds` of simulation) is done once per process for the same model and step: later calls get
    copies of its result (a batch starts every ride of a vehicle from it)."""
    key = (id(mm), float(seconds), float(dt))
    kept = _POSES.get(key)
    if kept is None or kept[0]() is not mm:
        s = TwoWheelerSim(mm, dt=dt)
        s.run(seconds)
        if len(_POSES) >= 16:
            _POSES.clear()
        kept = _POSES[key] = (weakref.ref(mm), s.data.q.copy(), s.parts.tyre[:, TO_FZ].copy())
    return kept[1].copy(), kept[2].copy()


def rear_contact(sim: TwoWheelerSim) -> np.ndarray:
    """The rear wheel's lowest point (x, y), m: the motorcycle's reference point on the road."""
    q = sim.data.q
    w = sim._g(q, "W_R")
    a = sim._g(q, "V")
    up = np.array([0.0, 0.0, 1.0]) - a[2] * a
    up /= np.linalg.norm(up)
    return (w - sim.mm.config.rear_wheel.radius_m * up)[:2]
