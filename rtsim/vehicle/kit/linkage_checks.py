"""A suspension linkage checked as a mechanism when its vehicle file loads: no link, pivot axis or lever
shorter than MIN_LINK_M (coincident pivots leave a knuckle free to turn, and the solver then finds some pose
on a continuum of them), and a steered axle's overall steering ratio, computed from the linkage itself,
inside STEERING_RATIO_RANGE.

The ratio is the steering-wheel angle per road-wheel angle at straight ahead on the design ride height:
1 / (rack travel per steering-wheel radian x road-wheel radians per metre of rack), the latter from the
linkage solved 1 mm either side of the centred rack (rtsim.vehicle.kit.linkages, the same solver the model
is built with). Points are the left corner's hardpoints, design frame, m.
"""
from __future__ import annotations

import math
from dataclasses import fields

import numpy as np

from rtsim.errors import ModelError

from .linkages import DoubleWishbone, VerticalSlider, _solve_double_wishbone, _solve_vertical_slider

MIN_LINK_M = 0.01        # m: the shortest link, pivot axis or lever (a shock's eyes too) that is not degenerate
#: Overall steering ratios of road cars: about 10 (quick racing racks) to 25 (heavy cars without assist).
STEERING_RATIO_RANGE = (10.0, 25.0)
RACK_STEP_M = 1e-3

# (point, other point or line through two points, what the two define) per suspension type; a "planar" one
# is measured in the body's x-y plane (the vertical slider's steering is a crank and rod in that plane)
_LINKS = {
    "double_wishbone": (
        ("lower_rear", ("lower_front",), "the lower arm's pivot axis"),
        ("upper_rear", ("upper_front",), "the upper arm's pivot axis"),
        ("lower_ball", ("lower_front", "lower_rear"), "the lower arm (ball joint off its pivot axis)"),
        ("upper_ball", ("upper_front", "upper_rear"), "the upper arm (ball joint off its pivot axis)"),
        ("upper_ball", ("lower_ball",), "the kingpin axis"),
        ("tie_inner", ("tie_outer",), "the tie rod"),
        ("tie_outer", ("lower_ball", "upper_ball"), "the steering arm (tie rod end off the kingpin axis)"),
        ("spring_upper", ("spring_lower",), "the spring/damper"),
    ),
    "macpherson": (
        ("lower_rear", ("lower_front",), "the lower arm's pivot axis"),
        ("lower_ball", ("lower_front", "lower_rear"), "the lower arm (ball joint off its pivot axis)"),
        ("strut_lower", ("strut_top",), "the strut axis"),
        ("toe_inner", ("toe_outer",), "the toe link"),
        ("toe_outer", ("lower_ball", "strut_top"), "the toe arm (toe link end off the steering axis)"),
    ),
    "vertical_slider": (
        ("spring_upper", ("spring_lower",), "the spring/damper"),
        ("tie_outer", ("kingpin",), "the steering arm (planar)"),
        ("tie_inner", ("tie_outer",), "the tie rod (planar)"),
    ),
}


def _distance(p: np.ndarray, ref: list[np.ndarray]) -> float:
    if len(ref) == 1:
        return float(np.linalg.norm(p - ref[0]))
    axis = ref[1] - ref[0]
    n = float(np.linalg.norm(axis))
    if n < 1e-12:
        return float(np.linalg.norm(p - ref[0]))
    return float(np.linalg.norm(np.cross(p - ref[0], axis / n)))


_SHORT: dict = {}            # short_link's results by suspension and hardpoints (this process's)


def short_link(suspension: str, hardpoints: dict) -> tuple[str, tuple, str] | None:
    """(key, value, reason) of the first link shorter than MIN_LINK_M among `hardpoints` (name -> (x, y, z)
    or None), else None. Kept per process for the same suspension and points (validating a vehicle file
    asks it at every load: a batch's plain overrides load one linkage many times)."""
    key = (suspension, *((k, None if v is None else tuple(float(x) for x in v)) for k, v in sorted(hardpoints.items())))
    if key not in _SHORT:
        if len(_SHORT) >= 256:
            _SHORT.clear()
        _SHORT[key] = _short_link(suspension, hardpoints)
    return _SHORT[key]


def _short_link(suspension: str, hardpoints: dict) -> tuple[str, tuple, str] | None:
    for key, refs, what in _LINKS[suspension]:
        if hardpoints.get(key) is None or any(hardpoints.get(r) is None for r in refs):
            continue
        n = 2 if what.endswith("(planar)") else 3
        point = np.array(hardpoints[key], dtype=float)[:n]
        d = _distance(point, [np.array(hardpoints[r], dtype=float)[:n] for r in refs])
        if d < MIN_LINK_M:
            other = refs[0] if len(refs) == 1 else f"the line {refs[0]}-{refs[1]}"
            what = what.replace("(planar)", "(in the horizontal plane)")
            return key, tuple(hardpoints[key]), (f"{1e3 * d:.1f} mm from {other}: {what} is degenerate "
                                                 f"(need at least {1e3 * MIN_LINK_M:g} mm)")
    return None


def steering_arm(geom: DoubleWishbone | VerticalSlider) -> float:
    """The steering arm's length, m: the tie rod's outer end from the kingpin axis (the ball joints' line;
    a vertical slider's kingpin, in the horizontal plane)."""
    if isinstance(geom, VerticalSlider):
        return _distance(geom.tie_outer[:2], [geom.kingpin[:2]])
    return _distance(geom.tie_outer, [geom.lower_ball, geom.upper_ball])


_RATIOS: dict = {}           # steering_ratio's results by linkage and rack ratio (this process's)


def steering_ratio(geom: DoubleWishbone | VerticalSlider, rack_travel_per_rad: float) -> float:
    """Steering-wheel angle per road-wheel angle of a steered left corner at straight ahead (design ride
    height), from its linkage; ModelError if the linkage cannot be assembled 1 mm either side. A result
    is kept per process for the same linkage and ratio (validating a vehicle file asks it at every load)."""
    key = (type(geom).__name__, float(rack_travel_per_rad),
           *((f.name, None if getattr(geom, f.name) is None else tuple(np.ravel(getattr(geom, f.name)).tolist()))
             for f in fields(geom)))
    ratio = _RATIOS.get(key)
    if ratio is None:
        ratio = _steering_ratio(geom, rack_travel_per_rad)
        if len(_RATIOS) >= 256:
            _RATIOS.clear()
        _RATIOS[key] = ratio
    return ratio


def _steering_ratio(geom: DoubleWishbone | VerticalSlider, rack_travel_per_rad: float) -> float:
    angles = []
    for s in (-RACK_STEP_M, RACK_STEP_M):
        if isinstance(geom, VerticalSlider):
            x = _solve_vertical_slider(geom, 0.0, s, np.zeros(6))
        else:
            x = _solve_double_wishbone(geom, 0.0, s, np.zeros(6))
        rot = x[:3]
        angle = float(np.linalg.norm(rot))
        axis = geom.spin_axis if angle == 0.0 else _rotate(geom.spin_axis, rot / angle, angle)
        angles.append(math.atan2(-axis[0], axis[1]))
    road_per_rack = (angles[1] - angles[0]) / (2.0 * RACK_STEP_M)
    if road_per_rack == 0.0:
        return math.inf
    return abs(1.0 / (rack_travel_per_rad * road_per_rack))


def _rotate(v: np.ndarray, k: np.ndarray, angle: float) -> np.ndarray:
    """v turned by angle about the unit axis k (Rodrigues)."""
    return v * math.cos(angle) + np.cross(k, v) * math.sin(angle) + k * (k @ v) * (1.0 - math.cos(angle))


__all__ = ["MIN_LINK_M", "STEERING_RATIO_RANGE", "short_link", "steering_arm", "steering_ratio", "ModelError"]
