"""`rtsim bench --suite dispatch`: what one call from Python into a compiled kernel costs when the kernel
takes the vehicle's model and state (8 named tuples, 109 arrays: everything the service's step
passes), called directly (numba unboxes every array at every call) and through rtsim.boundcall (one
address table); for a no-op kernel and for one vehicle step of a parked car."""
from __future__ import annotations

import time

import numpy as np

from rtsim.boundcall import bind
from rtsim.jit import kernel


@kernel
def noop(m, d, veh, vd, road, parts, states, io, h, n):
    """Takes what vehicle_advance takes, does nothing."""
    return n


@kernel
def noop_free(h, n):
    """The free arguments alone: the floor of any call."""
    return n


def _count(x, kind) -> int:
    return sum(_count(v, kind) for v in x) if isinstance(x, tuple) else int(isinstance(x, kind))


def dispatch_costs(reps: int = 20000, repeats: int = 7) -> dict:
    """Microseconds per call (median and best of ``repeats`` interleaved rounds of ``reps`` calls, the
    vehicle steps ``reps // 4``), with the times to bind and to load (or compile) the wrappers."""
    from rtsim.service.config import DEFAULT_SCENARIO
    from rtsim.service.server import build_sim
    from rtsim.vehicle.car.step import vehicle_advance

    sim, _ = build_sim(DEFAULT_SCENARIO)                 # at rest, held by the brake
    fixed = (sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states, sim.io)
    h = sim.dt
    noop_free(h, 1), noop(*fixed, h, 1), vehicle_advance(*fixed, h, 1)      # compile / load
    t0 = time.perf_counter()
    b_noop, b_step = bind(noop, *fixed, n_free=2), bind(vehicle_advance, *fixed, n_free=2)
    t1 = time.perf_counter()
    b_noop.compile(h, 1), b_step.compile(h, 1)
    t2 = time.perf_counter()
    cases = {
        "free arguments alone (h, n)": (lambda: noop_free(h, 1), reps),
        "no-op, direct": (lambda: noop(*fixed, h, 1), reps),
        "no-op, bound": (lambda: b_noop(h, 1), reps),
        "vehicle_advance n=1, direct": (lambda: vehicle_advance(*fixed, h, 1), reps // 4),
        "vehicle_advance n=1, bound": (lambda: b_step(h, 1), reps // 4),
    }
    rounds: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(repeats):
        for name, (fn, n) in cases.items():
            t = time.perf_counter()
            for _ in range(n):
                fn()
            rounds[name].append((time.perf_counter() - t) / n * 1e6)
    return {
        "fixed_tuples": len(fixed), "fixed_arrays": _count(fixed, np.ndarray),
        "fixed_scalars": _count(fixed, (int, float, np.number)),
        "bind_s": t1 - t0, "wrappers_ready_s": t2 - t1,
        "wrapper_cache_hits": sum(sum(b.wrapper.stats.cache_hits.values()) for b in (b_noop, b_step)),
        "us_per_call": {k: {"median": float(np.median(v)), "best": float(min(v))} for k, v in rounds.items()},
    }


def format_report(res: dict) -> str:
    lines = [f"{res['fixed_tuples']} fixed named tuples, {res['fixed_arrays']} arrays, {res['fixed_scalars']} "
             f"scalars; both bound in "
             f"{1e3 * res['bind_s']:.0f} ms, wrappers ready in {res['wrappers_ready_s']:.2f} s "
             f"({res['wrapper_cache_hits']} of 2 from the cache)",
             f"{'us per call':<32} {'median':>8} {'best':>8}"]
    for k, v in res["us_per_call"].items():
        lines.append(f"{k:<32} {v['median']:8.2f} {v['best']:8.2f}")
    return "\n".join(lines)
