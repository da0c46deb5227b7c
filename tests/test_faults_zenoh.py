"""Live fault arming over Zenoh (control ops inject_fault and clear_fault) against a service in lockstep,
in process: the arguments are checked like every control op's (one-line errors), the fault acts from the
next step, the status reports it, and the recording has the requests and the fault's onset and end."""
from __future__ import annotations

import threading

import pytest

from bridge.can_bus import LoopbackHub
from bridge.mcap_recorder import read_recording
from bridge.zenoh_link import ZenohClient
from rtsim.service.server import ServeOptions, Service
from waits import EVENT, HUB_START


def test_inject_and_clear_over_zenoh_and_resim(tmp_path):
    from rtsim.service.resim import resim

    rec = tmp_path / "live.mcap"
    hub = LoopbackHub(0, start_timeout=HUB_START)
    svc = Service(ServeOptions(mode="lockstep", can_interface="remote", can_channel=hub.channel, start_hub=False,
                               zenoh_listen=["tcp/127.0.0.1:0"], record=rec), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    client = ZenohClient(svc.vehicle_id, connect=tuple(svc.zenoh.endpoints))
    try:
        assert client.control("step", n=50, timeout=EVENT)["ok"]
        for args, words in (({"id": "g", "kind": "gain", "target": "accel_z", "gain": float("nan")},
                             "not a finite number"),
                            ({"id": "g", "kind": "gain", "target": "accel_z", "gain": 2.0, "bogus": 1},
                             "inject_fault: bogus = 1: unknown key"),
                            ({"id": "g", "kind": "gain", "target": "nope", "gain": 2.0}, "not a sensor channel"),
                            ({"id": "g", "kind": "loss", "target": "BRAKE_CMD", "probability": 2},
                             "0 <= probability <= 1")):
            r = client.control("inject_fault", timeout=EVENT, **args)
            assert not r["ok"] and words in r["error"] and "\n" not in r["error"], r
        r = client.control("inject_fault", timeout=EVENT, id="g", kind="gain", target="accel_z", gain=2.0)
        assert r["ok"] and r["fault"]["state"] == "armed", r
        r = client.control("inject_fault", timeout=EVENT, id="n", kind="noise_burst", target="gyro_x",
                           amplitude=0.1, seed=3, duration=0.02)
        assert r["ok"], r
        assert client.control("step", n=30, timeout=EVENT)["ok"]
        st = svc.loop.status()["injected_faults"]["faults"]
        assert [(f["id"], f["state"], f["onset_time"]) for f in st] == [("g", "active", 51 * 0.001),
                                                                         ("n", "ended", 51 * 0.001)]
        bad = client.control("clear_fault", timeout=EVENT, id="nope")
        assert not bad["ok"] and "no fault 'nope'" in bad["error"]
        r = client.control("clear_fault", timeout=EVENT, id="g")
        assert r["ok"] and r["fault"]["state"] == "ended" and r["fault"]["end_time"] == pytest.approx(0.08)
        assert client.control("step", n=40, timeout=EVENT)["ok"]
    finally:
        client.close()
        svc.stop()
        th.join(EVENT)
        hub.close()
    assert not th.is_alive()
    messages, _ = read_recording(rec)
    ev = [(m.data["id"], m.data["event"], m.data["step"]) for m in messages["rtsim/xbw/faults"]]
    assert ev == [("g", "onset", 51), ("n", "onset", 51), ("n", "end", 71), ("g", "end", 80)]
    ops = [m.data["op"] for m in messages["rtsim/xbw/control"]]
    assert ops.count("inject_fault") == 2 and ops.count("clear_fault") == 1
    rep = resim(rec)
    assert rep["faults"]["identical"] and rep["faults"]["recorded"] == 4
    assert rep["identical"], (rep["sensors"], rep["state"])
