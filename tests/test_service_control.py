"""The service's Zenoh side, in process: the control queryable (step, pause, resume, reset,
load_scenario, errors), the config query, and the published topics, against a service in lockstep mode
(so every expectation is exact). Zenoh on tcp/127.0.0.1 with a port chosen by the OS, scouting off;
CAN on a loopback hub started here. Every request waits up to EVENT s for its reply (tests/waits.py:
a bound on the wait, not a criterion; the replies come in milliseconds on a quiet machine)."""
from __future__ import annotations

import threading
import time

import pytest

from bridge import payloads
from bridge.can_bus import LoopbackHub
from bridge.zenoh_link import ZenohClient
from rtsim.service.server import ServeOptions, Service
from waits import EVENT, HUB_START


@pytest.fixture(scope="module")
def service():
    hub = LoopbackHub(0, start_timeout=HUB_START)
    svc = Service(ServeOptions(mode="lockstep", can_interface="remote", can_channel=hub.channel, start_hub=False,
                               zenoh_listen=["tcp/127.0.0.1:0"]), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    client = ZenohClient(svc.vehicle_id, connect=tuple(svc.zenoh.endpoints))
    client.control("step", n=1, timeout=EVENT)         # first request: connection and first step done
    try:
        yield svc, client
    finally:
        client.close()
        svc.stop()
        th.join(EVENT)
        hub.close()
    assert not th.is_alive()


def test_step_advances_exactly_and_publishes_every_sample(service):
    svc, client = service
    got = {"sensors": [], "state": [], "status": []}
    for kind in got:
        client.subscribe(kind, got[kind].append)
    # the subscriptions have reached the service once a step's samples arrive
    deadline = time.monotonic() + EVENT
    while not (got["sensors"] and got["state"] and got["status"]):
        assert time.monotonic() < deadline, {k: len(v) for k, v in got.items()}
        client.control("step", n=10, timeout=EVENT)
        time.sleep(0.05)
    t0 = client.control("step", n=1, timeout=EVENT)["sim_time"]
    r = client.control("step", n=100, timeout=EVENT)
    assert r["ok"] and r["sim_time"] == pytest.approx(t0 + 0.1)
    # wait for the last sample each stream owes for those 100 steps: the sensors' at t0 + 0.1; the
    # state's (every state_every steps) at the latest within the last state_every steps. (Waiting for
    # a state sample at t0 + 0.1 itself ran into the bound whenever t0 was off the state's grid.)
    state_dt = svc.loop.state_every * svc.sim.dt
    last = {"sensors": t0 + 0.1, "state": t0 + 0.1 - state_dt + svc.sim.dt}
    deadline = time.monotonic() + EVENT
    while time.monotonic() < deadline and any(got[k][-1]["time"] < last[k] - 1e-9 for k in last):
        time.sleep(0.05)
    times = [m["time"] for m in got["sensors"] if m["time"] > t0]
    # 500 Hz in simulated time: every sample of the 100 steps, exactly 2 ms apart
    assert len(times) == 50 and times[-1] == pytest.approx(t0 + 0.1)
    assert times == pytest.approx([t0 + 0.002 * (k + 1) for k in range(50)], abs=1e-9)
    # the state at its own rate (100 Hz by default): every sample of the 100 steps, state_dt apart
    st = [m["time"] for m in got["state"] if t0 + 1e-9 < m["time"] <= t0 + 0.1 + 1e-9]
    assert len(st) == round(0.1 / state_dt) and st[-1] >= last["state"] - 1e-9, (t0, st)
    assert st == pytest.approx([st[0] + state_dt * k for k in range(len(st))], abs=1e-9)
    for kind, msgs in got.items():
        assert msgs, kind
        assert payloads.validation_errors(kind, msgs[-1]) == [], kind
    assert got["status"][-1]["mode"] == "lockstep"


def test_pause_resume_and_errors(service):
    svc, client = service
    assert client.control("pause", timeout=EVENT)["run_state"] == "paused"
    r = client.control("step", n=5, timeout=EVENT)
    assert not r["ok"] and "paused" in r["error"]
    assert client.control("resume", timeout=EVENT)["run_state"] == "running"
    assert client.control("step", n=5, timeout=EVENT)["ok"]
    for bad in ({"op": "step", "n": 0}, {"op": "warp"}, {"op": "load_scenario", "scenario": "no_such"}):
        op = bad.pop("op")
        r = client.control(op, **bad, timeout=EVENT)
        assert r["ok"] is False and r["error"], r


def test_reset_and_load_scenario_restart_time(service):
    svc, client = service
    client.control("step", n=20, timeout=EVENT)
    r = client.control("reset", timeout=EVENT)
    assert r["ok"] and r["sim_time"] == 0.0
    assert client.control("step", n=10, timeout=EVENT)["sim_time"] == pytest.approx(0.01)
    r = client.control("load_scenario", scenario="step_steer_80kph", timeout=EVENT)
    assert r["ok"] and r["scenario"] == "step_steer_80kph"
    client.control("step", n=200, timeout=EVENT)
    cfg = client.config(timeout=EVENT)
    assert cfg["scenario"]["name"] == "step_steer_80kph" and cfg["dt"] == 0.001
    assert cfg["vehicle"]["id"] == "xbw" and cfg["options"]["mode"] == "lockstep"
    # the new scenario starts at 80 km/h: the car is moving (the brake holds, so it slows down)
    assert svc.loop.state[12] > 15.0


def test_refused_requests_change_nothing_and_say_why(service):
    """Unknown arguments, wrong types and non-finite numbers are refused with one line (ok false) and never
    applied: the step counter and the user's channels are as before (rtsim.service.control_args)."""
    svc, client = service
    assert client.control("step", n=3, timeout=EVENT)["ok"]
    k = svc.loop.k
    for op, args, words in [("step", {"steps": 5}, "unknown argument 'steps'"),
                            ("step", {"count": 7}, "unknown argument 'count'"),
                            ("step", {"n": 5.5}, "n = 5.5"),
                            ("step", {"n": "5"}, "n = '5'"),
                            ("pause", {"now": True}, "unknown argument 'now'"),
                            ("drive", {"throttle_angle_cmd": float("nan")}, "not a finite number"),
                            ("drive", {"throttle_angle_cmd": 0.2, "brake_pressure_cmd": float("inf")},
                             "not a finite number"),
                            ("drive", {"throttle": 0.5}, "unknown argument 'throttle'"),
                            ("load_scenario", {"scenario": "/etc/passwd"}, "absolute path"),
                            ("load_scenario", {"scenario": "../vehicles/xbw"}, "'..'")]:
        r = client.control(op, **args, timeout=EVENT)
        assert r["ok"] is False and words in r["error"] and "\n" not in r["error"], (op, args, r)
        assert r["error"].startswith(f"{op}: "), r
    assert svc.loop.k == k and svc.loop.run_state == "running"
    assert svc.loop.user_status()["channels"] == {} and svc.loop.user_status()["requests"] == 0
    # the same request with its declared argument runs
    assert client.control("step", n=5, timeout=EVENT)["sim_time"] == pytest.approx((k + 5) * svc.sim.dt)


def test_load_scenario_reads_the_declared_scenario_folders_only(service, tmp_path):
    """A folder the settings declare (scenario_dirs) is read; a link in it that leads out is refused."""
    import os
    from pathlib import Path

    svc, client = service
    mine, outside = tmp_path / "mine", tmp_path / "outside"
    mine.mkdir()
    outside.mkdir()
    shipped = Path(__file__).resolve().parent.parent / "configs" / "scenarios"
    text = (shipped / "hil_flat.toml").read_text().replace('name = "hil_flat"', 'name = "mine"')
    text = text.replace('road = "../roads/flat.toml"', f'road = "{shipped.parent / "roads" / "flat.toml"}"')
    (mine / "mine.toml").write_text(text)
    (outside / "away.toml").write_text(text)
    os.symlink(outside / "away.toml", mine / "away.toml")
    r = client.control("load_scenario", scenario="mine", timeout=EVENT)
    assert r["ok"] is False and "no scenario 'mine'" in r["error"], r
    before = svc.opts.scenario_dirs
    svc.opts.scenario_dirs = [mine]
    try:
        r = client.control("load_scenario", scenario="away", timeout=EVENT)
        assert r["ok"] is False and "is a link to" in r["error"], r
        r = client.control("load_scenario", scenario="mine", timeout=EVENT)
        assert r["ok"] and r["scenario"] == "mine", r
    finally:
        svc.opts.scenario_dirs = before
        assert client.control("load_scenario", scenario="hil_flat", timeout=EVENT)["ok"]
