"""The channel dictionary: every signal's name, SI unit and meaning, used alike by the vehicle model,
the DBC, MCAP schemas, Zenoh payloads, CSV exports and the validation workflow.

Axes and signs follow ISO 8855 throughout: x forward, y left, z up; positive yaw rate turns left;
positive steer angle steers left; wheel order fl, fr, rl, rr.
"""
from __future__ import annotations

import json
from dataclasses import dataclass


@dataclass(frozen=True)
class Channel:
    name: str
    unit: str
    description: str


def _ch(name, unit, description):
    return Channel(name, unit, description)


WHEELS = ("fl", "fr", "rl", "rr")

def car_sensors(driven=("rl", "rr")) -> tuple[Channel, ...]:
    """The four-wheel car's sensor channels (the seed's Table 1), sampled at 500 Hz; the two drive-torque
    sensors sit on the driven wheels (`driven`: left, right wheel names)."""
    left, right = driven
    return (
        _ch("accel_x", "m/s^2", "specific force at the sensor mounting point, body x"),
        _ch("accel_y", "m/s^2", "specific force at the sensor mounting point, body y"),
        _ch("accel_z", "m/s^2", "specific force at the sensor mounting point, body z"),
        _ch("gyro_x", "rad/s", "body angular rate about x (roll rate)"),
        _ch("gyro_y", "rad/s", "body angular rate about y (pitch rate)"),
        _ch("gyro_z", "rad/s", "body angular rate about z (yaw rate, positive turning left)"),
        _ch("roll", "rad", "inclinometer roll angle, positive right side down"),
        _ch("pitch", "rad", "inclinometer pitch angle, positive nose down"),
        *(_ch(f"wheel_angle_{w}", "rad", f"cumulative rotation angle of wheel {w}, positive rolling forward")
          for w in WHEELS),
        _ch("brake_pressure", "kPa", "brake line pressure"),
        _ch("steering_wheel_angle", "rad", "steering-wheel angle, positive steering left"),
        _ch("steer_angle_fl", "rad", "road-wheel steer angle front left, positive left"),
        _ch("steer_angle_fr", "rad", "road-wheel steer angle front right, positive left"),
        _ch("engine_speed", "rad/s", "engine crankshaft speed"),
        _ch("steering_torque", "N*m", "inline torque sensor on the steering column (torsion bar)"),
        _ch("throttle_angle", "rad", "throttle plate angle"),
        _ch(f"wheel_torque_{left}", "N*m", f"drive/brake torque measured at the driven wheel {left}"),
        _ch(f"wheel_torque_{right}", "N*m", f"drive/brake torque measured at the driven wheel {right}"),
    )


#: Actuator commands from the ECU.
COMMANDS: tuple[Channel, ...] = (
    _ch("throttle_angle_cmd", "rad", "commanded throttle angle"),
    _ch("brake_pressure_cmd", "kPa", "commanded brake line pressure"),
    _ch("steering_wheel_angle_cmd", "rad", "commanded steering-wheel angle"),
)

#: The electric power steering's own sensors (cars with ``[eps]``), after the car's: what its controller
#: reads beside the torsion-bar torque (``steering_torque``) and the steering-wheel angle.
EPS_SENSORS: tuple[Channel, ...] = (
    _ch("eps_motor_angle", "rad", "EPS motor rotor angle (position sensor), positive steering left"),
    _ch("eps_motor_speed", "rad/s", "EPS motor speed, positive steering left"),
    _ch("eps_motor_current", "A", "EPS motor current (the drive's current sensor)"),
    _ch("eps_power_stage", "1", "EPS power stage: 1 on, 0 off (not yet enabled, or the safe state)"),
    _ch("vehicle_speed", "m/s", "vehicle speed as the chassis bus reports it (centre-of-mass speed)"),
)

#: The EPS controller's command (cars with ``[eps]`` served in the loop: the controller under test
#: replaces the built-in assistance law; the driver's inputs come from the scenario).
EPS_COMMANDS: tuple[Channel, ...] = (
    _ch("motor_current_cmd", "A", "EPS motor current command (executed by the drive's current loop)"),
)

#: Vehicle state published for observers (Zenoh ``state``, MCAP ``state``), 100 Hz by default.
STATE: tuple[Channel, ...] = (
    _ch("pos_x", "m", "centre of mass x, world frame"),
    _ch("pos_y", "m", "centre of mass y, world frame"),
    _ch("pos_z", "m", "centre of mass z, world frame"),
    _ch("roll_angle", "rad", "chassis roll (Euler z-y-x), positive right side down"),
    _ch("pitch_angle", "rad", "chassis pitch (Euler z-y-x), positive nose down"),
    _ch("yaw_angle", "rad", "chassis yaw (Euler z-y-x), positive turning left"),
    _ch("vel_x", "m/s", "centre-of-mass velocity, body x (forward)"),
    _ch("vel_y", "m/s", "centre-of-mass velocity, body y (left)"),
    _ch("vel_z", "m/s", "centre-of-mass velocity, body z (up)"),
    _ch("roll_rate", "rad/s", "body angular rate about x"),
    _ch("pitch_rate", "rad/s", "body angular rate about y"),
    _ch("yaw_rate", "rad/s", "body angular rate about z"),
    _ch("speed", "m/s", "magnitude of the centre-of-mass velocity"),
    *(_ch(f"wheel_speed_{w}", "rad/s", f"spin rate of wheel {w}, positive rolling forward") for w in WHEELS),
    *(_ch(f"tyre_fx_{w}", "N", f"longitudinal tyre force {w}, tyre frame") for w in WHEELS),
    *(_ch(f"tyre_fy_{w}", "N", f"lateral tyre force {w}, tyre frame") for w in WHEELS),
    *(_ch(f"tyre_fz_{w}", "N", f"vertical tyre load {w}") for w in WHEELS),
    *(_ch(f"slip_ratio_{w}", "1", f"longitudinal slip ratio {w}") for w in WHEELS),
    *(_ch(f"slip_angle_{w}", "rad", f"tyre slip angle {w}") for w in WHEELS),
    *(_ch(f"brake_torque_{w}", "N*m", f"brake torque on wheel {w}") for w in WHEELS),
    _ch("throttle_angle", "rad", "throttle plate angle (actuator state)"),
    _ch("brake_pressure", "kPa", "brake line pressure (actuator state)"),
    _ch("steering_wheel_angle", "rad", "steering-wheel angle (actuator state)"),
    _ch("rack_position", "m", "steering rack position, positive steering left"),
    _ch("engine_speed", "rad/s", "engine crankshaft speed"),
    _ch("constraint_violation", "1", "max |Phi| of the multibody constraints (coordinate units)"),
)

#: The power audit of a run (rtsim.vehicle.car.energy), recorded beside the sensors and state of offline
#: runs (MCAP topic ``energy``, CSV columns): cumulative work of every port on the vehicle (J, positive:
#: energy into the vehicle), the stored energies' change since the audit started (J), the balance's
#: residual, and the electric power steering's electrical and actuator values (zero without EPS).
ENERGY_FLOWS = ("tyres", "dampers", "axle_reactions", "brakes", "drive", "aero", "effects", "steer_by_wire",
                "driver_torque", "column_friction", "motor_friction", "gear_loss", "pinion_friction",
                "rack_loss", "rack_friction", "driver_angle", "joints", "motor_supply", "motor_winding",
                "motor_conversion")
ENERGY_STORED = ("kinetic", "gravity", "suspension_springs", "anti_roll_bars", "torsion_bar", "inductance")
ENERGY: tuple[Channel, ...] = (
    *(_ch(f"work_{n}", "J", f"work done on the vehicle through the {n.replace('_', ' ')} port") for n in ENERGY_FLOWS),
    *(_ch(f"stored_{n}", "J", f"change of the {n.replace('_', ' ')} energy since the audit started")
      for n in ENERGY_STORED),
    _ch("energy_residual", "J", "stored change - (inputs - dissipation): the integrator's energy error"),
    _ch("motor_current", "A", "EPS motor current"),
    _ch("motor_voltage", "V", "EPS motor drive voltage"),
    _ch("motor_power", "W", "EPS motor electrical input power"),
    _ch("motor_speed", "rad/s", "EPS motor speed"),
    _ch("motor_angle", "rad", "EPS motor angle"),
    _ch("torsion_bar_torque", "N*m", "EPS torsion-bar torque (the torque sensor)"),
    _ch("driver_torque", "N*m", "the driver's torque on the steering wheel"),
    _ch("assist_torque", "N*m", "EPS assistance torque at the pinion"),
)

#: A two-wheeler's sensors (rtsim.vehicle.motorcycle.plant): the IMU on the rear frame, the wheel-speed
#: sensors, the steering head's angle, rate and torque sensors, the suspension potentiometers, the
#: rider's demands (throttle grip, brake lever and pedal master cylinders) and the actuators' states.
#: A rider-assist ECU reads the rider's demands and may replace them (see configs/can/motorcycle.dbc).
TWO_WHEELER_SENSORS: tuple[Channel, ...] = (
    _ch("accel_x", "m/s^2", "specific force at the IMU on the rear frame, frame x (forward)"),
    _ch("accel_y", "m/s^2", "specific force at the IMU, frame y (left)"),
    _ch("accel_z", "m/s^2", "specific force at the IMU, frame z (up)"),
    _ch("gyro_x", "rad/s", "rear frame angular rate about its x (roll rate)"),
    _ch("gyro_y", "rad/s", "rear frame angular rate about its y (pitch rate)"),
    _ch("gyro_z", "rad/s", "rear frame angular rate about its z (yaw rate in the frame, positive turning left)"),
    _ch("roll", "rad", "rear frame roll (the IMU's attitude), positive leaning right (right side down)"),
    _ch("pitch", "rad", "rear frame pitch (the IMU's attitude), positive nose down"),
    _ch("wheel_speed_front", "rad/s", "front wheel spin rate relative to the fork, positive rolling forward"),
    _ch("wheel_speed_rear", "rad/s", "rear wheel spin rate relative to the swingarm, positive rolling forward"),
    _ch("steer_angle", "rad", "handlebar angle about the steering axis, positive steering left"),
    _ch("steer_rate", "rad/s", "handlebar rate about the steering axis, positive steering left"),
    _ch("steering_torque", "N*m", "the rider's torque on the handlebars (steering-head torque sensor), positive steering left"),
    _ch("fork_travel", "m", "fork compression from full extension"),
    _ch("shock_travel", "m", "rear shock compression from full extension"),
    _ch("rider_throttle", "1", "the rider's throttle grip, 0 closed .. 1 fully open"),
    _ch("rider_brake_front", "kPa", "front master cylinder pressure (the rider's brake lever)"),
    _ch("rider_brake_rear", "kPa", "rear master cylinder pressure (the rider's brake pedal)"),
    _ch("throttle", "1", "throttle opening acting on the engine, 0 .. 1"),
    _ch("brake_pressure_front", "kPa", "front caliper pressure acting on the brake"),
    _ch("brake_pressure_rear", "kPa", "rear caliper pressure acting on the brake"),
)

#: A two-wheeler's commands from a rider-assist ECU: each replaces the rider's demand while it is valid
#: (the rider's own demand acts when it is missing or timed out); the steering torque adds to the rider's.
TWO_WHEELER_COMMANDS: tuple[Channel, ...] = (
    _ch("throttle_cmd", "1", "commanded throttle opening, 0 .. 1 (ride-by-wire)"),
    _ch("brake_pressure_front_cmd", "kPa", "commanded front caliper pressure (ABS modulator)"),
    _ch("brake_pressure_rear_cmd", "kPa", "commanded rear caliper pressure (ABS modulator)"),
    _ch("assist_torque_cmd", "N*m", "additional steering torque on the steering axis (steering assist), positive steering left"),
)

#: A two-wheeler's state for observers (Zenoh ``state``, MCAP ``state``): the rear frame's pose and
#: motion, the steering, suspension and wheels, the tyres, the inputs and the rider's path error.
TWO_WHEELER_STATE: tuple[Channel, ...] = (
    _ch("pos_x", "m", "swingarm pivot (the rear frame's reference point) x, world frame"),
    _ch("pos_y", "m", "swingarm pivot y, world frame"),
    _ch("pos_z", "m", "swingarm pivot z, world frame"),
    _ch("roll_angle", "rad", "rear frame roll, positive leaning right (right side down)"),
    _ch("pitch_angle", "rad", "rear frame pitch, positive nose down"),
    _ch("yaw_angle", "rad", "rear frame heading, positive turning left"),
    _ch("vel_x", "m/s", "swingarm pivot velocity along the heading (forward)"),
    _ch("vel_y", "m/s", "swingarm pivot velocity across the heading (left)"),
    _ch("vel_z", "m/s", "swingarm pivot velocity, vertical"),
    _ch("roll_rate", "rad/s", "rate of the roll angle (angular velocity about the heading)"),
    _ch("pitch_rate", "rad/s", "rear frame angular rate about its y axis"),
    _ch("yaw_rate", "rad/s", "angular rate about the vertical, positive turning left"),
    _ch("speed", "m/s", "horizontal speed of the swingarm pivot"),
    _ch("steer_angle", "rad", "steer angle about the steering axis, positive left"),
    _ch("steer_rate", "rad/s", "steer rate, positive left"),
    _ch("fork_travel", "m", "fork compression from full extension"),
    _ch("shock_travel", "m", "rear shock compression from full extension"),
    _ch("swingarm_angle", "rad", "swingarm angle from its design position, positive rear axle up relative to the frame"),
    _ch("wheel_speed_front", "rad/s", "front wheel spin rate relative to the fork"),
    _ch("wheel_speed_rear", "rad/s", "rear wheel spin rate relative to the swingarm"),
    _ch("wheel_angle_front", "rad", "front wheel spin angle relative to the fork"),
    _ch("wheel_angle_rear", "rad", "rear wheel spin angle relative to the rear frame"),
    *(_ch(f"tyre_{k}_{w}", u, f"{what}, {w} tyre") for w in ("front", "rear") for k, u, what in (
        ("fx", "N", "longitudinal tyre force (tyre frame)"), ("fy", "N", "lateral tyre force (tyre frame)"),
        ("fz", "N", "vertical tyre load"), ("mz", "N*m", "tyre twisting moment"),
        ("slip_ratio", "1", "longitudinal slip ratio"), ("slip_angle", "rad", "slip angle"),
        ("camber", "rad", "camber angle"))),
    _ch("steering_torque", "N*m", "the rider's torque on the handlebars"),
    _ch("assist_torque", "N*m", "the assist torque applied (the ECU's command while valid)"),
    _ch("drive_torque", "N*m", "drive torque at the rear wheel"),
    _ch("throttle", "1", "throttle opening acting on the engine"),
    _ch("brake_pressure_front", "kPa", "front caliper pressure acting"),
    _ch("brake_pressure_rear", "kPa", "rear caliper pressure acting"),
    _ch("engine_speed", "rad/s", "engine crankshaft speed (0 without an engine model)"),
    _ch("gear", "1", "engaged gear, 1 .. n (0 without an engine model)"),
    _ch("path_offset", "m", "the rider's lateral offset from the path, left positive (0 without a rider)"),
    _ch("constraint_violation", "1", "max |Phi| of the multibody constraints (coordinate units)"),
)

#: The units a channel may have: SI units and the SI-derived ones the interface uses (``1``: dimensionless).
SI_UNITS = frozenset(("1", "s", "ms", "m", "m/s", "m/s^2", "rad", "rad/s", "rad/s^2", "N", "N*m", "Pa",
                      "kPa", "kg", "K", "A", "V", "W", "J"))
KINDS = ("sensors", "commands", "state")


@dataclass(frozen=True)
class ChannelDictionary:
    """A vehicle's interface: its sensor, command and state channels (names, SI units, meanings). The
    DBC, the MCAP and JSON schemas, the Zenoh payloads, the CSV exports and the validation workflow of
    that vehicle are derived from it. Names are unique within each kind and across sensors and
    commands (they share the DBC); every unit is one of ``SI_UNITS``."""
    sensors: tuple[Channel, ...]
    commands: tuple[Channel, ...]
    state: tuple[Channel, ...]

    def __post_init__(self):
        for kind, names in (("sensor and command", [c.name for c in self.sensors + self.commands]),
                            ("state", [c.name for c in self.state])):
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ValueError(f"{kind} channel names must be unique; repeated: {', '.join(dup)}")
        for kind in KINDS:
            for c in getattr(self, kind):
                if not c.name.isidentifier():
                    raise ValueError(f"{kind} channel {c.name!r}: a name must be an identifier")
                if c.unit not in SI_UNITS:
                    raise ValueError(f"{kind} channel {c.name}: unit {c.unit!r} is not one of "
                                     f"{', '.join(sorted(SI_UNITS))}")

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.sensors)

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.state)

    @property
    def command_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.commands)

    @property
    def by_name(self) -> dict[str, Channel]:
        """Sensor and command channels by name (state channels: ``index("state", name)``)."""
        return {c.name: c for c in self.sensors + self.commands}

    def index(self, kind: str, name: str) -> int:
        """Position of channel `name` among the `kind` channels ("sensors", "commands", "state")."""
        if kind not in KINDS:
            raise ValueError(f"channel kind {kind!r} is not one of {', '.join(KINDS)}")
        names = [c.name for c in getattr(self, kind)]
        if name not in names:
            raise KeyError(f"{name!r} is not a {kind} channel of the vehicle (its {kind}: {', '.join(names)})")
        return names.index(name)

    def to_json(self) -> str:
        """The dictionary as JSON (recorded with a session, so a replay knows its channels)."""
        return json.dumps({k: [[c.name, c.unit, c.description] for c in getattr(self, k)] for k in KINDS})

    @classmethod
    def from_json(cls, text: str) -> "ChannelDictionary":
        """The dictionary ``to_json`` wrote (ValueError if it is not one)."""
        try:
            d = json.loads(text)
            return cls(*(tuple(Channel(str(n), str(u), str(t)) for n, u, t in d[k]) for k in KINDS))
        except (TypeError, KeyError, json.JSONDecodeError) as exc:
            raise ValueError(f"not a channel dictionary: {exc}") from None


def car_channels(driven=("rl", "rr"), eps: bool = False) -> ChannelDictionary:
    """The four-wheel car's channel dictionary, its drive-torque sensors on the `driven` wheels; with
    `eps` (electric power steering), the EPS's sensors after the car's and its controller's command
    instead of the by-wire commands."""
    if eps:
        return ChannelDictionary(car_sensors(driven) + EPS_SENSORS, EPS_COMMANDS, STATE)
    return ChannelDictionary(car_sensors(driven), COMMANDS, STATE)


def two_wheeler_channels() -> ChannelDictionary:
    """A two-wheeler's channel dictionary (the motorcycle's, and any two-wheeler the kit assembles)."""
    return ChannelDictionary(TWO_WHEELER_SENSORS, TWO_WHEELER_COMMANDS, TWO_WHEELER_STATE)


#: The rear-wheel-drive car's dictionary: the default where no vehicle is at hand (a vehicle in use
#: carries its own: VehicleModel.channels).
CAR = car_channels()
SENSORS = CAR.sensors
SENSOR_NAMES = CAR.sensor_names
STATE_NAMES = CAR.state_names
COMMAND_NAMES = CAR.command_names
BY_NAME = {c.name: c for c in car_sensors(("fl", "fr")) + SENSORS + COMMANDS + EPS_SENSORS + EPS_COMMANDS}


@dataclass(frozen=True)
class Plausible:
    """The range a channel's reading can take on a road vehicle, in the channel's SI unit: wide enough for
    any real manoeuvre and sensor offset, narrow enough that the same signal logged in another unit (degrees
    for radians, km/h for m/s, Pa for kPa, rpm for rad/s, mm for m, percent for a fraction) falls outside it.
    `rate`: the range holds the channel's time derivative (per s) instead of its value (a cumulative angle);
    `other_unit`: the likely mistake named when a reading falls outside."""
    lo: float
    hi: float
    other_unit: str
    rate: bool = False


_PRESSURE = Plausible(-200.0, 25_000.0, "Pa or psi")          # kPa: 250 bar is far above any brake line
_WHEEL_ANGLE = Plausible(-30.0, 400.0, "degrees", rate=True)  # rad/s: about 110 m/s on a 0.28 m wheel
_FRACTION = Plausible(-0.05, 1.05, "percent")

#: The plausible range of every sensor and command channel of the shipped dictionaries (declared once,
#: here; the validation workflow's data checks read it; tests/test_validate_data.py checks it is complete).
PLAUSIBLE: dict[str, Plausible] = {
    **{f"accel_{a}": Plausible(-60.0, 60.0, "g or ft/s^2") for a in "xyz"},       # about 6 g
    **{f"gyro_{a}": Plausible(-10.0, 10.0, "deg/s") for a in "xyz"},
    "roll": Plausible(-1.7, 1.7, "degrees"),            # a two-wheeler lying on its side: about 1.5 rad
    "pitch": Plausible(-1.2, 1.2, "degrees"),
    **{f"wheel_angle_{w}": _WHEEL_ANGLE for w in WHEELS},
    "brake_pressure": _PRESSURE, "brake_pressure_cmd": _PRESSURE,
    "steering_wheel_angle": Plausible(-15.0, 15.0, "degrees"),      # more than 2 turns either way
    "steering_wheel_angle_cmd": Plausible(-15.0, 15.0, "degrees"),
    "steer_angle_fl": Plausible(-1.2, 1.2, "degrees"), "steer_angle_fr": Plausible(-1.2, 1.2, "degrees"),
    "engine_speed": Plausible(-50.0, 1_300.0, "rpm"),                # 12 400 rpm
    "steering_torque": Plausible(-150.0, 150.0, "N*cm"),
    "throttle_angle": Plausible(-0.2, 1.8, "degrees"), "throttle_angle_cmd": Plausible(-0.2, 1.8, "degrees"),
    **{f"wheel_torque_{w}": Plausible(-20_000.0, 20_000.0, "N*cm") for w in WHEELS},
    "eps_motor_angle": Plausible(-5_000.0, 5_000.0, "degrees"),
    "eps_motor_speed": Plausible(-1_500.0, 1_500.0, "rpm"),
    "eps_motor_current": Plausible(-300.0, 300.0, "mA"), "motor_current_cmd": Plausible(-300.0, 300.0, "mA"),
    "eps_power_stage": Plausible(0.0, 1.0, "another code"),
    "vehicle_speed": Plausible(-10.0, 90.0, "km/h"),
    "wheel_speed_front": Plausible(-30.0, 400.0, "rpm or deg/s"),
    "wheel_speed_rear": Plausible(-30.0, 400.0, "rpm or deg/s"),
    "steer_angle": Plausible(-1.2, 1.2, "degrees"), "steer_rate": Plausible(-20.0, 20.0, "deg/s"),
    "fork_travel": Plausible(-0.02, 0.4, "mm"), "shock_travel": Plausible(-0.02, 0.3, "mm"),
    "rider_throttle": _FRACTION, "throttle": _FRACTION, "throttle_cmd": _FRACTION,
    "rider_brake_front": _PRESSURE, "rider_brake_rear": _PRESSURE,
    "brake_pressure_front": _PRESSURE, "brake_pressure_rear": _PRESSURE,
    "brake_pressure_front_cmd": _PRESSURE, "brake_pressure_rear_cmd": _PRESSURE,
    "assist_torque_cmd": Plausible(-150.0, 150.0, "N*cm"),
}
