"""Field runs of the motorcycle for the validation tests: rtsim's own motorcycle ridden by the rider
model (drivers.rider) on a scenario, with a hidden effect and run-to-run variation, logged at 100 Hz as
a data logger would write them (CSV of the two-wheeler's sensor channels, rtsim.channels).

The throttle body and the brake calipers follow the rider's demands through a first-order lag
(`ACTUATOR_TAU`), as actuators do; the logged `throttle` and `brake_pressure_*` are their outputs.
Variation per seed: the start speed (+-0.1 m/s), the rider's target speeds (+-0.05 m/s), the
logger's start (0..50 ms late) and white sensor noise (IMU, wheel speeds, steering, suspension).
Hidden effects: an added mass (kg, at the rider) changes the vehicle file; a sensor bias is added to
the logged channel."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from drivers.scenario import load_scenario
from rtsim.channels import TWO_WHEELER_SENSORS
from rtsim.vehicle.motorcycle.offline import prepare
from drivers.rider import RO_BRAKE_F, RO_BRAKE_R, RO_THROTTLE
from rtsim.vehicle.motorcycle.plant import (C_BRAKE_FRONT, C_BRAKE_FRONT_INVALID, C_BRAKE_REAR, C_BRAKE_REAR_INVALID,
                                            C_THROTTLE, C_THROTTLE_INVALID, plant_sensors)

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "motorcycle.toml"
ROAD = ROOT / "configs" / "roads" / "flat.toml"
NAMES = [c.name for c in TWO_WHEELER_SENSORS]
NOISE_ON = 1.0
ACTUATOR_TAU = 0.04    # s: first-order lag of the throttle body and the brake modulator after the rider's demand
LEAD_IN = 500          # ms ridden before the logger starts (the tyres' slips settled)
LOG_EVERY = 10         # steps of 1 ms between logged rows (a 100 Hz logger)
NOISE = {"accel_x": 0.05, "accel_y": 0.05, "accel_z": 0.05, "gyro_x": 0.002, "gyro_y": 0.002, "gyro_z": 0.002,
         "roll": 0.001, "pitch": 0.0005, "wheel_speed_front": 0.02, "wheel_speed_rear": 0.02, "steer_angle": 0.0005,
         "steer_rate": 0.005, "steering_torque": 0.2, "fork_travel": 0.0002, "shock_travel": 0.0002}

#: the scenario lines both manoeuvres share after their name (files, timing, start speed)
HEADER = """vehicle = "{vehicle}"
road = "{road}"
duration = {duration}
dt = 0.001
output_rate = 100.0
[initial]
speed = {v0}
"""

STRAIGHT = 'name = "field_straight"\n' + HEADER + """[rider]
x = [0.0, 1000.0]
y = [0.0, 0.0]
speed = [{a}, {a}, {b}, {b}, {c}]
time = [0.0, 1.0, 2.5, 3.0, 5.5]
"""

LANE_CHANGE = 'name = "field_lane_change"\n' + HEADER + """[rider]
speed = {a}
[rider.double_lane_change]
offset = 3.0
entry = 20.0
transition = 50.0
hold = 25.0
exit = 50.0
"""


def vehicle_with_mass(folder: Path, added_mass: float) -> Path:
    """A copy of the motorcycle's file with the rider `added_mass` kg heavier."""
    text = VEHICLE.read_text()
    m = re.search(r"\[rider\]\n(?:#[^\n]*\n)*mass_kg = ([0-9.]+)", text)
    new = text[:m.start(1)] + f"{float(m.group(1)) + added_mass:.3f}" + text[m.end(1):]
    p = folder / "motorcycle_field.toml"
    p.write_text(new)
    return p


def ride(folder: Path, kind: str, seed: int, added_mass: float = 0.0, bias: dict | None = None,
         duration: float = 5.0) -> Path:
    """One field run as CSV in `folder`; kind 'straight' (speed up, hold, brake) or 'lane_change'."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    vehicle = vehicle_with_mass(folder, added_mass) if added_mass else VEHICLE
    dv = float(rng.uniform(-0.05, 0.05))
    v0 = 15.0 + float(rng.uniform(-0.1, 0.1))
    if kind == "straight":
        text = STRAIGHT.format(vehicle=vehicle.as_posix(), road=ROAD.as_posix(), duration=duration, v0=v0, a=15.0 + dv, b=20.0 + dv,
                               c=13.0 + dv)
    else:
        text = LANE_CHANGE.format(vehicle=vehicle.as_posix(), road=ROAD.as_posix(), duration=duration, v0=v0 + 3.0, a=18.0 + dv)
    sc = folder / f"scenario_{kind}_{seed}.toml"
    sc.write_text(text)
    r, _ = prepare(None, load_scenario(sc, check_files=True))
    s = r.sim
    p = s.parts
    start = LEAD_IN + int(rng.integers(0, 50))    # ms of riding before the logger starts
    n = start + int(round(duration * 1000.0))
    rows = []
    buf = np.zeros(len(NAMES))
    act = np.zeros(3)                              # throttle, front and rear caliper pressure
    slots = (C_THROTTLE, C_BRAKE_FRONT, C_BRAKE_REAR)
    for c in (C_THROTTLE_INVALID, C_BRAKE_FRONT_INVALID, C_BRAKE_REAR_INVALID):
        r.commands[c] = 0.0                        # the actuators' outputs act (ride-by-wire, brake modulator)
    a = 0.001 / ACTUATOR_TAU
    for i in range(n):
        r.step()
        act += a * (r.out[[RO_THROTTLE, RO_BRAKE_F, RO_BRAKE_R]] - act)
        r.commands[list(slots)] = act
        if i >= start and (i - start) % LOG_EVERY == LOG_EVERY - 1:
            plant_sensors(s.data, p.idx, p.par, r.params.pp, r.state.inp, buf)
            rows.append((s.time, *buf))
    data = np.array(rows)
    data[:, 0] -= data[0, 0]
    for k, name in enumerate(NAMES):
        col = data[:, k + 1]
        col += rng.normal(0.0, NOISE.get(name, 0.0) * NOISE_ON, col.size) if name in NOISE else 0.0
        col += (bias or {}).get(name, 0.0)
    path = folder / f"run_{kind}_{seed:02d}.csv"
    np.savetxt(path, data, delimiter=",", header=",".join(["time", *NAMES]), comments="", fmt="%.7g")
    return path
