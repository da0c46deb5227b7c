"""Typed errors of rtsim. Each message names what failed and where, so the CLI can print it as is."""
from __future__ import annotations


class RtsimError(Exception):
    """Base class: an error the CLI reports in one line, without a traceback."""


class ModelError(RtsimError):
    """A mechanism or model declaration is inconsistent (bad parameters, missing items)."""


class AssemblyError(RtsimError):
    """Initial coordinates or velocities cannot be made consistent with the constraints."""


class SimulationError(RtsimError):
    """A step failed. Carries the step number, the time reached and a residual."""

    def __init__(self, message: str, step: int, time: float, residual: float | None = None):
        super().__init__(message)
        self.step = step
        self.time = time
        self.residual = residual


class ConvergenceError(SimulationError):
    """Newton-Raphson (or a projection) did not converge within the iteration limit."""


class NonFiniteForceError(SimulationError):
    """An applied force evaluated to NaN or infinity."""


class NonFiniteStateError(SimulationError):
    """The state became NaN or infinite."""


class FactorizationError(SimulationError):
    """The tangent matrix was not positive definite."""


class ConfigError(RtsimError):
    """A configuration or data file is malformed: the message names the file, the key (or line), the
    offending value and what is allowed."""
