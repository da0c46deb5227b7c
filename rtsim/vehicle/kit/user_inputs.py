"""What a person may drive of a vehicle (`rtsim view`'s keyboard, gamepad or wheel, through the service's
``drive`` op), declared once by the vehicle: its user channels in slot order with their ranges, units and
full scales, the bus command each competes with, which of the page's controls drives each, and how the
page groups them. The service's loop, its ``config`` answer (``user_inputs``) and the page read this;
none of them branches on the vehicle's kind.

The page has three controls, each in a unit range: ``throttle`` and ``brake`` 0..1 (a key ramped like a
pedal, a pedal axis), ``steer`` -1..1 (positive to the right). A channel's value is
``sign * control * full_scale`` in the channel's own unit. Channels come in *groups*: touching any control
of a group takes over every channel of the group (the rest stay with whoever drives them: the in-loop
driver or rider, the bus ECU). When the group's controls are all back at rest, its ``release`` says what
happens: ``"hold"`` keeps the channels at their rest values (a car coasts with its pedals up),
``"hand_back"`` hands them back (null: a rider in the loop keeps the speed again).

Priority (applied in the service's compiled step after the watchdog): a user channel replaces the in-loop
source's (the scenario's driver, the rider) always, and the bus ECU's command only where the bus has no
valid command or while the user has taken over; a channel whose bus command *adds* to it (an assist
torque on a rider's lean) is the user's whenever given, the ECU's part added unless the user took over.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

CONTROLS = ("throttle", "brake", "steer")      # the page's controls
RELEASE = ("hold", "hand_back")                # what a group does when its controls are back at rest
WRITES = ("command", "in_loop")


@dataclass(frozen=True)
class UserChannel:
    name: str
    lo: float                 # range, SI (unit)
    hi: float
    unit: str
    meaning: str
    full_scale: float         # > 0: what a full key or pedal asks, times ``sign``, SI (within lo .. hi)
    bus: str                  # the bus command it competes with
    control: str              # the page's control that drives it (CONTROLS)
    sign: float = 1.0         # +1 or -1: the channel's value at a full control is sign * full_scale
    adds_to_bus: bool = False  # the bus command adds to the user's input instead of replacing it

    def __post_init__(self):
        if self.control not in CONTROLS:
            raise ValueError(f"{self.name}: control {self.control!r}: expected one of {', '.join(CONTROLS)}")
        if self.sign not in (1.0, -1.0):
            raise ValueError(f"{self.name}: sign {self.sign!r} must be 1 or -1")
        if not (self.lo < self.hi and math.isfinite(self.full_scale) and self.full_scale > 0.0
                and self.lo <= self.sign * self.full_scale <= self.hi):
            raise ValueError(f"{self.name}: full scale {self.sign * self.full_scale:g} {self.unit} must be "
                             f"nonzero and within {self.lo:g} .. {self.hi:g}")


@dataclass(frozen=True)
class ControlGroup:
    """Channels (by name) the page takes over together; ``release``: one of RELEASE."""
    name: str
    release: str
    channels: tuple[str, ...]

    def __post_init__(self):
        if self.release not in RELEASE:
            raise ValueError(f"group {self.name}: release {self.release!r}: expected one of {', '.join(RELEASE)}")
        if not self.channels:
            raise ValueError(f"group {self.name}: no channels")


@dataclass(frozen=True)
class UserInputs:
    """A vehicle's user channels and the page's groups of them. ``writes``: "command" (the user's value
    goes into the bus command's slot of the step's command array) or "in_loop" (it replaces the in-loop
    source's output inside the step, and a takeover sets the competing bus command's invalid flag).
    ``in_loop``: the name of the in-loop source (who drives when neither the user nor the ECU does, if
    there is one); ``idle``: who drives when nobody does. ``plots``: the channels the page plots by
    default (what the person driving watches)."""
    channels: tuple[UserChannel, ...]
    groups: tuple[ControlGroup, ...]
    writes: str
    in_loop: str
    idle: str
    plots: tuple[str, ...] = ()

    def __post_init__(self):
        if self.writes not in WRITES:
            raise ValueError(f"writes {self.writes!r}: expected one of {', '.join(WRITES)}")
        grouped = [n for g in self.groups for n in g.channels]
        if len(set(self.names)) != len(self.names) or sorted(grouped) != sorted(self.names):
            raise ValueError(f"every user channel in exactly one group: channels {self.names}, groups {grouped}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    def table(self) -> dict[str, tuple[float, float, str, str]]:
        """name -> (lo, hi, unit, meaning), in slot order."""
        return {c.name: (c.lo, c.hi, c.unit, c.meaning) for c in self.channels}

    def full_scales(self) -> dict[str, float]:
        """name -> the channel's value at a full control (sign included), SI."""
        return {c.name: c.sign * c.full_scale for c in self.channels}

    def as_json(self) -> dict:
        """The declaration as the service's ``config`` answer sends it (``user_inputs``): the channels by
        name in slot order, the groups with their channels' names, the default plots."""
        return {"writes": self.writes, "in_loop": self.in_loop, "idle": self.idle,
                "channels": {c.name: {"lo": c.lo, "hi": c.hi, "unit": c.unit, "meaning": c.meaning,
                                      "full_scale": c.full_scale, "sign": c.sign, "control": c.control,
                                      "bus": c.bus, "adds_to_bus": c.adds_to_bus} for c in self.channels},
                "groups": [{"name": g.name, "release": g.release, "channels": list(g.channels)}
                           for g in self.groups],
                "plots": list(self.plots)}

    def slot(self, ch: UserChannel, command_slots: dict, invalid_slots: dict, bus_names) -> int:
        """The step's command-array slot the user channel writes ("command") or flags on a takeover
        ("in_loop": the competing bus command's invalid flag, if the bus carries it); -1: none."""
        if self.writes == "command":
            return command_slots.get(ch.name, -1)
        return invalid_slots.get(ch.bus, -1) if ch.bus in bus_names else -1

    def who(self, ch: UserChannel, user_set: bool, takeover: bool, valid: bool, in_loop: bool) -> str:
        """Who drives the channel now: "user", "ecu", the in-loop source's name, ``idle``; with
        "+ecu" where the bus command adds to it."""
        user = user_set and (takeover or not valid or ch.adds_to_bus)
        below = self.in_loop if in_loop else self.idle
        if ch.adds_to_bus:
            return ("user" if user else below) + ("+ecu" if valid and not (user and takeover) else "")
        return "user" if user else "ecu" if valid else below
