"""The extrapolating Newton predictor (Settings.extrapolate) and the absolute increment tolerance
(Settings.absolute_tol_dq) on the motorcycle: Newton starts closer and needs fewer iterations, and the
steps it accepts are the trapezoidal solution the Taylor predictor converges to; a state set from
outside falls back to the Taylor predictor."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.mbs.model import FS_TOL_DQ, IS_PREDICTOR, ST_ITER_TOTAL, ST_STEPS
from rtsim.vehicle.motorcycle.build import build_motorcycle
from rtsim.vehicle.motorcycle.config import load_motorcycle
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim, static_pose
from rtsim.vehicle.motorcycle.step import U_STEER_TORQUE

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bike():
    cfg, base = load_motorcycle(ROOT / "configs" / "vehicles" / "motorcycle.toml")
    mm = build_motorcycle(cfg, base)
    return mm, static_pose(mm)[0]


def _run(mm, q, steps, predictor, tol_dq=None):
    """The benchmark's manoeuvre (20 m/s, 2 N m on the bars): the final state and Newton iterations a step."""
    sim = TwoWheelerSim(mm, speed=20.0, q=q)
    m = sim.model
    saved = m.iset[IS_PREDICTOR], m.fset[FS_TOL_DQ]
    try:
        m.iset[IS_PREDICTOR] = predictor
        if tol_dq is not None:
            m.fset[FS_TOL_DQ] = tol_dq
        sim.parts.u[U_STEER_TORQUE] = 2.0
        sim.run(0.05)
        it0 = sim.data.stats[ST_ITER_TOTAL]
        n0 = sim.data.stats[ST_STEPS]
        sim.run(steps * sim.dt)
        iters = (sim.data.stats[ST_ITER_TOTAL] - it0) / (sim.data.stats[ST_STEPS] - n0)
        return sim.data.q.copy(), sim.data.qd.copy(), iters, sim
    finally:
        m.iset[IS_PREDICTOR], m.fset[FS_TOL_DQ] = saved


def test_extrapolated_start_converges_to_the_same_steps_in_fewer_iterations(bike):
    mm, q = bike
    q_ext, qd_ext, it_ext, _ = _run(mm, q, 300, 1)
    q_tay, qd_tay, it_tay, _ = _run(mm, q, 300, 0)
    q_ref, qd_ref, _, _ = _run(mm, q, 300, 0, tol_dq=1e-13)     # Newton to round-off: the trapezoidal solution
    assert it_ext < 1.1 and it_tay >= 2.5      # the first increment mostly within tolerance: one iteration
    err_ext = np.max(np.abs(q_ext - q_ref)), np.max(np.abs(qd_ext - qd_ref))
    err_tay = np.max(np.abs(q_tay - q_ref)), np.max(np.abs(qd_tay - qd_ref))
    # after 0.35 s, with the same stopping test: the extrapolated start ends closer to the solution
    assert err_ext[0] < 2e-8 and err_ext[1] < 1e-6
    assert err_ext[0] < err_tay[0] and err_ext[1] < err_tay[1]


def test_a_state_set_from_outside_falls_back_to_the_taylor_start(bike):
    """Changing the accelerations between steps (as a restored snapshot or an assembly would) must not
    extrapolate from a history that no longer belongs to the state: the step falls back and converges."""
    mm, q = bike
    _, _, _, sim = _run(mm, q, 20, 1)
    m = sim.model
    m.iset[IS_PREDICTOR] = 1
    try:
        sim.data.qdd[:] = 0.0
        sim.data.pred[:] = 1e3          # a history that would throw the extrapolated start far off
        sim.step()                      # raises if Newton fails
        assert sim.data.stats[3] < 10   # the step's iterations: a Taylor start from qdd = 0
        assert np.all(np.isfinite(sim.data.q)) and np.all(sim.data.pred[m.nq:2 * m.nq] == sim.data.qdd)
    finally:
        m.iset[IS_PREDICTOR] = 1
