"""IFToMM / A Coruna multibody benchmark problems and the `rtsim bench` runner."""
from .problems import PROBLEMS, Problem

__all__ = ["PROBLEMS", "Problem"]
