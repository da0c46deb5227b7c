"""Synthetic "field data" for the validation-workflow tests: the rtsim vehicle model with a hidden
effect switched on drives a short version of the seed's straight-line manoeuvre (hold on the brake,
slow release, a throttle press through the engine model, coasting, slow braking to a stop) seven
times with run-to-run variation of the pedal timing and amplitude; the sensor channels are sampled at
500 Hz, get white noise, and each recording starts and ends at a slightly different time on its own
clock. Only the CSV files reach the workflow.

The hidden effects, model and sensor alike, are switched on in the model itself
(`VehicleSim.set_effects`: sensor effects act in its sensor stage at every integrator step), so the
workflow's own post-hoc sensor effects are checked against the model's implementation.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rtsim.channels import SENSOR_NAMES
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE
from rtsim.vehicle.car.sensors import NSENSOR
from rtsim.vehicle.car.sim import VehicleSim

DT = 1e-3
RATE = 500.0
DURATION = 12.0
SETTLE = 1.0
#: brake line pressure command nodes (s, kPa) and the throttle pulse (t0, rise, width, fall s; rad)
BRAKE_T = (0.0, 1.0, 2.5, 7.0, 10.0)
BRAKE_P = (2500.0, 2500.0, 0.0, 0.0, 1800.0)
THROTTLE = (2.6, 0.5, 2.0, 0.5, 0.22)
#: run-to-run variation of the by-wire pedal commands: timing (s) and amplitude (relative), 1 sigma
JITTER = 0.015
SPREAD = 0.015
#: white sensor noise, standard deviation per channel (SI units)
NOISE = {"accel_x": 0.1, "accel_y": 0.1, "accel_z": 0.05, "gyro_x": 0.002, "gyro_y": 0.002, "gyro_z": 0.002,
         "roll": 0.0005, "pitch": 0.0005, "wheel_angle_fl": 0.002, "wheel_angle_fr": 0.002,
         "wheel_angle_rl": 0.002, "wheel_angle_rr": 0.002, "brake_pressure": 4.0, "wheel_torque_rl": 1.0,
         "wheel_torque_rr": 1.0, "throttle_angle": 0.001, "steering_wheel_angle": 0.0005}


def pedal_profiles(rng: np.random.Generator | None, brake_t=BRAKE_T, brake_p=BRAKE_P, throttle=THROTTLE):
    """Brake (kPa) and throttle (rad) commands as functions of time (nodes and pulse as BRAKE_T, BRAKE_P,
    THROTTLE), varied run to run."""
    bt = np.array(brake_t)
    bp = np.array(brake_p)
    t0, rise, width, fall, amp = throttle
    if rng is not None:
        bt = bt + np.concatenate([[0.0], rng.normal(0.0, JITTER, bt.size - 1)])
        bp = bp * np.concatenate([[1.0] * (bp.size - 1), [1.0 + rng.normal(0.0, SPREAD)]])
        t0 += rng.normal(0.0, JITTER)
        width += rng.normal(0.0, JITTER)
        amp *= 1.0 + rng.normal(0.0, SPREAD)
    tt = np.array([t0, t0 + rise, t0 + rise + width, t0 + rise + width + fall])
    tv = np.array([0.0, amp, amp, 0.0])
    return (lambda t: float(np.interp(t, bt, bp))), (lambda t: float(np.interp(t, tt, tv)))


def simulate(model, road, effects: dict | None, rng, duration: float = DURATION,
             profiles=pedal_profiles) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free sensor samples at RATE with the effects on: (time, (n, NSENSOR)). `profiles(rng)`
    gives the commands as functions of time: brake (kPa), throttle (rad) and optionally the
    steering-wheel angle (rad)."""
    brake, throttle, *steer = profiles(rng)
    sim = VehicleSim(model, road, DT, brake_pressure=brake(0.0), effects=effects or {})
    sim.io.commands[CMD_BRAKE] = brake(0.0)
    sim.step(int(round(SETTLE / DT)))            # the car stood on the brake before the test began
    every = int(round(1.0 / (RATE * DT)))
    n = int(round(duration * RATE)) + 1
    out = np.zeros((n, NSENSOR))
    row = np.zeros(NSENSOR)
    sim.sensors(row)
    out[0] = row
    for k in range(1, n):
        tm = (k - 0.5) / RATE
        sim.io.commands[CMD_BRAKE] = brake(tm)
        sim.io.commands[CMD_THROTTLE] = throttle(tm)
        if steer:
            sim.io.commands[CMD_STEER] = steer[0](tm)
        sim.step(every)
        sim.sensors(row)
        out[k] = row
    out[0, SENSOR_NAMES.index("brake_pressure")] = brake(0.0)
    return np.arange(n) / RATE, out


def write_runs(folder: Path, model, road, effects: dict | None = None, n: int = 7, seed: int = 0,
               channels: tuple[str, ...] | None = None, profiles=pedal_profiles,
               duration: float = DURATION) -> list[Path]:
    """n recordings of the manoeuvre (`profiles`, see simulate) with the hidden effects (a set_effects
    mapping), CSV files in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    names = channels or tuple(c for c in SENSOR_NAMES if c in NOISE)
    idx = [SENSOR_NAMES.index(c) for c in names]
    noise = np.array([NOISE[c] for c in names])
    paths = []
    for i in range(n):
        t, x = simulate(model, road, effects, rng, duration, profiles)
        x = x[:, idx]
        x = x + rng.normal(0.0, 1.0, x.shape) * noise
        # the logger's own clock and trigger: start up to 0.25 s late, end up to 0.25 s early
        k0 = int(rng.integers(0, 125))
        k1 = t.size - int(rng.integers(0, 125))
        clock = 100.0 * (i + 1) + rng.uniform(0.0, 1.0)
        tt = t[k0:k1] + clock
        path = folder / f"run{i + 1}.csv"
        with path.open("w") as fh:
            fh.write(",".join(("time", *names)) + "\n")
            np.savetxt(fh, np.column_stack([tt, x[k0:k1]]), delimiter=",", fmt="%.9g")
        paths.append(path)
    return paths
