"""Loop health: per-step lateness and step CPU time in preallocated ring buffers, plus counters.

``record()`` writes two floats into preallocated numpy arrays and updates a few integer counters;
it allocates nothing of its own per step. Percentiles (p50, p99) are taken over the samples still in
the window (the last ``window`` steps, ``numpy.percentile`` with its default linear interpolation);
the maxima cover every step recorded since the last ``reset()``.

Steal time (CPU time the hypervisor took away from this VM) is read from ``/proc/stat`` (field
``steal`` of the aggregate ``cpu`` line, in clock ticks, converted with ``os.sysconf('SC_CLK_TCK')``)
at ``begin()`` and ``end()``; it is machine-wide (all CPUs summed), not per process. Where it cannot
be read, ``steal_s`` is ``None``.
"""
from __future__ import annotations

import os

import numpy as np

PROC_STAT = "/proc/stat"


def parse_proc_stat_steal(text: str) -> int | None:
    """Steal ticks of the aggregate ``cpu`` line of a /proc/stat text, or None if absent.

    Fields after ``cpu``: user nice system idle iowait irq softirq steal guest guest_nice.
    """
    for line in text.splitlines():
        fields = line.split()
        if fields and fields[0] == "cpu":
            if len(fields) < 9:
                return None
            try:
                return int(fields[8])
            except ValueError:
                return None
    return None


def _clk_tck() -> int | None:
    try:
        tck = os.sysconf("SC_CLK_TCK")
    except (ValueError, OSError, AttributeError):
        return None
    return tck if tck and tck > 0 else None


def read_steal_seconds(path: str = PROC_STAT) -> float | None:
    """Machine-wide steal time so far in seconds, or None where /proc/stat is unavailable."""
    try:
        with open(path, encoding="ascii") as f:
            text = f.read()
    except OSError:
        return None
    ticks = parse_proc_stat_steal(text)
    tck = _clk_tck()
    if ticks is None or tck is None:
        return None
    return ticks / tck


class LoopHealth:
    """Statistics of a paced loop. ``period`` (s) is the overrun threshold; the pacer sets it."""

    def __init__(self, window: int = 65536, period: float | None = None, steal_source=read_steal_seconds):
        if window < 1:
            raise ValueError(f"LoopHealth: window must be >= 1, got {window}")
        self.window = int(window)
        self.period = period
        self._steal_source = steal_source
        self._lateness = np.zeros(self.window, dtype=np.float64)
        self._cpu = np.zeros(self.window, dtype=np.float64)
        self.reset()

    def reset(self) -> None:
        self._lateness.fill(0.0)
        self._cpu.fill(0.0)
        self._next = 0          # ring write index
        self._filled = 0        # samples held (<= window)
        self.samples = 0        # steps recorded with lateness/CPU samples
        self.steps = 0          # all steps run (including lockstep steps, which carry no samples)
        self.overruns = 0
        self.catch_up_steps = 0
        self.skipped_steps = 0
        self.stalls = 0
        self.max_lateness = 0.0
        self.max_cpu = 0.0
        self._steal0: float | None = None
        self._steal1: float | None = None

    # -- recording (hot path) -------------------------------------------------------------------
    def record(self, lateness: float, cpu: float, catch_up: bool = False) -> None:
        i = self._next
        self._lateness[i] = lateness
        self._cpu[i] = cpu
        i += 1
        self._next = 0 if i == self.window else i
        if self._filled < self.window:
            self._filled += 1
        self.samples += 1
        self.steps += 1
        if catch_up:
            self.catch_up_steps += 1
        if lateness > self.max_lateness:
            self.max_lateness = lateness
        if cpu > self.max_cpu:
            self.max_cpu = cpu
        p = self.period
        if p is not None and (lateness > p or cpu > p):
            self.overruns += 1

    def count_steps(self, n: int) -> None:
        """Steps run without a schedule (lockstep): counted, no samples."""
        self.steps += n

    def note_stall(self) -> None:
        self.stalls += 1

    def note_skipped(self, n: int) -> None:
        self.skipped_steps += n

    # -- steal time -----------------------------------------------------------------------------
    def begin(self) -> None:
        """Snapshot the machine's steal time at the start of a run."""
        self._steal0 = self._steal_source()
        self._steal1 = None

    def end(self) -> None:
        """Snapshot the machine's steal time at the end of a run."""
        self._steal1 = self._steal_source()

    def steal_seconds(self) -> float | None:
        if self._steal0 is None:
            return None
        s1 = self._steal1 if self._steal1 is not None else self._steal_source()
        if s1 is None:
            return None
        return s1 - self._steal0

    # -- reading --------------------------------------------------------------------------------
    def lateness_samples(self) -> np.ndarray:
        """The windowed lateness samples, oldest first (a copy)."""
        return self._ordered(self._lateness)

    def cpu_samples(self) -> np.ndarray:
        """The windowed step CPU times, oldest first (a copy)."""
        return self._ordered(self._cpu)

    def _ordered(self, buf: np.ndarray) -> np.ndarray:
        if self._filled < self.window:
            return buf[: self._filled].copy()
        return np.concatenate((buf[self._next:], buf[: self._next]))

    def recent_percentiles(self, n: int = 2000) -> dict:
        """p50/p99 of lateness and CPU (s) over the last ``n`` samples (None before any): cheap enough
        for a live status at 10 Hz (the full-window ``summary`` sorts up to ``window`` samples)."""
        m = min(n, self._filled)
        if m == 0:
            return {"lateness_p50": None, "lateness_p99": None, "cpu_p50": None, "cpu_p99": None}
        idx = (self._next - 1 - np.arange(m)) % self.window
        lat50, lat99 = np.percentile(self._lateness[idx], [50.0, 99.0])
        cpu50, cpu99 = np.percentile(self._cpu[idx], [50.0, 99.0])
        return {"lateness_p50": float(lat50), "lateness_p99": float(lat99),
                "cpu_p50": float(cpu50), "cpu_p99": float(cpu99)}

    def summary(self) -> dict:
        """Percentiles over the window, maxima over the whole run, counters and steal time (s)."""
        n = self._filled
        if n:
            lat = self._lateness[:n]
            cpu = self._cpu[:n]
            lat50, lat99 = (float(v) for v in np.percentile(lat, [50.0, 99.0]))
            cpu50, cpu99 = (float(v) for v in np.percentile(cpu, [50.0, 99.0]))
            lat_max, cpu_max = float(self.max_lateness), float(self.max_cpu)
        else:
            lat50 = lat99 = cpu50 = cpu99 = lat_max = cpu_max = None
        return {
            "period_s": self.period,
            "window": self.window,
            "samples_in_window": n,
            "lateness_p50_s": lat50,
            "lateness_p99_s": lat99,
            "lateness_max_s": lat_max,
            "step_cpu_p50_s": cpu50,
            "step_cpu_p99_s": cpu99,
            "step_cpu_max_s": cpu_max,
            "steps": self.steps,
            "overruns": self.overruns,
            "catch_up_steps": self.catch_up_steps,
            "skipped_steps": self.skipped_steps,
            "stalls": self.stalls,
            "steal_s": self.steal_seconds(),
        }
