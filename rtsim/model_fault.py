"""A model failure as the rest of rtsim reports it, and the test-only hook that forces one.

``ModelFault`` is a failed vehicle step described once for every consumer (the service's SIM_STATUS
and SIM_DIAG frames, its status payload and recording, `rtsim resim`, offline runs): the reason code
(the step's status, rtsim.mbs.model ERR_* or a two-wheeler's fall, 0 = none), its short name, the
model's message, the failed step's number and the simulation time it was to end at (s), and the
generalized coordinate the failure names (``""`` when the failure names none: a Newton or projection
that did not converge, a non-finite state, a fall).

TEST-ONLY HOOK. ``RTSIM_TEST_MODEL_FAULT_AT=<seconds>`` in the environment of `rtsim serve` or
`rtsim run` forces a model failure through the model's own failure path: before the first step that
ends at or after that simulation time, the first generalized velocity of the multibody state is set to
NaN, so that step's force evaluation and Newton iteration fail as a real model would (a non-finite
generalized force or state, with the coordinate it names). The service records the time in its session
metadata (``rtsim.session``: ``test_model_fault_at``) so `rtsim resim` repeats the failure at the same
step. It exists to test the model-fault state; it is not a simulation feature.
"""
from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass

import numpy as np

from rtsim.errors import (ConfigError, ConvergenceError, FactorizationError, NonFiniteForceError,
                          NonFiniteStateError, SimulationError)
from rtsim.mbs.model import (ERR_FACTOR, ERR_NEWTON, ERR_NONFINITE_FORCE, ERR_NONFINITE_STATE, ERR_PROJECTION,
                             ST_FAIL_INDEX)

TEST_FAULT_ENV = "RTSIM_TEST_MODEL_FAULT_AT"
TEST_FAULT_METADATA = "test_model_fault_at"      # key in the recording's rtsim.session metadata
FELL = 64                                        # a two-wheeler's fall (rtsim.vehicle.motorcycle.plant.FELL)
REASONS = {ERR_NEWTON: "newton_not_converged", ERR_NONFINITE_FORCE: "nonfinite_force",
           ERR_NONFINITE_STATE: "nonfinite_state", ERR_FACTOR: "tangent_not_positive_definite",
           ERR_PROJECTION: "projection_not_converged", FELL: "fell"}
NAMED_COORDINATE = (ERR_NONFINITE_FORCE, ERR_FACTOR)   # the failures whose fail index names a coordinate


@dataclass(frozen=True)
class ModelFault:
    """A failed vehicle step (see the module docstring); ``sim_time`` in s."""
    reason_code: int
    reason: str
    message: str
    step: int
    sim_time: float
    coordinate: str

    def as_dict(self) -> dict:
        return asdict(self)

    def line(self) -> str:
        """One line: time, step, reason, coordinate."""
        where = f" at coordinate '{self.coordinate}'" if self.coordinate else ""
        return (f"model fault at t = {self.sim_time:.3f} s (step {self.step}): {self.reason} "
                f"(code {self.reason_code}){where}: {self.message}")


def describe(sim, status: int, step: int, names: dict[int, str] | None = None) -> ModelFault:
    """The ModelFault of vehicle sim ``sim`` (a car's VehicleSim, a two-wheeler's TwoWheelerHil or ride)
    whose step number ``step`` returned ``status``; ``sim.raise_status`` (or the multibody simulation's
    own) supplies the message, its multibody data the coordinate; ``names``: the reason codes' names as
    the served DBC declares them (its SIM_DIAG.model_fault_reason values), else REASONS."""
    mbs = sim.sim
    try:
        (sim.raise_status if hasattr(sim, "raise_status") else mbs._raise)(status, step)
        message = f"failed with status {status}"
    except SimulationError as exc:
        message = str(exc)
    coordinate = _coordinate(mbs) if status in NAMED_COORDINATE else ""
    reason = (names or {}).get(int(status)) or REASONS.get(int(status), f"status_{int(status)}")
    return ModelFault(int(status), reason, message, int(step), round(step * sim.dt, 9), coordinate)


def _coordinate(mbs) -> str:
    """The generalized coordinate a multibody simulation's last failure names (its fail index)."""
    i = int(mbs.data.stats[ST_FAIL_INDEX])
    coords = mbs.mech.coordinate_names
    return coords[i] if 0 <= i < len(coords) else ""


def error_code(exc: SimulationError) -> int:
    """The step status a typed SimulationError stands for (0: an untyped one)."""
    if isinstance(exc, NonFiniteForceError):
        return ERR_NONFINITE_FORCE
    if isinstance(exc, FactorizationError):
        return ERR_FACTOR
    if isinstance(exc, NonFiniteStateError):
        return ERR_NONFINITE_STATE
    if isinstance(exc, ConvergenceError):
        return ERR_PROJECTION if "projection" in str(exc) else ERR_NEWTON
    if type(exc).__name__ == "Fall":
        return FELL
    return 0


def describe_error(sim, exc: SimulationError, step: int) -> ModelFault:
    """The ModelFault of an offline run whose step number ``step`` raised ``exc`` (``sim`` holds the
    multibody simulation as ``sim.sim``: the coordinate)."""
    code = error_code(exc)
    coordinate = _coordinate(sim.sim) if code in NAMED_COORDINATE else ""
    return ModelFault(code, REASONS.get(code, f"status_{code}"), str(exc), int(step), round(step * sim.dt, 9),
                      coordinate)


def test_fault_time(value: str | None = None) -> float | None:
    """The forced failure's simulation time (s) from ``value`` (default: the environment), None if unset."""
    text = os.environ.get(TEST_FAULT_ENV) if value is None else value
    if text is None or text == "":
        return None
    try:
        t = float(text)
    except ValueError:
        t = math.nan
    if not (math.isfinite(t) and t > 0):
        raise ConfigError(f"{TEST_FAULT_ENV} = {text!r}: must be a simulation time > 0 s (test-only hook)")
    return t


def test_fault_step(at: float | None, dt: float) -> int | None:
    """The number of the step that the hook makes fail (the first ending at or after ``at`` s)."""
    if at is None:
        return None
    return max(1, int(math.ceil(at / dt - 1e-9)))


def force_failure(sim) -> None:
    """The hook's act: the first generalized velocity of ``sim``'s multibody state becomes NaN."""
    sim.sim.data.qd[0] = np.nan
