"""Declared ranges of a vehicle file's geometry and mass properties, shared by every vehicle's config.

Positions are in the vehicle's design frame (x forward, y left, z up; origin on the ground under the
front axle centre, or the front contact point): every point of a road vehicle lies within +-10 m of it,
so a length given in mm instead of m (1000 times too large) is caught where it is read. Moments and
products of inertia in kg m^2 about a body's centre of mass, within +-1e5 kg m^2 (a loaded coach's yaw
inertia is ~5e4; in kg mm^2 a car's would be ~1e9). The relations between them (positive moments, the
triangle inequality) are rtsim.vehicle.kit.inertia's rules.
"""
from __future__ import annotations

from rtsim.configfile import Range

MAX_COORD_M = 10.0
MAX_INERTIA_KGM2 = 1e5

Coord = Range(-MAX_COORD_M, MAX_COORD_M, "m, design frame")
Vec2 = tuple[Coord, Coord]               # (x, z): a point of a single-track vehicle's plane
Vec3 = tuple[Coord, Coord, Coord]        # (x, y, z)
Moment = Range(0.0, MAX_INERTIA_KGM2, "kg m^2")
Moments = tuple[Moment, Moment, Moment]  # Ixx, Iyy, Izz about the centre of mass
Product = Range(-MAX_INERTIA_KGM2, MAX_INERTIA_KGM2, "kg m^2")
