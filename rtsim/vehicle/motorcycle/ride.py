"""The rider (rtsim.vehicle.motorcycle.rider) on the two-wheeler: each step the rider reads the motorcycle's view and
its commands act on the handlebars, the rear wheel and the brakes, through the same kernels as in the
HIL service (rtsim.vehicle.motorcycle.plant, with no bus commands): the throttle drives the engine and
gearbox of the vehicle file's [powertrain] (rtsim.vehicle.motorcycle.engine), whose rear-wheel torque
the step turns into chain tension; a vehicle without one takes the throttle as a rear-wheel torque
demand up to `max_wheel_torque_nm` (an ideal drive). Brake pressures map by the vehicle's brake gains."""
from __future__ import annotations

import time

import numpy as np

from .rider import (RiderState, RO_BRAKE_F, RO_BRAKE_R, RO_THROTTLE, RO_TORQUE, RV_PHI, RV_DELTA, RV_U, RV_X, RV_Y,
                    rider_step)

from .build import MotorcycleModel, combine
from .layout import K_PHI_R
from .plant import INVALID_SLOTS, MAX_WHEEL_TORQUE, NCOMMAND, PP_MAX_DRIVE, make_plant, plant_inputs, plant_view
from .sim import TwoWheelerSim


#: The commands a rider (or an open-loop profile) gives, in the order of rtsim.vehicle.motorcycle.rider's RO_* outputs.
COMMANDS = ("steering_torque", "throttle", "brake_front", "brake_rear")
assert (RO_TORQUE, RO_THROTTLE, RO_BRAKE_F, RO_BRAKE_R) == (0, 1, 2, 3)


def tyre_lean_ratio(mm: MotorcycleModel) -> float:
    """k = rho / (h - rho) of the rider's lean feed-forward (rtsim.vehicle.motorcycle.rider): the tyres' mean
    crown radius rho and the height h of the whole machine's mass centre with the rider on (0 for knife-edge wheels)."""
    cfg = mm.config
    if mm.knife_edge:
        return 0.0
    from .config import Body

    wheels = [Body(mass_kg=w.mass_kg, cg_m=(x, w.radius_m)) for w, x in
              ((cfg.front_wheel, cfg.geometry.wheelbase_m), (cfg.rear_wheel, 0.0))]
    _m, cg, _i = combine(cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork, *wheels)
    rho = 0.5 * (cfg.tyres.front.crown_radius_m + cfg.tyres.rear.crown_radius_m)
    return rho / (cg[2] - rho)


class Ride:
    """A rider on a two-wheeler sim; `log` collects (t, x, y, roll, steer, torque, speed, n, phi_ff, kappa)
    rows. rider None: no rider (open loop, the commands from `open_loop`). gear: a fixed gear for the
    engine (None: the vehicle file's choice; 0: automatic). open_loop: functions of time replacing the
    rider's commands, by the names of `COMMANDS` (steering torque N m, throttle 0..1, brake pressures
    kPa)."""

    def __init__(self, sim: TwoWheelerSim, rider, max_wheel_torque_nm: float = MAX_WHEEL_TORQUE,
                 gear: int | None = None, open_loop: dict | None = None):
        self.sim, self.rider = sim, rider
        self.params, self.state = make_plant(sim.mm, rider is not None, gear)
        self.params.pp[PP_MAX_DRIVE] = max_wheel_torque_nm
        self.view, self.out = self.state.rider_view, self.state.rider_out
        self.engine = self.params.ep if sim.mm.config.powertrain is not None else None
        self.engine_state = self.state.es
        self.commands = np.zeros(NCOMMAND)
        self.commands[list(INVALID_SLOTS.values())] = 1.0          # no bus: the rider's demands act
        self.open_loop = {} if open_loop is None else dict(open_loop)
        unknown = set(self.open_loop) - set(COMMANDS)
        if unknown:
            raise ValueError(f"open-loop commands {sorted(unknown)}: use {', '.join(COMMANDS)}")
        self.log: list[tuple] = []
        self.step_s = 0.0        # s of wall time inside the two-wheeler's steps (the sim's step alone)

    @property
    def wheel_speed(self) -> float:
        """Rear wheel's spin rate relative to the frame, rad/s (what the gearbox sees)."""
        return float(self.sim.data.qd[self.sim.parts.idx[K_PHI_R]])

    def step(self) -> None:
        s, v, out = self.sim, self.view, self.out
        p = s.parts
        plant_view(s.data, p.idx, self.params.pp, v)
        if self.rider is not None:
            rider_step(self.rider, v, out)
        for name, f in self.open_loop.items():
            out[COMMANDS.index(name)] = f(s.time)
        plant_inputs(self.params.pp, self.params.ep, self.state.es, self.commands, out, p.u, self.state.inp,
                     self.wheel_speed, s.dt)
        x, y, u = v[RV_X], v[RV_Y], v[RV_U]
        t0 = time.perf_counter()
        try:
            s.step()
        finally:
            self.step_s += time.perf_counter() - t0
        if self.rider is not None:
            st = self.rider.st
            self.log.append((s.time, x, y, v[RV_PHI], v[RV_DELTA], out[RO_TORQUE], u, st[RiderState.N],
                             st[RiderState.PHI_FF], st[RiderState.KAPPA]))

    def run(self, seconds: float) -> np.ndarray:
        for _ in range(int(round(seconds / self.sim.dt))):
            self.step()
        return np.array(self.log)
