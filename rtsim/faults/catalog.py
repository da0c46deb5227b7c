"""The fault catalogue, declared once: every fault kind rtsim can inject into a session, its target type,
its parameters with their ranges and units, and what it does. Validation (rtsim.faults.spec), the
compiled table (rtsim.faults.table), the manual (docs/faults.md) and `rtsim faults --list` all read it.

Target types:

* ``sensor``: a sensor channel of the vehicle's channel dictionary (``accel_y``, ``brake_pressure``...);
  the fault changes the value the sensor reports, so every consumer (its CAN frame, the sensors topic)
  sees the faulted value from the onset's sample on;
* ``frame``: a CAN frame of the vehicle's DBC, by name or id (the simulator's sensor and status frames it
  sends, the ECU's command frames it receives); ``babble`` takes any id;
* ``bus``: the simulated bus segment as a whole (``bus_off``; target ``"bus"``);
* ``actuator``: an actuator the vehicle declares (``VehicleSim.fault_actuators``); arming a fault on a
  vehicle that does not have the actuator is refused.

Each parameter is a number with a closed range (integer parameters take whole numbers); a parameter
with a default may be left out. Actuator targets (the vehicle's actuator names): the car's ``throttle``,
``brake_fl`` .. ``brake_rr``, ``steering_motor`` (steer-by-wire) or ``eps_motor`` and ``eps_power_stage``
(an EPS car).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: s: the longest delay a delay fault may add (its ring is preallocated for it)
MAX_DELAY = 1.0
BIG = 1e9


@dataclass(frozen=True)
class Param:
    name: str
    lo: float
    hi: float
    unit: str
    meaning: str
    default: float | None = None      # None: required
    integer: bool = False


@dataclass(frozen=True)
class FaultKind:
    name: str
    code: int
    target: str                        # sensor, frame, bus, actuator
    params: tuple[Param, ...]
    description: str
    actuator: str | None = None        # actuator kinds: the actuator family it needs (VehicleSim.fault_actuators)

    def param(self, name: str) -> Param:
        return next(p for p in self.params if p.name == name)


_SEED = Param("seed", 0, 2**31 - 1, "", "seed of the fault's own random generator (same seed, same draws)", 1.0,
              integer=True)

KINDS: tuple[FaultKind, ...] = (
    # ---- sensor faults -------------------------------------------------------------------------------
    FaultKind("stuck_value", 1, "sensor", (Param("value", -BIG, BIG, "channel unit", "the value reported"),),
              "The channel reports a constant value."),
    FaultKind("stuck_last", 2, "sensor", (),
              "The channel keeps reporting its last value before the onset."),
    FaultKind("offset", 3, "sensor", (Param("offset", -BIG, BIG, "channel unit", "added to the value"),),
              "A constant offset is added to the channel's value."),
    FaultKind("drift", 4, "sensor", (Param("rate", -BIG, BIG, "channel unit/s", "growth of the offset per second"),),
              "An offset growing linearly from zero at the onset (rate times the time since the onset) is added."),
    FaultKind("gain", 5, "sensor", (Param("gain", -1e3, 1e3, "1", "factor on the value"),),
              "The channel's value is multiplied by a factor."),
    FaultKind("noise_burst", 6, "sensor", (Param("amplitude", 0.0, BIG, "channel unit", "half-width of the noise"),
                                           _SEED),
              "Uniform noise in [-amplitude, amplitude] from a seeded generator is added for the fault's duration."),
    FaultKind("dropout", 7, "sensor", (),
              "The CAN frame that carries the channel is not sent (the channel's value is unchanged elsewhere)."),
    FaultKind("delay", 8, "sensor", (Param("delay", 0.0, MAX_DELAY, "s", "age of the reported value: a whole number "
                                           "of the channel's sample periods"),),
              "The channel reports its value of `delay` seconds earlier."),
    FaultKind("out_of_range", 9, "sensor", (Param("value", -BIG, BIG, "channel unit", "the value reported: outside "
                                                  "the channel's DBC signal range"),),
              "The channel reports a value outside its DBC signal's range (the frame carries the saturated raw "
              "value, as a real sensor's out-of-range code)."),
    # ---- bus faults ------------------------------------------------------------------------------------
    FaultKind("loss", 20, "frame", (Param("probability", 0.0, 1.0, "", "chance that each frame is lost", 1.0),
                                    Param("n", 0, 1000, "", "pattern: lose n frames of every m (0: use the "
                                          "probability)", 0.0, integer=True),
                                    Param("m", 1, 1000, "", "pattern: cycle length in frames", 1.0, integer=True),
                                    _SEED),
              "Frames of the id are lost: each with a probability from a seeded generator, or the first n of every "
              "m frames counted from the onset."),
    FaultKind("frame_delay", 21, "frame", (Param("delay", 0.0, MAX_DELAY, "s", "added latency: whole steps"),),
              "Frames of the id arrive (are sent, or are taken by the simulator) `delay` seconds late."),
    FaultKind("corrupt_crc", 22, "frame", (),
              "Received frames of the id arrive with their CRC byte inverted (the E2E check rejects them); the id "
              "must be a command frame with a CRC."),
    FaultKind("corrupt_counter", 23, "frame", (Param("add", 1, 15, "", "added to the alive counter (mod its range)",
                                                     8.0, integer=True),),
              "Received frames of the id arrive with their alive counter moved by `add` and a CRC that matches "
              "(a sender's counter bug: the E2E check sees a jump); the id must be a command frame with a counter."),
    FaultKind("babble", 24, "frame", (Param("period", 1e-4, 10.0, "s", "sending period: whole steps"),
                                      Param("payload", 0, 2**64 - 1, "", "8 payload bytes as a little-endian "
                                            "integer (TOML: 0x0807060504030201: byte 0 is 0x01)", 0.0,
                                            integer=True)),
              "A frame of the id (any id) is sent every period with a fixed payload, from the onset."),
    FaultKind("bus_off", 25, "bus", (),
              "The simulator's bus controller is off: no frame in or out (the lockstep SIM_STEP_REQ and "
              "SIM_STEP_ACK excepted: they drive the simulation, not the bus)."),
    # ---- actuator faults ------------------------------------------------------------------------------
    FaultKind("stuck_throttle", 40, "actuator", (Param("value", 0.0, 2.0, "rad", "plate angle it sticks at "
                                                       "(leave out: the angle commanded at the onset)", math.nan),),
              "The throttle plate's command sticks (at a value, or at the command at the onset).",
              actuator="throttle"),
    FaultKind("brake_loss", 41, "actuator", (),
              "One wheel's brake loses its pressure: no brake torque at that wheel (target: brake_fl, brake_fr, ...).",
              actuator="wheel_brake"),
    FaultKind("caliper_stuck", 42, "actuator", (),
              "One wheel's caliper sticks: its brake torque stays at the value of the onset whatever the pressure "
              "(target: brake_fl, brake_fr, ...).", actuator="wheel_brake"),
    FaultKind("steering_motor_failure", 43, "actuator", (),
              "The steering motor (steer-by-wire rack motor or EPS assist motor) gives no torque.",
              actuator="steering_motor"),
    FaultKind("power_stage_off", 44, "actuator", (),
              "The EPS power stage is switched off: the motor's safe state (no current, as the stage's own fault "
              "reaction), reported by the vehicle's power-stage channel.", actuator="power_stage"),
)

BY_NAME: dict[str, FaultKind] = {k.name: k for k in KINDS}
BY_CODE: dict[int, FaultKind] = {k.code: k for k in KINDS}
TARGETS = ("sensor", "frame", "bus", "actuator")

# kind codes the kernels branch on
K_STUCK_VALUE, K_STUCK_LAST, K_OFFSET, K_DRIFT, K_GAIN, K_NOISE, K_DROPOUT, K_DELAY, K_OUT_OF_RANGE = range(1, 10)
K_LOSS, K_FRAME_DELAY, K_CORRUPT_CRC, K_CORRUPT_COUNTER, K_BABBLE, K_BUS_OFF = range(20, 26)
K_STUCK_THROTTLE, K_BRAKE_LOSS, K_CALIPER_STUCK, K_STEERING_MOTOR, K_POWER_STAGE = range(40, 45)
assert [k.code for k in KINDS] == [*range(1, 10), *range(20, 26), *range(40, 45)]


def listing() -> str:
    """The catalogue as text (`rtsim faults --list`)."""
    lines = []
    for target in TARGETS:
        lines.append(f"{target} faults:")
        for k in (k for k in KINDS if k.target == target):
            lines.append(f"  {k.name}: {k.description}")
            for p in k.params:
                fmt = "d" if p.integer else "g"
                rng = f"{p.lo:{fmt}} .. {p.hi:{fmt}}" if not p.integer else f"{int(p.lo)} .. {int(p.hi)}"
                rng += f" {p.unit}" if p.unit else ""
                dflt = "" if p.default is None else (" (default: the command at the onset)" if p.default != p.default
                                                     else f" (default {p.default:g})")
                lines.append(f"      {p.name}: {p.meaning}; {rng}{dflt}")
    lines.append("triggers (one of): at = s | when = \"CHANNEL > value\" (also <, abs(CHANNEL) > value; a sensor or "
                 "state channel, at its samples) | after = \"FAULT_ID\" with after_delay = s; none: at the next "
                 "step (live); duration = s (leave out: until cleared)")
    return "\n".join(lines)
