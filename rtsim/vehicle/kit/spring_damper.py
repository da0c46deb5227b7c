"""The spring/damper element, one kit part for every vehicle (the car's corners, the two-wheeler's fork
and shock): a spring force against the element's compression and a damper force against its
compression rate, each a 1-D table (rtsim.vehicle.kit.tables), compression positive:

    F = F_spring(x) + F_damper(x')      N, along the element; x in m, x' in m/s

A config gives either the linear laws (a rate with preload and stops; a two-rate damper) or a table
of points (`Characteristic`); the builders here turn either into the tables the kernels read, and
`spring_damper_force` evaluates both with their slopes for the tangent.
"""
from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from rtsim.configfile import Range, Strict
from rtsim.jit import inline_kernel

from .tables import TABLE_POINTS, table_1d, table_eval


class Characteristic(Strict):
    """A nonlinear law as a table of points (piecewise linear, continued with the end slopes): force
    (N, compression positive) against travel (m) or travel rate (m/s), x increasing."""
    x: list[Range(-10.0, 10.0, "m or m/s")] = Field(min_length=2, max_length=TABLE_POINTS)
    force_n: list[Range(-1e6, 1e6, "N")] = Field(min_length=2, max_length=TABLE_POINTS)

    @model_validator(mode="after")
    def _points(self):
        if len(self.x) != len(self.force_n):
            raise ValueError(f"x and force_n must have the same length ({len(self.x)} != {len(self.force_n)})")
        if any(b <= a for a, b in zip(self.x, self.x[1:])):
            raise ValueError("x must increase")
        return self


def characteristic_table(ch: Characteristic, offset: float | None = None) -> np.ndarray:
    """The table of a Characteristic, its forces shifted by `offset` (N; e.g. a static preload)."""
    force = ch.force_n if offset is None else np.asarray(ch.force_n) + offset
    return table_1d(ch.x, force)


def bump_stop_spring_table(rate: float, preload: float, clearance: float, stop_rate: float) -> np.ndarray:
    """A linear spring (rate N/m, `preload` N at compression 0) with a bump stop of `stop_rate` N/m
    beyond `clearance` m of compression; three points, exact (the ends continue linearly)."""
    k, kb, gap, pre = rate, stop_rate, clearance, preload
    return table_1d([-1.0, gap, gap + 1.0], [pre - k, pre + k * gap, pre + k * (gap + 1.0) + kb])


def stroke_spring_table(rate: float, preload: float, stroke: float, top_out_rate: float, bottom_out_rate: float,
                        reach: float) -> np.ndarray:
    """A linear spring over its stroke (compression 0 .. `stroke` m from full extension, `preload` N at
    0, rate N/m), a top-out stop (N/m) below 0 and a bottom-out stop (N/m, added to the rate) beyond the
    stroke; the outer points `reach` m beyond the ends."""
    k, pre, s = rate, preload, stroke
    return table_1d([-reach, 0.0, s, s + reach],
                    [pre - top_out_rate * reach, pre, pre + k * s, pre + k * s + (k + bottom_out_rate) * reach])


def two_rate_damper_table(bump: float, rebound: float, reach: float) -> np.ndarray:
    """A damper of `bump` N s/m in compression and `rebound` N s/m in extension; the outer points at
    +-`reach` m/s (the ends continue linearly)."""
    return table_1d([-reach, 0.0, reach], [-rebound * reach, 0.0, bump * reach])


@inline_kernel
def spring_damper_force(spring_tab, damper_tab, x, xd):
    """The element's spring and damper at compression x (m) and rate xd (m/s): (F_spring N, its
    stiffness N/m, F_damper N, its damping N s/m)."""
    f_spring, k = table_eval(spring_tab, x)
    f_damper, c = table_eval(damper_tab, xd)
    return f_spring, k, f_damper, c
