"""`rtsim bench --suite fuzz`: the full property-based command fuzzing of rtsim.robustness, per vehicle:
``count`` rides drawn by hypothesis (rtsim.robustness.commands.ride_strategy, seeded: the same seed draws
the same rides) on every shipped road the vehicle runs on, each run to its end (rtsim.robustness.harness);
per vehicle the rides run, the model failures, the falls (a two-wheeler's defined end of a ride), the
largest energy ratio (at most 1 holds the bound) and the wall time. Every failing ride is written, as
drawn, to a JSON-lines file (``--failures``) from which it replays (``Ride.from_json``)."""
from __future__ import annotations

import json
import time
from pathlib import Path

from .commands import Ride, ride_strategy
from .harness import FuzzSummary, FuzzTarget, shipped_vehicles

SEGMENT_S = 1.0                  # s: the longest segment
SEGMENTS = 5                     # so a ride lasts at most 5 s


def fuzz_vehicle(target: FuzzTarget, count: int, seed: int = 0, failures=None, progress=None,
                 segment_s: float = SEGMENT_S, segments: int = SEGMENTS) -> FuzzSummary:
    """``count`` drawn rides of ``target``; each failure also as one JSON line to the open file ``failures``."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as hseed

    summary = FuzzSummary(target.name)
    strategy = ride_strategy(target.space, target.roads, target.top_speed, segment_s, segments,
                             rider_optional=target.rig.rider_optional, eps_optional=target.eps)
    t0 = time.perf_counter()

    @hseed(seed)
    @settings(max_examples=count, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def draw(ride: Ride) -> None:
        res = target.ride(ride)
        summary.add(ride, res)
        if res.failed and failures is not None:
            failures.write(json.dumps({"vehicle": target.name, "ride": ride.to_json(), "error": res.failure,
                                       "type": res.error_type, "t": res.t}) + "\n")
            failures.flush()
        if progress is not None:
            progress(summary)

    draw()
    summary.wall_s = time.perf_counter() - t0
    return summary


def format_summary(s: FuzzSummary, target: FuzzTarget | None = None) -> str:
    line = (f"{s.vehicle:<20} {s.rides:6d} rides  {s.failures:4d} failures  {s.falls:5d} falls  "
            f"max energy ratio {s.max_energy_ratio:6.3f}  {s.wall_s:8.1f} s wall")
    if target is not None and target.skipped_roads:
        line += "  (not run on: " + ", ".join(f"{k}: {v}" for k, v in target.skipped_roads.items()) + ")"
    return line


def run_fuzz_bench(vehicles: list[Path] | None, count: int, seed: int = 0, failures: Path | None = None,
                   out=print) -> list[dict]:
    """The suite (module docstring) for ``vehicles`` (None: every shipped vehicle); prints one line per
    vehicle as it finishes and returns the summaries as dictionaries."""
    paths = vehicles or shipped_vehicles()
    fh = open(failures, "a") if failures is not None else None
    results = []
    try:
        for p in paths:
            t0 = time.perf_counter()
            target = FuzzTarget(p)
            built = time.perf_counter() - t0
            s = fuzz_vehicle(target, count, seed, fh)
            out(format_summary(s, target) + f"  (built in {built:.1f} s)")
            for ride, res in s.failed[:5]:
                out(f"    {res.error_type}: {res.failure}\n      ride: {ride.dumps()}")
            results.append({"vehicle": s.vehicle, "rides": s.rides, "failures": s.failures, "falls": s.falls,
                            "max_energy_ratio": s.max_energy_ratio, "wall_s": s.wall_s,
                            "roads": list(target.roads), "skipped_roads": target.skipped_roads,
                            "top_speed_m_s": target.top_speed})
    finally:
        if fh is not None:
            fh.close()
    return results
