"""Faults on a two-wheeler (rtsim.faults): a sensor fault acts at its steps in the two-wheeler's own compiled
step; an actuator fault is refused in one line (the two-wheeler declares no actuator for faults yet)."""
from __future__ import annotations

from bridge.can_codec import Codec
from rtsim.configfile import validate
from rtsim.faults.spec import FaultSpec
from rtsim.service.loop import HilLoop
from rtsim.service.rings import H_SENSOR
from rtsim.service.server import build_sim
from rtsim.vehicle.registry import resolve_vehicle


def _sensors(loop, channel):
    r = loop.rings
    i = loop.sim.vm.channels.sensor_names.index(channel)
    return {int(round(r.sensor_t[j] / loop.sim.dt)): r.sensor_v[j, i] for j in range(int(r.heads[H_SENSOR]))}


def test_two_wheeler_sensor_fault_and_refused_actuator_fault():
    def loop_with(faults):
        sim, sc = build_sim(None, resolve_vehicle("motorcycle"), models=models)
        return HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver(),
                       faults=[validate(FaultSpec, f, "test") for f in faults])
    models: dict = {}
    base = loop_with([])
    run = loop_with([dict(id="s", kind="offset", target="steer_rate", offset=0.25, at=0.05, duration=0.02)])
    r = run.apply_control("inject_fault", dict(id="t", kind="stuck_throttle", target="throttle", value=0.1))
    assert not r["ok"] and "it has no throttle actuator" in r["error"] and "\n" not in r["error"]
    base.advance(100)
    run.advance(100)
    a, b = _sensors(base, "steer_rate"), _sensors(run, "steer_rate")
    assert a.keys() == b.keys()
    for k in a:
        assert b[k] == (a[k] + 0.25 if 50 <= k < 70 else a[k]), k
