"""The service's Zenoh side, in process: the control queryable (step, pause, resume, reset,
load_scenario, errors), the config query, and the published topics, against a service in lockstep mode
(so every expectation is exact). Zenoh on tcp/127.0.0.1 with a port chosen by the OS, scouting off;
CAN on a loopback hub started here."""
from __future__ import annotations

import threading
import time

import pytest

pytest.importorskip("zenoh")
pytest.importorskip("can_remote")

from bridge import payloads  # noqa: E402
from bridge.can_bus import LoopbackHub  # noqa: E402
from bridge.zenoh_link import ZenohClient  # noqa: E402
from rtsim.service.server import ServeOptions, Service  # noqa: E402


@pytest.fixture(scope="module")
def service():
    hub = LoopbackHub(0)
    svc = Service(ServeOptions(mode="lockstep", can_interface="remote", can_channel=hub.channel, start_hub=False,
                               zenoh_listen=["tcp/127.0.0.1:0"]), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    client = ZenohClient(svc.vehicle_id, connect=tuple(svc.zenoh.endpoints))
    client.control("step", n=1, timeout=30)            # first request: connection and first step done
    try:
        yield svc, client
    finally:
        client.close()
        svc.stop()
        th.join(10)
        hub.close()
    assert not th.is_alive()


def test_step_advances_exactly_and_publishes_every_sample(service):
    svc, client = service
    got = {"sensors": [], "state": [], "status": []}
    for kind in got:
        client.subscribe(kind, got[kind].append)
    time.sleep(0.5)                                    # subscriptions reach the service
    t0 = client.control("step", n=1, timeout=20)["sim_time"]
    r = client.control("step", n=100, timeout=20)
    assert r["ok"] and r["sim_time"] == pytest.approx(t0 + 0.1)
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and (not got["status"] or any(
            not got[k] or got[k][-1]["time"] < t0 + 0.1 - 1e-9 for k in ("sensors", "state"))):
        time.sleep(0.05)
    times = [m["time"] for m in got["sensors"] if m["time"] > t0]
    assert len(times) == 50 and times[-1] == pytest.approx(t0 + 0.1)     # 500 Hz: every 2 ms
    for kind, msgs in got.items():
        assert msgs, kind
        assert payloads.validation_errors(kind, msgs[-1]) == [], kind
    assert got["status"][-1]["mode"] == "lockstep"


def test_pause_resume_and_errors(service):
    svc, client = service
    assert client.control("pause")["run_state"] == "paused"
    r = client.control("step", n=5)
    assert not r["ok"] and "paused" in r["error"]
    assert client.control("resume")["run_state"] == "running"
    assert client.control("step", n=5)["ok"]
    for bad in ({"op": "step", "n": 0}, {"op": "warp"}, {"op": "load_scenario", "scenario": "no_such"}):
        op = bad.pop("op")
        r = client.control(op, **bad)
        assert r["ok"] is False and r["error"], r


def test_reset_and_load_scenario_restart_time(service):
    svc, client = service
    client.control("step", n=20)
    r = client.control("reset", timeout=20)
    assert r["ok"] and r["sim_time"] == 0.0
    assert client.control("step", n=10)["sim_time"] == pytest.approx(0.01)
    r = client.control("load_scenario", scenario="step_steer_80kph", timeout=20)
    assert r["ok"] and r["scenario"] == "step_steer_80kph"
    client.control("step", n=200)
    cfg = client.config()
    assert cfg["scenario"]["name"] == "step_steer_80kph" and cfg["dt"] == 0.001
    assert cfg["vehicle"]["id"] == "xbw" and cfg["options"]["mode"] == "lockstep"
    # the new scenario starts at 80 km/h: the car is moving (the brake holds, so it slows down)
    assert svc.loop.state[12] > 15.0
