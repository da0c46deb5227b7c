"""OpenDRIVE test files written by the tests themselves (plain XML, ASAM OpenDRIVE 1.6 elements): the bar's
road of a line, a clothoid and an arc with a superelevation ramp and two lanes per side, and single-geometry
roads for the analytic checks."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

LANE_WIDTH = 3.5            # m
LINE = 60.0                 # m, the straight
SPIRAL = 40.0               # m, the clothoid: curvature 0 -> 1/RADIUS
RADIUS = 100.0              # m, the arc (turning left)
ARC = 0.5 * math.pi * RADIUS   # m, a quarter circle
GRADE = 0.01               # the road's constant grade (elevation b)
CROSS_SLOPE = 0.04          # the arc's superelevation, tan(roll): 4 %, falling to the inside (left)


def _lane(lid: int, friction: float | None, mark: str) -> str:
    mat = f'<material sOffset="0" surface="asphalt" friction="{friction}"/>' if friction is not None else ""
    return (f'<lane id="{lid}" type="driving" level="false"><width sOffset="0" a="{LANE_WIDTH}" b="0" c="0" d="0"/>'
            f'<roadMark sOffset="0" type="{mark}" width="0.12" color="standard"/>{mat}</lane>')


def lanes_xml(friction: dict | None = None) -> str:
    """Two lanes per side, the outer ones with a solid edge line, the inner ones broken; centre line solid."""
    f = friction or {}
    left = _lane(2, f.get(2), "solid") + _lane(1, f.get(1), "broken")
    right = _lane(-1, f.get(-1), "broken") + _lane(-2, f.get(-2), "solid")
    centre = '<lane id="0" type="none" level="false"><roadMark sOffset="0" type="solid" width="0.12"/></lane>'
    return (f'<lanes><laneSection s="0"><left>{left}</left><center>{centre}</center>'
            f'<right>{right}</right></laneSection></lanes>')


def road_xml(geometries: str, length: float, lanes: str, elevation: str = "", lateral: str = "",
             rid: str = "1") -> str:
    return (f'<road name="r{rid}" length="{float(length)!r}" id="{rid}" junction="-1" rule="RHT">'
            f'<planView>{geometries}</planView><elevationProfile>{elevation}</elevationProfile>'
            f'<lateralProfile>{lateral}</lateralProfile>{lanes}</road>')


def document(*roads: str) -> str:
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<OpenDRIVE><header revMajor="1" revMinor="6" '
            f'name="rtsim test" version="1.00"/>{"".join(roads)}</OpenDRIVE>\n')


def bar_road(friction: dict | None = None, grade: float = GRADE) -> str:
    """Line (LINE m, heading +x from the origin), clothoid (0 -> 1/RADIUS over SPIRAL m), arc (RADIUS, a
    quarter circle, turning left); elevation a constant `grade`; superelevation 0 on the line, a linear ramp
    over the clothoid to -atan(CROSS_SLOPE) (the left, inner side low) held on the arc."""
    k = 1.0 / RADIUS
    # the arc starts where the clothoid ends: a fine midpoint-rule integration of its heading (independent
    # of the reader's Fresnel closed form)
    n = 200000
    du = SPIRAL / n
    u = (0.5 + np.arange(n)) * du
    th = 0.5 * k / SPIRAL * u * u
    xs, ys, hs = LINE + float(np.sum(np.cos(th)) * du), float(np.sum(np.sin(th)) * du), 0.5 * k * SPIRAL
    geo = (f'<geometry s="0" x="0" y="0" hdg="0" length="{LINE!r}"><line/></geometry>'
           f'<geometry s="{LINE!r}" x="{LINE!r}" y="0" hdg="0" length="{SPIRAL!r}">'
           f'<spiral curvStart="0" curvEnd="{k!r}"/></geometry>'
           f'<geometry s="{LINE + SPIRAL!r}" x="{xs!r}" y="{ys!r}" hdg="{hs!r}" length="{ARC!r}">'
           f'<arc curvature="{k!r}"/></geometry>')
    sup = -math.atan(CROSS_SLOPE)
    lateral = (f'<superelevation s="0" a="0" b="0" c="0" d="0"/>'
               f'<superelevation s="{LINE!r}" a="0" b="{sup / SPIRAL!r}" c="0" d="0"/>'
               f'<superelevation s="{LINE + SPIRAL!r}" a="{sup!r}" b="0" c="0" d="0"/>')
    elevation = f'<elevation s="0" a="0" b="{grade!r}" c="0" d="0"/>'
    return document(road_xml(geo, LINE + SPIRAL + ARC, lanes_xml(friction), elevation, lateral))


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def road_toml(path: Path, xodr: Path, **keys) -> Path:
    extra = "".join(f"{k} = {v!r}\n" for k, v in keys.items())
    path.write_text(f'type = "opendrive"\nfile = "{xodr.name}"\n{extra}')
    return path
