"""A small ECU for the test-catalogue tests, written apart from the demo ECU and never shown to any shipped
catalogue: it speaks the by-wire car's DBC (configs/can/xbw.dbc; cantools decodes the sensor frames, the
project's codec adds the alive counters and CRCs of its command frames) and drives simulated time in
lockstep (SIM_STEP_REQ of 10 steps after each command cycle, then waits for SIM_STEP_ACK).

Behaviour: brake held (2500 kPa) for the first 0.3 s, then a proportional speed controller to 5 m/s on the
speed of the two front wheels (their angle sensors differenced over each 10 ms cycle, times the wheel
radius). Plausibility: when the two front wheel speeds disagree by more than 1 m/s for 5 cycles in a row it
latches its safe state: throttle closed, 4000 kPa of brake.

THE DELIBERATE BUG (what tests/test_ecu_catalog_unseen.py expects the catalogue to catch): the check is
one-sided (``v_fr - v_fl > 1``), so a stuck front-right sensor (v_fr = 0) is never noticed.

    python tests/ecu_small.py --can-interface remote --can-channel 127.0.0.1:PORT --duration 3 --lockstep
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

RADIUS = 0.2818          # m, the car's wheel radius (what rtsim describe prints)
TARGET = 5.0             # m/s
SAFE_BRAKE = 4000.0      # kPa
STEPS = 10               # 1 ms steps per cycle


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--can-interface", required=True)
    p.add_argument("--can-channel", required=True)
    p.add_argument("--duration", type=float, required=True)
    p.add_argument("--lockstep", action="store_true")
    args = p.parse_args()
    if not args.lockstep:
        print("ecu_small: lockstep only", file=sys.stderr)
        return 2

    import can
    import cantools

    from bridge.can_codec import Codec

    dbc_path = ROOT / "configs" / "can" / "xbw.dbc"
    db = cantools.database.load_file(str(dbc_path))
    codec = Codec(dbc_path)
    wheels = db.get_message_by_name("SIM_WHEEL_ANGLE_F")
    span = {s.name: s.maximum - s.minimum for s in wheels.signals if s.name.startswith("wheel_angle")}
    bus = can.Bus(interface=args.can_interface, channel=args.can_channel)
    counters = {"throttle_angle_cmd": 0, "brake_pressure_cmd": 0, "steering_wheel_angle_cmd": 0, "step": 0}
    prev = None              # (wheel_angle_fl, wheel_angle_fr) at the last cycle
    t = 0.0
    disagree = 0
    safe = False
    cmd = {"throttle_angle_cmd": 0.0, "brake_pressure_cmd": 2500.0, "steering_wheel_angle_cmd": 0.0}
    try:
        while t < args.duration - 1e-9:
            for name, value in cmd.items():
                counters[name] = (counters[name] + 1) & 0xF
                fid, data = codec.encode_command(name, value, counters[name])
                bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
            counters["step"] = (counters["step"] + 1) & 0xF
            fid, data = codec.encode_step_request(STEPS, counters["step"])
            bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
            latest = None
            while True:
                msg = bus.recv(30.0)
                if msg is None:
                    print("ecu_small: no SIM_STEP_ACK", file=sys.stderr)
                    return 2
                if msg.arbitration_id == wheels.frame_id:
                    d = wheels.decode(bytes(msg.data), decode_choices=False)
                    latest = (d["wheel_angle_fl"], d["wheel_angle_fr"])
                elif msg.arbitration_id == codec.step_ack.frame_id:
                    if codec.decode_step_ack(bytes(msg.data))[1] == counters["step"]:
                        break
            t += STEPS * 1e-3
            if latest is None:
                continue
            if prev is not None:
                h = STEPS * 1e-3
                dfl = (latest[0] - prev[0] + span["wheel_angle_fl"] / 2) % span["wheel_angle_fl"] - span["wheel_angle_fl"] / 2
                dfr = (latest[1] - prev[1] + span["wheel_angle_fr"] / 2) % span["wheel_angle_fr"] - span["wheel_angle_fr"] / 2
                v_fl, v_fr = dfl / h * RADIUS, dfr / h * RADIUS
                disagree = disagree + 1 if v_fr - v_fl > 1.0 else 0      # the bug: one-sided
                if disagree >= 5:
                    safe = True
                v = 0.5 * (v_fl + v_fr)
                if safe:
                    cmd.update(throttle_angle_cmd=0.0, brake_pressure_cmd=SAFE_BRAKE)
                elif t >= 0.3:
                    cmd.update(throttle_angle_cmd=min(max(0.25 * (TARGET - v) + 0.2, 0.0), 1.0), brake_pressure_cmd=0.0)
            prev = latest
    finally:
        bus.shutdown()
    print('{"ecu_time": %r, "safe": %s}' % (t, "true" if safe else "false"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
