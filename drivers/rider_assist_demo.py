"""A demo rider-assist ECU: the motorcycle's electronics on the bench, talking to the simulated motorcycle
over CAN only (``configs/can/motorcycle.dbc``), as the ECU under test would.

Every complete 2 ms sample (IMU, attitude, wheel speeds, steering) it sends STEER_ASSIST_CMD, an
electronic steering damper against weave and kickback:

    tau_assist = -c(v) delta',   c(v) = C0 + C1 v   (N m s/rad, v from the front wheel speed)

and every 5th sample (10 ms, the frames' DBC period) the ride-by-wire and ABS commands from the rider's
demands (SIM_RIDER, 100 Hz):

- THROTTLE_CMD: the rider's throttle grip, cut in proportion while the rear wheel spins more than
  ``TC_SLIP`` faster than the front (traction control);
- BRAKE_FRONT_CMD, BRAKE_REAR_CMD: the rider's pressures, released while that wheel runs more than
  ``ABS_SLIP`` slower than the other (anti-lock).

Its only knowledge of the motorcycle is the DBC and a calibration (``WHEEL_RADIUS_*``): the values a
supplier flashes. ``--lockstep``: it also drives simulated time (drivers.bus_controller). ``--silent-after
T``: it stops commanding after T s of simulated time (the service's watchdog hands the throttle and
brakes back to the rider and drops the assist). Run as a separate process (``python -m
drivers.rider_assist_demo --can-interface remote --can-channel 127.0.0.1:54701``); it prints a one-line
JSON summary last; failures are one ``rider_assist_demo: error: ...`` line on stderr and a non-zero exit.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bridge.can_codec import Codec
from bridge.can_pack import SensorDecoder
from drivers.bus_controller import main as bus_main
from rtsim.channels import two_wheeler_channels

ROOT = Path(__file__).resolve().parents[1]
DBC = ROOT / "configs" / "can" / "motorcycle.dbc"
FAST_FRAMES = ("SIM_IMU_ACCEL", "SIM_IMU_GYRO", "SIM_INCLINATION", "SIM_WHEEL_SPEEDS", "SIM_STEERING")
SLOW_FRAMES = ("SIM_SUSPENSION", "SIM_RIDER", "SIM_ACTUATORS")
C0, C1 = 1.0, 0.1                   # N m s/rad, N m s^2/(rad m): the steering damper's calibration
ASSIST_LIMIT = 20.0                 # N m
WHEEL_RADIUS_FRONT, WHEEL_RADIUS_REAR = 0.300, 0.315   # m, the calibration's rolling radii
TC_SLIP, ABS_SLIP = 0.10, 0.15      # traction control and anti-lock thresholds (slip ratio)
SLOW_EVERY = 5                      # fast samples per throttle/brake command (10 ms)


class FastAndSlow:
    """Both decoders fed with every frame; a sample is the fast frames' (``time``, ``values``), the slow
    frames' latest values beside it (``slow.values``)."""

    def __init__(self, codec: Codec):
        self.fast = SensorDecoder(codec, frames=FAST_FRAMES)
        self.slow = SensorDecoder(codec, frames=SLOW_FRAMES)

    def receive(self, can_id: int, data: bytes) -> bool:
        self.slow.receive(can_id, data)
        return self.fast.receive(can_id, data)

    @property
    def time(self) -> float:
        return self.fast.time

    @property
    def values(self):
        return self.fast.values


class RiderAssistEcu:
    """The ECU's logic on decoded samples (see the module docstring); bus I/O is drivers.bus_controller's."""

    def __init__(self, codec: Codec):
        self.codec = codec
        self.decoder = FastAndSlow(codec)
        names = codec.channels.sensor_names
        self._i = {n: names.index(n) for n in names}
        self.counters = {n: 0 for n in codec.channels.command_names}
        self.assist = 0.0
        self.throttle = self.brake_front = self.brake_rear = 0.0
        self.samples = 0
        self.t = 0.0
        self.peak_assist = 0.0
        self.tc_active = self.abs_active = 0          # samples with traction control / anti-lock acting

    def on_sample(self, t: float, values: np.ndarray) -> None:
        """One complete fast sample at simulated time t (s)."""
        self.t = t
        self.samples += 1
        i = self._i
        v_front = values[i["wheel_speed_front"]] * WHEEL_RADIUS_FRONT
        v_rear = values[i["wheel_speed_rear"]] * WHEEL_RADIUS_REAR
        c = C0 + C1 * max(v_front, 0.0)
        self.assist = float(np.clip(-c * values[i["steer_rate"]], -ASSIST_LIMIT, ASSIST_LIMIT))
        self.peak_assist = max(self.peak_assist, abs(self.assist))
        slow = self.decoder.slow.values
        if np.isnan(slow[i["rider_throttle"]]):
            return                                  # the rider's demands not seen yet
        ref = max(v_front, v_rear, 1.0)
        tc = max(0.0, (v_rear - v_front) / ref - TC_SLIP)
        self.throttle = float(slow[i["rider_throttle"]] * max(0.0, 1.0 - 10.0 * tc))
        self.tc_active += tc > 0.0
        front_lock = (v_rear - v_front) / ref > ABS_SLIP
        rear_lock = (v_front - v_rear) / ref > ABS_SLIP
        self.abs_active += front_lock or rear_lock
        self.brake_front = 0.0 if front_lock else float(slow[i["rider_brake_front"]])
        self.brake_rear = 0.0 if rear_lock else float(slow[i["rider_brake_rear"]])

    def _frame(self, name: str, value: float) -> tuple[int, bytes]:
        self.counters[name] = (self.counters[name] + 1) & 0xF
        return self.codec.encode_command(name, value, self.counters[name])

    def command_frames(self) -> list[tuple[int, bytes]]:
        """The assist every sample; throttle and brakes every SLOW_EVERY samples, once the rider's demands
        have been seen."""
        out = [self._frame("assist_torque_cmd", self.assist)]
        if self.samples % SLOW_EVERY == 0 and not np.isnan(self.decoder.slow.values[self._i["rider_throttle"]]):
            out += [self._frame("throttle_cmd", self.throttle),
                    self._frame("brake_pressure_front_cmd", self.brake_front),
                    self._frame("brake_pressure_rear_cmd", self.brake_rear)]
        return out

    def summary(self) -> dict:
        return {"ecu_time": self.t, "samples": self.samples, "peak_assist_cmd": self.peak_assist,
                "traction_control_samples": int(self.tc_active), "anti_lock_samples": int(self.abs_active)}


def main(argv: list[str] | None = None) -> int:
    return bus_main("rider_assist_demo", __doc__, lambda: RiderAssistEcu(Codec(DBC, two_wheeler_channels())), argv)


if __name__ == "__main__":
    sys.exit(main())
