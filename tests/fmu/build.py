"""Builds the tests' controller FMUs from the Python classes beside this file (pythonfmu3: nothing is
downloaded), and the same controllers as plain Python command sources (rtsim.fmu.controller's interface)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def build_fmu(name: str, dest: Path) -> Path:
    """tests/fmu/<name>.py built into an FMU in dest."""
    from pythonfmu3.builder import FmuBuilder

    return Path(FmuBuilder.build_FMU(HERE / f"{name}.py", dest=dest))


def module(name: str):
    spec = importlib.util.spec_from_file_location(f"rtsim_test_fmu_{name}", HERE / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class PythonPiSpeed:
    """The PI speed controller of pi_speed.py as a command source written in Python."""
    inputs = ("speed",)
    outputs = ("throttle_angle_cmd", "brake_pressure_cmd")

    def __init__(self, step: float, **params):
        self.step = step
        self.mod = module("pi_speed")
        self.p = {**self.mod.PARAMS, **params}

    def start(self, t0=0.0):
        self.st = [0.0]

    def communicate(self, t, x):
        return np.array(self.mod.law(self.p, self.st, float(x[0]), self.step))

    def close(self):
        pass


class PythonLaneKeep:
    """The lane-keeping controller of lane_keep.py as a command source written in Python (its lateral
    input in mm, as the FMU declares it: the same inputs)."""
    inputs = ("pos_y", "yaw_angle")
    outputs = ("steering_wheel_angle_cmd",)

    def __init__(self, step: float, **params):
        self.step = step
        self.mod = module("lane_keep")
        self.p = {**self.mod.PARAMS, **params}

    def start(self, t0=0.0):
        pass

    def communicate(self, t, x):
        return np.array([self.mod.law(self.p, float(x[0]) * 1000.0, float(x[1]))])

    def close(self):
        pass
