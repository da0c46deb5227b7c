"""Array layouts of the four-wheel car assembly (no imports of its builder or config, so the kernels,
the effects and the config can all use them without an import cycle): the Vehicle tuple of model
arrays the kernels read, and the index tables into it."""
from __future__ import annotations

from collections import namedtuple
from enum import IntEnum

from rtsim.mbs.model import EARTH_GRAVITY

from ..kit.eps import NPORT_EPS

G = EARTH_GRAVITY    # m/s^2: the gravity the car's model is built with, (0, 0, -G); kernels read the model's own
#                      vector (rtsim.vehicle.kit.imu.model_gravity), never this constant
WHEELS = ("fl", "fr", "rl", "rr")   # corner order of every per-wheel array: front axle first, left first
FRONT_AXLE, REAR_AXLE = (0, 1), (2, 3)

# Corner coordinate index table (Vehicle.corner_idx[w, :]).
CI_WX, CI_WY, CI_WZ, CI_Z, CI_PHI, CI_S = range(6)
# Chassis coordinate index table (Vehicle.chassis_idx): r (0..2), u (3..5), v (6..8), w (9..11).



class Susp(IntEnum):
    """Per-corner suspension parameters: columns of Vehicle.susp[w, :]."""
    L0 = 0          # m, the spring/damper element's length at design ride height (the tables' compression from it)
    ARB = 1         # N/m of travel difference, anti-roll bar
    PARTNER = 2     # the other wheel of the axle (corner index)
    BX = 3          # 1/m, axle reaction (Brouilhet effect): force on the travel per N m of Fx r
    BY = 4          # 1/m, the same per N m of Fy r
    CFY = 5         # rad/N of Fy, compliance steer
    CMZ = 6         # rad/(N m) of Mz, compliance steer
    Z_LO = 7        # m, the travel stops: rebound end
    Z_HI = 8        # m, bump end
    STOP_K = 9      # N/m at the wheel, their stiffness
    STOP_C = 10     # N s/m at the wheel, their damping


NSP = len(Susp)

Vehicle = namedtuple("Vehicle", [
    "chassis_idx",     # (12,) int
    "corner_idx",      # (4, 6) int, CI_*
    "axis_coef", "rotz_coef", "rots_coef",   # (4, 3, nterm) polynomials in (z, s), body frame
    "spring_coef",     # (4, nterm) spring/damper length polynomial, m
    "susp",            # (4, NSP) float
    "spring_tab",      # (4, TABLE) spring force (N, compression positive, preload included) against
                       # compression from Susp.L0 (m): rtsim.vehicle.kit.tables 1-D table
    "damper_tab",      # (4, TABLE) damper force (N) against compression speed (m/s)
    "steer_idx",       # (2,) int coordinate indices of the steering column angle and the rack travel
    "steer_kind",      # (1,) int STEER_BY_WIRE or STEER_EPS (which of rtsim.vehicle.kit.steering / eps)
    "driver_row",      # (1,) int constraint row of the driver's steering-wheel angle (EPS angle mode) or -1
    "imu_local",       # (3,) IMU position in the body frame relative to the CG, m
    "aero",            # (2,) drag area m^2, air density kg/m^3
    "tyre_model",      # (1,) int: TYRE_MAGIC_FORMULA or TYRE_LINEAR
    "driven",          # (2,) int corners of the driven axle, left then right
    "drive_slot",      # (4,) int per corner: its index in `driven`, or -1
    "side",            # (4,) float per corner: +1 left, -1 right (mirrors the tyre property file)
])
TYRE_MAGIC_FORMULA, TYRE_LINEAR = 0, 1
STEER_COLUMN, STEER_RACK = 0, 1     # Vehicle.steer_idx
STEER_BY_WIRE, STEER_EPS = 0, 1     # Vehicle.steer_kind

# Energy-audit ports: rows of the port-force array (VehicleData.pf), each the generalized forces one
# element puts on the coordinates, written by its force stage (rtsim.vehicle.car.forces) and summed by
# the power audit (rtsim.vehicle.car.energy). The EPS's own ports follow PORT_EPS
# (rtsim.vehicle.kit.eps PORT_*).
(PORT_TYRE, PORT_SPRING, PORT_DAMPER, PORT_ARB, PORT_AXLE_REACTION, PORT_BRAKE, PORT_DRIVE, PORT_AERO,
 PORT_EFFECTS, PORT_STEER_BY_WIRE, PORT_EPS) = range(11)
NPORT = PORT_EPS + NPORT_EPS
CAR_PORT_NAMES = ("tyres", "suspension_springs", "dampers", "anti_roll_bars", "axle_reactions", "brakes",
                  "drive", "aero", "effects", "steer_by_wire")
