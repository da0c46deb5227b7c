"""A vehicle on a road: builds everything from the configuration, places the car on the road in
static equilibrium, and steps it (compiled) with the subsystems' states."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rtsim.errors import ConfigError
from rtsim.mbs import Simulation
from rtsim.mbs.model import OK
from rtsim.road.model import Road
from rtsim.road.query import NQUERY, Q_NX, Q_NZ, Q_Z, road_query

from .brake import brake_config, brake_params, brake_state
from .brake import BI_PRESSURE_CMD
from .dynamics import make_vehicle_data, vehicle_step
from .model import VehicleModel
from .tyre.tir import P_UNLOADED_RADIUS, P_VERTICAL_STIFFNESS, load_tir


def _align_z(n: np.ndarray) -> np.ndarray:
    """The smallest rotation taking (0, 0, 1) to the unit vector n."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    sin_a, cos_a = np.linalg.norm(axis), float(z @ n)
    if sin_a < 1e-12:
        return np.eye(3)
    k = axis / sin_a
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + sin_a * kx + (1 - cos_a) * kx @ kx


class VehicleSim:
    """The vehicle model, its multibody state and the subsystem states, at fixed step dt (s)."""

    def __init__(self, model: VehicleModel, road: Road, dt: float = 1e-3, brake_pressure: float = 0.0,
                 position=(0.0, 0.0), yaw: float = 0.0, speed: float = 0.0):
        self.vm = model
        self.road = road
        self.dt = float(dt)
        cfg = model.config
        self.tyre = load_tir(Path(model.base) / cfg.tyres.property_file)
        self.tp = self.tyre.params
        self.bcfg = brake_config(cfg.brakes or None)
        self.bp = brake_params(self.bcfg)
        self.bs = brake_state(self.bp, self.dt, pressure=brake_pressure, stuck=brake_pressure > 0 and speed == 0)
        self.vd = make_vehicle_data()
        self.vd.brake_in[BI_PRESSURE_CMD] = brake_pressure
        mech = model.mech
        q0 = self._placed(mech.q0.copy(), position, yaw)
        qd0 = np.zeros_like(q0)
        self.sim = Simulation(mech, self.dt, q0=q0, qd0=qd0)
        self.data = self.sim.data
        self.m = mech.model

    def _placed(self, q: np.ndarray, position, yaw: float) -> np.ndarray:
        """Design coordinates moved onto the road: yawed by `yaw`, the design ground point under the
        centre of mass put on the road surface at `position` (x, y), the car tilted to the local road
        normal, and lowered along it so that the tyres carry their static loads."""
        tp = self.tp
        defl = self.vm.static_loads / tp[P_VERTICAL_STIFFNESS]
        wz = self.vm.design_wheel_centre[:, 2]
        dz = float(np.mean(tp[P_UNLOADED_RADIUS] - defl - wz))
        out = np.zeros(NQUERY)
        if road_query(self.road, float(position[0]), float(position[1]), out) < 0:
            raise ConfigError(f"start position {tuple(position)} is off the road")
        n = out[Q_NX:Q_NZ + 1]
        c, s = np.cos(yaw), np.sin(yaw)
        rot = _align_z(n) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        cg = np.array(self.vm.config.chassis.cg_m, dtype=float)
        ref = np.array([cg[0], cg[1], 0.0])
        target = np.array([position[0], position[1], out[Q_Z]]) + dz * n
        mech = self.vm.mech
        names = mech.coordinate_names
        res = q.copy()
        for name in {n_[:-2] for n_ in names if n_.endswith(".x")}:
            i = names.index(name + ".x")
            if name in ("chassis.u", "chassis.v", "chassis.w"):
                res[i:i + 3] = rot @ q[i:i + 3]                 # frame unit vectors rotate only
            else:
                res[i:i + 3] = rot @ (q[i:i + 3] - ref) + target
        return res

    def step(self, n: int = 1) -> None:
        m, d = self.m, self.data
        for _ in range(n):
            status = vehicle_step(m, d, self.vm.vehicle, self.vd, self.road, self.tp, self.bp, self.bs, self.dt)
            if status != OK:
                self.sim._raise(status, int(d.stats[0]) + 1)
