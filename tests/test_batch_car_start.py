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


def test_the_kept_linkage_check_answers_as_a_fresh_one():
    from rtsim.vehicle.kit import linkage_checks as lc

    cfg = open_vehicle(ROOT / "configs" / "vehicles" / "xbw.toml").config
    points = cfg.front.hardpoints.model_dump()
    bad = {**points, "tie_inner": tuple(np.array(points["tie_outer"]) + [0.0, 0.004, 0.0])}
    for hp in (points, bad, points, bad):
        assert lc.short_link(cfg.front.suspension, hp) == lc._short_link(cfg.front.suspension, hp)
    assert lc.short_link(cfg.front.suspension, points) is None
    assert lc.short_link(cfg.front.suspension, bad)[0] == "tie_inner"


@pytest.mark.parametrize("vehicle", ["xbw.toml", "eps_car.toml", "motorcycle.toml"])
def test_the_envelope_of_a_mass_matrix_holds_each_entry_of_its_profile(vehicle):
    """rtsim.mbs.envelope.to_envelope (a build's mass matrix in envelope form, vectorised) against its
    definition entry by entry: row r of the permuted matrix from its first stored column to the diagonal."""
    from rtsim.mbs import envelope

    mech = open_vehicle(ROOT / "configs" / "vehicles" / vehicle).model.mech
    m = mech.model
    rng = np.random.default_rng(7)
    for dense in (mech.mass_dense, (lambda a: a + a.T)(rng.standard_normal(mech.mass_dense.shape))):
        want = np.zeros(m.ptr[-1])
        for r in range(m.first.size):
            for c in range(m.first[r], r + 1):
                want[m.ptr[r] + c - m.first[r]] = dense[m.perm[r], m.perm[c]]
        got = envelope.to_envelope(dense, m.first, m.ptr, m.perm)
        assert got.tobytes() == want.tobytes()
    assert envelope.to_envelope(mech.mass_dense, m.first, m.ptr, m.perm).tobytes() == m.m_env.tobytes()


def test_two_models_started_in_turn_keep_their_own_starts(model):
    """A batch pool runs the cars of a plan in any order: each model's start stays kept beside the other's."""
    other = open_vehicle(ROOT / "configs" / "vehicles" / "xbw.toml").model
    road = make_plane()
    car_sim._STARTS.clear()
    cars = [car_sim.VehicleSim(m, road, 1e-3, **START) for m in (model, other, model, other)]
    assert len(car_sim._STARTS) == 2
    _same_bits(cars[0], cars[2])
    _same_bits(cars[1], cars[3])
    assert cars[2].vm is model and cars[3].vm is other


@pytest.mark.parametrize("vehicle, driven, eps", [("xbw.toml", ("rl", "rr"), False), ("eps_car.toml", None, True),
                                                  ("xbw_fwd.toml", ("fl", "fr"), False)])
def test_a_kept_channel_dictionary_is_the_cars_own(vehicle, driven, eps):
    from rtsim.channels import car_channels
    from rtsim.vehicle.car.build import vehicle_channels

    cfg = open_vehicle(ROOT / "configs" / "vehicles" / vehicle).config
    driven = driven or (("fl", "fr") if cfg.driven_axle == "front" else ("rl", "rr"))
    assert vehicle_channels(cfg) == car_channels(driven, eps=eps) and vehicle_channels(cfg) is vehicle_channels(cfg)
