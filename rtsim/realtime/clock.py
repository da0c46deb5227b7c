"""Clocks for the pacer: the real monotonic clock and a deterministic fake clock for tests.

A clock offers, in seconds as float:

``now()``              the current time;
``sleep(dt)``          block for about ``dt`` (may overshoot, never returns early on purpose);
``spin_until(t)``      busy-wait until ``now() >= t`` (the precise last part of a wait);
``thread_time()``      CPU time consumed by the calling thread (for the step's own CPU cost).
"""
from __future__ import annotations

import time
from bisect import insort


class MonotonicClock:
    """The machine's monotonic clock (``time.monotonic_ns``), thread CPU time from ``time.thread_time_ns``."""

    __slots__ = ()

    def now(self) -> float:
        return time.monotonic_ns() * 1e-9

    def sleep(self, dt: float) -> None:
        if dt > 0.0:
            time.sleep(dt)

    def spin_until(self, t: float) -> None:
        deadline_ns = int(t * 1e9)
        mono = time.monotonic_ns
        while mono() < deadline_ns:
            pass

    def thread_time(self) -> float:
        return time.thread_time_ns() * 1e-9


class FakeClock:
    """A deterministic clock: time moves only when asked to.

    - ``sleep(dt)`` advances time by exactly ``dt`` and records ``dt`` in ``sleeps``;
    - ``spin_until(t)`` sets time to exactly ``t`` (if ahead) and records the spun span in ``spins``;
    - ``advance(dt, cpu=None)`` lets a fake step "work": time moves by ``dt`` and the fake thread CPU
      time by ``cpu`` (default ``dt``); ``thread_time()`` returns that fake CPU time;
    - stalls: ``stalls=[(at, delay), ...]`` (or ``add_stall``) — whenever time would reach or pass the
      wall time ``at``, an extra ``delay`` is added (as the hypervisor stealing the CPU would), and
      ``(at, delay)`` is appended to ``stalled``. Stalls hit only on sleep/spin/advance, not on ``now()``.
    """

    def __init__(self, start: float = 0.0, stalls=()):
        self._t = float(start)
        self._cpu = 0.0
        self._stalls: list[tuple[float, float]] = []
        for at, delay in stalls:
            self.add_stall(at, delay)
        self.sleeps: list[float] = []
        self.spins: list[float] = []
        self.stalled: list[tuple[float, float]] = []

    def add_stall(self, at: float, delay: float) -> None:
        if delay < 0:
            raise ValueError(f"FakeClock.add_stall: delay must be >= 0, got {delay}")
        insort(self._stalls, (float(at), float(delay)))

    def _move_to(self, target: float) -> None:
        while self._stalls and self._stalls[0][0] <= target:
            at, delay = self._stalls.pop(0)
            self.stalled.append((at, delay))
            target += delay
        if target > self._t:
            self._t = target

    def now(self) -> float:
        return self._t

    def sleep(self, dt: float) -> None:
        if dt > 0.0:
            self.sleeps.append(dt)
            self._move_to(self._t + dt)

    def spin_until(self, t: float) -> None:
        if t > self._t:
            self.spins.append(t - self._t)
            self._cpu += t - self._t
            self._move_to(t)

    def advance(self, dt: float, cpu: float | None = None) -> None:
        if dt < 0:
            raise ValueError(f"FakeClock.advance: dt must be >= 0, got {dt}")
        self._cpu += dt if cpu is None else cpu
        self._move_to(self._t + dt)

    def thread_time(self) -> float:
        return self._cpu
