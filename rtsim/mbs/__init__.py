"""The multibody formulation: natural/mixed coordinates, constraints, forces, the ALI3-P integrator."""
from .builder import Mechanism, MechanismBuilder, Ref, Scalar, Settings
from .simulation import Simulation

__all__ = ["Mechanism", "MechanismBuilder", "Ref", "Scalar", "Settings", "Simulation"]
