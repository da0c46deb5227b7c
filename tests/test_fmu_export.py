"""The vehicle as an FMU (`rtsim export-fmu`): the exported FMI 3.0 co-simulation FMU passes fmpy's model
description validation and, imported with fmpy and fed the commands `rtsim run` fed the vehicle, reproduces
the run's channels within 1e-9 over a step steer."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.scenario import load_scenario
from rtsim.vehicle.registry import ROOT, open_vehicle

FLAT = ROOT / "configs" / "roads" / "flat.toml"

STEP_STEER = f"""name = "fmu_step_steer"
road = "{FLAT}"
duration = 1.5
dt = 0.001
output_rate = 100.0
[initial]
speed = 20.0
[inputs.throttle_angle_cmd]
type = "constant"
value = 0.12
[inputs.steering_wheel_angle_cmd]
type = "step"
t0 = 0.3
before = 0.0
after = 0.6
ramp = 0.1
"""


def test_exported_vehicle_reproduces_rtsim_run_over_a_step_steer(tmp_path):
    import fmpy
    from rtsim.cli import main
    from rtsim.fmu.controller import open_slave

    scen = tmp_path / "step_steer.toml"
    scen.write_text(STEP_STEER)
    fmu_path = tmp_path / "xbw.fmu"
    assert main(["export-fmu", "--vehicle", "xbw", "--scenario", str(scen), "--out", str(fmu_path)]) == 0
    md = fmpy.read_model_description(str(fmu_path), validate=True)     # raises on any validation problem
    assert md.fmiVersion == "3.0" and md.coSimulation is not None
    byname = {v.name: v for v in md.modelVariables}
    commands = [v.name for v in md.modelVariables if v.causality == "input"]
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    assert commands == ["throttle_angle_cmd", "brake_pressure_cmd", "steering_wheel_angle_cmd"]
    assert byname["steering_wheel_angle_cmd"].unit == "rad" and byname["brake_pressure_cmd"].unit == "kPa"

    # `rtsim run` of the scenario: what it fed the vehicle at each step, and the channels it logged
    sc = load_scenario(scen, check_files=True)
    ref = open_vehicle("xbw").run_offline(sc)
    assert ref.status == "ok"
    driver = sc.driver()
    dt, every = sc.dt, 10

    fmu = open_slave(md, fmpy.extract(str(fmu_path), unzipdir=tmp_path / "fmu"), "car")
    try:
        in_vr = [byname[c].valueReference for c in commands]
        out_vr = [byname[o].valueReference for o in outputs]
        rows = [fmu.getFloat64(out_vr)]
        nsteps = int(round(sc.duration / dt))
        state = sc.initial_state()
        t = 0.0                                         # the vehicle's clock: a sum of steps, as the run's
        for n in range(nsteps):
            cmd = driver.step(t + dt, state)            # open loop: the state is not read
            fmu.setFloat64(in_vr, [float(cmd[i]) for i in range(len(commands))])
            fmu.doStep(t, dt)
            t += dt
            if (n + 1) % every == 0:
                rows.append(fmu.getFloat64(out_vr))
        fmu.terminate()
    finally:
        fmu.freeInstance()
    got = np.array(rows)
    want = np.column_stack([ref.column(o) for o in outputs])
    assert got.shape == want.shape
    diff = np.abs(got - want)
    worst = outputs[int(np.argmax(diff.max(axis=0)))]
    assert diff.max() <= 1e-9, f"{worst} differs by {diff.max():.3g}"
    # and the run is a step steer: the car turns left after the step
    assert want[-1, outputs.index("yaw_rate")] > 0.05
