"""How a two-wheeler is drawn (rtsim.vehicle.kit.drawing), from its config's geometry
(rtsim.vehicle.motorcycle.geometry.design): points relative to the swingarm pivot (the reference point
of its state pose: yaw, roll, then the frame's own pitch) in the rear frame's (x, z) plane; the rear
wheel on the swingarm, turned by its ``swingarm_angle``; the front wheel on the steering, turned about
the steering axis by ``steer_angle`` and slid along it by the fork's travel; the frame as one box (the
Foxglove scene), and for the viewer's page a frame, seat, swingarm, fork tubes, handlebar and the rider
(none for a machine without one, the benchmark bicycle)."""
from __future__ import annotations

import math

from ..kit.drawing import Drawing, DrawnWheel, Steering, Swingarm

DARK = "#2a2a2e"
RIDER = "#e0a030"
FORK = "#b8bcc2"
PAINT = "#1f5fbf"          # the page's colour of a two-wheeler drawn in the default colour


def two_wheeler_drawing(cfg) -> Drawing:
    """The two-wheeler of config ``cfg`` (rtsim.vehicle.motorcycle.config.MotorcycleConfig)."""
    from .geometry import design

    des = design(cfg)
    p = [float(v) for v in des.pivot]

    def rel(v):
        return tuple(float(v[k]) - p[k] for k in range(3))

    rr, rf = float(cfg.rear_wheel.radius_m), float(cfg.front_wheel.radius_m)
    head = rel(des.head)
    e1 = (float(des.e1[0]), 0.0, float(des.e1[2]))
    axis = tuple(float(v) for v in des.h)
    wheels = (DrawnWheel("rear", rel(des.rear_centre), rr, 0.18, "wheel_angle_rear", "wheel_speed_rear",
                         carrier="swingarm"),
              DrawnWheel("front", rel(des.front_centre), rf, 0.12, "wheel_angle_front", "wheel_speed_front",
                         "steer_angle", carrier="steering"))
    steering = Steering(head, axis, e1, "steer_angle", "fork_travel", float(des.fork_length), float(des.fork_offset),
                        float(des.zeta0))
    swingarm = Swingarm(float(des.swingarm_length), float(des.theta0), e1, "swingarm_angle")
    mid = tuple(0.5 * head[k] for k in range(3))
    body_size = (math.dist(head, (0.0, 0.0, 0.0)) + 0.3, 0.3, 0.3)
    # the page's pieces, from the config's points relative to the pivot
    g = cfg.geometry
    px, pz = (float(v) for v in g.swingarm_pivot_m)
    caster = math.radians(g.caster_deg)
    ground = g.wheelbase_m + float(cfg.trail)        # the steering axis meets the ground here (x)
    ax = (-math.sin(caster), 0.0, math.cos(caster))
    top = (ground + ax[0] - px, 0.0, ax[2] - pz)     # a point of the steering axis 1 m from the ground
    cg = (float(cfg.rear_frame.cg_m[0]) - px, 0.0, float(cfg.rear_frame.cg_m[1]) - pz)
    rider = None if cfg.rider is None else (float(cfg.rider.cg_m[0]) - px, 0.0, float(cfg.rider.cg_m[1]) - pz)
    rw = (-px, 0.0, rr - pz)
    fw = (g.wheelbase_m - px, 0.0, rf - pz)
    r = rider or cg
    pieces = [{"shape": "box", "at": [top[0] / 2, 0.0, (top[2] + cg[2]) / 2],
               "size": [math.hypot(top[0], top[2]) + 0.2, 0.22, 0.28],
               "pitch": -math.atan2(top[2] - cg[2], top[0]) * 0.5, "colour": "paint", "carrier": "body"},
              {"shape": "box", "at": [cg[0] - 0.15, 0.0, cg[2] + 0.25], "size": [0.6, 0.26, 0.1], "colour": DARK,
               "carrier": "body"}]
    if rider is not None:
        pieces += [{"shape": "box", "at": [r[0], 0.0, r[2] + 0.05], "size": [0.32, 0.4, 0.62], "pitch": 0.45,
                    "colour": RIDER, "carrier": "body"},
                   {"shape": "sphere", "at": [r[0] + 0.22, 0.0, r[2] + 0.45], "radius": 0.14, "colour": DARK,
                    "carrier": "body"}]
    pieces.append({"shape": "box", "at": [rw[0] / 2, 0.08, rw[2] / 2], "size": [math.hypot(rw[0], rw[2]), 0.06, 0.06],
                   "pitch": math.atan2(-rw[2], rw[0]) + math.pi, "colour": DARK, "carrier": "body"})
    tube = tuple(fw[k] - top[k] for k in range(3))
    length = math.hypot(tube[0], tube[2])
    for y in (0.1, -0.1):
        pieces.append({"shape": "cylinder", "at": [top[0] + 0.5 * tube[0], y, top[2] + 0.5 * tube[2]],
                       "direction": [tube[0] / length, 0.0, tube[2] / length], "radius": 0.025, "length": length,
                       "colour": FORK, "carrier": "steering"})
    pieces.append({"shape": "box", "at": [top[0] - 0.05, 0.0, top[2] + 0.05], "size": [0.05, 0.7, 0.04], "colour": DARK,
                   "carrier": "steering"})
    return Drawing("zx_frame_pitch", (mid[0], 0.0, mid[2]), body_size, wheels, steering, swingarm, tuple(pieces),
                   eye=(r[0] + 0.3, 0.0, r[2] + 0.5), chase=(5.5, 2.0), paint=PAINT)
