"""A controller FMU as a command source (rtsim.fmu): FMUs built here with pythonfmu3 from the Python
classes in rtsim/fmu/examples drive the car offline, and their runs equal the same controllers written as Python
command sources (same inputs, same step) within 1e-9; bad mappings and FMUs get one clear line."""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from drivers.scenario import load_scenario
from rtsim.errors import ConfigError
from rtsim.fmu.controller import FmuController
from rtsim.fmu.mapping import load_mapping
from rtsim.vehicle.offline import run, sim_for
from rtsim.vehicle.registry import ROOT, open_vehicle

from fmu.build import PythonLaneKeep, PythonPiSpeed
from rtsim.fmu.examples import build_example

FLAT = ROOT / "configs" / "roads" / "flat.toml"
STEP = 0.01          # s, the controllers' communication step (10 run steps)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("fmus")
    return {"pi": build_example("pi_speed", d), "lane": build_example("lane_keep", d)}


@pytest.fixture(scope="module")
def car():
    return open_vehicle(None)


def write(d: Path, name: str, text: str) -> Path:
    p = d / name
    p.write_text(text)
    return p


PI_MAP = """fmu = "{fmu}"
step = {step}
[inputs]
v = "speed"
[outputs]
throttle = "throttle_angle_cmd"
brake = "brake_pressure_cmd"
[parameters]
v_ref = 19.0
"""

LANE_MAP = """fmu = "{fmu}"
step = {step}
[inputs]
y_mm = "pos_y"
yaw = "yaw_angle"
[outputs]
steer = "steering_wheel_angle_cmd"
"""


def scenario(d: Path, mapping: Path, extra: str = "", duration: float = 3.0, speed: float = 15.0, y: float = 0.0):
    return write(d, "sc.toml", f"""name = "fmu_run"
road = "{FLAT}"
duration = {duration}
dt = 0.001
output_rate = 100.0
controller = "{mapping.name}"
[initial]
speed = {speed}
y = {y}
{extra}""")


def compare(a, b, columns):
    drop = {c for c in columns if c.startswith(("work_", "stored_", "energy_"))}
    keep = [i for i, c in enumerate(columns) if c not in drop]
    assert a.shape == b.shape
    diff = np.abs(a[:, keep] - b[:, keep])
    worst = int(np.argmax(diff.max(axis=0)))
    assert diff.max() <= 1e-9, f"{columns[keep[worst]]} differs by {diff.max():.3g}"


def test_pi_speed_fmu_drives_the_car_and_equals_the_python_controller(tmp_path, fmus, car):
    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmus["pi"], step=STEP))
    sc = load_scenario(scenario(tmp_path, mapping), check_files=True)
    res = car.run_offline(sc)                     # what `rtsim run` runs
    assert res.status == "ok", res.message
    ref = run(sim_for(car.model, sc), sc, controller=PythonPiSpeed(STEP, v_ref=19.0))
    compare(res.data, ref.data, res.columns)
    v = res.column("speed")
    t = res.column("time")
    # the controller accelerates the car from 15 m/s towards its 19 m/s target (integral action: no offset)
    assert v[0] == pytest.approx(15.0, abs=0.05)
    assert v[-1] > 17.5 and np.all(np.diff(v[t > 0.2]) > -1e-3)
    assert res.column("throttle_angle")[-1] > 0.0


def test_lane_keeping_fmu_converts_units_and_equals_the_python_controller(tmp_path, fmus, car):
    mapping = write(tmp_path, "lane.toml", LANE_MAP.format(fmu=fmus["lane"], step=STEP))
    follower = "[inputs.speed_follower]\ntime = [0.0]\nspeed = [20.0]\n"
    sc = load_scenario(scenario(tmp_path, mapping, follower, duration=4.0, speed=20.0, y=0.5), check_files=True)
    res = car.run_offline(sc)
    assert res.status == "ok", res.message
    ref = run(sim_for(car.model, sc), sc, controller=PythonLaneKeep(STEP))
    compare(res.data, ref.data, res.columns)
    y = res.column("pos_y")
    # it steers the car back from 0.5 m off the lane's centre (y = 0) and holds it there
    assert y[0] == pytest.approx(0.5, abs=0.05)
    assert abs(y[-1]) < 0.1 and res.column("steering_wheel_angle").min() < -0.01


def test_rtsim_run_takes_the_scenario_controller(tmp_path, fmus):
    from rtsim.cli import main

    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmus["pi"], step=STEP))
    sc = scenario(tmp_path, mapping, duration=0.5)
    out = tmp_path / "run.csv"
    assert main(["run", "--scenario", str(sc), "--out", str(out)]) == 0
    cols = out.read_text().splitlines()[0].split(",")
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert rows[-1, cols.index("throttle_angle")] > 0.0


# ---- bad mappings and FMUs: one line each ------------------------------------------------------------


def _channels():
    from rtsim.channels import CAR
    return CAR


def _commands():
    from rtsim.channels import COMMANDS
    return {c.name: c.unit for c in COMMANDS}


def _error(tmp_path, text) -> str:
    m = write(tmp_path, "m.toml", text)
    with pytest.raises(ConfigError) as exc:
        FmuController(load_mapping(m), _channels(), _commands(), 1e-3)
    line = str(exc.value)
    assert "\n" not in line and line.startswith(str(m))
    return line


def test_missing_variable(tmp_path, fmus):
    line = _error(tmp_path, PI_MAP.format(fmu=fmus["pi"], step=STEP).replace('v = "speed"', 'vel = "speed"'))
    assert "inputs.vel = 'speed'" in line and "missing variable" in line and "its inputs: v" in line


def test_unit_mismatch(tmp_path, fmus):
    line = _error(tmp_path, PI_MAP.format(fmu=fmus["pi"], step=STEP).replace('v = "speed"', 'v = "yaw_rate"'))
    assert "inputs.v = 'yaw_rate'" in line and "unit mismatch" in line


def test_output_that_is_an_input_and_unknown_channel(tmp_path, fmus):
    line = _error(tmp_path, PI_MAP.format(fmu=fmus["pi"], step=STEP).replace('throttle = ', 'v = '))
    assert "outputs.v = 'throttle_angle_cmd'" in line and "wrong causality" in line and "is input, not output" in line
    line = _error(tmp_path, PI_MAP.format(fmu=fmus["pi"], step=STEP).replace('"speed"', '"sped"'))
    assert "inputs.v = 'sped'" in line and "not a sensor or state channel" in line


def test_step_not_a_multiple_of_the_run(tmp_path, fmus):
    line = _error(tmp_path, PI_MAP.format(fmu=fmus["pi"], step=0.0025))
    assert "step = 0.0025" in line and "whole multiple" in line


def test_wrong_fmi_kind(tmp_path, fmus):
    me = tmp_path / "me.fmu"
    with zipfile.ZipFile(fmus["pi"]) as src, zipfile.ZipFile(me, "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b"<CoSimulation", b"<ModelExchange").replace(b"</CoSimulation", b"</ModelExchange")
            dst.writestr(item, data)
    line = _error(tmp_path, PI_MAP.format(fmu=me, step=STEP))
    assert "wrong FMI kind" in line and "model-exchange" in line


def test_not_an_fmu_and_bad_mapping_keys(tmp_path, fmus):
    junk = write(tmp_path, "junk.fmu", "not a zip")
    assert "not an FMU" in _error(tmp_path, PI_MAP.format(fmu=junk, step=STEP))
    m = write(tmp_path, "bad.toml", PI_MAP.format(fmu=fmus["pi"], step=-1.0))
    with pytest.raises(ConfigError, match=r"bad.toml: step = -1.0: out of range"):
        load_mapping(m)
    m = write(tmp_path, "bad2.toml", PI_MAP.format(fmu=tmp_path / "none.fmu", step=STEP))
    with pytest.raises(ConfigError, match=r"bad2.toml: fmu = .*file not found"):
        load_mapping(m)


def test_scenario_refuses_a_command_with_two_sources(tmp_path, fmus):
    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmus["pi"], step=STEP))
    follower = "[inputs.speed_follower]\ntime = [0.0]\nspeed = [20.0]\n"
    with pytest.raises(ConfigError, match=r"sc.toml: controller = 'pi.toml': its FMU drives throttle_angle_cmd, "
                                          r"which inputs.speed_follower drives too"):
        load_scenario(scenario(tmp_path, mapping, follower))


def test_rtsim_batch_runs_the_controller(tmp_path, fmus, car):
    """`rtsim batch` over the initial speed of the PI scenario: each point's run is the offline run's."""
    import csv

    from rtsim.cli import main

    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmus["pi"], step=STEP))
    sc = scenario(tmp_path, mapping, duration=1.0)
    plan = write(tmp_path, "plan.toml", f"""name = "fmu"
metrics = ["distance"]
[[cases]]
scenario = "{sc}"
[grid]
"scenario.initial.speed" = [15.0, 17.0]
""")
    out = tmp_path / "batch"
    assert main(["batch", str(plan), "--workers", "1", "--out", str(out)]) == 0
    rows = {float(r["scenario.initial.speed"]): r for r in csv.DictReader((out / "results.csv").open())}
    assert {r["status"] for r in rows.values()} == {"ok"}
    res = car.run_offline(load_scenario(sc))         # the scenario's own speed, 15 m/s
    dist = float(np.sum(np.hypot(np.diff(res.column("pos_x")), np.diff(res.column("pos_y")))))
    assert float(rows[15.0]["distance"]) == pytest.approx(dist, rel=1e-9)
    assert float(rows[17.0]["distance"]) > dist + 1.5      # 2 m/s faster for 1 s
