"""A lane-keeping controller as an FMI 3.0 co-simulation FMU (built by the tests with pythonfmu3) and the
same law for a controller written in Python (`law`): steering-wheel angle = -(k_y (y - y_ref) + k_psi yaw),
clipped to +-delta_max (rad). Its lateral input is declared in millimetres, so the run converts."""
from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64
from pythonfmu3.unit import Unit

PARAMS = {"y_ref": 0.0, "k_y": 0.06, "k_psi": 1.6, "delta_max": 1.0}


def law(p, y_mm, yaw):
    """Steering-wheel angle (rad) for the lateral position y_mm (mm) and yaw (rad)."""
    d = -(p["k_y"] * (y_mm * 1e-3 - p["y_ref"]) + p["k_psi"] * yaw)
    return max(-p["delta_max"], min(p["delta_max"], d))


class LaneKeep(Fmi3Slave):
    author = "rtsim tests"
    description = "lane-keeping controller"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.time = 0.0
        self.y_mm = 0.0
        self.yaw = 0.0
        self.steer = 0.0
        self.register_units([Unit("mm", m=1, factor=1e-3), Unit("rad", rad=1)])
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        self.register_variable(Float64("y_mm", causality=Fmi3Causality.input, unit="mm", start=0.0))
        self.register_variable(Float64("yaw", causality=Fmi3Causality.input, unit="rad", start=0.0))
        self.register_variable(Float64("steer", causality=Fmi3Causality.output, unit="rad"))
        for name, value in PARAMS.items():
            setattr(self, name, value)
            self.register_variable(Float64(name, causality=Fmi3Causality.parameter,
                                           variability=Fmi3Variability.tunable, start=value))

    def do_step(self, current_time, step_size):
        p = {k: getattr(self, k) for k in PARAMS}
        self.steer = law(p, self.y_mm, self.yaw)
        return True
