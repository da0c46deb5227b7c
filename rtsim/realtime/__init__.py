"""Pacing layer of the fixed-step real-time loop: clocks, the pacer and loop-health statistics.

The model step itself lives elsewhere; the pacer only calls a ``step(n)`` callable. See
:mod:`rtsim.realtime.pacer` for the timing and stall policy.
"""
from __future__ import annotations

from rtsim.realtime.clock import FakeClock, MonotonicClock
from rtsim.realtime.health import LoopHealth, parse_proc_stat_steal, read_steal_seconds
from rtsim.realtime.pacer import MODES, Pacer

__all__ = [
    "FakeClock",
    "LoopHealth",
    "MODES",
    "MonotonicClock",
    "Pacer",
    "parse_proc_stat_steal",
    "read_steal_seconds",
]
