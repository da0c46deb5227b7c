"""Piecewise-linear tables for the compiled kernels: a 1-D characteristic y(x) (a spring's force against
its compression, a damper's force against its speed) and a 2-D map z(x, y) on a grid (an assistance law
against torsion-bar torque and vehicle speed).

A 1-D table is a flat float array [n, x_0..x_{N-1}, y_0..y_{N-1}] (N = capacity, n points used, x
strictly increasing); beyond its ends it continues with the end segments' slopes, so a linear law is
a 2-point table and a bump stop one more point. `table_integral` gives the exact integral of the
interpolant (a spring's stored energy). A 2-D map [nx, ny, x.., y.., z (nx*ny, x-major)] is
interpolated bilinearly and clamped at its edges.
"""
from __future__ import annotations

import numpy as np

from rtsim.jit import inline_kernel

TABLE_POINTS = 16          # capacity of a 1-D table


def table_1d(x, y, capacity: int = TABLE_POINTS) -> np.ndarray:
    """Pack points (x strictly increasing, at least 2) into a 1-D table array."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = x.size
    if n < 2 or n > capacity or y.shape != x.shape or np.any(np.diff(x) <= 0.0):
        raise ValueError(f"a table needs 2..{capacity} points with strictly increasing x (got {n})")
    out = np.zeros(1 + 2 * capacity)
    out[0] = n
    out[1:1 + n] = x
    out[1 + capacity:1 + capacity + n] = y
    return out


def map_2d(x, y, z) -> np.ndarray:
    """Pack a grid map z[i, j] at (x[i], y[j]) into a flat array."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    z = np.asarray(z, dtype=float)
    if z.shape != (x.size, y.size) or np.any(np.diff(x) <= 0.0) or np.any(np.diff(y) <= 0.0):
        raise ValueError("a map needs z of shape (len(x), len(y)) and strictly increasing x and y")
    return np.concatenate([[x.size, y.size], x, y, z.ravel()])


@inline_kernel
def _segment(t, x):
    """Index k of the segment [x_k, x_k+1] holding x (end segments extended)."""
    n = int(t[0])
    cap = (t.shape[0] - 1) // 2
    k = 0
    while k < n - 2 and x > t[1 + k + 1]:
        k += 1
    return k, n, cap


@inline_kernel
def table_eval(t, x):
    """(y, dy/dx) of a 1-D table at x."""
    k, n, cap = _segment(t, x)
    x0 = t[1 + k]
    x1 = t[2 + k]
    y0 = t[1 + cap + k]
    y1 = t[2 + cap + k]
    slope = (y1 - y0) / (x1 - x0)
    return y0 + slope * (x - x0), slope


@inline_kernel
def table_integral(t, x):
    """Integral of the 1-D table's interpolant from 0 to x (exact: piecewise quadratic)."""
    return _integral_to(t, x) - _integral_to(t, 0.0)


@inline_kernel
def _integral_to(t, x):
    """Integral from the first point x_0 to x (negative below x_0)."""
    n = int(t[0])
    cap = (t.shape[0] - 1) // 2
    acc = 0.0
    k = 0
    while k < n - 2 and x > t[1 + k + 1]:
        x0 = t[1 + k]
        x1 = t[2 + k]
        acc += 0.5 * (t[1 + cap + k] + t[2 + cap + k]) * (x1 - x0)
        k += 1
    x0 = t[1 + k]
    y0 = t[1 + cap + k]
    slope = (t[2 + cap + k] - y0) / (t[2 + k] - x0)
    dx = x - x0
    return acc + y0 * dx + 0.5 * slope * dx * dx


@inline_kernel
def map_eval(t, x, y):
    """Bilinear interpolation of a 2-D map at (x, y), clamped to the grid."""
    nx = int(t[0])
    ny = int(t[1])
    xs = 2
    ys = 2 + nx
    zs = 2 + nx + ny
    if x <= t[xs]:
        x = t[xs]
    elif x >= t[xs + nx - 1]:
        x = t[xs + nx - 1]
    if y <= t[ys]:
        y = t[ys]
    elif y >= t[ys + ny - 1]:
        y = t[ys + ny - 1]
    i = 0
    while i < nx - 2 and x > t[xs + i + 1]:
        i += 1
    j = 0
    if ny > 1:
        while j < ny - 2 and y > t[ys + j + 1]:
            j += 1
    fx = (x - t[xs + i]) / (t[xs + i + 1] - t[xs + i])
    if ny == 1:
        return (1.0 - fx) * t[zs + i] + fx * t[zs + i + 1]
    fy = (y - t[ys + j]) / (t[ys + j + 1] - t[ys + j])
    z00 = t[zs + i * ny + j]
    z01 = t[zs + i * ny + j + 1]
    z10 = t[zs + (i + 1) * ny + j]
    z11 = t[zs + (i + 1) * ny + j + 1]
    return ((1.0 - fx) * ((1.0 - fy) * z00 + fy * z01) + fx * ((1.0 - fy) * z10 + fy * z11))
