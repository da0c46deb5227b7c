"""Benchmark of the validation workflow on the seed's manoeuvre: seven repetitions of
configs/scenarios/straight_line.toml (30 s, campus road) driven by the rtsim model with a hidden
effect, with run-to-run variation of the pedal commands (time warp and amplitude, 1.5 %), sensor noise
(the vehicle's sensor model, rtsim.vehicle.kit.sensor_model, with `NOISE`) and logger offsets, written
as CSV; then `python -m rtsim.validate.cli` on them, as a user runs it
(process start to report), timed.

    python -m rtsim.validate.bench [--out DIR] [--effect NAME=VALUE]   (default brake_friction=0.85)
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from rtsim.channels import SENSOR_NAMES
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE
from rtsim.vehicle.car.sensors import NSENSOR

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "scenarios" / "straight_line.toml"
NOISE = {"accel_x": 0.1, "wheel_angle_fl": 0.002, "wheel_angle_fr": 0.002, "wheel_angle_rl": 0.002,
         "wheel_angle_rr": 0.002, "brake_pressure": 4.0, "wheel_torque_rl": 1.0, "wheel_torque_rr": 1.0,
         "throttle_angle": 0.001, "steering_wheel_angle": 0.0005}


def generate(out: Path, effects: dict, n: int = 7, seed: int = 0) -> list[Path]:
    from drivers.base import I_BRAKE, I_STEER, I_THROTTLE, NSTATE
    from drivers.scenario import load_scenario
    from rtsim.road.config import load_road
    from rtsim.vehicle.car.config import load_vehicle
    from rtsim.vehicle.car.build import build_vehicle
    from rtsim.vehicle.offline import default_vehicle_path
    from rtsim.vehicle.car.sim import VehicleSim
    from rtsim.vehicle.kit.sensor_model import apply_to_series, sensor_params

    sc = load_scenario(SCENARIO, check_files=True)
    cfg, base = load_vehicle(sc.vehicle_path or default_vehicle_path())
    model = build_vehicle(cfg, base)
    road = load_road(sc.road_path)
    rng = np.random.default_rng(seed)
    out.mkdir(parents=True, exist_ok=True)
    names = list(NOISE)
    idx = [SENSOR_NAMES.index(c) for c in names]
    logger = sensor_params(names, 1.0 / 500.0, channels={c: {"noise_std": NOISE[c]} for c in names})
    paths = []
    for k in range(n):
        warp, shift, gain = 1.0 + rng.normal(0.0, 0.015), rng.normal(0.0, 0.02), 1.0 + rng.normal(0.0, 0.015)
        drv = sc.driver()
        state = np.zeros(NSTATE)

        def cmd(t):
            c = drv.step(max(0.0, (t - shift) * warp), state)
            return c[I_THROTTLE] * gain, c[I_BRAKE], c[I_STEER]

        thr, brk, st = cmd(0.0)
        sim = VehicleSim(model, road, sc.dt, brake_pressure=brk, effects=effects)
        sim.io.commands[CMD_BRAKE] = brk
        sim.step(int(round(1.0 / sc.dt)))                  # standing before the test
        every = int(round(1.0 / (500.0 * sc.dt)))
        m = int(round(sc.duration * 500.0)) + 1
        rows = np.zeros((m, NSENSOR))
        row = np.zeros(NSENSOR)
        sim.sensors(row)
        rows[0] = row
        for i in range(1, m):
            thr, brk, st = cmd((i - 0.5) / 500.0)
            sim.io.commands[CMD_THROTTLE], sim.io.commands[CMD_BRAKE], sim.io.commands[CMD_STEER] = thr, brk, st
            sim.step(every)
            sim.sensors(row)
            rows[i] = row
        x = apply_to_series(logger, rows[:, idx], seed=int(rng.integers(0, 2 ** 63)))
        t = np.arange(m) / 500.0
        k0, k1 = int(rng.integers(0, 125)), m - int(rng.integers(0, 125))
        path = out / f"straight_line_{k + 1}.csv"
        with path.open("w") as fh:
            fh.write(",".join(("time", *names)) + "\n")
            np.savetxt(fh, np.column_stack([t[k0:k1] + 100.0 * k, x[k0:k1]]), delimiter=",", fmt="%.9g")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("/tmp/rtsim_validate_bench"))
    p.add_argument("--effect", default="brake_friction=0.85", help="hidden model effect NAME=VALUE (its "
                   "first parameter), or 'none'")
    args = p.parse_args(argv)
    effects = {}
    if args.effect != "none":
        from rtsim.vehicle.car.effects import EFFECTS
        name, value = args.effect.split("=")
        effects = {name: {EFFECTS[name].params[0].name: float(value)}}
    t0 = time.perf_counter()
    paths = generate(args.out / "runs", effects)
    print(f"generated {len(paths)} runs of {SCENARIO.name} with {effects or 'no effect'} in "
          f"{time.perf_counter() - t0:.1f} s")
    road = ROOT / "configs" / "roads" / "campus.toml"
    cmd = [sys.executable, "-m", "rtsim.validate.cli", "--vehicle", str(ROOT / "configs" / "vehicles" / "xbw.toml"),
           "--road", str(road), "--runs", str(args.out / "runs"), "--report", str(args.out / "report")]
    t1 = time.perf_counter()
    rc = subprocess.call(cmd)
    print(f"rtsim validate: exit {rc}, {time.perf_counter() - t1:.1f} s wall (process start to report)")
    return rc


if __name__ == "__main__":
    sys.exit(main())
