"""A vehicle whose batch overrides differ from a kept one's in plain parameters only (the car's:
rtsim.vehicle.car.plain) is built on the kept one's corner fits and symbolic analysis
(rtsim.batch.models, ``VehicleKind.rebuild``): its model arrays and the rows of its runs equal a fresh
build's bit for bit, for each kind of plain parameter (a mass, an inertia, a spring stiffness, a damper,
a steering gain, a bar); a key that changes the topology builds the vehicle from scratch."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rtsim.batch import models, run
from rtsim.batch.results import VOLATILE
from rtsim.mbs import MechanismBuilder

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "configs" / "scenarios" / "step_steer_80kph.toml"
SHORT = {"scenario.duration": 0.4, "scenario.inputs.steering_wheel_angle_cmd.t0": 0.2,
         "scenario.inputs.steering_wheel_angle_cmd.after": 0.3}
JOB = {"metrics": ["peak_lateral_acceleration", "yaw_rate_overshoot", "max_constraint_violation",
                   "energy_residual_max", "peak_roll"], "param_keys": [], "per_run": "none", "out_dir": "",
       "criteria": []}
#: the symbolic analysis a rebuilt model shares with the kept one (immutable arrays)
SYMBOLIC = ("perm", "pinv", "first", "ptr", "fperm", "fcolptr", "frowidx", "fw_map", "asm_pos")


@pytest.fixture
def worker(monkeypatch):
    kept = models.OpenedVehicles()
    monkeypatch.setattr(run, "WORKER", kept)
    return kept


def _spec(vehicle: str, overrides: dict) -> dict:
    return {"run_id": "r", "case": 0, "scenario": str(SCENARIO), "vehicle": str(ROOT / "configs" / "vehicles" / vehicle),
            "seed": 0, "params": {}, "overrides": {**SHORT, **{f"vehicle.{k}": v for k, v in overrides.items()}}}


def _bits(row: dict) -> dict:
    return {k: (v.hex() if isinstance(v, float) and not math.isnan(v) else "nan" if isinstance(v, float) else v)
            for k, v in row.items() if k not in VOLATILE}


def _arrays_equal(a, b) -> None:
    for f in a._fields:
        x, y = getattr(a, f), getattr(b, f)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), f
        else:
            assert x == y, f


@pytest.mark.parametrize("vehicle, overrides", [
    ("xbw.toml", {"chassis.mass_kg": 1250.0}),                                   # a mass
    ("xbw.toml", {"chassis.inertia_kgm2": [330.0, 1000.0, 1300.0], "rear.unsprung_mass_kg": 38.0}),  # inertia
    ("xbw.toml", {"front.spring.stiffness_n_per_m": 30000.0}),                   # a stiffness
    ("xbw.toml", {"rear.spring.damping_rebound_ns_per_m": 3300.0, "front.anti_roll_bar_n_per_m": 9000.0}),
    ("xbw.toml", {"steering.rack_travel": 0.06, "front.pivot_inertia_kgm2": 0.5}),   # steering, reflected inertia
    ("eps_car.toml", {"chassis.mass_kg": 950.0}),
    ("eps_car.toml", {"eps.current_loop_gain_v_per_a": 1.5, "eps.rack_mass_kg": 4.0}),    # a gain, a mass
    ("eps_car.toml", {"eps.torsion_bar_nm_per_rad": 100.0, "aero.drag_area_m2": 0.6}),
])
def test_a_plain_parameter_builds_on_the_kept_model_bit_for_bit(worker, vehicle, overrides):
    base = run.run_one(_spec(vehicle, {}), JOB)                       # the kept vehicle: the file as it is
    assert base["status"] == "ok", base["error"]
    patched = run.run_one(_spec(vehicle, overrides), JOB)
    assert worker.built == 2 and worker.rebuilt == 1
    fresh = run.run_one(_spec(vehicle, overrides), {**JOB, "build_once": False})
    assert patched["status"] == fresh["status"] == "ok", patched["error"]
    assert _bits(patched) == _bits(fresh)
    assert _bits(patched) != _bits(base)                          # the parameter did change the run
    kept, new = list(worker.kept.values())
    from rtsim.vehicle.registry import open_vehicle
    from rtsim.configfile import overrides as with_overrides

    path = ROOT / "configs" / "vehicles" / vehicle
    with with_overrides({path.resolve(): overrides}):
        alone = open_vehicle(path).model                          # built from scratch
    _arrays_equal(new.model.mech.model, alone.mech.model)
    _arrays_equal(new.model.vehicle, alone.vehicle)
    assert new.model.static_loads.tobytes() == alone.static_loads.tobytes()
    for f in SYMBOLIC:                                             # taken from the kept model, not computed
        assert getattr(new.model.mech.model, f) is getattr(kept.model.mech.model, f)


#: keys the car applies in place (rtsim.vehicle.car.plain, IN_PLACE), a value of each for each car (the
#: EPS car's springs and dampers are tables; compliance steer needs the EPS car's pivots)
_BOTH = {"chassis.mass_kg": 1250.0, "chassis.inertia_kgm2": [330.0, 1000.0, 1300.0], "chassis.ixz_kgm2": 60.0,
         "front.anti_roll_bar_n_per_m": 9000.0, "rear.travel_stop_stiffness_n_per_m": 3e5,
         "front.travel_stop_margin_m": 0.01, "rear.anti_pitch_arm_m": 2.5, "front.anti_roll_arm_m": 3.0,
         "aero.drag_area_m2": 0.6, "aero.air_density_kg_m3": 1.1, "brakes.proportioning_knee": 2000.0,
         "powertrain.gearbox.final_drive": 4.1, "sensors.channels.gyro_z.noise_std": 0.01}
IN_PLACE_CASES = [
    *[("xbw.toml", k, v) for k, v in {
        **_BOTH, "front.spring.stiffness_n_per_m": 30000.0, "rear.spring.free_length_m": 0.45,
        "front.spring.bump_stop_clearance_m": 0.04, "rear.spring.bump_stop_stiffness_n_per_m": 3e5,
        "rear.spring.damping_rebound_ns_per_m": 3300.0, "front.spring.damping_bump_ns_per_m": 2000.0}.items()],
    *[("eps_car.toml", k, v) for k, v in {
        **_BOTH, "front.compliance_steer_rad_per_n": 2e-6, "front.compliance_steer_rad_per_nm": 1e-5,
        "front.spring.spring_table": {"x": [-0.1, 0.0, 0.05, 0.1], "force_n": [-5000.0, 0.0, 1500.0, 9000.0]},
        "rear.spring.damper_table": {"x": [-1.0, 0.0, 1.0], "force_n": [-1200.0, 0.0, 700.0]}}.items()],
]


def test_every_key_applied_in_place_is_tested():
    from fnmatch import fnmatchcase

    from rtsim.vehicle.car.plain import IN_PLACE, PLAIN, in_place

    declared = [p for p, (how, _) in PLAIN.items() if how == IN_PLACE]
    keys = [k for _, k, _ in IN_PLACE_CASES]
    assert declared and all(any(fnmatchcase(k, p) for k in keys) for p in declared)
    assert in_place(keys) and not in_place(["front.unsprung_mass_kg"]) and not in_place(["eps.driver_input"])
    assert not in_place(["chassis.mass_kg", "steering.rack_travel"])


def _snapshot(model) -> dict:
    """Every array of a car's model (the mechanism's, the vehicle's, the loads), as bytes."""
    out = {f"mech.{f}": getattr(model.mech.model, f).tobytes() for f in model.mech.model._fields
           if isinstance(getattr(model.mech.model, f), np.ndarray)}
    out.update({f"vehicle.{f}": getattr(model.vehicle, f).tobytes() for f in model.vehicle._fields})
    out.update(mass_dense=model.mech.mass_dense.tobytes(), static_loads=model.static_loads.tobytes(),
               q0=model.mech.q0.tobytes())
    return out


@pytest.mark.parametrize("vehicle, key, value", IN_PLACE_CASES)
def test_a_key_applied_in_place_gives_the_fresh_build_bit_for_bit(worker, vehicle, key, value):
    """The kept model with copies of the arrays the key reaches: every array equal to a fresh build's
    with the override, bit for bit; the kept model's arrays untouched; the rest shared with it."""
    from rtsim.configfile import overrides as with_overrides
    from rtsim.vehicle.registry import open_vehicle

    path = ROOT / "configs" / "vehicles" / vehicle
    _, kept = worker.open_run(SCENARIO, path, SHORT)
    before = _snapshot(kept.model)
    _, new = worker.open_run(SCENARIO, path, {**SHORT, f"vehicle.{key}": value})
    assert worker.built == 2 and worker.rebuilt == 1
    with with_overrides({path.resolve(): {key: value}}):
        alone = open_vehicle(path).model                          # built from scratch
    assert _snapshot(new.model) == _snapshot(alone)
    assert new.model.config == alone.config
    assert _snapshot(kept.model) == before                       # applying copied, never wrote the kept arrays
    # applied in place: the corner fits, the constraints and the symbolic analysis are the kept model's
    assert new.model.corners is kept.model.corners
    assert new.model.vehicle.corner_idx is kept.model.vehicle.corner_idx
    for f in (*SYMBOLIC, "con_idx", "con_par", "poly_coef"):
        assert getattr(new.model.mech.model, f) is getattr(kept.model.mech.model, f)
    if key.startswith("chassis."):                               # the mass matrix is the key's, the kept one's not
        assert new.model.mech.mass_dense.tobytes() != before["mass_dense"]


def test_a_mass_applied_in_place_runs_as_the_fresh_build(worker):
    """A run on the model with the chassis mass applied in place: the fresh build's row, bit for bit (its
    start on the road, the static equilibrium of the new mass, made for that model)."""
    spec = _spec("xbw.toml", {"chassis.mass_kg": 1100.0})
    run.run_one(_spec("xbw.toml", {}), JOB)
    patched = run.run_one(spec, JOB)
    again = run.run_one(spec, JOB)                                # the kept start of that model
    assert worker.rebuilt == 1 and worker.reused == 1
    fresh = run.run_one(spec, {**JOB, "build_once": False})
    assert patched["status"] == "ok", patched["error"]
    assert _bits(patched) == _bits(fresh) == _bits(again)


def test_a_topology_change_builds_from_scratch(worker):
    _, a = worker.open_run(SCENARIO, ROOT / "configs" / "vehicles" / "eps_car.toml", SHORT)
    # the driver's torque instead of the steering-wheel angle: no driver constraint row (not plain)
    _, b = worker.open_run(SCENARIO, ROOT / "configs" / "vehicles" / "eps_car.toml",
                           {**SHORT, "vehicle.eps.driver_input": "torque"})
    assert worker.built == 2 and worker.rebuilt == 0
    assert b.model.mech.model.nc == a.model.mech.model.nc - 1
    assert b.model.mech.structure != a.model.mech.structure
    # a plain parameter and a topology change together: from scratch as well
    _, c = worker.open_run(SCENARIO, ROOT / "configs" / "vehicles" / "xbw.toml",
                           {**SHORT, "vehicle.chassis.mass_kg": 900.0})
    _, d = worker.open_run(SCENARIO, ROOT / "configs" / "vehicles" / "xbw.toml",
                           {**SHORT, "vehicle.chassis.mass_kg": 1000.0, "vehicle.front.static_toe_rad": 0.002})
    assert worker.built == 4 and worker.rebuilt == 0
    assert d.model.mech.model.perm is not c.model.mech.model.perm


def _pendulum(mass: float, second: bool):
    b = MechanismBuilder(dim=2)
    o = b.fixed_point((0.0, 0.0))
    p = b.point("p", (1.0, 0.0))
    b.point_mass(p, mass)
    b.distance(o, p)
    if second:                                    # another body: another topology
        q = b.point("q", (2.0, 0.0))
        b.point_mass(q, mass)
        b.distance(p, q)
    b.gravity((0.0, -9.81))
    return b


def test_compile_reuses_the_symbolic_analysis_only_for_the_same_topology():
    one = _pendulum(1.0, False).compile()
    heavier = _pendulum(2.0, False).compile(reuse=one)
    assert heavier.model.perm is one.model.perm and heavier.structure == one.structure
    _arrays_equal(heavier.model, _pendulum(2.0, False).compile().model)
    two = _pendulum(2.0, True).compile(reuse=one)                # declared "reuse", topology differs
    assert two.structure != one.structure and two.model.nq == 4
    _arrays_equal(two.model, _pendulum(2.0, True).compile().model)


@pytest.mark.parametrize("wheel_speed", [0.0, 3.0, 35.0, 80.0])
def test_the_rolling_start_scans_in_one_compiled_call_to_the_same_bits(wheel_speed):
    """The powertrain's rolling start (rtsim.vehicle.kit.powertrain) scans the engine's net torque on
    400 speeds in one compiled call: the state of the point-by-point scan, bit for bit."""
    from rtsim.vehicle.kit.powertrain import _rolling_state, powertrain_config, powertrain_params

    p = powertrain_params(powertrain_config(None))
    a = _rolling_state(p, 1e-3, wheel_speed)
    b = _rolling_state(p, 1e-3, wheel_speed, compiled_scan=False)
    assert a.tobytes() == b.tobytes()


def test_a_two_wheelers_rows_carry_the_time_in_its_steps(worker):
    """The motorcycle's offline ride times its model's steps (the rider and the logging outside them):
    its rows have step_s, outside_s and outside_pct like a car's."""
    spec = {"run_id": "m", "case": 0, "scenario": str(ROOT / "configs" / "scenarios" / "motorcycle_double_lane_change.toml"),
            "vehicle": None, "seed": 0, "params": {}, "overrides": {"scenario.duration": 0.3}}
    job = {**JOB, "metrics": ["peak_roll"]}
    run.warm(spec, job)                 # kernels loaded (or compiled) first, as a batch worker does
    row = run.run_one(spec, job)
    assert row["status"] == "ok", row["error"]
    assert 0.0 < row["step_s"] < row["wall_s"]
    assert row["step_s"] + row["outside_s"] == pytest.approx(row["wall_s"], rel=1e-12)
    assert 0.0 < row["outside_pct"] < 100.0


@pytest.mark.parametrize("overrides", [
    {"rear_frame.mass_kg": 190.0},                                              # a mass
    {"suspension.fork.spring.stiffness_n_per_m": 18000.0, "steering.damper_nms_per_rad": 8.0},   # a spring, a damper
])
def test_a_two_wheeler_builds_on_the_kept_model_bit_for_bit(worker, overrides):
    """The two-wheeler takes nothing of a kept model but its symbolic analysis (for the same topology):
    the rows of a run on it equal a fresh build's, bit for bit."""
    scen = str(ROOT / "configs" / "scenarios" / "motorcycle_double_lane_change.toml")
    spec = {"run_id": "m", "case": 0, "scenario": scen, "vehicle": str(ROOT / "configs" / "vehicles" / "motorcycle.toml"),
            "seed": 0, "params": {}, "overrides": {"scenario.duration": 0.3}}
    job = {**JOB, "metrics": ["peak_roll", "path_error_rms", "max_constraint_violation"]}
    base = run.run_one(spec, job)
    other = {**spec, "overrides": {**spec["overrides"], **{f"vehicle.{k}": v for k, v in overrides.items()}}}
    patched = run.run_one(other, job)
    fresh = run.run_one(other, {**job, "build_once": False})
    assert base["status"] == patched["status"] == fresh["status"] == "ok", patched["error"]
    assert worker.rebuilt == 1 and _bits(patched) == _bits(fresh) and _bits(patched) != _bits(base)
    kept, new = list(worker.kept.values())
    for f in SYMBOLIC:
        assert getattr(new.model.mech.model, f) is getattr(kept.model.mech.model, f)


def test_a_two_wheelers_topology_change_computes_its_symbolic_analysis(worker):
    scen = ROOT / "configs" / "scenarios" / "motorcycle_double_lane_change.toml"
    bike = ROOT / "configs" / "vehicles" / "motorcycle.toml"
    _, a = worker.open_run(scen, bike, {})
    _, b = worker.open_run(scen, bike, {"vehicle.suspension.locked": True})     # two more constraint rows
    assert worker.rebuilt == 1                     # built on a: only a same topology would share its analysis
    assert b.model.mech.model.nc == a.model.mech.model.nc + 2
    assert b.model.mech.structure != a.model.mech.structure
    assert b.model.mech.model.perm is not a.model.mech.model.perm


def test_the_two_wheelers_static_pose_is_settled_once_per_model():
    """Every ride of a two-wheeler starts from its static pose (1.5 s of settling simulated): kept per
    model, each call gets copies equal to a settling simulated afresh, bit for bit."""
    from rtsim.vehicle.motorcycle.sim import TO_FZ, TwoWheelerSim, static_pose
    from rtsim.vehicle.registry import open_vehicle

    mm = open_vehicle(ROOT / "configs" / "vehicles" / "motorcycle.toml").model
    q1, f1 = static_pose(mm, seconds=0.3)
    q2, f2 = static_pose(mm, seconds=0.3)
    s = TwoWheelerSim(mm, dt=1e-3)
    s.run(0.3)
    assert q1 is not q2 and q1.tobytes() == q2.tobytes() == s.data.q.tobytes()
    assert f1.tobytes() == f2.tobytes() == s.parts.tyre[:, TO_FZ].tobytes()
    q1[:] = 0.0                                    # a caller's copy: the kept pose is untouched
    assert static_pose(mm, seconds=0.3)[0].tobytes() == q2.tobytes()
