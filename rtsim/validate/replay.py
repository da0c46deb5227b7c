"""Replaying the benchmark's mean inputs into the vehicle model (the seed's third phase): the model is
built once per workflow run, and every re-simulation starts a fresh VehicleSim on it (5 ms) with the
effect set under test (`set_effects`), so no state can leak from one simulation into the next.

Inputs, as the seed drove its model: the measured rear-wheel torques (torque mode) and the brake line
pressure; the steering-wheel angle when the manoeuvre steers; the throttle angle when the runs carry
no torques. The measured brake pressure and throttle angle are already the actuators' outputs, so the
model's brake-pressure and throttle actuator lags are bypassed (time constant 0, no rate limit):
replaying them through the actuator would delay them twice. The steering-wheel angle is a command to
the steer-by-wire model (its position loop follows it closely; its lag is not bypassed).

Resampling to the integrator step: the model steps at `dt` (default 1 ms; candidate fits use the
coarser `fit_dt`, default 2 ms, which changes the nominal replay's cost by about 4 % and halves the
fitting time; the reported before/after simulations use `dt`); the inputs are held over each interval
of the comparison grid (default 10 ms) at the interval's mean value (the average of the grid values at
both ends), which is second-order accurate and adds no delay; the sensors are read at the grid times.

Initial state: at rest when the mean front wheel speed is below 0.2 rad/s, else rolling straight at
the speed the front wheels give with the tyre's effective rolling radius; the brake starts at the
measured line pressure (stuck when at rest). A car found at rest first settles for `SETTLE` s with the
first inputs held (it stood before the recording started; an added mass or a grade would otherwise
show a start-up transient the runs do not have).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtsim.channels import SENSOR_NAMES
from rtsim.errors import ConfigError
from rtsim.road.config import load_road
from rtsim.vehicle.actuators import LAG_RATE, LAG_TAU
from rtsim.vehicle.brake import BP_ACT
from rtsim.vehicle.config import load_vehicle
from rtsim.vehicle.dynamics import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_TORQUE_RL, EX_TORQUE_RR
from rtsim.vehicle.model import build_vehicle
from rtsim.vehicle.powertrain import PP_THR
from rtsim.vehicle.sensors import NSENSOR
from rtsim.vehicle.sim import VehicleSim
from rtsim.vehicle.tyre.magic_formula import effective_rolling_radius

from .benchmark import Benchmark
from .effectset import Effect, model_mapping
from .signals import derive_wheel_speeds

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_ROAD = ROOT / "configs" / "roads" / "flat.toml"
SETTLE = 1.0          # s


@dataclass
class ReplayInputs:
    """Mean inputs on the comparison grid and the start state."""
    t: np.ndarray                       # grid, s
    brake: np.ndarray | None            # kPa, line pressure
    torque_rl: np.ndarray | None        # N m
    torque_rr: np.ndarray | None        # N m
    throttle: np.ndarray | None         # rad
    steer: np.ndarray | None            # rad, steering-wheel angle
    speed0: float                       # m/s
    mode: str                           # text: which inputs drive the model


class Replayer:
    """The vehicle model built once; `simulate` replays the inputs with a set of model effects."""

    def __init__(self, vehicle: str | Path, road: str | Path | None = None, dt: float = 1e-3,
                 fit_dt: float = 2e-3):
        self.vehicle_path = Path(vehicle)
        self.config, base = load_vehicle(self.vehicle_path)
        self.model = build_vehicle(self.config, base)
        self.road_path = Path(road) if road is not None else DEFAULT_ROAD
        self.road = load_road(self.road_path)
        self.dt = float(dt)
        self.fit_dt = float(fit_dt)
        probe = VehicleSim(self.model, self.road, self.dt)
        self.wheel_radius = float(effective_rolling_radius(probe.tp, self.model.static_loads[0]))
        self.simulations = 0

    def inputs(self, bench: Benchmark, run: int | None = None) -> ReplayInputs:
        """The benchmark's mean inputs and start state (or those of run number `run`)."""
        m = {c: (bench.mean(c) if run is None else bench.values[c][run]) for c in bench.inputs}
        tq = "wheel_torque_rl" in m and "wheel_torque_rr" in m
        if not tq and "throttle_angle" not in m and "brake_pressure" not in m:
            raise ConfigError("the runs carry neither wheel torques, throttle angle nor brake pressure: the "
                              "longitudinal inputs cannot be replayed")
        parts = []
        if tq:
            parts.append("measured rear-wheel torques (torque mode)")
        elif "throttle_angle" in m:
            parts.append("throttle angle (engine model; no wheel torques recorded)")
        if "brake_pressure" in m:
            parts.append("brake line pressure")
        if "steering_wheel_angle" in m:
            parts.append("steering-wheel angle")
        w = [(bench.mean(c) if run is None or run >= bench.values[c].shape[0] else bench.values[c][run])[0]
             for c in ("wheel_speed_fl", "wheel_speed_fr") if c in bench.bands]
        omega0 = float(np.mean(w)) if w else 0.0
        speed0 = omega0 * self.wheel_radius if abs(omega0) > 0.2 else 0.0
        return ReplayInputs(bench.t, m.get("brake_pressure"), m.get("wheel_torque_rl") if tq else None,
                            m.get("wheel_torque_rr") if tq else None,
                            None if tq else m.get("throttle_angle"), m.get("steering_wheel_angle"), speed0,
                            ", ".join(parts))

    def new_sim(self, inp: ReplayInputs, effects: list[Effect], dt: float) -> VehicleSim:
        p0 = float(inp.brake[0]) if inp.brake is not None else 0.0
        sim = VehicleSim(self.model, self.road, dt, brake_pressure=p0, speed=inp.speed0,
                         effects=model_mapping(effects))
        sim.parts.brake[BP_ACT + LAG_TAU] = 0.0             # measured line pressure: actuator bypassed
        sim.parts.brake[BP_ACT + LAG_RATE] = math.inf
        sim.parts.powertrain[PP_THR + LAG_TAU] = 0.0        # measured throttle angle: actuator bypassed
        sim.parts.powertrain[PP_THR + LAG_RATE] = math.inf
        if inp.torque_rl is not None:
            sim.set_torque_mode(True)
        return sim

    def simulate(self, inp: ReplayInputs, effects: list[Effect], fit: bool = False) -> dict[str, np.ndarray]:
        """Sensor channels (and wheel speeds) of the model on the grid, with the model effects of
        `effects` switched on (sensor effects are not applied here: see sensorfx); `fit`: at fit_dt."""
        dt = self.fit_dt if fit else self.dt
        sim = self.new_sim(inp, effects, dt)
        t = inp.t
        n = t.size
        dtg = float(t[1] - t[0])
        sub = int(round(dtg / dt))
        if abs(sub * dt - dtg) > 1e-9 * dtg or sub < 1:
            raise ConfigError(f"grid step {dtg} s is not a multiple of the model step {dt} s")
        out = np.zeros((n, NSENSOR))
        row = np.zeros(NSENSOR)

        def mid(x, k):
            return 0.5 * (x[k] + x[k + 1])

        cmd, extra = sim.io.commands, sim.io.extra
        if inp.brake is not None:                  # the first inputs, held through the settling
            cmd[CMD_BRAKE] = max(0.0, float(inp.brake[0]))
        if inp.torque_rl is not None:
            extra[EX_TORQUE_RL] = float(inp.torque_rl[0])
            extra[EX_TORQUE_RR] = float(inp.torque_rr[0])
        if inp.throttle is not None:
            cmd[CMD_THROTTLE] = max(0.0, float(inp.throttle[0]))
        if inp.steer is not None:
            cmd[CMD_STEER] = float(inp.steer[0])
        if inp.speed0 == 0.0:
            sim.step(int(round(SETTLE / dt)))
        sim.sensors(row)
        out[0] = row
        for k in range(n - 1):
            if inp.brake is not None:
                cmd[CMD_BRAKE] = max(0.0, mid(inp.brake, k))
            if inp.torque_rl is not None:
                extra[EX_TORQUE_RL] = mid(inp.torque_rl, k)
                extra[EX_TORQUE_RR] = mid(inp.torque_rr, k)
            if inp.throttle is not None:
                cmd[CMD_THROTTLE] = max(0.0, mid(inp.throttle, k))
            if inp.steer is not None:
                cmd[CMD_STEER] = mid(inp.steer, k)
            sim.step(sub)
            sim.sensors(row)
            out[k + 1] = row
        self.simulations += 1
        res = {name: out[:, i].copy() for i, name in enumerate(SENSOR_NAMES)}
        res.update(derive_wheel_speeds(res, dtg))
        return res
