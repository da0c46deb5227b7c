"""The EPS car's actuator faults (rtsim.faults), at their steps: the power stage switched off (its channel and
the motor current at zero from the first sample after the onset's step, back on after the end) and the
assist motor's failure (no assist torque from the step after the onset). The controller under test is
played by the test: a valid motor-current command every 1 ms, in lockstep, in process."""
from __future__ import annotations

import pytest

from bridge.can_codec import Codec
from rtsim.configfile import validate
from rtsim.faults.spec import FaultSpec
from rtsim.service.loop import HilLoop
from rtsim.service.rings import H_SENSOR
from rtsim.service.server import build_sim
from rtsim.vehicle.registry import resolve_vehicle

ON, OFF, STEPS = 100, 150, 200


@pytest.fixture(scope="module")
def models():
    return {}


def _run(models, faults, probe=None):
    sim, sc = build_sim(None, resolve_vehicle("eps_car"), models=models)
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver(),
                   faults=[validate(FaultSpec, f, "test") for f in faults])
    at = {}
    for k in range(STEPS):
        fid, data = loop.codec.encode_command("motor_current_cmd", 2.0, k % 16)
        loop.rx_writer.put(fid, data)
        loop.take_frames()
        loop.advance(1)
        if probe is not None:
            at[loop.k] = probe(sim)
    r = loop.rings
    names = sim.vm.channels.sensor_names
    sensors = {int(round(r.sensor_t[j] / sim.dt)): dict(zip(names, r.sensor_v[j]))
               for j in range(int(r.heads[H_SENSOR]))}
    return sensors, at, loop


def test_power_stage_off_from_the_step_after_the_onset(models):
    s, _, loop = _run(models, [dict(id="p", kind="power_stage_off", target="eps_power_stage", at=0.1, duration=0.05)])
    assert s[ON - 2]["eps_power_stage"] == 1.0 and s[ON]["eps_power_stage"] == 1.0
    assert abs(s[ON]["eps_motor_current"]) > 0.5
    for k in range(ON + 2, OFF + 1, 2):
        assert s[k]["eps_power_stage"] == 0.0 and s[k]["eps_motor_current"] == 0.0, k
    assert s[OFF + 2]["eps_power_stage"] == 1.0          # the stage back on once the fault ended
    assert not loop.sim.eps_fault                        # the fault's latch restored with it


def test_assist_motor_failure_gives_no_assist_torque(models):
    from rtsim.vehicle.kit.eps import EO_ASSIST_TORQUE

    _, at, _ = _run(models, [dict(id="m", kind="steering_motor_failure", target="eps_motor", at=0.1,
                                  duration=0.05)], probe=lambda sim: sim.io.eps_out[EO_ASSIST_TORQUE])
    assert at[ON] != 0.0
    for k in range(ON + 1, OFF + 1):
        assert at[k] == 0.0, k
    assert at[OFF + 1] != 0.0


def test_the_xbw_actuators_are_not_the_eps_cars(models):
    from rtsim.errors import ConfigError
    with pytest.raises(ConfigError, match="'steering_motor': this vehicle has no such actuator.*eps_motor"):
        _run(models, [dict(id="m", kind="steering_motor_failure", target="steering_motor", at=0.1)])
