"""rtsim: a real-time hardware-in-the-loop vehicle simulator built on a numba ALI3-P multibody core."""
__version__ = "0.1.0"
