"""What a person's controls mean for a vehicle (`rtsim view`'s keyboard, gamepad or wheel): a part each
vehicle fills in from its own config, sent to the page with the service's configuration.

The page has three controls, each in a unit range: ``throttle`` and ``brake`` 0..1 (a key ramped like a
pedal, a pedal axis), ``steer`` -1..1 (positive to the right). A vehicle maps them onto its user channels
(rtsim.service.user_input) in *groups*: touching any control of a group takes over every channel of the
group (the rest stay with whoever drives them: the in-loop driver or rider, the bus ECU); a channel's value
is ``sign * control * full_scale`` in the channel's own unit. When the group's controls are all back at
rest, ``release`` says what happens: ``"hold"`` keeps the channels at their rest values (a car coasts with
its pedals up), ``"hand_back"`` hands them back (null: a rider in the loop keeps the speed again).
"""
from __future__ import annotations

import math

CONTROLS = ("throttle", "brake", "steer")
RELEASE = ("hold", "hand_back")


def channel(name: str, control: str, full_scale: float, sign: float = 1.0) -> dict:
    """One user channel driven by ``control``: value = sign * control * full_scale (channel's unit)."""
    if control not in CONTROLS:
        raise ValueError(f"control {control!r}: expected one of {', '.join(CONTROLS)}")
    if not (math.isfinite(full_scale) and full_scale > 0.0):
        raise ValueError(f"{name}: full_scale {full_scale!r} must be a positive finite number")
    if sign not in (1.0, -1.0):
        raise ValueError(f"{name}: sign {sign!r} must be 1 or -1")
    return {"channel": name, "control": control, "full_scale": float(full_scale), "sign": float(sign)}


def group(name: str, release: str, *channels: dict) -> dict:
    """Channels taken over together (see the module docstring)."""
    if release not in RELEASE:
        raise ValueError(f"group {name}: release {release!r}: expected one of {', '.join(RELEASE)}")
    if not channels:
        raise ValueError(f"group {name}: no channels")
    return {"name": name, "release": release, "channels": list(channels)}


def view_description(groups: list[dict], plots: list[str]) -> dict:
    """What the page needs of a vehicle: its control groups and the channels plotted by default."""
    seen = [c["channel"] for g in groups for c in g["channels"]]
    if len(seen) != len(set(seen)):
        raise ValueError(f"a user channel in two control groups: {seen}")
    return {"controls": groups, "plots": list(plots)}
