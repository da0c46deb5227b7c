"""A PI speed controller as an FMI 3.0 co-simulation FMU (built by the tests with pythonfmu3) and the same
law for a controller written in Python (`law`): demand u = kp e + I (m/s^2, e = v_ref - v), I += ki e h;
u > 0 opens the throttle (thr_gain rad per m/s^2, up to thr_max), u < 0 brakes (brk_gain kPa per m/s^2)."""
from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64
from pythonfmu3.unit import Unit

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
    author = "rtsim tests"
    description = "PI speed controller"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.time = 0.0
        self.v = 0.0
        self.throttle = 0.0
        self.brake = 0.0
        self.st = [0.0]
        self.register_units([Unit("m/s", m=1, s=-1), Unit("rad", rad=1), Unit("kPa", kg=1, m=-1, s=-2, factor=1e3)])
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        self.register_variable(Float64("v", causality=Fmi3Causality.input, unit="m/s", start=0.0))
        self.register_variable(Float64("throttle", causality=Fmi3Causality.output, unit="rad"))
        self.register_variable(Float64("brake", causality=Fmi3Causality.output, unit="kPa"))
        for name, value in PARAMS.items():
            setattr(self, name, value)
            self.register_variable(Float64(name, causality=Fmi3Causality.parameter,
                                           variability=Fmi3Variability.tunable, start=value))

    def do_step(self, current_time, step_size):
        p = {k: getattr(self, k) for k in PARAMS}
        self.throttle, self.brake = law(p, self.st, self.v, step_size)
        return True
