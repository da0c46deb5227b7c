"""A vehicle's command space, read from its DBC, and command sequences drawn in it.

The command space (``command_space``) is every value signal of the DBC's command frames (frames the ECU
sends with an ``E2EDataID``; the lockstep request is not a command): its name, its [min, max] from the
DBC and its frame's period (``GenMsgCycleTime``, ms). A car whose DBC does not carry the driver's inputs
(the EPS car: the controller under test commands the motor current, the scenario's driver steers,
throttles and brakes) has those inputs added as ``driver`` commands, each ranged by the DBC's sensor
signal of the same quantity (``steering_wheel_angle_cmd`` by ``steering_wheel_angle``, ...): the DBC
says what range the quantity can take on the bus. Nothing is clamped here: the values drawn are the
values the bus can carry.

A sequence is a tuple of ``Segment``: from the values reached so far, a ``step`` to new values held for
``frames`` command periods, a ``ramp`` to them over ``frames`` periods, or a ``chatter`` between the
values before and the new ones every ``period`` frames. Values are drawn from each command's ends and
zero (full lock, full throttle, full brake, released) or anywhere in its range, so steps from lock to
lock and full throttle with full brake at once are drawn often. Sequences are plain data (``to_json`` /
``from_json``), so a failing case is kept and replayed as it was drawn.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

STEP_REQUEST = "SIM_STEP_REQ"                 # an ECU frame with an E2EDataID that carries no command
SHAPES = ("step", "ramp", "chatter")


@dataclass(frozen=True)
class Command:
    """One command: its channel name, its range [lo, hi] in the DBC's unit, its period (s), and whether
    the bus carries it (``bus``) or the in-loop driver (``driver``: ranged by the DBC's sensor signal)."""
    name: str
    lo: float
    hi: float
    unit: str
    period_s: float
    source: str = "bus"

    @property
    def rest(self) -> float:
        """The released value: zero where the range holds it, else its end nearer zero."""
        return min(max(0.0, self.lo), self.hi)


@dataclass(frozen=True)
class CommandSpace:
    """The commands of a vehicle (bus commands first, in the DBC's frame order), and the command period
    sequences are written in (the fastest command frame's, s)."""
    dbc: str
    commands: tuple[Command, ...]
    frame_s: float

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.commands)

    def rest(self) -> np.ndarray:
        return np.array([c.rest for c in self.commands])


def command_space(dbc: str | Path, driver_inputs: tuple[str, ...] = ()) -> CommandSpace:
    """The command space of the DBC (module docstring); ``driver_inputs``: command channels the in-loop
    driver writes (``<quantity>_cmd``) that the DBC carries only as the sensor signal ``<quantity>``."""
    import cantools  # imported here: only the robustness check and the bridge need it

    db = cantools.database.load_file(str(dbc), strict=True)
    out: list[Command] = []
    periods = []
    for msg in db.messages:
        if "ECU" not in (msg.senders or []) or msg.name == STEP_REQUEST:
            continue
        attrs = msg.dbc.attributes if msg.dbc is not None else {}
        if "E2EDataID" not in attrs:
            continue
        period = float(attrs["GenMsgCycleTime"].value) * 1e-3 if "GenMsgCycleTime" in attrs else 0.0
        if not period > 0.0:
            raise ValueError(f"{dbc}: command frame {msg.name} has no GenMsgCycleTime")
        periods.append(period)
        for s in msg.signals:
            if s.name.endswith("_counter") or s.name.endswith("_crc"):
                continue
            out.append(Command(s.name, float(s.minimum), float(s.maximum), s.unit or "", period))
    if not out:
        raise ValueError(f"{dbc}: no command frames")
    frame_s = min(periods)
    bus = {c.name for c in out}
    for name in driver_inputs:
        if name in bus:
            continue
        quantity = name[:-len("_cmd")] if name.endswith("_cmd") else name
        sig = next((s for m in db.messages for s in m.signals if s.name == quantity), None)
        if sig is None:
            raise ValueError(f"{dbc}: the driver's input {name} has no signal {quantity} to range it")
        out.append(Command(name, float(sig.minimum), float(sig.maximum), sig.unit or "", frame_s, "driver"))
    return CommandSpace(str(dbc), tuple(out), frame_s)


@dataclass(frozen=True)
class Segment:
    """One part of a sequence (module docstring): ``values`` in the space's command order."""
    shape: str
    frames: int
    values: tuple[float, ...]
    period: int = 1


@dataclass(frozen=True)
class Ride:
    """One drawn case: a road (a name of configs/roads), the initial speed (m/s, straight ahead), the
    options of the vehicle's kind (``rider``: a two-wheeler's scenario rider on or off; ``eps_external``:
    the EPS car's motor commanded from the bus, or its built-in assistance law) and the sequence."""
    road: str
    speed: float
    segments: tuple[Segment, ...]
    rider: bool = True
    eps_external: bool = True
    note: str = field(default="", compare=False)

    @property
    def frames(self) -> int:
        return sum(s.frames for s in self.segments)

    def to_json(self) -> dict:
        d = asdict(self)
        d["segments"] = [[s.shape, s.frames, list(s.values), s.period] for s in self.segments]
        return d

    @classmethod
    def from_json(cls, d: dict) -> "Ride":
        segs = tuple(Segment(sh, int(n), tuple(float(v) for v in vals), int(p)) for sh, n, vals, p in d["segments"])
        return cls(d["road"], float(d["speed"]), segs, bool(d.get("rider", True)), bool(d.get("eps_external", True)),
                   d.get("note", ""))

    def dumps(self) -> str:
        return json.dumps(self.to_json())


def expand(segments: tuple[Segment, ...], start: np.ndarray) -> np.ndarray:
    """The command values of each command period, (frames, ncommand), from ``start``."""
    rows = []
    prev = np.asarray(start, dtype=float).copy()
    for s in segments:
        target = np.asarray(s.values, dtype=float)
        if s.frames <= 0:
            continue
        if s.shape == "step":
            block = np.repeat(target[None, :], s.frames, axis=0)
        elif s.shape == "ramp":
            a = (np.arange(1, s.frames + 1) / s.frames)[:, None]
            block = prev[None, :] + a * (target - prev)[None, :]
        elif s.shape == "chatter":
            on = ((np.arange(s.frames) // max(1, s.period)) % 2 == 0)[:, None]
            block = np.where(on, target[None, :], prev[None, :])
        else:
            raise ValueError(f"unknown segment shape {s.shape!r} (expected one of {', '.join(SHAPES)})")
        rows.append(block)
        prev = block[-1].copy()
    return np.concatenate(rows) if rows else np.zeros((0, len(start)))


# ---- hypothesis strategies ---------------------------------------------------------------------------
def value_strategy(c: Command):
    """A command's value: one of its ends or its released value, or anywhere in its range."""
    from hypothesis import strategies as st

    ends = sorted({c.lo, c.hi, c.rest})
    return st.one_of(st.sampled_from(ends), st.floats(c.lo, c.hi, allow_nan=False, allow_infinity=False))


def segment_strategy(space: CommandSpace, max_frames: int):
    from hypothesis import strategies as st

    values = st.tuples(*(value_strategy(c) for c in space.commands))
    return st.builds(Segment, shape=st.sampled_from(SHAPES), frames=st.integers(1, max_frames), values=values,
                     period=st.integers(1, 10))


def ride_strategy(space: CommandSpace, roads: tuple[str, ...], top_speed: float, max_segment_s: float = 1.0,
                  max_segments: int = 5, rider_optional: bool = False, eps_optional: bool = False):
    """Rides (``Ride``) on ``roads`` from standstill to ``top_speed`` (m/s) with at most ``max_segments``
    segments of at most ``max_segment_s`` seconds each (in command periods of the space); the vehicle's
    options drawn where they apply: with or without its rider (``rider_optional``), the EPS motor current
    from the bus or the built-in law (``eps_optional``)."""
    from hypothesis import strategies as st

    max_frames = max(1, int(round(max_segment_s / space.frame_s)))

    speed = st.one_of(st.sampled_from((0.0, top_speed)), st.floats(0.0, top_speed, allow_nan=False))
    segs = st.lists(segment_strategy(space, max_frames), min_size=1, max_size=max_segments).map(tuple)
    return st.builds(Ride, road=st.sampled_from(roads), speed=speed, segments=segs,
                     rider=st.booleans() if rider_optional else st.just(True),
                     eps_external=st.booleans() if eps_optional else st.just(True))
