"""The rider (drivers.rider) on the two-wheeler: each step the rider reads the motorcycle's view and
its commands act on the handlebars, the rear wheel and the brakes. The throttle drives the engine and
gearbox of the vehicle file's [powertrain] (rtsim.vehicle.motorcycle.engine), whose rear-wheel torque
the step turns into chain tension; a vehicle without one takes the throttle as a rear-wheel torque
demand up to `max_wheel_torque_nm` (an ideal drive). Brake pressures map by the vehicle's brake gains."""
from __future__ import annotations

import numpy as np

from drivers.rider import (NRO, NRV, ST_KAPPA, ST_N, ST_PHI_FF, RO_BRAKE_F, RO_BRAKE_R, RO_THROTTLE, RO_TORQUE, RV_DELTA, RV_DELTADOT, RV_PHI,
                           RV_PHIDOT, RV_R, RV_T, RV_U, RV_V, RV_X, RV_Y, RV_YAW, rider_step)

from .build import MotorcycleModel, combine
from .engine import engine_state, pack_engine, rear_wheel_torque
from .layout import K_PHI_R
from .sim import TwoWheelerSim, rear_contact
from .step import U_BRAKE_FRONT, U_BRAKE_REAR, U_DRIVE_TORQUE, U_STEER_TORQUE

MAX_WHEEL_TORQUE = 1200.0    # N m at the rear wheel at full throttle, for a vehicle without [powertrain]


#: The commands a rider (or an open-loop profile) gives, in the order of drivers.rider's RO_* outputs.
COMMANDS = ("steering_torque", "throttle", "brake_front", "brake_rear")
assert (RO_TORQUE, RO_THROTTLE, RO_BRAKE_F, RO_BRAKE_R) == (0, 1, 2, 3)


def tyre_lean_ratio(mm: MotorcycleModel) -> float:
    """k = rho / (h - rho) of the rider's lean feed-forward (drivers.rider): the tyres' mean crown radius
    rho and the height h of the whole machine's mass centre with the rider on (0 for knife-edge wheels)."""
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
        self.view = np.zeros(NRV)
        self.out = np.zeros(NRO)
        self.max_torque = max_wheel_torque_nm
        cfg = sim.mm.config
        brakes = cfg.brakes
        self.brake_gain = (0.0, 0.0) if brakes is None else (brakes.front_nm_per_kpa, brakes.rear_nm_per_kpa)
        self.engine = None if cfg.powertrain is None else pack_engine(cfg.powertrain, cfg.final_ratio, gear)
        self.engine_state = engine_state()
        self.open_loop = {} if open_loop is None else dict(open_loop)
        unknown = set(self.open_loop) - set(COMMANDS)
        if unknown:
            raise ValueError(f"open-loop commands {sorted(unknown)}: use {', '.join(COMMANDS)}")
        self.log: list[tuple] = []

    @property
    def wheel_speed(self) -> float:
        """Rear wheel's spin rate relative to the frame, rad/s (what the gearbox sees)."""
        return float(self.sim.data.qd[self.sim.parts.idx[K_PHI_R]])

    def step(self) -> None:
        s, v, out = self.sim, self.view, self.out
        x, y = rear_contact(s)
        u, lat = s.velocity
        if self.rider is not None:
            v[RV_T], v[RV_X], v[RV_Y], v[RV_YAW] = s.time, x, y, s.yaw
            v[RV_U], v[RV_V], v[RV_R] = u, lat, s.yaw_rate
            v[RV_PHI], v[RV_PHIDOT], v[RV_DELTA], v[RV_DELTADOT] = s.roll, s.roll_rate, s.steer, s.steer_rate
            rider_step(self.rider, v, out)
        for name, f in self.open_loop.items():
            out[COMMANDS.index(name)] = f(s.time)
        inp = s.parts.u
        inp[U_STEER_TORQUE] = out[RO_TORQUE]
        if self.engine is not None:
            inp[U_DRIVE_TORQUE] = rear_wheel_torque(self.engine, self.engine_state, out[RO_THROTTLE],
                                                    self.wheel_speed, s.dt)
        else:
            inp[U_DRIVE_TORQUE] = min(max(out[RO_THROTTLE], 0.0), 1.0) * self.max_torque
        inp[U_BRAKE_FRONT] = max(out[RO_BRAKE_F], 0.0) * self.brake_gain[0]
        inp[U_BRAKE_REAR] = max(out[RO_BRAKE_R], 0.0) * self.brake_gain[1]
        s.step()
        if self.rider is not None:
            st = self.rider.st
            self.log.append((s.time, x, y, s.roll, s.steer, out[RO_TORQUE], u, st[ST_N], st[ST_PHI_FF], st[ST_KAPPA]))

    def run(self, seconds: float) -> np.ndarray:
        for _ in range(int(round(seconds / self.sim.dt))):
            self.step()
        return np.array(self.log)
