"""The sport motorcycle (configs/vehicles/motorcycle.toml) in the time domain, against references:
statics (the tyre loads carry the weight), counter-steering (Moreno Giner et al.'s open-loop torque step),
energy of the conservative variant (knife-edge tyres, no dampers, no aero), a fall ending in a status."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.configfile import load_toml, validate
from rtsim.vehicle.kit.tables import table_integral
from rtsim.vehicle.motorcycle.build import build_motorcycle
from rtsim.vehicle.motorcycle.config import MotorcycleConfig, load_motorcycle
from rtsim.vehicle.motorcycle.layout import K_THETA, K_ZETA
from rtsim.vehicle.motorcycle.sim import Fall, TwoWheelerSim, static_pose
from rtsim.vehicle.motorcycle.step import (MP_SHOCK_C0, MP_SHOCK_L0, T_FORK_SPRING, T_SHOCK_SPRING,
                                           U_STEER_TORQUE, _shock_length)

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "motorcycle.toml"
G = 9.81


@pytest.fixture(scope="module")
def bike():
    cfg, base = load_motorcycle(VEHICLE)
    return build_motorcycle(cfg, base)


@pytest.fixture(scope="module")
def pose(bike):
    return static_pose(bike)


def test_static_loads_carry_the_weight_with_the_rider_on(bike, pose):
    cfg = bike.config
    mass = sum(b.mass_kg for b in (cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork,
                                   cfg.front_wheel, cfg.rear_wheel))
    _q, loads = pose
    assert abs(loads.sum() - mass * G) < 1e-4 * mass * G
    # front share from the moment balance about the rear contact at the design geometry (the sag
    # moves the mass centre by millimetres: 1 %)
    x_cg = sum(b.mass_kg * b.cg_m[0] for b in (cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork,
                                                cfg.lower_fork)) + cfg.front_wheel.mass_kg * cfg.geometry.wheelbase_m
    assert abs(loads[0] / loads.sum() - x_cg / mass / cfg.geometry.wheelbase_m) < 0.01


def test_counter_steering_torque_step(bike, pose):
    """A steering torque to the left at 1 s: the motorcycle first yaws left, then leans right and turns
    right (Moreno Giner et al. 2008, figure 7, mirrored)."""
    q, _ = pose
    s = TwoWheelerSim(bike, speed=20.0, q=q)
    s.run(1.0)
    yaw_rates, rolls = [], []
    while s.time < 3.0 - 1e-9:
        s.parts.u[U_STEER_TORQUE] = 5.0
        s.step()
        yaw_rates.append(s.yaw_rate)
        rolls.append(s.roll)
    yaw_rates = np.array(yaw_rates)
    # the first yaw rate beyond 5 mrad/s (the frame's reaction to the torque, about 1 mrad/s for a few ms,
    # comes before it): the tyres' response to the steer
    first = yaw_rates[np.argmax(np.abs(yaw_rates) > 5e-3)]
    assert first > 0, "the initial yaw rate has the sign of the steer (left)"
    assert yaw_rates[-1] < -0.02 and rolls[-1] > 0.05, "then it leans right and turns right"


def test_straight_running_conserves_energy_without_dissipation():
    """Knife-edge tyres (no slip), dampers, steering damper and aero off: a 15 m/s run released from the
    design position (the suspensions oscillate) keeps its energy (kinetic, gravity, springs) to 1e-6."""
    data = load_toml(VEHICLE)
    data["tyres"] = {"model": "knife_edge"}
    for k in ("fork", "shock"):
        data["suspension"][k]["damper"] = {}
    data["steering"]["damper_nms_per_rad"] = 0.0
    data["aero"] = {"drag_area_m2": 0.0, "lift_area_m2": 0.0}
    mm = build_motorcycle(validate(MotorcycleConfig, data, "conservative motorcycle"), ROOT)
    s = TwoWheelerSim(mm, speed=15.0)
    p = s.parts

    def energy():
        q, qd = s.data.q, s.data.qd
        e = 0.5 * qd @ mm.mech.mass_dense @ qd - s.model.q_grav @ q
        e += table_integral(p.tab[T_FORK_SPRING], q[p.idx[K_ZETA]]) - table_integral(p.tab[T_FORK_SPRING], 0.0)
        length, _ = _shock_length(p.par, q[p.idx[K_THETA]])
        comp = p.par[MP_SHOCK_C0] + p.par[MP_SHOCK_L0] - length
        return e + table_integral(p.tab[T_SHOCK_SPRING], comp) - table_integral(p.tab[T_SHOCK_SPRING], 0.0)

    e0 = energy()
    travel = []
    worst = 0.0
    for _ in range(2000):
        s.step()
        worst = max(worst, abs(energy() - e0))
        travel.append(s.data.q[p.idx[K_ZETA]])
    assert np.ptp(travel) > 2e-3, "the fork moves (the test exercises the springs)"
    assert worst < 1e-6 * e0


def test_a_fall_ends_the_run_with_a_status(bike, pose):
    q, _ = pose
    s = TwoWheelerSim(bike, speed=3.0, q=q)
    s.parts.u[U_STEER_TORQUE] = 20.0
    with pytest.raises(Fall, match="fell"):
        s.run(10.0)
    assert np.all(np.isfinite(s.data.q))
