"""`rtsim bench --suite fmu`: what an FMU costs beside the 1 ms loop budget.

- one call of a controller FMU as a command source (rtsim.fmu.controller.FmuController.communicate: set
  its input, doStep, get its two outputs), for the example PI speed controller (rtsim/fmu/examples)
  built here with pythonfmu3 (a Python FMU: the cost is fmpy's ctypes calls plus the FMU's Python);
- one doStep of 1 ms of the car exported as an FMU (`rtsim export-fmu`), imported with fmpy, with its
  commands set and its channels read, against `rtsim run`'s cost per step.
Medians and best of `repeats` rounds of `reps` calls (microseconds)."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

MAPPING = '''fmu = "PiSpeed.fmu"
step = 0.01
[inputs]
v = "speed"
[outputs]
throttle = "throttle_angle_cmd"
brake = "brake_pressure_cmd"
'''


def _rounds(fn, reps: int, repeats: int) -> dict:
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(reps):
            fn()
        out.append((time.perf_counter() - t) / reps * 1e6)
    return {"median": float(np.median(out)), "best": float(min(out))}


def fmu_costs(reps: int = 2000, repeats: int = 5) -> dict:
    import fmpy

    from rtsim.channels import CAR, COMMANDS
    from rtsim.fmu.controller import FmuController, open_slave
    from rtsim.fmu.examples import build_example
    from rtsim.fmu.export import export_vehicle
    from rtsim.vehicle.registry import open_vehicle

    res: dict = {"loop_budget_us": 1000.0}
    with tempfile.TemporaryDirectory(prefix="rtsim_bench_fmu_") as tmp:
        d = Path(tmp)
        build_example("pi_speed", d)
        (d / "pi.toml").write_text(MAPPING)
        ctl = FmuController(d / "pi.toml", CAR, {c.name: c.unit for c in COMMANDS}, 1e-3)
        ctl.start(0.0)
        x = np.array([15.0])
        clock = [0.0]

        def call():
            ctl.communicate(clock[0], x)
            clock[0] += ctl.step
        try:
            res["controller_call_us"] = _rounds(call, reps, repeats)
        finally:
            ctl.close()

        vehicle = open_vehicle("xbw")
        fmu_path = export_vehicle("xbw", d / "xbw.fmu")
        md = fmpy.read_model_description(str(fmu_path))
        fmu = open_slave(md, fmpy.extract(str(fmu_path), unzipdir=d / "xbw"), "car")
        try:
            ins = [v.valueReference for v in md.modelVariables if v.causality == "input"]
            outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
            cmd = [0.0] * len(ins)
            t = [0.0]

            def vstep():
                fmu.setFloat64(ins, cmd)
                fmu.doStep(t[0], 1e-3)
                fmu.getFloat64(outs)
                t[0] += 1e-3
            res["vehicle_fmu_dostep_us"] = _rounds(vstep, max(reps // 4, 1), repeats)
            res["vehicle_fmu_outputs"] = len(outs)
            fmu.terminate()
        finally:
            fmu.freeInstance()

        from rtsim.fmu.served_vehicle import ServedVehicle
        sv = ServedVehicle(vehicle.path, vehicle.default_scenario)
        res["vehicle_step_us"] = _rounds(lambda: sv.advance(1e-3), max(reps // 4, 1), repeats)
    return res


def format_report(res: dict) -> str:
    b = res["loop_budget_us"]
    rows = [("controller FMU call (set 1, doStep, get 2)", res["controller_call_us"]),
            (f"car FMU doStep 1 ms (set 3, get {res['vehicle_fmu_outputs']})", res["vehicle_fmu_dostep_us"]),
            ("car step in rtsim (1 ms, channels read)", res["vehicle_step_us"])]
    lines = [f"{'us per call':<48} {'median':>8} {'best':>8} {'of 1 ms':>8}"]
    for name, v in rows:
        lines.append(f"{name:<48} {v['median']:8.1f} {v['best']:8.1f} {100 * v['median'] / b:7.1f}%")
    return "\n".join(lines)
