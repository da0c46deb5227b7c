"""A demo EPS controller: the electric power steering's ECU on the bench, talking to the simulated car
over CAN only (``configs/can/eps_car.dbc``), as the controller under test would.

Every 1 ms, when both EPS sensor frames of a sample have arrived (torsion-bar torque, steering-wheel
angle, motor speed, angle and current, the power stage's state, the vehicle speed), it computes a
motor current command and sends EPS_MOTOR_CMD with its alive counter and CRC:

    i* = boost(|T_tb|, v) sign(T_tb) - k_d omega_m          (A)

``boost`` is the controller's own calibration (``BOOST_*``: current against torsion-bar torque at a
few vehicle speeds, interpolated; a dead band of 0.5 N m, a rise to the full 70 A at 8 N m parked and
at 16 N m and above at speed), ``k_d`` a damping on the motor speed that keeps the hands-off wheel
from overshooting. It knows nothing of the car's model or of its configuration: the same DBC a real
EPS ECU would be flashed against.

``--lockstep``: the controller also drives simulated time (one SIM_STEP_REQ of 1 step after each
command, waiting for SIM_STEP_ACK): deterministic runs for CI. ``--silent-after T``: stop sending
commands after T s of simulated time (a controller that hangs) but keep requesting steps in lockstep
for ``--linger`` s more, so the service's watchdog and safe state can be observed; the summary then
says when the power stage was seen off.

Run as a separate process (``python -m drivers.eps_demo --can-interface remote --can-channel
127.0.0.1:54701``); it prints a one-line JSON summary last; failures are one ``eps_demo: error: ...``
line on stderr and a non-zero exit.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from bridge.can_codec import Codec
from bridge.can_pack import SensorDecoder
from drivers.bus_controller import main as bus_main
from rtsim.channels import car_channels

ROOT = Path(__file__).resolve().parents[1]
DBC = ROOT / "configs" / "can" / "eps_car.dbc"
EPS_FRAMES = ("EPS_SENSORS_A", "EPS_SENSORS_B")
# the controller's calibration: motor current (A) against torsion-bar torque (N m), per vehicle speed
BOOST_SPEED = (0.0, 10.0, 30.0)                       # m/s
BOOST_TORQUE = (0.0, 0.5, 2.0, 4.0, 8.0, 16.0)        # N m
BOOST_CURRENT = ((0.0, 0.0, 10.0, 30.0, 70.0, 70.0),  # parked
                 (0.0, 0.0, 6.0, 18.0, 45.0, 70.0),
                 (0.0, 0.0, 3.0, 9.0, 25.0, 60.0))    # at speed: less assistance, more feel
DAMPING = 0.02                                        # A per rad/s of motor speed
CURRENT_LIMIT = 70.0                                  # A


def boost(torque: float, speed: float) -> float:
    """The calibration's current (A) for a torsion-bar torque (N m) at a vehicle speed (m/s)."""
    mag = abs(torque)
    rows = [np.interp(mag, BOOST_TORQUE, row) for row in BOOST_CURRENT]
    return math.copysign(float(np.interp(speed, BOOST_SPEED, rows)), torque)


class EpsController:
    """The controller's logic on decoded samples; bus I/O is done by ``run``."""

    def __init__(self, codec: Codec):
        self.codec = codec
        self.decoder = SensorDecoder(codec, frames=EPS_FRAMES)
        names = codec.channels.sensor_names
        self._i = {n: names.index(n) for n in ("steering_torque", "eps_motor_speed", "vehicle_speed",
                                               "eps_power_stage")}
        self.command = 0.0
        self.counter = 0
        self.samples = 0
        self.t = 0.0
        self.peak_current = 0.0
        self.stage_off_at: float | None = None      # simulated time the power stage was seen off, s
        self.stage_seen_on = False

    def on_sample(self, t: float, values: np.ndarray) -> None:
        """One complete EPS sample at simulated time t (s): the next current command."""
        self.t = t
        self.samples += 1
        tb = values[self._i["steering_torque"]]
        i = boost(tb, values[self._i["vehicle_speed"]]) - DAMPING * values[self._i["eps_motor_speed"]]
        self.command = min(max(i, -CURRENT_LIMIT), CURRENT_LIMIT)
        self.peak_current = max(self.peak_current, abs(self.command))
        on = values[self._i["eps_power_stage"]] > 0.5
        if on:
            self.stage_seen_on = True
        elif self.stage_seen_on and self.stage_off_at is None:
            self.stage_off_at = t

    def command_frames(self) -> list[tuple[int, bytes]]:
        """The frames to send after a sample: the motor current command."""
        self.counter = (self.counter + 1) & 0xF
        return [self.codec.encode_command("motor_current_cmd", self.command, self.counter)]

    def summary(self) -> dict:
        return {"ecu_time": self.t, "samples": self.samples, "peak_current_cmd": self.peak_current,
                "stage_seen_on": self.stage_seen_on, "stage_off_at": self.stage_off_at}


def main(argv: list[str] | None = None) -> int:
    return bus_main("eps_demo", __doc__, lambda: EpsController(Codec(DBC, car_channels(("fl", "fr"), eps=True))), argv)


if __name__ == "__main__":
    sys.exit(main())
