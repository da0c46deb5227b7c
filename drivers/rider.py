"""The motorcycle rider, as the drivers and scenarios use it: steering torque on the handlebars (plus
throttle and brakes) to follow a path. The two-wheeler runs the rider inside its compiled step, so the
rider's kernels and layouts (RV_*, RO_*, P_*, ST_*) are declared with the vehicle
(rtsim.vehicle.motorcycle.rider, whose docstring states the control law); this module names them for
the driver layer."""
from rtsim.vehicle.motorcycle.rider import *  # noqa: F401,F403  (the rider's public names)
