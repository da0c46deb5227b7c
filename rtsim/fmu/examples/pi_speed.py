"""Example controller FMU: a PI speed controller (FMI 3.0 co-simulation; build it with
`rtsim.fmu.examples.build_example("pi_speed", DIR)`, which needs pythonfmu3), and its law for a controller
written in Python (`law`): demand u = kp e + I (m/s^2, e = v_ref - v), I += ki e h; u > 0 opens the
throttle (thr_gain rad per m/s^2, up to thr_max), u < 0 brakes (brk_gain kPa per m/s^2)."""
from pythonfmu3 import Fmi3Slave

try:                                  # inside the FMU, its project file sits beside this script
    from fmu_vars import declare
except ImportError:                   # imported from the package (the Python form of the law)
    from rtsim.fmu.examples.fmu_vars import declare

PARAMS = {"v_ref": 20.0, "kp": 0.8, "ki": 0.3, "thr_gain": 0.35, "thr_max": 1.4, "brk_gain": 800.0}


def law(p, st, v, h):
    """(throttle rad, brake kPa) for the measured speed v (m/s); st[0] the integrator, updated."""
    e = p["v_ref"] - v
    st[0] += p["ki"] * e * h
    u = p["kp"] * e + st[0]
    thr = min(u * p["thr_gain"], p["thr_max"]) if u > 0.0 else 0.0
    brk = -u * p["brk_gain"] if u < 0.0 else 0.0
    return thr, brk


class PiSpeed(Fmi3Slave):

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.author, self.description = "rtsim", "PI speed controller"
        self.st = [0.0]
        declare(self, {"v": "m/s"}, {"throttle": "rad", "brake": "kPa"}, PARAMS)

    def do_step(self, current_time, step_size):
        p = {k: getattr(self, k) for k in PARAMS}
        self.throttle, self.brake = law(p, self.st, self.v, step_size)
        return True
