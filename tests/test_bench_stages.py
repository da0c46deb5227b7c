"""`rtsim bench --suite vehicle --stages` (rtsim.benchmarks.stages) times the vehicles' steps stage by
stage in loops of their own; those loops must compute what the vehicles' own steps compute. Reference:
the plain step (rtsim.vehicle.car.step.vehicle_advance, rtsim.vehicle.motorcycle.step.two_wheeler_step)
from a copy of the same state: the trajectories are identical bit for bit, and the counts the report
gives per step are the integrator's own statistics."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from rtsim.benchmarks import stages as S
from rtsim.benchmarks.vehicle import _vehicle
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.car.step import CMD_STEER, CMD_THROTTLE, vehicle_advance


def _state(sim):
    return (sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states, sim.io)


def _copy(x):
    """Deep copy of (named) tuples of arrays; readonly arrays stay readonly (numba types them apart: a
    writable copy would compile a second specialization of the vehicle's kernels)."""
    if isinstance(x, np.ndarray):
        c = x.copy()
        c.setflags(write=x.flags.writeable)
        return c
    if isinstance(x, tuple):
        items = [_copy(v) for v in x]
        return type(x)(*items) if hasattr(type(x), "_fields") else tuple(items)
    return copy.copy(x)


@pytest.mark.parametrize("vehicle", ["xbw", "eps_car"])
def test_staged_car_step_is_the_car_step(vehicle):
    model, road = _vehicle(None, vehicle)
    sim = VehicleSim(model, road, 1e-3, speed=22.22, position=(2.0, 0.0))
    sim.io.commands[CMD_THROTTLE] = 0.2
    sim.io.commands[CMD_STEER] = np.radians(35.0)
    sim.step(50)
    plain, staged = _copy(_state(sim)), _copy(_state(sim))
    cyc = np.zeros(S.NSLOTS, dtype=np.int64)
    s0 = staged[1].stats.copy()
    assert vehicle_advance(*plain, sim.dt, 400) == (0, 400)
    assert S.car_steps_staged(*staged, sim.dt, 400, cyc) == (0, 400)
    for name in ("q", "qd", "qdd", "lam", "stats"):
        assert getattr(plain[1], name).tobytes() == getattr(staged[1], name).tobytes(), name
    assert plain[3].slip.tobytes() == staged[3].slip.tobytes()
    assert plain[7].signals.tobytes() == staged[7].signals.tobytes()
    assert not np.array_equal(plain[1].q, sim.data.q)               # it did move
    r = S.stage_report(vehicle, cyc, s0, staged[1].stats, 400, car=True)
    assert r["newton_iterations_per_step"] == (staged[1].stats[1] - s0[1]) / 400 >= 1.0
    # one evaluation per Newton iteration; none at the converged state (the car keeps Newton's factor and
    # the last iteration's forces: Settings.finish_forces), and a tangent only where Newton refactors
    assert r["force_evaluations_per_step"] == pytest.approx(r["newton_iterations_per_step"])
    assert r["tangent_evaluations_per_step"] == pytest.approx(r["factorizations_per_step"])
    assert all(v >= 0.0 for v in r["stages_us"].values())


def test_staged_two_wheeler_step_is_the_two_wheeler_step():
    from rtsim.benchmarks.vehicle import motorcycle_turning
    from rtsim.vehicle.motorcycle.step import two_wheeler_step

    sim = motorcycle_turning()
    p = sim.parts
    parts = (p.idx, p.par, p.tab, p.u, p.tp, p.slip, p.tyre)
    a = (_copy(sim.model), _copy(sim.data), _copy(parts))
    b = (_copy(sim.model), _copy(sim.data), _copy(parts))
    for _ in range(300):
        assert two_wheeler_step(a[0], a[1], 1e-3, *a[2]) == 0
    assert S.two_wheeler_steps_staged(b[0], b[1], 1e-3, *b[2], 300, np.zeros(S.NSLOTS, dtype=np.int64)) == (0, 300)
    for name in ("q", "qd", "qdd", "lam", "stats"):
        assert getattr(a[1], name).tobytes() == getattr(b[1], name).tobytes(), name
    assert a[2][5].tobytes() == b[2][5].tobytes()                  # the tyres' relaxation states
