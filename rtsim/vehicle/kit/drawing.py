"""How a vehicle is drawn: one description, built by the vehicle from its config, that the Foxglove 3D
scene (bridge.scene) and the browser viewer's page (rtsim.viewer, web/scene.js) both draw from, so
neither asks which kind of vehicle it is.

All in the vehicle's reference frame (the state's pose: ``pos_*`` and ``roll/pitch/yaw_angle``; a car's
centre of mass, a two-wheeler's swingarm pivot), ISO 8855 axes (x forward, y left, z up), metres and
radians.

- ``attitude``: how the state's three angles give the reference frame's orientation: ``"zyx"``, Euler
  z-y-x (yaw, then pitch, then roll: rtsim.channels.STATE); ``"zx_frame_pitch"``, yaw, then roll, then
  the frame's own pitch, where the state's ``pitch_angle`` is that of the frame's x axis, so the frame's
  own pitch is ``asin(sin(pitch_angle) / cos(roll_angle))`` (rtsim.vehicle.motorcycle.geometry).
- ``body_centre``, ``body_size``: the body as one box (the Foxglove scene's).
- ``wheels``: each wheel's design centre, radius and width, the channels of its spin angle and spin
  rate, of its steer angle about z (a car's), of its tyre's vertical load (with ``stiffness``, N/m, the
  wheel stands on the road at its loaded radius), and what carries it: ``"body"`` (fixed), ``"steering"``
  (turns about the steering axis, slides along it with the fork's travel) or ``"swingarm"``.
- ``steering``, ``swingarm``: the articulated assemblies (None: none); ``articulate`` places the wheels
  and the assemblies' primitives for a state.
- ``pieces``: what the page draws of the body besides the wheels, each a dict: ``shape`` ("box" of
  ``size``, "sphere" of ``radius``, "cylinder" of ``radius`` and ``length`` along ``direction``), its
  centre ``at``, an optional ``pitch`` (rad, about y), ``colour`` (a colour, or "paint": the vehicle's),
  ``carrier`` ("body" or "steering") and ``in_cockpit`` (False: hidden from the driver's camera); the
  driver's ``eye``, the ``chase`` camera's distance behind and height above (m), and the ``paint`` a
  vehicle drawn in the default colour takes instead.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Callable

Vec = tuple[float, float, float]


# ------------------------------------------------------------------ quaternions (x, y, z, w), pure Python

def q_axis(ax: float, ay: float, az: float, angle: float) -> tuple[float, float, float, float]:
    """Rotation by `angle` (rad) about the unit axis (ax, ay, az), right-handed."""
    s = math.sin(0.5 * angle)
    return (ax * s, ay * s, az * s, math.cos(0.5 * angle))


def q_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def q_rotate(q, v):
    """The vector v rotated by the unit quaternion q."""
    x, y, z, w = q
    vx, vy, vz = v
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty, vy + w * ty + z * tx - x * tz, vz + w * tz + x * ty - y * tx)


def zyx_orientation(roll: float, pitch: float, yaw: float):
    """Euler z-y-x (ISO 8855): yaw about z, then pitch about y, then roll about x."""
    return q_mul(q_mul(q_axis(0, 0, 1, yaw), q_axis(0, 1, 0, pitch)), q_axis(1, 0, 0, roll))


def zx_frame_pitch_orientation(roll: float, pitch: float, yaw: float):
    """Yaw about z, roll about x, then the frame's own pitch about y (module docstring)."""
    c = math.cos(roll)
    s = math.sin(pitch) / c if abs(c) > 1e-9 else 0.0
    own = math.asin(max(-1.0, min(1.0, s)))
    return q_mul(q_mul(q_axis(0, 0, 1, yaw), q_axis(1, 0, 0, roll)), q_axis(0, 1, 0, own))


ATTITUDES: dict[str, Callable] = {"zyx": zyx_orientation, "zx_frame_pitch": zx_frame_pitch_orientation}


# ------------------------------------------------------------------ the description

@dataclass(frozen=True)
class DrawnWheel:
    """A wheel (module docstring); ``name`` is its channels' suffix (``tyre_fx_<name>``, ...)."""
    name: str
    centre: Vec
    radius: float
    width: float
    spin: str
    spin_rate: str
    steer: str | None = None
    load: str | None = None
    stiffness: float = 0.0
    carrier: str = "body"


@dataclass(frozen=True)
class Steering:
    """A steering assembly: it turns by the channel ``angle`` about the unit ``axis`` through ``head``;
    the wheel it carries sits ``fork_length - (travel - travel0)`` down the axis from the head and
    ``fork_offset`` ahead of it along ``forward`` (the frame's axis normal to the steering axis) turned
    with the steer; ``travel`` names the fork's travel channel (m)."""
    head: Vec
    axis: Vec
    forward: Vec
    angle: str
    travel: str
    fork_length: float
    fork_offset: float
    travel0: float


@dataclass(frozen=True)
class Swingarm:
    """A swingarm from the reference point: ``length``, its angle ``theta0`` from ``forward`` about y at
    the design position plus the channel ``angle``."""
    length: float
    theta0: float
    forward: Vec
    angle: str


@dataclass(frozen=True)
class Drawing:
    """How a vehicle is drawn (module docstring)."""
    attitude: str
    body_centre: Vec
    body_size: Vec
    wheels: tuple[DrawnWheel, ...]
    steering: Steering | None = None
    swingarm: Swingarm | None = None
    pieces: tuple[dict, ...] = ()
    eye: Vec = (0.0, 0.0, 1.0)
    chase: tuple[float, float] = (8.5, 3.0)
    paint: str | None = None
    wheel_travel: float = 0.12          # m: how far the page lets a wheel that stands on the road move

    def orientation(self, roll: float, pitch: float, yaw: float):
        """The reference frame's orientation quaternion (x, y, z, w) from the state's angles."""
        return ATTITUDES[self.attitude](roll, pitch, yaw)

    def channels(self) -> tuple[str, ...]:
        """The state channels the articulation reads."""
        out = []
        if self.steering is not None:
            out += [self.steering.angle, self.steering.travel]
        if self.swingarm is not None:
            out.append(self.swingarm.angle)
        return tuple(out)

    def articulate(self, value: Callable[[str, float], float]):
        """(wheel centres, wheel steer axes, parts) for a state: ``value(channel, default)`` reads a state
        channel (the default when it is missing or not finite). Parts are the assemblies' primitives,
        ``(shape, centre, orientation quaternion, size)`` with shape ``"cylinder"`` (its z along the
        steering axis) or ``"box"`` (its x along the swingarm)."""
        centres, axes, parts = [], [], []
        st, arm = self.steering, self.swingarm
        wf = wr = None
        if st is not None:
            zeta = value(st.travel, st.travel0)
            d = value(st.angle, 0.0)
            h, e1, head = st.axis, st.forward, st.head
            ext = -st.fork_length + (zeta - st.travel0)
            f_u = (math.cos(d) * e1[0], math.sin(d), math.cos(d) * e1[2])
            wf = tuple(head[k] + ext * h[k] + st.fork_offset * f_u[k] for k in range(3))
            mid = tuple(0.5 * (head[k] + wf[k]) for k in range(3))
            parts.append(("cylinder", mid, q_axis(0, 1, 0, math.atan2(h[0], h[2])), (0.08, 0.08, math.dist(head, wf))))
        if arm is not None:
            theta = arm.theta0 + value(arm.angle, 0.0)
            e1 = arm.forward
            s_u = (math.cos(theta) * e1[0] + math.sin(theta) * e1[2], 0.0,
                   -math.sin(theta) * e1[0] + math.cos(theta) * e1[2])
            wr = tuple(arm.length * s_u[k] for k in range(3))
            parts.append(("box", tuple(0.5 * wr[k] for k in range(3)), q_axis(0, 1, 0, math.atan2(-wr[2], wr[0])),
                          (arm.length, 0.08, 0.06)))
        for w in self.wheels:
            if w.carrier == "steering" and wf is not None:
                centres.append(wf)
                axes.append(st.axis)
            elif w.carrier == "swingarm" and wr is not None:
                centres.append(wr)
                axes.append((0.0, 0.0, 1.0))
            else:
                centres.append(w.centre)
                axes.append((0.0, 0.0, 1.0))
        return centres, axes, parts

    def page(self) -> dict:
        """The description as the viewer's page takes it (JSON: lists for vectors)."""
        return asdict(self)
