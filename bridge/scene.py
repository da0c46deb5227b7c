"""The 3D scene of a served vehicle as Foxglove messages: the same bytes go live (bridge.foxglove_live)
and into the MCAP recordings (bridge.mcap_recorder), so Foxglove's 3D panel shows the car on both.

Topics (``topic key`` -> ``rtsim/<vehicle_id>/<key>``), protobuf messages of the foxglove SDK's own
schemas (``foxglove.messages.*.get_schema()``: a FileDescriptorSet, schema encoding ``protobuf``):

* ``scene`` (foxglove.SceneUpdate, with the state samples, at most 100 Hz): entity ``<vehicle_id>`` in
  frame ``world``: the heading arrow whose pose is exactly the state's pose (reference point ``pos_x,
  pos_y, pos_z``, orientation from ``roll_angle, pitch_angle, yaw_angle``), the body as a box, the wheels
  as cylinders with their steer and a spoke per wheel turned by its spin angle (a car's wheel at its
  design position in the body, lowered onto the road to its loaded radius from the tyre load; a
  two-wheeler's from its fork travel, swingarm angle and steer), a two-wheeler's fork and swingarm.
* ``tf`` (foxglove.FrameTransforms, with the scene): ``world`` -> ``<vehicle_id>`` (the same pose), so a
  3D panel can follow the vehicle.
* ``road`` (foxglove.SceneUpdate; the service sends it at the start, when simulation time restarts and
  when a live client subscribes): entity ``road`` in frame ``world``: a plane or constant grade as two
  triangles 2 km across around the start with grid lines every 10 m, or the survey mesh as one
  triangle list.

Orientation: the car's angles are Euler z-y-x (yaw, then pitch, then roll: rtsim.channels.STATE); the
two-wheeler's state angles are yaw, roll, then the frame's pitch (rtsim.vehicle.motorcycle.geometry
``frame_rotation``; its ``pitch_angle`` is that of the frame's x axis, so the frame's own pitch is
``asin(sin(pitch_angle) / cos(roll_angle))``). Units SI (m, rad); times are simulation times.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from foxglove.messages import (ArrowPrimitive, Color, CubePrimitive, CylinderPrimitive, FrameTransform,
                               FrameTransforms, LinePrimitive, LinePrimitiveLineType, Point3, Pose, Quaternion,
                               SceneEntity, SceneUpdate, Timestamp, TriangleListPrimitive, Vector3)

WORLD = "world"
SCENE_KEYS = ("scene", "tf", "road")
_MESSAGE = {"scene": SceneUpdate, "tf": FrameTransforms, "road": SceneUpdate}

BODY_COLOUR = Color(r=0.85, g=0.25, b=0.15, a=0.9)
WHEEL_COLOUR = Color(r=0.08, g=0.08, b=0.08, a=1.0)
SPOKE_COLOUR = Color(r=0.9, g=0.9, b=0.9, a=1.0)
ARROW_COLOUR = Color(r=1.0, g=0.85, b=0.1, a=1.0)
ROAD_COLOUR = Color(r=0.45, g=0.47, b=0.5, a=1.0)
LINE_COLOUR = Color(r=0.9, g=0.9, b=0.9, a=0.6)


def topic_schemas() -> dict[str, tuple[str, str, bytes]]:
    """topic key -> (schema name, schema encoding, schema data) of the scene topics: the foxglove
    SDK's own definitions."""
    out = {}
    for key, cls in _MESSAGE.items():
        s = cls.get_schema()
        out[key] = (s.name, s.encoding, bytes(s.data))
    return out


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


def car_orientation(roll: float, pitch: float, yaw: float):
    """Euler z-y-x (ISO 8855): yaw about z, then pitch about y, then roll about x."""
    return q_mul(q_mul(q_axis(0, 0, 1, yaw), q_axis(0, 1, 0, pitch)), q_axis(1, 0, 0, roll))


def two_wheeler_orientation(roll: float, pitch: float, yaw: float):
    """The rear frame: yaw about z, roll about x, then the frame's own pitch about y (see the module
    docstring for the state's pitch of the frame's x axis)."""
    c = math.cos(roll)
    s = math.sin(pitch) / c if abs(c) > 1e-9 else 0.0
    own = math.asin(max(-1.0, min(1.0, s)))
    return q_mul(q_mul(q_axis(0, 0, 1, yaw), q_axis(1, 0, 0, roll)), q_axis(0, 1, 0, own))


_CYL_Y = q_axis(1, 0, 0, -0.5 * math.pi)     # a cylinder's axis (its z) along y: a wheel's axle


def _pose(p, q) -> Pose:
    return Pose(position=Vector3(x=p[0], y=p[1], z=p[2]), orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def _stamp(t: float) -> Timestamp:
    ns = max(0, int(round(t * 1e9)))
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


# ------------------------------------------------------------------ vehicle shapes

@dataclass(frozen=True)
class Wheel:
    """A wheel in the vehicle's reference frame: centre (m), radius and width (m); `steer` and `spin`
    name the channels of its steer and spin angles (rad); `load` that of its tyre's vertical load (N),
    which with `stiffness` (N/m) puts a car's wheel on the road (see SceneBuilder)."""
    centre: tuple[float, float, float]
    radius: float
    width: float
    spin: str
    steer: str | None = None
    load: str | None = None
    stiffness: float = 0.0


@dataclass(frozen=True)
class Shape:
    """What the scene draws of a vehicle, in its reference frame (the state's pose: the car's centre of
    mass, the two-wheeler's swingarm pivot)."""
    kind: str                                   # "car" or "two_wheeler"
    body_centre: tuple[float, float, float]
    body_size: tuple[float, float, float]
    wheels: tuple[Wheel, ...]
    design: object = None                       # the two-wheeler's geometry.Design


def car_shape(vm, tyre_radius: float, tyre_stiffness: float = 0.0) -> Shape:
    """A four-wheel car from its model (rtsim.vehicle.car.build.VehicleModel): wheel centres from the
    design wheel centres relative to the centre of mass; the body spans the wheelbase plus overhangs."""
    cg = [float(v) for v in vm.config.chassis.cg_m]
    wc = [[float(v) for v in row] for row in vm.design_wheel_centre]
    rel = [tuple(c[k] - cg[k] for k in range(3)) for c in wc]
    xs = [r[0] for r in rel]
    ys = [r[1] for r in rel]
    front, rear = max(xs), min(xs)
    length = front - rear + 2.0 * tyre_radius + 0.5
    width = max(ys) - min(ys) + 0.05
    zc = min(r[2] for r in rel) + 0.35
    body = (0.5 * (front + rear) + 0.1, 0.0, zc)
    width_t = max(0.12, 0.55 * tyre_radius)
    names = ("fl", "fr", "rl", "rr")
    wheels = tuple(Wheel(rel[i], tyre_radius, width_t, f"wheel_angle_{w}",
                         f"steer_angle_{w}" if w in ("fl", "fr") else None, f"tyre_fz_{w}", tyre_stiffness)
                   for i, w in enumerate(names))
    return Shape("car", body, (length, width, 0.55), wheels)


def two_wheeler_shape(mm) -> Shape:
    """A two-wheeler from its model (rtsim.vehicle.motorcycle.build.MotorcycleModel)."""
    from rtsim.vehicle.motorcycle.geometry import design

    cfg = mm.config
    des = design(cfg)
    rr, rf = float(cfg.rear_wheel.radius_m), float(cfg.front_wheel.radius_m)
    p = [float(v) for v in des.pivot]
    head = [float(v) for v in des.head]
    mid = tuple(0.5 * (head[k] + p[k]) - p[k] for k in range(3))
    length = math.dist(head, p) + 0.3
    wheels = (Wheel(tuple(float(des.rear_centre[k]) - p[k] for k in range(3)), rr, 0.18, "wheel_angle_rear"),
              Wheel(tuple(float(des.front_centre[k]) - p[k] for k in range(3)), rf, 0.12, "wheel_angle_front",
                    "steer_angle"))
    return Shape("two_wheeler", (mid[0], 0.0, mid[2]), (length, 0.3, 0.3), wheels, des)


def shape_of(sim) -> Shape:
    """The shape of the vehicle a service serves: a car's VehicleSim or a two-wheeler's TwoWheelerHil."""
    model = getattr(sim.vm, "model", None)
    if model is not None and hasattr(model, "design"):
        return two_wheeler_shape(model)
    from rtsim.vehicle.kit.tyre.tir import P_UNLOADED_RADIUS, P_VERTICAL_STIFFNESS

    return car_shape(sim.vm, float(sim.tp[P_UNLOADED_RADIUS]), float(sim.tp[P_VERTICAL_STIFFNESS]))


def scene_for(sim, vehicle_id: str, centre=(0.0, 0.0)) -> tuple["SceneBuilder", bytes]:
    """(SceneBuilder, road scene bytes) of a car's VehicleSim or a two-wheeler's TwoWheelerHil; `centre`
    (x, y, m) where the road's plane and grid are drawn around (the start)."""
    road = getattr(sim, "road", None)
    return SceneBuilder(vehicle_id, shape_of(sim), sim.vm.channels, road), road_scene(road, centre=centre)


# ------------------------------------------------------------------ scene messages

class SceneBuilder:
    """Encodes a vehicle's scene and frame transform from its state (and, for a car's wheel spin and
    steer, its newest sensor sample), and the road's scene. Pure computation; the callers count errors."""

    def __init__(self, vehicle_id: str, shape: Shape, channels, road=None):
        """`road`: the rtsim.road.model.Road the vehicle drives on (None: the plane z = 0)."""
        self.vehicle_id = vehicle_id
        self.shape = shape
        self.road = road
        self._height = _height_fn(road)
        st = channels.state_names
        self._pose_idx = tuple(st.index(n) for n in ("pos_x", "pos_y", "pos_z", "roll_angle", "pitch_angle",
                                                     "yaw_angle"))
        self._orientation = car_orientation if shape.kind == "car" else two_wheeler_orientation
        sens = channels.sensor_names

        def where(name):
            if name is None:
                return None
            if name in st:
                return ("state", st.index(name))
            if name in sens:
                return ("sensors", sens.index(name))
            return None
        self._wheel_src = [(where(w.spin), where(w.steer)) for w in shape.wheels]
        self._wheel_load = [where(w.load) if w.stiffness > 0 else None for w in shape.wheels]
        self._extra = {n: st.index(n) for n in ("fork_travel", "swingarm_angle", "steer_angle") if n in st}

    def pose(self, state) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """(position, orientation quaternion x, y, z, w) of the reference frame from a state sample."""
        x, y, z, roll, pitch, yaw = (float(state[i]) for i in self._pose_idx)
        return (x, y, z), self._orientation(roll, pitch, yaw)

    def vehicle(self, t: float, state, sensors=None) -> tuple[bytes, bytes]:
        """(SceneUpdate bytes, FrameTransforms bytes) of the vehicle at simulation time t (s)."""
        p, q = self.pose(state)
        stamp = _stamp(t)
        vid = self.vehicle_id

        def world(local):
            r = q_rotate(q, local)
            return (p[0] + r[0], p[1] + r[1], p[2] + r[2])

        def value(src):
            if src is None:
                return 0.0
            kind, i = src
            arr = state if kind == "state" else sensors
            if arr is None:
                return 0.0
            v = float(arr[i])
            return v if math.isfinite(v) else 0.0

        sh = self.shape
        cubes = [CubePrimitive(pose=_pose(world(sh.body_centre), q),
                               size=Vector3(x=sh.body_size[0], y=sh.body_size[1], z=sh.body_size[2]),
                               color=BODY_COLOUR)]
        cylinders = []
        if sh.kind == "car":
            centres = [w.centre for w in sh.wheels]
            steer_axes = [(0.0, 0.0, 1.0)] * len(sh.wheels)
        else:
            centres, steer_axes, fork, arm = self._two_wheeler_parts(state)
            cylinders.append(fork(world, q))
            cubes.append(arm(world, q))
        for w, c, ax, (spin_src, steer_src), load in zip(sh.wheels, centres, steer_axes, self._wheel_src,
                                                          self._wheel_load):
            qs = q_mul(q, q_axis(*ax, value(steer_src)))
            pos = world(c)
            if load is not None and value(load) > 0.0:
                # a loaded tyre is on the road: its centre at the loaded radius above the surface under
                # its design position (the state has the tyre loads, not the suspension travel)
                z = self._height(pos[0], pos[1])
                if math.isfinite(z):
                    pos = (pos[0], pos[1], z + w.radius - value(load) / w.stiffness)
            cylinders.append(CylinderPrimitive(pose=_pose(pos, q_mul(qs, _CYL_Y)),
                                               size=Vector3(x=2 * w.radius, y=2 * w.radius, z=w.width),
                                               bottom_scale=1.0, top_scale=1.0, color=WHEEL_COLOUR))
            cubes.append(CubePrimitive(pose=_pose(pos, q_mul(qs, q_axis(0, 1, 0, value(spin_src)))),
                                       size=Vector3(x=1.9 * w.radius, y=w.width + 0.02, z=0.06), color=SPOKE_COLOUR))
        arrow = ArrowPrimitive(pose=_pose(p, q), shaft_length=1.0, shaft_diameter=0.06, head_length=0.3,
                               head_diameter=0.15, color=ARROW_COLOUR)
        entity = SceneEntity(timestamp=stamp, frame_id=WORLD, id=vid, arrows=[arrow], cubes=cubes,
                             cylinders=cylinders)
        scene = SceneUpdate(entities=[entity]).encode()
        tf = FrameTransforms(transforms=[FrameTransform(
            timestamp=stamp, parent_frame_id=WORLD, child_frame_id=vid,
            translation=Vector3(x=p[0], y=p[1], z=p[2]), rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))]).encode()
        return scene, tf

    def _two_wheeler_parts(self, state):
        """Wheel centres and steer axes in the reference frame, and the fork and swingarm primitives, of
        a two-wheeler from its fork travel and swingarm angle (geometry of rtsim.vehicle.motorcycle)."""
        des = self.shape.design
        zeta = float(state[self._extra["fork_travel"]]) if "fork_travel" in self._extra else des.zeta0
        swing = float(state[self._extra["swingarm_angle"]]) if "swingarm_angle" in self._extra else 0.0
        if not math.isfinite(zeta):
            zeta = des.zeta0
        if not math.isfinite(swing):
            swing = 0.0
        p0 = [float(v) for v in des.pivot]
        h = (float(des.h[0]), float(des.h[1]), float(des.h[2]))
        e1 = (float(des.e1[0]), 0.0, float(des.e1[2]))
        head = [float(des.head[k]) - p0[k] for k in range(3)]
        # the front wheel centre: down the steering axis by the fork's length, ahead of it by the fork
        # offset, which steering turns about the axis (e1 turned about h: cos d e1 + sin d (h x e1 = y))
        ext = -des.fork_length + (zeta - des.zeta0)
        d = float(state[self._extra["steer_angle"]]) if "steer_angle" in self._extra else 0.0
        d = d if math.isfinite(d) else 0.0
        f_u = (math.cos(d) * e1[0], math.sin(d), math.cos(d) * e1[2])
        wf = tuple(head[k] + ext * h[k] + des.fork_offset * f_u[k] for k in range(3))
        theta = des.theta0 + swing
        s_u = (math.cos(theta) * e1[0] + math.sin(theta) * e1[2], 0.0,
               -math.sin(theta) * e1[0] + math.cos(theta) * e1[2])
        wr = tuple(des.swingarm_length * s_u[k] for k in range(3))
        fork_mid = tuple(0.5 * (head[k] + wf[k]) for k in range(3))
        fork_len = math.dist(head, wf)
        q_fork = q_axis(0, 1, 0, math.atan2(h[0], h[2]))          # a cylinder's z along the steering axis
        arm_mid = tuple(0.5 * wr[k] for k in range(3))
        q_arm = q_axis(0, 1, 0, math.atan2(-wr[2], wr[0]))        # a box's x along the swingarm

        def fork(world, q):
            return CylinderPrimitive(pose=_pose(world(fork_mid), q_mul(q, q_fork)),
                                     size=Vector3(x=0.08, y=0.08, z=fork_len), bottom_scale=1.0, top_scale=1.0,
                                     color=SPOKE_COLOUR)

        def arm(world, q):
            return CubePrimitive(pose=_pose(world(arm_mid), q_mul(q, q_arm)),
                                 size=Vector3(x=des.swingarm_length, y=0.08, z=0.06), color=SPOKE_COLOUR)
        return (wr, wf), ((0.0, 0.0, 1.0), h), fork, arm


def _height_fn(road):
    """Surface height (m) at (x, y) of a road (None: the plane z = 0); -inf off a mesh."""
    if road is None:
        return lambda x, y: 0.0
    from rtsim.road.model import FP_GX, FP_GY, FP_X0, FP_Y0, FP_Z0, IP_KIND, ROAD_MESH

    if int(road.ipar[IP_KIND]) != ROAD_MESH:
        x0, y0, z0, gx, gy = (float(road.fpar[k]) for k in (FP_X0, FP_Y0, FP_Z0, FP_GX, FP_GY))
        return lambda x, y: z0 + gx * (x - x0) + gy * (y - y0)
    import numpy as np
    from rtsim.road.query import NQUERY, Q_Z, road_query

    out = np.zeros(NQUERY)

    def mesh(x, y):
        road_query(road, float(x), float(y), out)
        return float(out[Q_Z])
    return mesh


def road_scene(road=None, centre=(0.0, 0.0), t: float = 0.0, half: float = 1000.0, grid: float = 10.0) -> bytes:
    """SceneUpdate bytes of the road (rtsim.road.model.Road; None: the flat plane z = 0): a plane as two
    triangles of side 2 x `half` m around `centre` with lines every `grid` m over the middle 200 m, a mesh
    as its triangles."""
    import numpy as np
    from rtsim.road.model import FP_GX, FP_GY, FP_X0, FP_Y0, FP_Z0, IP_KIND, ROAD_MESH

    stamp = _stamp(t)
    if road is not None and int(road.ipar[IP_KIND]) == ROAD_MESH:
        v = np.asarray(road.vert, dtype=float)
        pts = [Point3(x=float(a), y=float(b), z=float(c)) for a, b, c in v]
        idx = [int(i) for i in np.asarray(road.tri).ravel()]
        prim = TriangleListPrimitive(pose=_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), points=pts,
                                     color=ROAD_COLOUR, indices=idx)
        entity = SceneEntity(timestamp=stamp, frame_id=WORLD, id="road", triangles=[prim])
        return SceneUpdate(entities=[entity]).encode()
    if road is None:
        x0 = y0 = z0 = gx = gy = 0.0
    else:
        f = road.fpar
        x0, y0, z0, gx, gy = (float(f[k]) for k in (FP_X0, FP_Y0, FP_Z0, FP_GX, FP_GY))

    def point(x, y, lift=0.0):
        return Point3(x=x, y=y, z=z0 + gx * (x - x0) + gy * (y - y0) + lift)
    cx = grid * round(centre[0] / grid)
    cy = grid * round(centre[1] / grid)
    corners = [point(cx - half, cy - half), point(cx + half, cy - half), point(cx + half, cy + half),
               point(cx - half, cy + half)]
    plane = TriangleListPrimitive(pose=_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), points=corners,
                                  color=ROAD_COLOUR, indices=[0, 1, 2, 0, 2, 3])
    lines = []
    n = 10
    for k in range(-n, n + 1):
        a = k * grid
        lines += [point(cx + a, cy - n * grid, 0.01), point(cx + a, cy + n * grid, 0.01),
                  point(cx - n * grid, cy + a, 0.01), point(cx + n * grid, cy + a, 0.01)]
    grid_lines = LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
                               thickness=0.05, scale_invariant=False, points=lines, color=LINE_COLOUR)
    entity = SceneEntity(timestamp=stamp, frame_id=WORLD, id="road", triangles=[plane], lines=[grid_lines])
    return SceneUpdate(entities=[entity]).encode()
