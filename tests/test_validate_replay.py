"""rtsim validate's replays: the compiled grid loop (rtsim.validate.replay_kernel) gives the replay of a
Python loop over the same kernels bit for bit, and a replay is made once per inputs, model effects and
step (a second request costs no simulation; a value differing in its last bit, another step or another
input is a new replay)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rtsim.validate.effectset import Effect
from rtsim.validate.replay import ReplayInputs, Replayer
from rtsim.vehicle.car.sensors import NSENSOR
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, EX_TORQUE_LEFT, EX_TORQUE_RIGHT

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"


@pytest.fixture(scope="module")
def rp():
    return Replayer(VEHICLE)


def _inputs(speed0: float = 12.0) -> ReplayInputs:
    """2 s on a 10 ms grid: a drive torque, a light brake that goes below zero (clipped), a steer ramp."""
    t = np.arange(201) * 0.01
    torque = 60.0 + 40.0 * np.sin(2.0 * t)
    brake = 300.0 * np.sin(3.0 * t)
    steer = 0.3 * np.clip(t - 0.5, 0.0, 1.0)
    return ReplayInputs(t, brake, torque, torque.copy(), None, steer, speed0, "test")


def _python_loop(rp: Replayer, inp: ReplayInputs, effects, dt: float) -> np.ndarray:
    """The grid loop as Python: commands at each interval's mean value, the model's steps, the physical
    sensor values at the grid times."""
    sim = rp.new_sim(inp, effects, dt)
    sub = int(round(float(inp.t[1] - inp.t[0]) / dt))
    cmd, extra = sim.io.commands, sim.io.extra
    cmd[CMD_BRAKE] = max(0.0, float(inp.brake[0]))
    extra[EX_TORQUE_LEFT], extra[EX_TORQUE_RIGHT] = float(inp.torque_rl[0]), float(inp.torque_rr[0])
    cmd[CMD_STEER] = float(inp.steer[0])
    out = np.zeros((inp.t.size, NSENSOR))
    row = np.zeros(NSENSOR)
    sim.physical_sensors(row)
    out[0] = row
    for k in range(inp.t.size - 1):
        cmd[CMD_BRAKE] = max(0.0, 0.5 * (inp.brake[k] + inp.brake[k + 1]))
        extra[EX_TORQUE_LEFT] = 0.5 * (inp.torque_rl[k] + inp.torque_rl[k + 1])
        extra[EX_TORQUE_RIGHT] = 0.5 * (inp.torque_rr[k] + inp.torque_rr[k + 1])
        cmd[CMD_STEER] = 0.5 * (inp.steer[k] + inp.steer[k + 1])
        sim.step(sub)
        sim.physical_sensors(row)
        out[k + 1] = row
    return out


def test_compiled_grid_loop_equals_the_python_loop(rp):
    inp = _inputs()
    effects = [Effect("mass", {"added_mass": 120.0})]
    raw = rp._replay(inp, effects, 2e-3, inp.steer)
    ref = _python_loop(rp, inp, effects, 2e-3)
    for i, name in enumerate(rp.model.channels.sensor_names):
        assert np.array_equal(raw[name], ref[:, i]), name
    assert np.ptp(raw["accel_y"]) > 0.5 and raw["brake_pressure"].min() == 0.0     # it steered and clipped


def test_a_replay_is_made_once(rp):
    inp = _inputs()
    mass = [Effect("mass", {"added_mass": 100.0})]
    n0 = rp.simulations
    a = rp._run(inp, mass, 2e-3, inp.steer)
    assert rp.simulations == n0 + 1
    a["accel_x"] = None                               # a caller's own mapping: the kept replay is untouched
    b = rp._run(inp, [*mass, Effect("sensor_bias", {"channel": "gyro_z", "bias": 0.03})], 2e-3, inp.steer)
    assert rp.simulations == n0 + 1                   # a sensor effect does not change the motion
    assert b["accel_x"] is not None and np.array_equal(b["gyro_z"], rp._run(inp, mass, 2e-3, inp.steer)["gyro_z"])
    for effects, dt, other in (([Effect("mass", {"added_mass": math.nextafter(100.0, 200.0)})], 2e-3, inp),
                               (mass, 1e-3, inp), (mass, 2e-3, _inputs(12.5))):
        n = rp.simulations
        rp._run(other, effects, dt, other.steer)
        assert rp.simulations == n + 1
    steer = inp.steer.copy()
    steer[-1] += 1e-12
    n = rp.simulations
    rp._run(inp, mass, 2e-3, steer)
    assert rp.simulations == n + 1


def test_fit_step_divides_the_grid():
    """The candidate fits' step: the largest step not above fit_dt that divides the comparison grid's
    interval (a replay holds its inputs over whole grid intervals), never below the model's step."""
    from types import SimpleNamespace
    rp = SimpleNamespace(dt=1e-3, fit_dt=5e-3)
    for grid, step in ((0.01, 5e-3), (5e-3, 5e-3), (4e-3, 4e-3), (8e-3, 4e-3), (0.02, 5e-3), (6e-3, 3e-3),
                       (1e-3, 1e-3)):
        got = Replayer.fit_step(rp, grid)
        assert got == pytest.approx(step, rel=1e-12), grid
        assert abs(grid / got - round(grid / got)) < 1e-9 and got <= rp.fit_dt * (1 + 1e-12)
