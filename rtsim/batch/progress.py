"""The batch's progress line and its ETA. The ETA is built from completed runs' own wall times (each
measured inside its worker from the run's start to its row: worker start-up, imports and the kernels'
warm-up or compilation are not in it), not from the time since the batch started."""
from __future__ import annotations

import math


def eta_seconds(done: list[tuple[str, float]], remaining: int, workers: int, skip_first: bool = False) -> float | None:
    """Seconds until `remaining` runs are done by `workers` parallel workers: the mean wall time of the
    completed runs in `done` ((worker, run wall time in s), in completion order) times the rounds of
    `workers` runs still to go. skip_first: each worker's first run is left out (a worker that loads or
    compiles the kernels in its first run: Ray's; the local pool's workers warm up before their first
    run). None while no run counts yet; 0 when nothing remains."""
    if remaining <= 0:
        return 0.0
    first_seen: set[str] = set()
    times = []
    for worker, wall in done:
        if wall is None or not math.isfinite(wall):
            continue                         # a run lost with its worker: no time of its own
        if skip_first and worker not in first_seen:
            first_seen.add(worker)
            continue
        times.append(wall)
    if not times:
        return None
    return sum(times) / len(times) * math.ceil(remaining / max(1, workers))


def eta_text(eta: float | None) -> str:
    return "ETA -" if eta is None else f"ETA {eta:.0f} s"
