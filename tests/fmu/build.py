"""Builds the tests' controller FMUs from the example classes (rtsim/fmu/examples, with pythonfmu3: nothing
is downloaded), and the same controllers as plain Python command sources (rtsim.fmu.controller's interface)."""
from __future__ import annotations

import numpy as np

from rtsim.fmu.examples import example_module


class PythonPiSpeed:
    """The example PI speed controller as a command source written in Python."""
    inputs = ("speed",)
    outputs = ("throttle_angle_cmd", "brake_pressure_cmd")

    def __init__(self, step: float, **params):
        self.step = step
        self.mod = example_module("pi_speed")
        self.p = {**self.mod.PARAMS, **params}

    def start(self, t0=0.0):
        self.st = [0.0]

    def communicate(self, t, x):
        return np.array(self.mod.law(self.p, self.st, float(x[0]), self.step))

    def close(self):
        pass


class PythonLaneKeep:
    """The example lane-keeping controller as a command source written in Python (its lateral
    input in mm, as the FMU declares it: the same inputs)."""
    inputs = ("pos_y", "yaw_angle")
    outputs = ("steering_wheel_angle_cmd",)

    def __init__(self, step: float, **params):
        self.step = step
        self.mod = example_module("lane_keep")
        self.p = {**self.mod.PARAMS, **params}

    def start(self, t0=0.0):
        pass

    def communicate(self, t, x):
        return np.array([self.mod.law(self.p, float(x[0]) * 1000.0, float(x[1]))])

    def close(self):
        pass
