"""A batch run's start on the road is assembled from the constraint Jacobian in dense form
(rtsim.mbs.simulation.dense_jacobian: each cell the sum of its slots' coefficients, slot by slot) and
the mask of the velocity rows (``Simulation.velocity_rows``). Both are computed the fast way; these
tests hold them to the plain definitions, bit for bit, on the shipped vehicles away from their design
pose: the Jacobian against an unbuffered slot-by-slot accumulation (np.add.at), the mask against
np.isin of the model's constraint kinds, and a start assembled afresh against one copied from the
process's kept starts."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.mbs import Simulation
from rtsim.mbs import simulation as msim
from rtsim.mbs.constraints import eval_constraints, eval_drivers
from rtsim.mbs.model import NSLOT, VELOCITY_KINDS
from rtsim.vehicle.registry import open_vehicle

ROOT = Path(__file__).resolve().parents[1]


def _reference_jacobian(m, d) -> np.ndarray:
    """The definition: every slot's coefficient added into its (row, column) cell, unbuffered, slot by slot."""
    jac = np.zeros((m.nc, m.nq))
    for s in range(NSLOT):
        cols = m.con_idx[:, s]
        ok = cols >= 0
        np.add.at(jac, (np.nonzero(ok)[0], cols[ok]), d.jac[ok, s])
    return jac


@pytest.fixture(scope="module", params=["xbw.toml", "eps_car.toml", "motorcycle.toml"])
def mech(request):
    opened = open_vehicle(ROOT / "configs" / "vehicles" / request.param)
    return opened.model.mech


def _perturbed(mech, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return mech.q0 + 1e-3 * rng.standard_normal(mech.q0.shape)


def test_the_dense_jacobian_is_the_slot_sum_bit_for_bit(mech):
    sim = Simulation(mech, 1e-3)
    m, d = sim.model, sim.data
    for seed in range(3):
        q = _perturbed(mech, seed)
        eval_drivers(m, d, d.t[0])
        eval_constraints(m, d, q)
        want = _reference_jacobian(m, d)
        got = msim.dense_jacobian(m, d)
        assert got.shape == want.shape and got.dtype == want.dtype
        assert got.tobytes() == want.tobytes()
        assert np.count_nonzero(want) > 0


def test_the_velocity_rows_are_the_models_velocity_constraints(mech):
    sim = Simulation(mech, 1e-3)
    rows = sim.velocity_rows
    assert rows.tobytes() == np.isin(sim.model.con_kind, VELOCITY_KINDS).tobytes()
    assert rows is sim.velocity_rows
    with pytest.raises(ValueError):
        rows[0] = not rows[0]


def test_a_kept_start_is_a_fresh_assembly_bit_for_bit(mech):
    q0 = _perturbed(mech, 7)
    msim._STARTS.clear()
    fresh = Simulation(mech, 1e-3, q0=q0)
    kept = Simulation(mech, 1e-3, q0=q0)          # copied from the process's kept starts
    msim._STARTS.clear()
    again = Simulation(mech, 1e-3, q0=q0)         # assembled again
    for a, b, c in zip(fresh.data, kept.data, again.data):
        assert a.tobytes() == b.tobytes() == c.tobytes()
    assert fresh.position_correction == kept.position_correction == again.position_correction > 0.0
