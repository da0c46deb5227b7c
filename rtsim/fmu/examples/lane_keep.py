"""Example controller FMU: lane keeping (FMI 3.0 co-simulation; build it with
`rtsim.fmu.examples.build_example("lane_keep", DIR)`, which needs pythonfmu3), and its law for a controller
written in Python (`law`): steering-wheel angle = -(k_y (y - y_ref) + k_psi yaw), clipped to +-delta_max
(rad). Its lateral input is declared in millimetres, so a run converts the channel (m) into it."""
from pythonfmu3 import Fmi3Slave

try:                                  # inside the FMU, its project file sits beside this script
    from fmu_vars import declare
except ImportError:                   # imported from the package (the Python form of the law)
    from rtsim.fmu.examples.fmu_vars import declare

PARAMS = {"y_ref": 0.0, "k_y": 0.06, "k_psi": 1.6, "delta_max": 1.0}


def law(p, y_mm, yaw):
    """Steering-wheel angle (rad) for the lateral position y_mm (mm) and yaw (rad)."""
    d = -(p["k_y"] * (y_mm * 1e-3 - p["y_ref"]) + p["k_psi"] * yaw)
    return max(-p["delta_max"], min(p["delta_max"], d))


class LaneKeep(Fmi3Slave):

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.author, self.description = "rtsim", "lane-keeping controller"
        declare(self, {"y_mm": "mm", "yaw": "rad"}, {"steer": "rad"}, PARAMS)

    def do_step(self, current_time, step_size):
        p = {k: getattr(self, k) for k in PARAMS}
        self.steer = law(p, self.y_mm, self.yaw)
        return True
