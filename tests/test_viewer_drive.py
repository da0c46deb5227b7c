"""The user's command source behind `rtsim view` (the service's ``drive`` control op), in the loop without a
browser: it drives a car nobody else drives, yields to a bus ECU with valid commands unless the user
takes over, says who drives, rejects bad values, lapses; a two-wheeler's lean demand is held by the lean
loop and turns it the way a steady turn does (yaw rate g tan(roll) / speed)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.can_codec import Codec
from rtsim.service.loop import HilLoop
from rtsim.service.server import build_sim

G = 9.81


def _loop(vehicle=None, **kw):
    sim, sc = build_sim(None, vehicle)
    codec = Codec(sim.vm.dbc, sim.vm.channels)
    return HilLoop(sim, codec, mode="fast", driver=sc.driver(), **kw)


def _state(loop, name):
    return float(loop.state[loop.codec.channels.state_names.index(name)])


def _drive_for(loop, steps, request):
    """The user's request again every 100 steps (the page sends it every 0.1 s; the service holds it 1 s of
    wall time), for ``steps`` steps; returns the last reply."""
    for _ in range(steps // 100):
        r = loop._control("drive", dict(request))
        assert r["ok"], r
        loop.advance(100)
    return r


def _ecu(loop, k, throttle=0.0, brake=2000.0, steer=0.0):
    """One 10 ms period of a bus ECU's three commands (counter k), then 10 steps."""
    for name, v in (("throttle_angle_cmd", throttle), ("brake_pressure_cmd", brake), ("steering_wheel_angle_cmd", steer)):
        loop.rx_writer.put(*loop.codec.encode_command(name, v, k & 0xF))
    loop.take_frames()
    loop.advance(10)


def test_the_user_drives_a_car_nobody_else_drives():
    loop = _loop()
    loop.advance(1000)                   # (and the compiled step is loaded: the hold time is wall time)
    assert _state(loop, "speed") < 0.05                          # the watchdog's hold pressure keeps it still
    assert set(loop.drivers().values()) == {"safe"}
    r = _drive_for(loop, 4000, {"throttle_angle_cmd": 0.6, "brake_pressure_cmd": 0.0, "steering_wheel_angle_cmd": 1.0,
                                "seq": 7})
    assert r["seq"] == 7 and set(r["drivers"].values()) == {"user"}
    assert _state(loop, "throttle_angle") == pytest.approx(0.6, abs=1e-3)
    assert _state(loop, "speed") > 5.0 and _state(loop, "yaw_rate") > 0.0       # steering left turns left
    status = loop.status()
    assert set(status["drivers"].values()) == {"user"} and status["user"]["channels"]["throttle_angle_cmd"] == 0.6
    r = loop._control("drive", {"release": True})
    assert r["ok"] and set(loop.drivers().values()) == {"safe"} and r["user"]["channels"] == {}


def test_a_bus_ecu_keeps_priority_unless_the_user_takes_over():
    loop = _loop()
    for k in range(100):                                         # 1 s of an ECU holding the car
        assert loop._control("drive", {"throttle_angle_cmd": 0.6, "brake_pressure_cmd": 0.0})["ok"]
        _ecu(loop, k)
    assert loop.drivers() == {"throttle_angle_cmd": "ecu", "brake_pressure_cmd": "ecu",
                              "steering_wheel_angle_cmd": "ecu"}
    assert _state(loop, "throttle_angle") < 0.01 and _state(loop, "brake_pressure") > 1500.0
    for k in range(100, 200):
        assert loop._control("drive", {"throttle_angle_cmd": 0.6, "brake_pressure_cmd": 0.0, "takeover": True})["ok"]
        _ecu(loop, k)
    assert loop.drivers() == {"throttle_angle_cmd": "user", "brake_pressure_cmd": "user",
                              "steering_wheel_angle_cmd": "ecu"}    # (the user left the steering to it)
    assert _state(loop, "throttle_angle") == pytest.approx(0.6, abs=1e-3) and _state(loop, "brake_pressure") < 50.0


def test_bad_requests_are_refused_and_the_commands_lapse():
    loop = _loop()
    r = loop._control("drive", {"throttle_angle_cmd": 9.0})
    assert not r["ok"] and "throttle_angle_cmd = 9.0: outside 0 .. 1.5708 rad" in r["error"]
    r = loop._control("drive", {"roll_angle_demand": 0.1})
    assert not r["ok"] and "not a user channel of this vehicle (those are: throttle_angle_cmd" in r["error"]
    assert not loop._control("drive", {"brake_pressure_cmd": "lots"})["ok"]
    assert not loop._control("drive", {"takeover": "yes"})["ok"]
    assert loop.user_status()["channels"] == {}                  # nothing of a refused request applied
    loop.user_hold = 0.0                                         # the page went away: the hold time passes
    assert loop._control("drive", {"throttle_angle_cmd": 0.3})["ok"]
    loop.advance(loop.status_every + 1)
    assert loop.user_status()["channels"] == {} and loop.drivers()["throttle_angle_cmd"] == "safe"
    refusing = _loop(user_input=False)
    r = refusing._control("drive", {"throttle_angle_cmd": 0.3})
    assert not r["ok"] and "--no-user-input" in r["error"]


def test_a_two_wheelers_lean_demand_is_held_and_turns_it():
    """At the scenario's speed (about 12 m/s), a little throttle, lean demands of +-0.3 rad for 3 s each:
    the roll follows to within 0.02 rad, and the yaw rate has the steady turn's sign and size,
    g tan(roll) / speed within 25 % (the tyres' crown makes the contact lean less than the frame)."""
    loop = _loop("configs/vehicles/motorcycle.toml")
    loop.advance(1)                      # (the first call loads the compiled step: longer than the hold time)
    for demand in (0.3, -0.3):
        r = _drive_for(loop, 3000, {"throttle_cmd": 0.15, "brake_pressure_front_cmd": 0.0,
                                    "brake_pressure_rear_cmd": 0.0, "roll_angle_demand": demand})
        assert r["drivers"]["roll_angle_demand"] == "user"
        assert loop.run_state == "running"
        roll, u, yaw_rate = _state(loop, "roll_angle"), _state(loop, "speed"), _state(loop, "yaw_rate")
        assert roll == pytest.approx(demand, abs=0.02)
        assert -yaw_rate == pytest.approx(G * math.tan(roll) / u, rel=0.25)    # leaning right: turning right
    assert np.all(np.isfinite(loop.state))
