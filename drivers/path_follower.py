"""Closed-loop lateral driver: steers along a path of (x, y) points by pure pursuit or Stanley.

Path. A polyline through the points (road frame, m), parametrised by arc length s. An open path is
extended straight beyond its ends (so a car that overshoots keeps a meaningful error); a closed path
(`closed=True`, or first point == last point) wraps around. The vertex headings (bisectors of the
adjacent segments) are interpolated along each segment, so the path heading is continuous.

Nearest point. The driver keeps the index of the segment it was nearest to at the previous call and
walks from there to the neighbour segments while the distance decreases: O(1) per call amortised,
and it cannot jump to another branch of a path that crosses itself. The first call searches the
whole path once. (The geometry and these kernels live in `rtsim.road.paths`, shared with the rider.)

Laws (rear axle at P_r = position - rear_offset * heading; wheelbase l):

- pure pursuit: the goal is the path point a look-ahead distance L = clip(la_gain v, la_min, la_max)
  ahead of the rear axle's nearest point (arc length); with (dx, dy) the goal in the car frame,
  curvature = 2 dy / (dx^2 + dy^2) and road-wheel angle delta = atan(l curvature). On a circle the
  rear axle's steady error is zero (the circle through the car tangent to its heading and through
  the goal is the path itself).
- Stanley: at the front axle P_f = P_r + l heading, with e its signed distance to the path (left
  positive) and psi_e the path heading minus the car's yaw, delta = psi_e - atan(k e / (v_soft + v)).
  On a circle the front axle's steady error is zero for a kinematic car.

Output: steering-wheel angle = steering_ratio * delta, with |delta| <= max_wheel_angle and the
steering-wheel rate limited to max_rate (rad/s) starting from 0 at the first call. ISO 8855: a
positive angle steers left.

Model/data: `PathFollower` is a named tuple of arrays (path `px, py, ps, hd, seg_len`, parameters
`par`, mutable state `st`); `path_follower_step` is a compiled kernel that writes
out[I_STEER] and allocates nothing. The state keeps diagnostics: cross-track error, arc length,
heading error.
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import asdict, dataclass
from enum import IntEnum

import numpy as np
from pydantic import create_model

from rtsim.configfile import Strict, check_ranges, range_fields
from rtsim.jit import inline_kernel, kernel

from .base import I_STEER, DriverView
from rtsim.road.paths import circle_points, nearest_segment, on_segment, point_ahead, polyline, seg_project, wrap_angle

__all__ = ["PathFollower", "PathFollowerParams", "PATH_FOLLOWER_RANGES", "path_follower", "path_follower_step",
           "reset", "circle_points", "PathPar", "PathState"]

PURE_PURSUIT = 0
STANLEY = 1
METHODS = {"pure_pursuit": PURE_PURSUIT, "stanley": STANLEY}


class PathPar(IntEnum):
    """The path follower's parameter array (par): geometry, gains and limits."""
    METHOD = 0      # PURE_PURSUIT or STANLEY
    WB = 1          # m, wheelbase
    RATIO = 2       # -, steering ratio (steering-wheel angle / road-wheel angle)
    LA_MIN = 3      # m, minimum look-ahead (pure pursuit)
    LA_GAIN = 4     # s, look-ahead per unit speed (pure pursuit)
    LA_MAX = 5      # m, maximum look-ahead (pure pursuit)
    K = 6           # 1/s, Stanley cross-track gain
    V_SOFT = 7      # m/s, Stanley softening speed
    MAX_WHEEL = 8   # rad, road-wheel angle limit
    MAX_RATE = 9    # rad/s, steering-wheel rate limit
    REAR = 10       # m, distance from the state's reference point back to the rear axle
    CLOSED = 11     # 1 for a closed path
    NSEG = 12       # number of segments
    LENGTH = 13     # m, total path length


NPAR = len(PathPar)      # slots in par


class PathState(IntEnum):
    """The path follower's state array (st): memory between calls and diagnostics."""
    INIT = 0
    IDX = 1    # segment nearest to the reference point at the last call
    T = 2      # time of the last call
    SW = 3     # last steering-wheel output, rad
    E = 4      # diagnostics: signed cross-track error of the reference point (left positive), m
    S = 5      # diagnostics: arc length of the nearest point, m
    HE = 6     # diagnostics: path heading minus yaw, rad
    DELTA = 7  # diagnostics: road-wheel angle before limits, rad
    GX = 8     # diagnostics: goal point x (pure pursuit), m
    GY = 9     # diagnostics: goal point y, m


NST = len(PathState)     # slots in st

PathFollower = namedtuple("PathFollower", ["px", "py", "ps", "hd", "seg_len", "par", "st"])


@dataclass(frozen=True)
class PathFollowerParams:
    wheelbase: float = 2.6
    steering_ratio: float = 16.0
    la_min: float = 3.0
    la_gain: float = 0.35
    la_max: float = 30.0
    k_stanley: float = 2.5
    v_soft: float = 1.0
    max_wheel_angle: float = 0.6
    max_rate: float = 12.0
    rear_offset: float = 0.0

    def __post_init__(self):
        check_ranges(_PARAMS_MODEL, asdict(self), "path follower")
        if self.la_max < self.la_min:
            raise ValueError(f"path follower: la_max = {self.la_max!r}: must be >= la_min = {self.la_min!r} m")


#: Allowed ranges of the parameters: name -> (lo, hi, unit, lo_open); the scenario files use them too.
PATH_FOLLOWER_RANGES = {
    "wheelbase": (0.0, 10.0, "m", True),
    "steering_ratio": (0.0, 100.0, "", True),
    "la_min": (0.0, 200.0, "m", True),
    "la_gain": (0.0, 10.0, "s", False),
    "la_max": (0.0, 500.0, "m", True),
    "k_stanley": (0.0, 50.0, "1/s", False),
    "v_soft": (0.0, 50.0, "m/s", True),
    "max_wheel_angle": (0.0, 1.5, "rad", True),
    "max_rate": (0.0, 100.0, "rad/s", True),
    "rear_offset": (-10.0, 10.0, "m", False),
}
_PARAMS_MODEL = create_model("PathFollowerParamsModel", __base__=Strict,
                             **range_fields(PATH_FOLLOWER_RANGES, {n: 0.0 for n in PATH_FOLLOWER_RANGES}))


def path_follower(x, y, method: str = "pure_pursuit", closed: bool = False,
                  params: PathFollowerParams | None = None, **kw) -> PathFollower:
    """Build a path follower for the polyline through (x[i], y[i]) (m, road frame)."""
    if params is None:
        params = PathFollowerParams(**kw)
    elif kw:
        params = PathFollowerParams(**{**asdict(params), **kw})
    if method not in METHODS:
        raise ValueError(f"path follower method {method!r}: use one of {', '.join(METHODS)}")
    px, py, ps, hd, seg, closed = polyline(x, y, closed)
    nseg = seg.size
    par = np.zeros(NPAR)
    par[PathPar.METHOD] = METHODS[method]
    par[PathPar.WB] = params.wheelbase
    par[PathPar.RATIO] = params.steering_ratio
    par[PathPar.LA_MIN] = params.la_min
    par[PathPar.LA_GAIN] = params.la_gain
    par[PathPar.LA_MAX] = params.la_max
    par[PathPar.K] = params.k_stanley
    par[PathPar.V_SOFT] = params.v_soft
    par[PathPar.MAX_WHEEL] = params.max_wheel_angle
    par[PathPar.MAX_RATE] = params.max_rate
    par[PathPar.REAR] = params.rear_offset
    par[PathPar.CLOSED] = 1.0 if closed else 0.0
    par[PathPar.NSEG] = nseg
    par[PathPar.LENGTH] = ps[-1]
    return PathFollower(px, py, ps, hd, seg, par, np.zeros(NST))


def reset(pf: PathFollower) -> None:
    pf.st[:] = 0.0


# --------------------------------------------------------------------------------------------------
# Kernels


@inline_kernel
def _wrap(a):
    return wrap_angle(a)


@inline_kernel
def _proj(pf, i, x, y):
    """Parameter u along segment i of the point nearest to (x, y), and the squared distance."""
    return seg_project(pf.px, pf.py, i, x, y, int(pf.par[PathPar.NSEG]), pf.par[PathPar.CLOSED] != 0.0)


@inline_kernel
def _nearest(pf, x, y):
    """Segment nearest to (x, y), walking from the last one (whole path on the first call)."""
    return nearest_segment(pf.px, pf.py, int(pf.par[PathPar.NSEG]), pf.par[PathPar.CLOSED] != 0.0,
                           pf.st[PathState.INIT] == 0.0, int(pf.st[PathState.IDX]), x, y)


@inline_kernel
def _point_ahead(pf, i, u, dist):
    """Point at arc length `dist` ahead of parameter u on segment i."""
    return point_ahead(pf.px, pf.py, pf.seg_len, int(pf.par[PathPar.NSEG]), pf.par[PathPar.CLOSED] != 0.0, i, u, dist)


@kernel
def path_follower_step(pf, t, state, out):
    """Write the steering-wheel angle (out[I_STEER], rad) for time t and the vehicle state."""
    p = pf.par
    st = pf.st
    v = max(state[DriverView.SPEED], 0.0)
    yaw = state[DriverView.YAW]
    c = math.cos(yaw)
    s = math.sin(yaw)
    wb = p[PathPar.WB]
    rx = state[DriverView.X] - p[PathPar.REAR] * c
    ry = state[DriverView.Y] - p[PathPar.REAR] * s
    if p[PathPar.METHOD] == STANLEY:
        qx = rx + wb * c
        qy = ry + wb * s
    else:
        qx = rx
        qy = ry
    if st[PathState.INIT] == 0.0 or t < st[PathState.T]:
        st[PathState.INIT] = 0.0
        st[PathState.T] = t
        st[PathState.SW] = 0.0
    i = _nearest(pf, qx, qy)
    st[PathState.INIT] = 1.0
    st[PathState.IDX] = i
    u, d2 = _proj(pf, i, qx, qy)
    e, h = on_segment(pf.px, pf.py, pf.hd, pf.seg_len, i, u, qx, qy)
    he = _wrap(h - yaw)
    st[PathState.E] = e
    st[PathState.S] = pf.ps[i] + u * pf.seg_len[i]
    st[PathState.HE] = he

    if p[PathPar.METHOD] == STANLEY:
        delta = he - math.atan(p[PathPar.K] * e / (p[PathPar.V_SOFT] + v))
    else:
        la = min(max(p[PathPar.LA_GAIN] * v, p[PathPar.LA_MIN]), p[PathPar.LA_MAX])
        gx, gy = _point_ahead(pf, i, u, la)
        st[PathState.GX] = gx
        st[PathState.GY] = gy
        dx = c * (gx - rx) + s * (gy - ry)
        dy = -s * (gx - rx) + c * (gy - ry)
        ld2 = dx * dx + dy * dy
        delta = 0.0
        if ld2 > 1e-12:
            delta = math.atan(wb * 2.0 * dy / ld2)
    st[PathState.DELTA] = delta
    lim = p[PathPar.MAX_WHEEL]
    delta = min(max(delta, -lim), lim)
    sw = p[PathPar.RATIO] * delta
    dt = t - st[PathState.T]
    step = p[PathPar.MAX_RATE] * dt
    prev = st[PathState.SW]
    sw = min(max(sw, prev - step), prev + step)
    st[PathState.SW] = sw
    st[PathState.T] = t
    out[I_STEER] = sw
