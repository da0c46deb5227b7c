"""A batch starts many runs of one car from the same place: the car's start on the road
(rtsim.vehicle.car.sim.VehicleSim: the placed and assembled mechanism, the subsystems' states, the
powertrain's rolling start, the sensor model) is made once per model, road and place and copied. The
copy must be the fresh start bit for bit, share no state array with it or with the next copy, and step
to the same states as a car started afresh."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.mbs import simulation as mbs_simulation
from rtsim.road.model import make_plane
from rtsim.vehicle.car import sim as car_sim
from rtsim.vehicle.registry import open_vehicle

ROOT = Path(__file__).resolve().parents[1]
START = {"brake_pressure": 0.0, "position": (1.0, -2.0), "yaw": 0.3, "speed": 22.0}


@pytest.fixture(scope="module")
def model():
    return open_vehicle(ROOT / "configs" / "vehicles" / "eps_car.toml").model


def _fresh(model, road, **kw) -> car_sim.VehicleSim:
    car_sim._STARTS.clear()
    mbs_simulation._STARTS.clear()
    sim = car_sim.VehicleSim(model, road, 1e-3, **{**START, **kw})
    car_sim._STARTS.clear()
    return sim


def _state_arrays(sim) -> dict[str, np.ndarray]:
    out = {}
    for group in ("parts", "states", "vd", "io", "data"):
        t = getattr(sim, group)
        for f in t._fields:
            out[f"{group}.{f}"] = getattr(t, f)
    out["sim._mref"], out["sim._jn"] = sim.sim._mref, sim.sim._jn
    return out


def _same_bits(a, b) -> None:
    xa, xb = _state_arrays(a), _state_arrays(b)
    assert xa.keys() == xb.keys()
    for k in xa:
        assert xa[k].dtype == xb[k].dtype and xa[k].shape == xb[k].shape and xa[k].tobytes() == xb[k].tobytes(), k
    assert a.effects == b.effects and a.nsensor == b.nsensor and a.dt == b.dt
    assert a.sim.position_correction == b.sim.position_correction


def test_a_kept_start_is_the_fresh_start_bit_for_bit_and_shares_no_state(model):
    road = make_plane()
    fresh = _fresh(model, road)
    first = car_sim.VehicleSim(model, road, 1e-3, **START)        # made, and kept
    second = car_sim.VehicleSim(model, road, 1e-3, **START)       # copied from the kept start
    _same_bits(fresh, first)
    _same_bits(fresh, second)
    kept = set(map(id, _state_arrays(first).values())) | set(map(id, _state_arrays(fresh).values()))
    shared = {k for k, a in _state_arrays(second).items() if id(a) in kept}
    assert shared == {"parts.tyre", "sim._mref", "sim._jn"}          # the tyre file's and read-only ones
    assert second.data is second.sim.data and second.sim is not first.sim
    # a run writes into its car: the next copy starts from the kept start, not from that run's end
    second.step(50)
    second.parts.brake[:] = -1.0
    third = car_sim.VehicleSim(model, road, 1e-3, **START)
    _same_bits(fresh, third)


def test_a_copied_start_steps_like_a_fresh_one(model):
    road = make_plane()
    fresh = _fresh(model, road)
    car_sim.VehicleSim(model, road, 1e-3, **START)
    copy = car_sim.VehicleSim(model, road, 1e-3, **START)
    for car in (fresh, copy):
        car.io.commands[2] = 0.4                  # a steering-wheel step
        car.step(200)
    _same_bits(fresh, copy)


@pytest.mark.parametrize("change", [{"speed": 21.0}, {"position": (1.0, -2.5)}, {"yaw": -0.3},
                                    {"brake_pressure": 300.0}])
def test_another_place_or_speed_starts_afresh(model, change):
    road = make_plane()
    car_sim.VehicleSim(model, road, 1e-3, **START)
    other = car_sim.VehicleSim(model, road, 1e-3, **{**START, **change})
    _same_bits(_fresh(model, road, **change), other)


def test_another_road_or_effects_start_afresh(model):
    road = make_plane()
    car_sim.VehicleSim(model, road, 1e-3, **START)
    other_road = make_plane()
    assert car_sim.VehicleSim(model, other_road, 1e-3, **START).road is other_road
    effects = {"sensor_bias": [{"channel": "gyro_z", "bias": -0.002}]}
    with_effects = car_sim.VehicleSim(model, road, 1e-3, effects=effects, **START)
    assert with_effects.effects == car_sim.VehicleSim(model, road, 1e-3, effects=effects, **START).effects
    assert car_sim.VehicleSim(model, road, 1e-3, **START).effects == {}
