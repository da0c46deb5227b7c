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
  triangles 2 km across around the start with grid lines every 10 m, or the survey's or an OpenDRIVE
  road's mesh as one triangle list (an OpenDRIVE road's marks as more triangle lists, one per colour).

What is drawn is the vehicle's own description (rtsim.vehicle.kit.drawing.Drawing: ``sim.drawing``): the
body's box, the wheels (a wheel that carries a tyre load stands on the road at its loaded radius, from
its design position in the body), the articulated assemblies (a steering and its fork, a swingarm) and
how the state's angles give the pose's orientation (``attitude``). Units SI (m, rad); times are
simulation times.
"""
from __future__ import annotations

import math

from foxglove.messages import (ArrowPrimitive, Color, CubePrimitive, CylinderPrimitive, FrameTransform,
                               FrameTransforms, LinePrimitive, LinePrimitiveLineType, Point3, Pose, Quaternion,
                               SceneEntity, SceneUpdate, Timestamp, TriangleListPrimitive, Vector3)

from rtsim.vehicle.kit.drawing import q_axis, q_mul, q_rotate

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


_CYL_Y = q_axis(1, 0, 0, -0.5 * math.pi)     # a cylinder's axis (its z) along y: a wheel's axle


def _pose(p, q) -> Pose:
    return Pose(position=Vector3(x=p[0], y=p[1], z=p[2]), orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def _stamp(t: float) -> Timestamp:
    ns = max(0, int(round(t * 1e9)))
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


# ------------------------------------------------------------------ the vehicle's drawing

def shape_of(sim):
    """How the vehicle a service serves (or an offline run recorded) is drawn: its own description
    (``sim.drawing``: rtsim.vehicle.kit.drawing.Drawing, built by the vehicle from its config)."""
    return sim.drawing


def scene_for(sim, vehicle_id: str, centre=(0.0, 0.0)) -> tuple["SceneBuilder", bytes]:
    """(SceneBuilder, road scene bytes) of a served or recorded vehicle (its ``drawing``, ``vm.channels`` and
    ``road``); `centre` (x, y, m) where the road's plane and grid are drawn around (the start)."""
    from rtsim.road.config import road_marks_of

    road = getattr(sim, "road", None)
    marks = road_marks_of(getattr(sim, "road_path", None))
    return (SceneBuilder(vehicle_id, shape_of(sim), sim.vm.channels, road),
            road_scene(road, centre=centre, marks=marks))


# ------------------------------------------------------------------ scene messages

class SceneBuilder:
    """Encodes a vehicle's scene and frame transform from its state (and, for a car's wheel spin and
    steer, its newest sensor sample), and the road's scene. Pure computation; the callers count errors."""

    def __init__(self, vehicle_id: str, shape, channels, road=None):
        """`shape`: the vehicle's rtsim.vehicle.kit.drawing.Drawing; `road`: the rtsim.road.model.Road the
        vehicle drives on (None: the plane z = 0)."""
        self.vehicle_id = vehicle_id
        self.shape = shape
        self.road = road
        self._height = _height_fn(road)
        st = channels.state_names
        self._pose_idx = tuple(st.index(n) for n in ("pos_x", "pos_y", "pos_z", "roll_angle", "pitch_angle",
                                                     "yaw_angle"))
        self._orientation = shape.orientation
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
        self._extra = {n: st.index(n) for n in shape.channels() if n in st}

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
            where, i = src
            arr = state if where == "state" else sensors
            if arr is None:
                return 0.0
            v = float(arr[i])
            return v if math.isfinite(v) else 0.0

        sh = self.shape
        cubes = [CubePrimitive(pose=_pose(world(sh.body_centre), q),
                               size=Vector3(x=sh.body_size[0], y=sh.body_size[1], z=sh.body_size[2]),
                               color=BODY_COLOUR)]
        cylinders = []
        centres, steer_axes, parts = sh.articulate(self._state_value(state))
        for form, c, qp, size in parts:           # the assemblies: a fork, a swingarm
            pose, dims = _pose(world(c), q_mul(q, qp)), Vector3(x=size[0], y=size[1], z=size[2])
            if form == "cylinder":
                cylinders.append(CylinderPrimitive(pose=pose, size=dims, bottom_scale=1.0, top_scale=1.0,
                                                   color=SPOKE_COLOUR))
            else:
                cubes.append(CubePrimitive(pose=pose, size=dims, color=SPOKE_COLOUR))
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

    def _state_value(self, state):
        """``value(channel, default)`` of a state sample for the drawing's articulation."""
        def value(name, default):
            i = self._extra.get(name)
            if i is None:
                return default
            v = float(state[i])
            return v if math.isfinite(v) else default
        return value


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


def road_scene(road=None, centre=(0.0, 0.0), t: float = 0.0, half: float = 1000.0, grid: float = 10.0,
               marks: dict | None = None) -> bytes:
    """SceneUpdate bytes of the road (rtsim.road.model.Road; None: the flat plane z = 0): a plane as two
    triangles of side 2 x `half` m around `centre` with lines every `grid` m over the middle 200 m, a mesh
    as its triangles; an OpenDRIVE road's marks (`marks`: rtsim.road.opendrive.road_markings) as one
    more triangle list per colour in the same entity."""
    import numpy as np
    from rtsim.road.model import FP_GX, FP_GY, FP_X0, FP_Y0, FP_Z0, IP_KIND, ROAD_MESH

    stamp = _stamp(t)
    if road is not None and int(road.ipar[IP_KIND]) == ROAD_MESH:
        v = np.asarray(road.vert, dtype=float)
        pts = [Point3(x=float(a), y=float(b), z=float(c)) for a, b, c in v]
        idx = [int(i) for i in np.asarray(road.tri).ravel()]
        prim = TriangleListPrimitive(pose=_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), points=pts,
                                     color=ROAD_COLOUR, indices=idx)
        entity = SceneEntity(timestamp=stamp, frame_id=WORLD, id="road", triangles=[prim] + _mark_lists(marks))
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


def _mark_lists(marks: dict | None) -> list:
    """Road marks (rtsim.road.opendrive.road_markings) as triangle lists, one per colour."""
    import numpy as np

    if not marks or not len(marks["triangles"]):
        return []
    v = np.asarray(marks["vertices"], dtype=float)
    tri = np.asarray(marks["triangles"])
    colours = np.asarray(marks["colour"])
    out = []
    for hexc in sorted(set(marks["colour"])):
        sel = tri[colours == hexc]
        used, idx = np.unique(sel.ravel(), return_inverse=True)
        r, g, b = (int(hexc[k:k + 2], 16) / 255.0 for k in (1, 3, 5))
        out.append(TriangleListPrimitive(pose=_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
                                         points=[Point3(x=float(a), y=float(b_), z=float(c)) for a, b_, c in v[used]],
                                         color=Color(r=r, g=g, b=b, a=1.0), indices=[int(i) for i in idx]))
    return out
