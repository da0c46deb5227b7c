"""A vehicle on a road: builds everything from the configuration, places the car on the road in
static equilibrium, and steps it (compiled) with the subsystems' states."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rtsim.channels import WHEELS
from rtsim.errors import ConfigError
from rtsim.mbs import Simulation
from rtsim.mbs.model import OK, Data
from rtsim.road.model import Road
from rtsim.road.query import NQUERY, Q_NX, Q_NZ, Q_Z, road_query

from .brake import brake_config, brake_params, brake_state
from .dynamics import (CMD_BRAKE, Parts, States, VehicleData, make_io, make_vehicle_data, vehicle_advance,
                       vehicle_mbs_step)
from .model import VehicleModel
from .powertrain import PP_MEASURED, powertrain_config, powertrain_params, powertrain_state
from .sensors import NSENSOR, true_sensors
from .steering import steering_config, steering_params, steering_state
from .tyre.magic_formula import effective_rolling_radius
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
        self.bcfg = brake_config(cfg.brakes or None, "brakes")
        bp = brake_params(self.bcfg)
        bs = brake_state(bp, self.dt, pressure=brake_pressure, stuck=brake_pressure > 0 and speed == 0)
        self.ptcfg = powertrain_config(cfg.powertrain or None, "powertrain")
        pp = powertrain_params(self.ptcfg)
        ps = powertrain_state(pp, self.dt)
        self.vd = make_vehicle_data()
        self.parts = Parts(self.tp, bp, pp, np.zeros(0))
        self.states = States(bs, ps, np.zeros(0))
        mech = model.mech
        q0, qd0 = self._placed(mech.q0.copy(), position, yaw, speed)
        self.sim = Simulation(mech, self.dt, q0=q0, qd0=qd0)
        self.data = self.sim.data
        self.m = mech.model
        steer = dict(cfg.steering)
        self.rack_inertia = self._probe_rack_inertia()
        steer.setdefault("linkage_mass", self.rack_inertia)
        self.stcfg = steering_config(steer, "steering")
        sp = steering_params(self.stcfg)
        ss = steering_state(sp, self.dt)
        self.parts = Parts(self.tp, bp, pp, sp)
        self.states = States(bs, ps, ss)
        self.io = make_io()
        self.io.commands[CMD_BRAKE] = brake_pressure

    def _placed(self, q: np.ndarray, position, yaw: float, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """Design coordinates moved onto the road: yawed by `yaw`, the design ground point under the
        centre of mass put on the road surface at `position` (x, y), the car tilted to the local road
        normal, and lowered along it so that the tyres carry their static loads; velocities of a car
        rolling straight ahead at `speed` (m/s), wheels spinning at speed / rolling radius."""
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
        vel = np.zeros_like(q)
        heading = rot @ np.array([1.0, 0.0, 0.0])
        for name in {n_[:-2] for n_ in names if n_.endswith(".x")}:
            i = names.index(name + ".x")
            if name in ("chassis.u", "chassis.v", "chassis.w"):
                res[i:i + 3] = rot @ q[i:i + 3]                 # frame unit vectors rotate only
            else:
                res[i:i + 3] = rot @ (q[i:i + 3] - ref) + target
                vel[i:i + 3] = speed * heading
        for i, w in enumerate(WHEELS):
            re = float(effective_rolling_radius(tp, self.vm.static_loads[i]))
            vel[names.index(f"spin_{w}")] = speed / re
        return res, vel

    def _probe_rack_inertia(self, accel: float = 0.2, steps: int = 20) -> float:
        """The inertia (kg) the guided linkage presents at the rack, measured on copies of the state:
        the change of the rack reaction per unit of imposed rack acceleration. The steering model
        needs it to take the inertial part out of the (one step late) rack force."""
        lam = []
        for a in (0.0, accel):
            d = Data(*[x.copy() for x in self.data])
            vd = VehicleData(*[x.copy() for x in self.vd])
            bs = self.states.brake.copy()
            k = self.vm.vehicle.rack_driver
            for n in range(1, steps + 1):
                t = n * self.dt
                d.drv_ext[k] = (0.5 * a * t * t, a * t, a)
                status = vehicle_mbs_step(self.m, d, self.vm.vehicle, vd, self.road, self.tp, self.parts.brake,
                                          bs, self.dt)
                if status != OK:
                    self.sim._raise(status, n)
            lam.append(float(d.lam[self.vm.vehicle.rack_con]))
        return abs(lam[1] - lam[0]) / accel

    def set_torque_mode(self, measured: bool) -> None:
        """Drive with the measured wheel torques (io.extra) instead of the engine model."""
        self.parts.powertrain[PP_MEASURED] = 1.0 if measured else 0.0

    def step(self, n: int = 1) -> None:
        """n steps with the commands in self.io held; raises a typed SimulationError on failure."""
        status, done = vehicle_advance(self.m, self.data, self.vm.vehicle, self.vd, self.road, self.parts,
                                       self.states, self.io, self.dt, n)
        if status != OK:
            self.sim._raise(status, int(self.data.stats[0]) + 1)

    def sensors(self, out: np.ndarray | None = None) -> np.ndarray:
        """True (noise-free) sensor channels of the current state, rtsim.channels.SENSOR_NAMES order."""
        out = np.zeros(NSENSOR) if out is None else out
        true_sensors(self.m, self.data, self.vm.vehicle, self.io.signals, out)
        return out
