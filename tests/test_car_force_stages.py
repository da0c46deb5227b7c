"""The car's force stages (rtsim.vehicle.car.forces): while the power audit is on, every generalized force
a stage adds is also in its force record (a row of VehicleData.pf), so the audit, a sum over the records,
sees every force. Reference: the total the stages add to d.force, which must equal the sum of the
records' rows. With the audit off the records are not written and the forces are the same, bit for bit."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rtsim.road.model import make_plane
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.forces import vehicle_forces
from rtsim.vehicle.car.layout import NPORT, PORT_BRAKE, PORT_DRIVE, PORT_EFFECTS, PORT_TYRE
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE

ROOT = Path(__file__).resolve().parents[1]
# effects that add forces of their own or change a stage's (bearing drag, added mass, road grade,
# driveline compliance, aero drag, rolling resistance)
EFFECTS = {"bearing_drag": {"torque": 2.0}, "mass": {"added_mass": 80.0}, "road_grade": {"grade": 0.05},
           "driveline_compliance": {"stiffness": 20000.0}, "aero_drag": {"drag_area": 0.2},
           "rolling_resistance": {"coefficient": 0.01}}


def _cornering_and_braking(name: str, effects) -> VehicleSim:
    vm = build_vehicle(*load_vehicle(ROOT / "configs" / "vehicles" / f"{name}.toml"))
    sim = VehicleSim(vm, make_plane(), 1e-3, speed=15.0, effects=effects)
    sim.io.commands[CMD_STEER] = 0.5
    sim.io.commands[CMD_THROTTLE] = 0.2
    sim.step(300)
    sim.io.commands[CMD_THROTTLE] = 0.0
    sim.io.commands[CMD_BRAKE] = 2000.0
    sim.step(300)
    return sim


def _evaluate(sim: VehicleSim) -> None:
    """One evaluation of the force stages at the present state, into a zeroed d.force."""
    d = sim.data
    d.force[:] = 0.0
    h = sim.dt
    bad = vehicle_forces(sim.m, d, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states, False, 0.25 * h * h,
                         0.5 * h)
    assert bad == -1


@pytest.mark.parametrize("name", ["xbw", "eps_car"])
@pytest.mark.parametrize("with_effects", [False, True])
def test_the_force_records_sum_to_the_force_the_stages_add(name, with_effects):
    sim = _cornering_and_braking(name, EFFECTS if with_effects else None)
    d = sim.data
    sim.vd.audit[0] = 1.0
    _evaluate(sim)
    pf = sim.vd.pf
    assert pf.shape[0] == NPORT
    total = pf.sum(axis=0)
    scale = np.max(np.abs(d.force))
    np.testing.assert_allclose(total, d.force, rtol=0.0, atol=1e-12 * scale)
    # the records are the stages' own: tyres, brakes and drive all act in this state
    for port in (PORT_TYRE, PORT_BRAKE, PORT_DRIVE):
        assert np.any(pf[port] != 0.0)
    assert np.any(pf[PORT_EFFECTS] != 0.0) == with_effects
    assert math.isfinite(scale) and scale > 0.0


@pytest.mark.parametrize("name", ["xbw", "eps_car"])
def test_with_the_audit_off_the_records_are_not_written_and_the_forces_are_the_same(name):
    sim = _cornering_and_braking(name, EFFECTS)
    assert sim.vd.audit[0] == 0.0
    sim.vd.pf[:] = np.nan                 # anything a stage wrote would show
    _evaluate(sim)
    off = sim.data.force.copy()
    assert np.all(np.isnan(sim.vd.pf))
    sim.vd.audit[0] = 1.0
    _evaluate(sim)
    assert np.all(np.isfinite(sim.vd.pf))
    assert off.tobytes() == sim.data.force.tobytes()
