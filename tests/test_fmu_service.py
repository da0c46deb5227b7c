"""A controller FMU in the service (rtsim.service.controller): a lockstep service in this process serves a
scenario naming the PI speed controller FMU (the example, built here with pythonfmu3); with no ECU on the bus the FMU
drives the throttle and brake through the user source (the watchdog's hold released by its commands) and
accelerates the car towards its target; its commands are recorded as user changes."""
from __future__ import annotations

import threading
from contextlib import contextmanager

from bridge.can_bus import LoopbackHub
from bridge.mcap_recorder import read_recording
from rtsim.service.server import ServeOptions, Service
from waits import EVENT, HUB_START

from rtsim.fmu.examples import build_example
from fmu.build import PythonLaneKeep, PythonPiSpeed
from test_fmu_controller import LANE_MAP, PI_MAP, scenario, write


@contextmanager
def _lockstep(rec, sc, controller=None, **opts):
    """A lockstep service of the scenario `sc` recording to `rec` (with `controller` in the place of its
    FMU, if given; `opts`: more ServeOptions) on its own loopback hub, run in a thread; stopped, joined and
    its hub closed on exit."""
    hub = LoopbackHub(0, start_timeout=HUB_START)
    svc = Service(ServeOptions(mode="lockstep", scenario=str(sc), can_interface="remote", can_channel=hub.channel,
                               start_hub=False, zenoh=False, record=rec, **opts), out=lambda *a: None,
                  controller=controller)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    try:
        yield svc
    finally:
        svc.stop()
        th.join(EVENT)
        hub.close()
    assert not th.is_alive()


def test_pi_speed_fmu_drives_the_car_in_the_service(tmp_path):
    fmu = build_example("pi_speed", tmp_path)
    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmu, step=0.01))
    sc = scenario(tmp_path, mapping, duration=10.0, speed=15.0)
    rec = tmp_path / "session.mcap"
    with _lockstep(rec, sc) as svc:
        loop = svc.loop
        names = loop.codec.channels.state_names
        speed = names.index("speed")
        v0 = None
        for _ in range(30):                                  # 3 s in steps of 0.1 s
            r = svc.control({"op": "step", "n": 100})
            assert r["ok"], r
            if v0 is None:
                v0 = float(loop.ls.state[speed])
        v = float(loop.ls.state[speed])
        drivers = loop.drivers()
        assert drivers["throttle_angle_cmd"] == "user" and drivers["brake_pressure_cmd"] == "user"
        assert v0 < 15.3 and v > 17.5, (v0, v)              # towards its 19 m/s target
        usr = loop.user_status()["channels"]
        assert usr["throttle_angle_cmd"] > 0.0 and usr["brake_pressure_cmd"] == 0.0
    msgs, _ = read_recording(rec)
    changes = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/user"] if m.data["cause"] == "controller"]
    assert len(changes) > 100 and all(c["step"] % 10 == 0 for c in changes)


def _served(tmp_path, name, sc, controller=None, seconds=2.0, **opts):
    """A lockstep service of the scenario `sc` (with `controller` in the place of its FMU, if given)
    stepped `seconds` of simulated time by the step control op; its recording's messages by topic."""
    rec = tmp_path / f"{name}.mcap"
    with _lockstep(rec, sc, controller, **opts) as svc:
        for _ in range(int(round(seconds / 0.1))):
            r = svc.control({"op": "step", "n": 100})
            assert r["ok"], r
    msgs, _ = read_recording(rec)
    return {t.rsplit("/", 1)[1]: m for t, m in msgs.items()}


def _same_samples(a, b) -> None:
    """Every recorded sensor and state sample of the runs `a` and `b`, matched by its simulated time stamp,
    agrees within 1e-9."""
    compared = 0
    for topic in ("sensors", "state"):
        sa, sb = _samples(a, topic), _samples(b, topic)
        assert len(sa) > 100 and sa.keys() == sb.keys(), topic
        for t, ma in sa.items():
            mb = sb[t]
            assert ma.keys() == mb.keys()
            for k, va in ma.items():
                if isinstance(va, float):
                    assert abs(va - mb[k]) <= 1e-9, f"{topic} {k} at t = {t}: {va} vs {mb[k]}"
                    compared += 1
    assert compared > 1000


def _samples(msgs, topic):
    """A recorded topic's samples as {simulated time stamp: message}."""
    return {m.data["time"]: m.data for m in msgs[topic]}


def test_pi_speed_fmu_in_the_service_equals_the_python_controller(tmp_path):
    """The same scenario served twice, once with the PI FMU and once with the same control law written in
    Python standing where the FMU stands (same user source, same step boundaries): every recorded sensor and
    state sample, matched by its simulated time stamp, agrees within 1e-9, and so do the commands."""
    fmu = build_example("pi_speed", tmp_path)
    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmu, step=0.01))
    sc = scenario(tmp_path, mapping, duration=10.0, speed=15.0)
    a = _served(tmp_path, "fmu", sc)
    b = _served(tmp_path, "python", sc, controller=PythonPiSpeed(0.01, v_ref=19.0))
    _same_samples(a, b)
    ua = [(c["step"], c["channels"]) for c in (m.data for m in a["user"]) if c["cause"] == "controller"]
    ub = [(c["step"], c["channels"]) for c in (m.data for m in b["user"]) if c["cause"] == "controller"]
    assert len(ua) > 100 and [s for s, _ in ua] == [s for s, _ in ub]
    for (_, ca), (_, cb) in zip(ua, ub):
        assert all(abs(ca[n] - cb[n]) <= 1e-9 for n in ("throttle_angle_cmd", "brake_pressure_cmd"))
    v = _samples(a, "state")
    assert max(v) > 1.9 and v[max(v)]["speed"] > v[min(v)]["speed"] + 1.0    # the controller accelerates it


def test_lane_keeping_fmu_in_the_service_equals_the_python_controller(tmp_path):
    """The lane-keeping FMU (its lateral input declared in mm) in the service: it alone drives the steering
    (no brake hold: nothing drives the brake, the car coasts from 20 m/s), steers the car back from 0.5 m
    off the lane's centre, and equals the same law written in Python within 1e-9 on every recorded sample."""
    fmu = build_example("lane_keep", tmp_path)
    mapping = write(tmp_path, "lane.toml", LANE_MAP.format(fmu=fmu, step=0.01))
    sc = scenario(tmp_path, mapping, duration=10.0, speed=20.0, y=0.5)
    a = _served(tmp_path, "fmu", sc, seconds=3.0, hold_pressure=0.0)
    b = _served(tmp_path, "python", sc, controller=PythonLaneKeep(0.01), seconds=3.0, hold_pressure=0.0)
    _same_samples(a, b)
    st = _samples(a, "state")
    first, last = st[min(st)], st[max(st)]
    assert abs(first["pos_y"] - 0.5) < 0.05 and abs(last["pos_y"]) < 0.25 and last["speed"] > 15.0, (first, last)
    steer = [c["channels"]["steering_wheel_angle_cmd"] for c in (m.data for m in a["user"]) if c["cause"] == "controller"]
    assert min(steer) < -0.01                                    # it steered right, back towards y = 0
