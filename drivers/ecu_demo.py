"""A demo ECU: drives the simulated car over CAN only, as a by-wire controller on a real bench would.

It knows the car only through the DBC (``configs/can/xbw.dbc``) and a few calibration constants
(wheel radius, wheelbase, steering ratio: the values `rtsim describe` prints for the xbw car). From
the sensor frames it estimates its own state: speed from the front (undriven) wheel angles
(differenced, times the wheel radius), yaw by integrating the yaw-rate gyro, position by dead
reckoning. Every 5th sensor sample (10 ms, the command frames' DBC period) it runs its drivers and
sends the three command frames with alive counters and CRCs.

The manoeuvre (``--manoeuvre demo``, the default) has two phases:

1. ``straight_line``: the seed's straight-line manoeuvre, open loop: the throttle and brake profiles of
   ``configs/scenarios/straight_line.toml`` (held by the brake, released, a throttle press to about
   23 km/h, braking to a stop), until the car has stopped after 22 s;
2. ``lane_change``: closed loop: a speed follower (accelerate to 45 km/h, hold, brake to a stop) and a
   pure-pursuit path follower through a 3.5 m single lane change (cosine-shaped over 40 m, starting
   60 m after the phase starts), in the frame of the car's own estimated pose at the phase start.

``--lockstep``: the ECU also drives simulated time: after each command cycle it sends SIM_STEP_REQ for
the 10 ms until its next cycle and waits for SIM_STEP_ACK (deterministic runs: CI, SIL).

Run as a separate process (``python -m drivers.ecu_demo --can-interface remote --can-channel
127.0.0.1:54701``); it prints a one-line JSON summary last. Started beside a service that is still
starting (a first run compiles for a minute or more), it waits for the service's bus and then its
first sensor frames, up to ``--connect-timeout`` (600 s) in all, saying so every ``--report-every``
(10 s) on stderr; every failure is one ``ecu_demo: error: ...`` line on stderr and a non-zero exit.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from bridge.bus_wait import Waiting, add_client_arguments, bus_name, wait_for_bus
from bridge.can_codec import Codec
from bridge.can_pack import SensorDecoder
from rtsim.errors import RtsimError

from . import bus_controller
from .base import I_BRAKE, I_STEER, I_THROTTLE, NSTATE, DriverView
from .driver import Driver
from .path_follower import path_follower
from .speed_follower import speed_follower

ROOT = Path(__file__).resolve().parents[1]
STRAIGHT_LINE = ROOT / "configs" / "scenarios" / "straight_line.toml"
COMMAND_EVERY = 5                  # sensor samples per command cycle (10 ms at 2 ms)
PHASE_A_END = 22.0                 # s: the straight-line manoeuvre has stopped the car by then
LANE_OFFSET = 3.5                  # m
LANE_START, LANE_LENGTH = 60.0, 40.0   # m, along the phase's start heading
SPEED_TABLE = ([0.0, 7.0, 17.0, 23.0, 25.0], [0.0, 12.5, 12.5, 0.0, 0.0])   # s -> m/s (45 km/h)


class DemoEcu:
    """The ECU's logic on decoded samples; bus I/O is done by ``run``."""

    def __init__(self, codec: Codec, wheel_radius: float = 0.2818, wheelbase: float = 2.40,
                 steering_ratio: float = 18.2, manoeuvre: str = "demo"):
        from drivers.scenario import load_scenario

        self.codec = codec
        self.decoder = SensorDecoder(codec)
        self.r = wheel_radius
        self.wheelbase = wheelbase
        self.ratio = steering_ratio
        self.manoeuvre = manoeuvre
        self.straight = load_scenario(STRAIGHT_LINE).driver()
        self.lane: Driver | None = None
        self.phase = "straight_line" if manoeuvre in ("demo", "straight_line") else "lane_change"
        self.phase_t0 = 0.0
        self.state = np.zeros(NSTATE)
        self.cmd = np.zeros(3)
        self.counters = [0, 0, 0]
        self.samples = 0
        self.t0: float | None = None
        self.t = 0.0
        self._prev_t: float | None = None
        self._prev_wheels: tuple[float, float] | None = None
        sensors = codec.channels.sensor_names             # the channels the DBC carries
        self._iw = (sensors.index("wheel_angle_fl"), sensors.index("wheel_angle_fr"))
        self._igz = sensors.index("gyro_z")
        self.done = False
        self.peak_speed = 0.0
        self.distance = 0.0
        self.max_lateral = 0.0
        self.phase_log: list[dict] = []
        self._warm_up()
        if self.phase == "lane_change":
            self._start_lane_change(0.0)

    def _warm_up(self) -> None:
        """Load the compiled driver kernels now (numba loads them at the first call, ~1 s), so the
        first command cycles on the bus are not late."""
        self.straight.step(0.0)
        self._start_lane_change(0.0)
        self.lane.step(0.0, self.state)
        self.lane, self.phase_log = None, []
        self.phase = "straight_line" if self.manoeuvre in ("demo", "straight_line") else "lane_change"

    # -- estimation ------------------------------------------------------------------------------
    def _estimate(self, t: float, values: np.ndarray) -> None:
        wl, wr = values[self._iw[0]], values[self._iw[1]]
        if self._prev_t is not None and t > self._prev_t:
            h = t - self._prev_t
            v = 0.5 * ((wl - self._prev_wheels[0]) + (wr - self._prev_wheels[1])) / h * self.r
            s = self.state
            s[DriverView.SPEED] = v
            s[DriverView.YAW] += values[self._igz] * h
            s[DriverView.X] += v * h * math.cos(s[DriverView.YAW])
            s[DriverView.Y] += v * h * math.sin(s[DriverView.YAW])
            self.distance += abs(v) * h
            self.peak_speed = max(self.peak_speed, v)
        self._prev_t, self._prev_wheels = t, (wl, wr)

    # -- drivers ---------------------------------------------------------------------------------
    def _start_lane_change(self, t: float) -> None:
        x0, y0, yaw0 = self.state[DriverView.X], self.state[DriverView.Y], self.state[DriverView.YAW]
        xs = np.arange(0.0, 400.0, 1.0)
        u = np.clip((xs - LANE_START) / LANE_LENGTH, 0.0, 1.0)
        ys = LANE_OFFSET * 0.5 * (1.0 - np.cos(math.pi * u))
        c, s = math.cos(yaw0), math.sin(yaw0)
        self._lane_frame = (x0, y0, c, s)
        sf = speed_follower(SPEED_TABLE[0], SPEED_TABLE[1], by="time")
        pf = path_follower(x0 + c * xs - s * ys, y0 + s * xs + c * ys, wheelbase=self.wheelbase,
                           steering_ratio=self.ratio)
        self.lane = Driver(None, speed=sf, path=pf)
        self.phase, self.phase_t0 = "lane_change", t
        self.phase_log.append({"phase": "lane_change", "start": t})

    def _lateral(self) -> float:
        x0, y0, c, s = self._lane_frame
        return -s * (self.state[DriverView.X] - x0) + c * (self.state[DriverView.Y] - y0)

    def on_sample(self, t: float, values: np.ndarray) -> bool:
        """Take one complete sensor sample; True when it is time to send commands (self.cmd)."""
        if self.t0 is None:
            self.t0 = t
            self.phase_log.append({"phase": self.phase, "start": 0.0})
        self.t = t - self.t0
        self._estimate(t, values)
        self.samples += 1
        if self.samples % COMMAND_EVERY:
            return False
        if self.phase == "straight_line":
            if self.t >= PHASE_A_END and abs(self.state[DriverView.SPEED]) < 0.05:
                if self.manoeuvre == "straight_line":
                    self.done = True
                else:
                    self._start_lane_change(self.t)
        if self.phase == "straight_line":
            out = self.straight.step(self.t)
        else:
            tl = self.t - self.phase_t0
            out = self.lane.step(tl, self.state)
            self.max_lateral = max(self.max_lateral, self._lateral())
            if tl >= SPEED_TABLE[0][-1] and abs(self.state[DriverView.SPEED]) < 0.05:
                self.done = True
        self.cmd[0] = min(max(out[I_THROTTLE], 0.0), 1.4)
        self.cmd[1] = min(max(out[I_BRAKE], 0.0), 12000.0)
        self.cmd[2] = min(max(out[I_STEER], -11.0), 11.0)
        return True

    def command_frames(self) -> list[tuple[int, bytes]]:
        frames = []
        for i, name in enumerate(self.codec.channels.command_names):
            self.counters[i] = (self.counters[i] + 1) & 0xF
            frames.append(self.codec.encode_command(name, float(self.cmd[i]), self.counters[i]))
        return frames

    def summary(self) -> dict:
        return {"ecu_time": self.t, "samples": self.samples, "phase": self.phase, "done": self.done,
                "distance_estimate": self.distance, "peak_speed_estimate": self.peak_speed,
                "lane_offset_estimate": self.max_lateral, "phases": self.phase_log}


def run(bus, ecu: DemoEcu, duration: float | None = None, lockstep: bool = False,
        timeout: float = 5.0, first_frame_timeout: float = 60.0, waiting: Waiting | None = None) -> dict:
    """Drive until the manoeuvre is done, ``duration`` s of ECU (simulation) time, or no sensor frame
    for ``timeout`` s of wall time once frames flowed (drivers.bus_controller.run: in lockstep, commands
    first, then 10 ms of 1 ms steps per request). Returns the ECU summary plus bus counters."""
    return bus_controller.run(bus, ecu, duration, lockstep, timeout=timeout, first_frame_timeout=first_frame_timeout,
                              waiting=waiting, steps=COMMAND_EVERY * 2, command_first=True)


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m drivers.ecu_demo", description=__doc__.split("\n\n")[0])
    add_client_arguments(p)
    p.add_argument("--manoeuvre", choices=["demo", "straight_line", "lane_change"], default="demo")
    args = p.parse_args(argv)

    from rtsim.compile_status import CompileProgress

    try:
        with CompileProgress("ecu_demo", _say, what="driver kernels", expect_s=None, every=None, predict=()):
            ecu = DemoEcu(Codec(), manoeuvre=args.manoeuvre)   # everything slow before the bus: no backlog
        waiting = Waiting("ecu_demo", _say, args.report_every)
        bus = wait_for_bus(args.can_interface, args.can_channel, waiting.start + args.connect_timeout, waiting)
        try:
            first = max(1.0, waiting.start + args.connect_timeout - time.monotonic())
            result = run(bus, ecu, args.duration, args.lockstep, args.timeout, first, waiting)
        finally:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001  (the bus is gone already: the service stopped)
                pass
    except RtsimError as exc:
        _say(f"ecu_demo: error: {exc}")
        return 2
    except KeyboardInterrupt:
        return 130
    print(json.dumps(result), flush=True)
    if result["samples"] == 0:
        n = result["frames_received"]
        what = "no frames from the service" if n == 0 else f"{n} frames but no complete sensor sample"
        _say(f"ecu_demo: error: {what} on {bus_name(args.can_interface, args.can_channel)} after "
             f"{waiting.elapsed:.0f} s (waits up to --connect-timeout {args.connect_timeout:g} s)")
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
