"""The rider (drivers.rider) on the two-wheeler: each step the rider reads the motorcycle's view and
its commands act on the handlebars, the rear wheel and the brakes. The throttle maps linearly to the
rear-wheel torque (`max_wheel_torque_nm`) until the engine model drives the chain; brake pressures map
by the vehicle's brake gains."""
from __future__ import annotations

import numpy as np

from drivers.rider import (NRO, NRV, ST_KAPPA, ST_N, ST_PHI_FF, RO_BRAKE_F, RO_BRAKE_R, RO_THROTTLE, RO_TORQUE, RV_DELTA, RV_DELTADOT, RV_PHI,
                           RV_PHIDOT, RV_R, RV_T, RV_U, RV_V, RV_X, RV_Y, RV_YAW, rider_step)

from .build import MotorcycleModel, combine
from .sim import TwoWheelerSim, rear_contact
from .step import U_BRAKE_FRONT, U_BRAKE_REAR, U_DRIVE_TORQUE, U_STEER_TORQUE

MAX_WHEEL_TORQUE = 1200.0    # N m at the rear wheel at full throttle (about 110 N m crank in second gear)


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
    """A rider on a two-wheeler sim; `log` collects (t, x, y, roll, steer, torque, speed, n, phi_ff) rows."""

    def __init__(self, sim: TwoWheelerSim, rider, max_wheel_torque_nm: float = MAX_WHEEL_TORQUE):
        self.sim, self.rider = sim, rider
        self.view = np.zeros(NRV)
        self.out = np.zeros(NRO)
        self.max_torque = max_wheel_torque_nm
        brakes = sim.mm.config.brakes
        self.brake_gain = (0.0, 0.0) if brakes is None else (brakes.front_nm_per_kpa, brakes.rear_nm_per_kpa)
        self.log: list[tuple] = []

    def step(self) -> None:
        s, v = self.sim, self.view
        x, y = rear_contact(s)
        u, lat = s.velocity
        v[RV_T], v[RV_X], v[RV_Y], v[RV_YAW] = s.time, x, y, s.yaw
        v[RV_U], v[RV_V], v[RV_R] = u, lat, s.yaw_rate
        v[RV_PHI], v[RV_PHIDOT], v[RV_DELTA], v[RV_DELTADOT] = s.roll, s.roll_rate, s.steer, s.steer_rate
        rider_step(self.rider, v, self.out)
        inp = s.parts.u
        inp[U_STEER_TORQUE] = self.out[RO_TORQUE]
        inp[U_DRIVE_TORQUE] = self.out[RO_THROTTLE] * self.max_torque
        inp[U_BRAKE_FRONT] = self.out[RO_BRAKE_F] * self.brake_gain[0]
        inp[U_BRAKE_REAR] = self.out[RO_BRAKE_R] * self.brake_gain[1]
        s.step()
        st = self.rider.st
        self.log.append((s.time, x, y, s.roll, s.steer, self.out[RO_TORQUE], u, st[ST_N], st[ST_PHI_FF], st[ST_KAPPA]))

    def run(self, seconds: float) -> np.ndarray:
        for _ in range(int(round(seconds / self.sim.dt))):
            self.step()
        return np.array(self.log)
