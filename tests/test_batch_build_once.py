"""A batch worker builds each distinct vehicle once (rtsim.batch.models): a reduced step_steer_sweep run
with the worker's kept vehicles gives the rows of the same runs built afresh every run, bit for bit
(a run that left anything in a kept model would change the next run of that vehicle); another vehicle
override is another vehicle, built afresh; and the timing columns account for the run's wall time
(the time in the model's steps plus the time outside them)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from rtsim.batch import models, run
from rtsim.batch.cli import copy_row, timing_summary
from rtsim.batch.expand import expand
from rtsim.batch.plan import load_plan
from rtsim.batch.results import VOLATILE

ROOT = Path(__file__).resolve().parents[1]
SWEEP = ROOT / "configs" / "batch" / "step_steer_sweep.toml"
DURATION = 0.4        # s simulated per run (the sweep's step comes at 0.3 s)


@pytest.fixture
def worker(monkeypatch):
    """A fresh set of kept vehicles for this test (the module's worker set replaced)."""
    kept = models.OpenedVehicles()
    monkeypatch.setattr(run, "WORKER", kept)
    return kept


def _reduced() -> tuple[list[dict], dict]:
    """Both cars, the lightest and heaviest mass, the smallest and largest step, seed 0, 0.4 s each;
    ordered so that each vehicle comes back after the other one has run."""
    plan, base = load_plan(SWEEP)
    job = {"metrics": list(plan.metrics), "param_keys": list(plan.grid), "per_run": "none", "out_dir": "",
           "criteria": [(c.metric, c.min, c.max) for c in plan.criteria]}
    keep = []
    for s in expand(plan, base):
        p = s["params"]
        if s["seed"] == plan.seed_base and p["vehicle.chassis.mass_kg"] in (800.0, 1400.0) and \
                p["scenario.inputs.steering_wheel_angle_cmd.after"] in (0.05, 0.5):
            keep.append({**s, "overrides": {**s["overrides"], "scenario.duration": DURATION}})
    keep.sort(key=lambda s: (s["params"]["scenario.inputs.steering_wheel_angle_cmd.after"], s["case"],
                             s["params"]["vehicle.chassis.mass_kg"]))
    return keep, job


def _identity(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in VOLATILE}


def test_build_once_rows_equal_fresh_builds_bit_for_bit(worker):
    specs, job = _reduced()
    assert len(specs) == 8
    kept = [run.run_one(s, job) for s in specs]
    fresh = [run.run_one(s, {**job, "build_once": False}) for s in specs]
    assert worker.built == 4 and worker.reused == 4          # 2 cars x 2 masses, each built once
    assert worker.rebuilt == 2                               # the second mass of each on the first's model
    assert len(worker.scenarios) == 2                        # the 2 steering steps, each read once
    for a, b in zip(kept, fresh):
        assert a["status"] == "ok", a["error"]
        ia, ib = _identity(a), _identity(b)
        assert ia.keys() == ib.keys()
        for k in ia:              # floats compared by their bits: NaN == NaN, -0.0 != 0.0
            va, vb = ia[k], ib[k]
            if isinstance(va, float):
                assert math.isnan(va) and math.isnan(vb) or va.hex() == vb.hex(), (a["run_id"], k, va, vb)
            else:
                assert va == vb, (a["run_id"], k)


def test_a_scenario_is_read_once_per_file_and_overrides(worker, monkeypatch):
    """The worker reads a scenario once for each distinct scenario overrides; the vehicle's overrides do not
    make it another scenario (the runs' rows are the fresh reads' bit for bit: the test above)."""
    import drivers.scenario as scenario

    reads = []
    load = scenario.load_scenario
    monkeypatch.setattr(scenario, "load_scenario", lambda *a, **k: reads.append(a[0]) or load(*a, **k))
    scen = ROOT / "configs" / "scenarios" / "step_steer_80kph.toml"
    car = ROOT / "configs" / "vehicles" / "xbw.toml"
    short = {"scenario.duration": DURATION}
    a, _ = worker.open_run(scen, car, short)
    b, _ = worker.open_run(scen, car, {**short, "vehicle.chassis.mass_kg": 1000.0})
    c, _ = worker.open_run(scen, car, {**short, "scenario.inputs.steering_wheel_angle_cmd.after": 0.2})
    assert b is a and c is not a and len(reads) == 2
    assert c.spec.inputs.steering_wheel_angle_cmd.after == 0.2 and a.spec.inputs.steering_wheel_angle_cmd.after != 0.2
    with pytest.raises(Exception, match="duration"):       # a bad value is read (and refused) every time
        worker.open_run(scen, car, {"scenario.duration": -1.0})
    with pytest.raises(Exception, match="duration"):
        worker.open_run(scen, car, {"scenario.duration": -1.0})
    assert len(reads) == 4 and len(worker.scenarios) == 2


def test_another_vehicle_override_builds_afresh_a_scenario_override_does_not(worker):
    scen = ROOT / "configs" / "scenarios" / "step_steer_80kph.toml"
    car = ROOT / "configs" / "vehicles" / "xbw.toml"
    short = {"scenario.duration": DURATION}
    _, a = worker.open_run(scen, car, short)
    _, b = worker.open_run(scen, car, {**short, "scenario.inputs.steering_wheel_angle_cmd.after": 0.2})
    assert b is a and worker.built == 1 and worker.reused == 1
    _, c = worker.open_run(scen, car, {**short, "vehicle.tyres.model": "linear"})       # another tyre model
    _, d = worker.open_run(scen, car, {**short, "vehicle.chassis.mass_kg": 1000.0})     # a plain parameter
    assert worker.built == 3 and worker.rebuilt == 1 and len({id(a), id(c), id(d)}) == 3   # d on a's model
    assert c.config.tyres.model == "linear" and a.config.tyres.model != "linear"
    assert d.model.config.chassis.mass_kg == 1000.0 != a.model.config.chassis.mass_kg
    _, e = worker.open_run(scen, car, {"vehicle.tyres.model": "linear", **short})       # the same as c
    assert e is c and worker.built == 3


def test_kept_vehicles_are_bounded(worker):
    worker.keep = 2
    scen = ROOT / "configs" / "scenarios" / "step_steer_80kph.toml"
    car = ROOT / "configs" / "vehicles" / "xbw.toml"
    for m in (900.0, 1000.0, 1100.0):
        worker.open_run(scen, car, {"vehicle.chassis.mass_kg": m})
    assert len(worker.kept) == 2 and worker.built == 3
    worker.open_run(scen, car, {"vehicle.chassis.mass_kg": 900.0})     # the least recently used went first
    assert worker.built == 4


def test_timing_columns_add_up_to_the_wall_time(worker):
    specs, job = _reduced()
    rows = [run.run_one(s, job) for s in specs[:3]]
    for r in rows:
        assert 0.0 < r["step_s"] < r["wall_s"]
        assert r["step_s"] + r["outside_s"] == pytest.approx(r["wall_s"], rel=1e-12, abs=1e-12)
        assert r["outside_pct"] == pytest.approx(100.0 * r["outside_s"] / r["wall_s"], rel=1e-12)
    copy = copy_row(rows[0], {**specs[0], "run_id": "copy", "seed": 1}, job)
    assert copy["wall_s"] == copy["step_s"] == copy["outside_s"] == 0.0 and math.isnan(copy["outside_pct"])
    line = timing_summary(rows + [copy])          # the copy is no simulated run: left out
    wall, step = sum(r["wall_s"] for r in rows), sum(r["step_s"] for r in rows)
    assert f"outside them {wall - step:.2f} s ({100.0 * (wall - step) / wall:.1f} % of {wall:.2f} s" in line
    between = sum(r["between_s"] for r in rows if math.isfinite(r["between_s"]))   # a first row: NaN
    assert f"; between runs {between:.2f} s (per run median" in line
    bad = run.run_one({**specs[0], "overrides": {**specs[0]["overrides"], "scenario.duration": -1.0}}, job)
    assert bad["status"] == "config_error"
    assert bad["step_s"] == 0.0 and bad["outside_s"] == bad["wall_s"] and bad["outside_pct"] == pytest.approx(100.0)


def test_the_time_between_runs_is_counted_from_the_previous_row(worker):
    """``between_s``: the worker's time from its previous row (or from being ready) to the run's start; a
    pause there is in it and in no run's wall time."""
    import time

    specs, job = _reduced()
    run.mark_ready()
    time.sleep(0.05)
    first = run.run_one(specs[0], job)
    assert first["between_s"] >= 0.05
    time.sleep(0.02)
    second = run.run_one(specs[1], job)
    assert second["between_s"] >= 0.02
    copy = copy_row(second, {**specs[1], "run_id": "copy", "seed": 1}, job)
    assert copy["between_s"] == 0.0


@pytest.mark.parametrize("scenario, vehicle, extra", [
    ("opendrive_curve", "xbw", {}),                                          # path and speed followers
    ("step_steer_80kph", "eps_car", {"vehicle.sensors.channels.gyro_z.noise_std": 0.01}),   # sensor noise
])
def test_the_compiled_offline_loop_logs_the_python_loops_rows(scenario, vehicle, extra):
    """The car's loop in one kernel (a run without progress reports) against the Python loop (a run
    with them): the same rows, bit for bit, noise and closed-loop drivers included; and the vehicle's
    offline run (one driver for the start's brake command and the run, reset in between) against a
    fresh driver for each."""
    from rtsim.batch.inputs import open_run
    from rtsim.vehicle.offline import run as run_offline, sim_for

    sc, opened = open_run(ROOT / "configs" / "scenarios" / f"{scenario}.toml",
                          ROOT / "configs" / "vehicles" / f"{vehicle}.toml", {"scenario.duration": 0.5, **extra})
    compiled = run_offline(sim_for(opened.model, sc), sc, seed=3)
    python = run_offline(sim_for(opened.model, sc), sc, progress=lambda f: None, seed=3)
    assert compiled.fault is None and python.fault is None
    assert compiled.data.shape == python.data.shape and compiled.data.shape[0] > 40
    assert compiled.data.tobytes() == python.data.tobytes()
    assert 0.0 < compiled.step_s <= compiled.wall_s
    one_driver = opened.run_offline(sc, seed=3)
    assert one_driver.data.tobytes() == compiled.data.tobytes()


def test_the_compiled_offline_loop_fails_where_the_python_loop_does(monkeypatch):
    """A model failure (rtsim.model_fault's test-only hook at 0.2 s) in the compiled loop: the rows up to
    it and the fault (step, time, reason, coordinate) of the Python loop."""
    from rtsim.batch.inputs import open_run
    from rtsim.model_fault import TEST_FAULT_ENV
    from rtsim.vehicle.offline import run as run_offline, sim_for

    monkeypatch.setenv(TEST_FAULT_ENV, "0.2")
    sc, opened = open_run(ROOT / "configs" / "scenarios" / "step_steer_80kph.toml",
                          ROOT / "configs" / "vehicles" / "xbw.toml", {"scenario.duration": 0.5})
    compiled = run_offline(sim_for(opened.model, sc), sc)
    python = run_offline(sim_for(opened.model, sc), sc, progress=lambda f: None)
    assert compiled.fault is not None and compiled.fault == python.fault and compiled.fault.step == 200
    assert compiled.steps == python.steps and compiled.data.tobytes() == python.data.tobytes()


def test_a_worker_builds_the_plans_vehicles_before_its_first_run(worker):
    """warm_specs: one spec per scenario and vehicle file loads the kernels, then one per further vehicle
    (a swept mass is another vehicle), in plan order and bounded; after warming with them every run of
    the reduced sweep finds its vehicle kept: none is built or rebuilt in a run."""
    from rtsim.batch.executors import KERNEL_SPECS, WARM_VEHICLES, warm_specs

    plan, base = load_plan(SWEEP)
    specs = expand(plan, base)
    chosen = warm_specs(specs)
    masses = plan.grid["vehicle.chassis.mass_kg"]
    assert len(chosen) == min(WARM_VEHICLES, 2 * len(masses)) and KERNEL_SPECS >= 2
    assert [s["case"] for s in chosen[:2]] == [0, 1]              # each car's kernels first
    keys = [(s["vehicle"], s["params"]["vehicle.chassis.mass_kg"]) for s in chosen]
    assert len(set(keys)) == len(keys)                            # each vehicle once
    reduced, job = _reduced()
    for s in warm_specs(reduced):
        run.warm(s, job)
    built = worker.built
    assert built == 4                                             # two cars, two masses each
    rows = [run.run_one(s, job) for s in reduced]
    assert worker.built == built and all(r["status"] == "ok" for r in rows)


def test_a_worker_reads_the_plans_scenarios_before_its_first_run(worker, monkeypatch):
    """scenario_specs: one spec per scenario file and scenario overrides (each steering step of the sweep
    is a scenario of its own), in plan order; after keep_scenarios no run of the reduced sweep reads its
    scenario, and a scenario that cannot be read is left for its run to report."""
    import drivers.scenario
    from rtsim.batch.executors import keep_scenarios, scenario_specs

    plan, base = load_plan(SWEEP)
    chosen = scenario_specs(expand(plan, base))
    steps = plan.grid["scenario.inputs.steering_wheel_angle_cmd.after"]
    assert [s["params"]["scenario.inputs.steering_wheel_angle_cmd.after"] for s in chosen] == steps
    reduced, job = _reduced()
    bad = {**reduced[0], "overrides": {**reduced[0]["overrides"], "scenario.duration": -1.0}}
    keep_scenarios(scenario_specs(reduced) + [bad])
    reads = []
    real = drivers.scenario.load_scenario
    monkeypatch.setattr(drivers.scenario, "load_scenario", lambda *a, **k: reads.append(a) or real(*a, **k))
    rows = [run.run_one(s, job) for s in reduced]
    assert reads == [] and all(r["status"] == "ok" for r in rows)
    assert run.run_one(bad, job)["status"] == "config_error" and len(reads) == 1


def test_the_workers_readiness_is_what_their_first_rows_leave():
    """ready_after: a worker's first row arriving at 5 s after 1 s of run and 0.5 s before it was ready
    at 3.5 s; the summary gives the last worker's; Ray's rows (no readiness) leave it out."""
    from rtsim.batch.cli import ready_after, ready_summary

    assert ready_after({"wall_s": 1.0, "between_s": 0.5}, 5.0) == pytest.approx(3.5)
    assert math.isnan(ready_after({"wall_s": 1.0, "between_s": math.nan}, 5.0))
    assert ready_summary({"a:1": 3.5, "a:2": 2.0}).startswith("; workers ready after 3.50 s")
    assert ready_summary({"ray:1": math.nan}) == ""
