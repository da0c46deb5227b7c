"""Run benchmark problems and measure them: accuracy figures, constraint violations, energy drift,
and the cost per step of the compiled ALI3-P loop (after compilation, excluding set-up)."""
from __future__ import annotations

import time

import numpy as np

from rtsim.mbs import Simulation
from rtsim.mbs.model import ST_FACTORIZATIONS, ST_ITER_TOTAL, ST_MAX_PHI, ST_MAX_PHID

from .problems import PROBLEMS, fourbar


def run_problem(name: str, dt: float | None = None, t_end: float | None = None) -> dict:
    """One problem to t_end: the JSON object of `rtsim bench`."""
    pr = PROBLEMS[name]
    dt = pr.dt if dt is None else dt
    t_end = pr.t_end if t_end is None else t_end
    mech = pr.build()
    Simulation(mech, dt).run(steps=2, record=False)          # load/compile the kernels untimed
    sim = Simulation(mech, dt)
    steps = int(round(t_end / dt))
    t0 = time.perf_counter()
    traj = sim.run(steps=steps, stride=1 if mech.conservative else steps)
    wall = time.perf_counter() - t0
    st = sim.data.stats
    drift = None
    if mech.conservative:
        e = sim.energy(traj)
        drift = float(np.max(np.abs(e - e[0])))
    return {
        "problem": name,
        "dt": dt,
        "t_end": steps * dt,
        "steps": steps,
        "wall_s": wall,
        "us_per_step": wall / max(steps, 1) * 1e6,
        "max_position_constraint_violation": float(st[ST_MAX_PHI]),
        "max_velocity_constraint_violation": float(st[ST_MAX_PHID]),
        "energy_drift": drift,
        "newton_iterations_per_step": float(st[ST_ITER_TOTAL]) / max(steps, 1),
        "factorizations_per_step": float(st[ST_FACTORIZATIONS]) / max(steps, 1),
        "n_coordinates": mech.model.nq,
        "n_constraints": mech.model.nc,
        "final": pr.compared(mech, sim.data.q),
    }


def scaling(sizes=(1, 2, 10, 40, 100), dt: float = 1e-3, steps: int = 2000) -> list[dict]:
    """Cost per step of the N-four-bar for several N (from rest at its initial state), so that the
    growth of the step cost with model size is known."""
    out = []
    for n in sizes:
        mech = fourbar(n)
        Simulation(mech, dt).run(steps=2, record=False)
        sim = Simulation(mech, dt)
        t0 = time.perf_counter()
        sim.run(steps=steps, record=False)
        wall = time.perf_counter() - t0
        out.append({"N": n, "n_coordinates": mech.model.nq, "n_constraints": mech.model.nc,
                    "envelope_size": int(mech.model.m_env.shape[0]), "steps": steps,
                    "us_per_step": wall / steps * 1e6})
    return out


def startup_seconds() -> float:
    """Seconds to have the kernels ready in this process (compile on a cold cache, load on a warm one)."""
    t0 = time.perf_counter()
    Simulation(PROBLEMS["pendulum"].build(), 1e-3).run(steps=2, record=False)
    return time.perf_counter() - t0
