"""Fixed-step pacer: runs a model's ``step(n)`` callable at a fixed period against a clock.

Modes
-----
``realtime``  Step ``k`` of a run is scheduled at ``t0 + k*period`` (``t0`` = clock time when
              ``run()`` starts; the schedule is recomputed from ``t0`` and ``k`` every step, so sleep
              overshoot never accumulates into drift). Before each step the pacer sleeps
              (``clock.sleep``) until ``spin`` seconds before the boundary, then busy-spins
              (``clock.spin_until``) to the boundary. If a step starts late by less than one period
              it simply runs late; the next one is still aimed at its own boundary.
``fast``      No waiting at all: steps run back to back (offline runs). Lateness is recorded as 0.
``lockstep``  No clock: ``advance(n)`` runs exactly ``n`` steps (one ``step(n)`` call) when the
              client asks; ``run()`` is not available.

Stall policy (realtime mode)
----------------------------
The hypervisor on these machines takes the CPU away for 10-30 ms at a time. When a step starts at
least one whole period behind its boundary (lateness ``L >= period``), the boundaries
``m = floor(L / period)`` after it have been missed too. That is a *stall* (counted once per
episode: an episode ends at the first step that starts less than one period late). Then:

1. the late step runs (its full lateness ``L`` is recorded);
2. **catch-up**: up to ``max_catch_up`` of the missed steps (per episode) run back to back, each as
   its own ``step(1)`` call with its own lateness/CPU sample, counted as catch-up steps;
3. **skip**: the remaining ``m - catch_up`` missed steps are not run. They are counted as skipped
   steps and the schedule is re-aligned (``t0`` moves forward by ``skipped * period``), so the next
   step is aimed at the next wall-clock boundary. From then on simulated time lags wall time by
   exactly the skipped amount (``Pacer.lag`` = ``skipped_steps * period``), and keeps no drift.

With ``max_catch_up=0`` every stall is skipped; a very large ``max_catch_up`` never skips (sim time
never lags, but the model runs faster than real time for a while after a stall). If catching up takes
so long that further boundaries pass, they join the same episode and share its catch-up budget.

Stopping
--------
``stop()`` (thread-safe) makes ``run()`` return before its next step; since a wait never exceeds one
period, ``run()`` ends within one period plus the duration of the step in progress. ``run()`` clears
the stop flag when it starts, unless the pacer was given the owner's ``stop_event``: then a stop that
came before ``run()`` still counts, and only the owner clears it. When ``run()`` ends on ``duration``/``until``/``steps`` in realtime mode
it first waits for the boundary after its last step, so ``run(steps=k)`` occupies exactly ``k``
periods and successive runs join up without a gap.

Per step, ``run()`` records the lateness (actual start - scheduled start, s) and the step's CPU time
(``clock.thread_time()`` around the call) into a :class:`~rtsim.realtime.health.LoopHealth`, whose
buffers are preallocated; the loop itself builds no per-step objects beyond Python's own floats.
"""
from __future__ import annotations

import math
import threading
from typing import Callable

from rtsim.realtime.clock import MonotonicClock
from rtsim.realtime.health import LoopHealth

MODES = ("realtime", "fast", "lockstep")

# Tolerance (in periods) for float round-off when counting missed boundaries / comparing times.
_EPS = 1e-9


class Pacer:
    """Pace ``step(n)`` (advances the model by ``n`` steps, returns nothing) at a fixed ``period`` (s)."""

    def __init__(
        self,
        step: Callable[[int], None],
        period: float = 1e-3,
        mode: str = "realtime",
        clock=None,
        spin: float = 0.0002,
        max_catch_up: int = 20,
        health: LoopHealth | None = None,
        stop_event: threading.Event | None = None,
    ):
        if mode not in MODES:
            raise ValueError(f"Pacer: mode must be one of {MODES}, got {mode!r}")
        if not period > 0:
            raise ValueError(f"Pacer: period must be > 0, got {period}")
        if spin < 0:
            raise ValueError(f"Pacer: spin must be >= 0, got {spin}")
        if max_catch_up < 0:
            raise ValueError(f"Pacer: max_catch_up must be >= 0, got {max_catch_up}")
        self.step = step
        self.period = float(period)
        self.mode = mode
        self.clock = clock if clock is not None else MonotonicClock()
        self.spin = float(spin)
        self.max_catch_up = int(max_catch_up)
        self.health = health if health is not None else LoopHealth(period=self.period)
        if self.health.period is None:
            self.health.period = self.period
        self.steps = 0                      # steps run in total (all runs and advances)
        # an owner's stop_event is the owner's to clear: a stop() before run() then still stops it
        self._own_stop = stop_event is None
        self._stop = threading.Event() if stop_event is None else stop_event
        self._running = threading.Event()

    # -- state --------------------------------------------------------------------------------
    @property
    def sim_time(self) -> float:
        """Simulated time (s): steps run times the period."""
        return self.steps * self.period

    @property
    def lag(self) -> float:
        """How far simulated time lags the wall-clock schedule because of skipped steps (s)."""
        return self.health.skipped_steps * self.period

    @property
    def running(self) -> bool:
        return self._running.is_set()

    def stop(self) -> None:
        """Ask a running ``run()`` to return (thread-safe; effective within one period)."""
        self._stop.set()

    # -- lockstep -----------------------------------------------------------------------------
    def advance(self, n: int = 1) -> None:
        """Lockstep mode: run exactly ``n`` steps now (a single ``step(n)`` call)."""
        if self.mode != "lockstep":
            raise RuntimeError(f"Pacer.advance is for lockstep mode; this pacer is in {self.mode!r} mode")
        n = int(n)
        if n < 0:
            raise ValueError(f"Pacer.advance: n must be >= 0, got {n}")
        if n == 0:
            return
        self.step(n)
        self.steps += n
        self.health.count_steps(n)

    # -- paced loop ---------------------------------------------------------------------------
    def run(self, duration: float | None = None, until: float | None = None, steps: int | None = None) -> int:
        """Run until ``stop()``, or until a limit is reached; returns the number of steps run.

        ``duration``: wall-clock seconds on the pacer's clock — no step is started whose scheduled
        start is at or after ``start + duration`` (in fast mode: no step starts after that time).
        ``until``: simulated time — stop once ``sim_time >= until``. ``steps``: at most this many
        steps in this call. With none given, only ``stop()`` ends the loop.
        """
        if self.mode == "lockstep":
            raise RuntimeError("Pacer.run is not available in lockstep mode; use advance(n)")
        if self._own_stop:
            self._stop.clear()
        self._running.set()
        self.health.begin()
        try:
            if self.mode == "fast":
                return self._run_fast(duration, until, steps)
            return self._run_realtime(duration, until, steps)
        finally:
            self.health.end()
            self._running.clear()

    def _limit_steps(self, until, steps) -> int:
        """Number of steps this run may take at most (-1: unlimited)."""
        limit = -1
        if steps is not None:
            limit = max(int(steps), 0)
        if until is not None:
            n = max(math.ceil(until / self.period - _EPS) - self.steps, 0)
            limit = n if limit < 0 else min(limit, n)
        return limit

    def _run_fast(self, duration, until, steps) -> int:
        clock, health, step, stop = self.clock, self.health, self.step, self._stop
        limit = self._limit_steps(until, steps)
        end = clock.now() + duration if duration is not None else math.inf
        done = 0
        while done != limit and not stop.is_set():
            if clock.now() >= end:
                break
            c0 = clock.thread_time()
            step(1)
            c1 = clock.thread_time()
            done += 1
            self.steps += 1
            health.record(0.0, c1 - c0)
        return done

    def _run_realtime(self, duration, until, steps) -> int:
        clock, health, step, stop = self.clock, self.health, self.step, self._stop
        period, spin = self.period, self.spin
        limit = self._limit_steps(until, steps)
        t0 = clock.now()
        end = t0 + duration - _EPS * period if duration is not None else math.inf
        k = 0                  # schedule index within this run (boundary t0 + k*period)
        done = 0
        pending_catch_up = 0   # catch-up steps still to run back to back
        pending_skip = 0       # steps to skip (schedule shift) once the late step has run
        in_stall = False       # inside a stall episode
        episode_budget = 0     # catch-up steps left in this episode
        hit_limit = False
        while not stop.is_set():
            if done == limit:
                hit_limit = True
                break
            target = t0 + k * period
            if target >= end:
                hit_limit = True
                break
            catch_up = pending_catch_up > 0
            if catch_up:
                pending_catch_up -= 1
                now = clock.now()
            else:
                now = clock.now()
                if now < target:
                    gap = target - now
                    if gap > spin:
                        clock.sleep(gap - spin)
                    clock.spin_until(target)
                    if stop.is_set():
                        break
                    now = clock.now()
                late = now - target
                missed = int(late / period + _EPS)
                if missed >= 1:
                    if not in_stall:
                        in_stall = True
                        episode_budget = self.max_catch_up
                        health.note_stall()
                    n_catch = missed if missed < episode_budget else episode_budget
                    episode_budget -= n_catch
                    pending_catch_up = n_catch
                    pending_skip = missed - n_catch
                else:
                    in_stall = False
            late = now - target
            c0 = clock.thread_time()
            step(1)
            c1 = clock.thread_time()
            health.record(late, c1 - c0, catch_up)
            done += 1
            self.steps += 1
            k += 1
            if pending_skip:
                health.note_skipped(pending_skip)
                t0 += pending_skip * period
                pending_skip = 0
        if hit_limit and not stop.is_set():
            # Occupy the whole last period so that successive runs join up without a gap.
            target = t0 + k * period
            now = clock.now()
            if now < target:
                gap = target - now
                if gap > spin:
                    clock.sleep(gap - spin)
                clock.spin_until(target)
        return done
