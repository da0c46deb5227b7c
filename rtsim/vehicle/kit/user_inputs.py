"""What a person may drive of a vehicle (`rtsim view`'s keyboard, gamepad or wheel, through the service's
``drive`` op), declared by the vehicle: its user channels in slot order, their ranges and full scales,
the bus command each competes with, and how the user's value acts. The service's loop and the viewer
read this; neither branches on the vehicle's kind.

Priority (applied in the service's compiled step after the watchdog): a user channel replaces the in-loop
source's (the scenario's driver, the rider) always, and the bus ECU's command only where the bus has no
valid command or while the user has taken over; a channel whose bus command *adds* to it (an assist
torque on a rider's lean) is the user's whenever given, the ECU's part added unless the user took over.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class UserChannel:
    name: str
    lo: float                 # range, SI (unit)
    hi: float
    unit: str
    meaning: str
    full_scale: float         # what a full key or pedal asks by default, SI (within lo .. hi)
    bus: str                  # the bus command it competes with
    adds_to_bus: bool = False  # the bus command adds to the user's input instead of replacing it


@dataclass(frozen=True)
class UserInputs:
    """A vehicle's user channels. ``writes``: "command" (the user's value goes into the bus command's
    slot of the step's command array) or "in_loop" (it replaces the in-loop source's output inside the
    step, and a takeover sets the competing bus command's invalid flag). ``in_loop``: the name of the
    in-loop source (who drives when neither the user nor the ECU does, if there is one); ``idle``: who
    drives when nobody does."""
    channels: tuple[UserChannel, ...]
    writes: str
    in_loop: str
    idle: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    def table(self) -> dict[str, tuple[float, float, str, str]]:
        """name -> (lo, hi, unit, meaning), in slot order."""
        return {c.name: (c.lo, c.hi, c.unit, c.meaning) for c in self.channels}

    def full_scales(self) -> dict[str, float]:
        return {c.name: c.full_scale for c in self.channels}

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
