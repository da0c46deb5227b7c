"""A controller FMU in the service (rtsim.service.controller): a lockstep service in this process serves a
scenario naming the PI speed controller FMU (the example, built here with pythonfmu3); with no ECU on the bus the FMU
drives the throttle and brake through the user source (the watchdog's hold released by its commands) and
accelerates the car towards its target; its commands are recorded as user changes."""
from __future__ import annotations

import threading

from bridge.can_bus import LoopbackHub
from bridge.mcap_recorder import read_recording
from rtsim.service.server import ServeOptions, Service
from waits import EVENT, HUB_START

from rtsim.fmu.examples import build_example
from test_fmu_controller import PI_MAP, scenario, write


def test_pi_speed_fmu_drives_the_car_in_the_service(tmp_path):
    fmu = build_example("pi_speed", tmp_path)
    mapping = write(tmp_path, "pi.toml", PI_MAP.format(fmu=fmu, step=0.01))
    sc = scenario(tmp_path, mapping, duration=10.0, speed=15.0)
    rec = tmp_path / "session.mcap"
    hub = LoopbackHub(0, start_timeout=HUB_START)
    svc = Service(ServeOptions(mode="lockstep", scenario=str(sc), can_interface="remote", can_channel=hub.channel,
                               start_hub=False, zenoh=False, record=rec), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    try:
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
    finally:
        svc.stop()
        th.join(EVENT)
        hub.close()
    assert not th.is_alive()
    msgs, _ = read_recording(rec)
    changes = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/user"] if m.data["cause"] == "controller"]
    assert len(changes) > 100 and all(c["step"] % 10 == 0 for c in changes)
