"""The motorcycle's scenario files run offline (rtsim run) and its inverse dynamics (rtsim inverse),
against references: counter-steering's sign pattern (Moreno Giner et al. 2008, figure 7); the steady
turn's lean against atan(u^2 / (g R)) with the tyres' crown correction (Cossalter ch. 2); hard braking
bounded by the front tyre's grip mu g and the stoppie limit g b / h, the rear load reaching zero there;
a stoppie ends in a fall status and a non-zero exit; the inverse solution's steady steering torque on
the circle equals the one the rider settles to."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from drivers.scenario import load_scenario
from rtsim.cli import main
from rtsim.analyses.inverse import InverseDynamics
from rtsim.vehicle.motorcycle.offline import prepare, run
from rtsim.vehicle.motorcycle.ride import tyre_lean_ratio

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "configs" / "scenarios"
G = 9.81


def _cli(tmp_path, name):
    out, summary = tmp_path / f"{name}.csv", tmp_path / f"{name}.json"
    code = main(["run", "--scenario", str(SCEN / f"{name}.toml"), "--out", str(out), "--summary", str(summary)])
    with out.open() as fh:
        rows = list(csv.reader(fh))
    data = np.array(rows[1:], dtype=float)
    assert np.all(np.isfinite(data))
    return code, json.loads(summary.read_text()), rows[0], data


def test_counter_steering_scenario(tmp_path):
    code, s, _, _ = _cli(tmp_path, "motorcycle_counter_steer")
    cs = s["counter_steering"]
    assert code == 0 and s["status"] == "ok"
    assert cs["torque_nm"] > 0 and cs["first_yaw_rate_rad_s"] > 0, "first yaws with the steer (left)"
    assert cs["final_yaw_rate_rad_s"] < -0.02 and cs["final_roll_deg"] > 3.0, "then leans and turns right"


def test_stoppie_ends_in_a_fall_with_the_rear_load_zero_at_g_b_over_h(tmp_path):
    code, s, header, data = _cli(tmp_path, "motorcycle_stoppie")
    assert code == 3 and s["status"] == "fall" and "pitched over" in s["message"]
    b = s["braking"]
    assert b["rear_load_zero_at_decel_m_s2"] == pytest.approx(b["limit_stoppie_decel_m_s2"], rel=0.02)
    assert b["rear_lifted_s"] > 0.1
    # before the rear lifts the deceleration stays below the stoppie limit
    fz_r = data[:, header.index("tyre_fz_rear")]
    t, v = data[:, 0], data[:, header.index("speed")]
    lift = int(np.argmax(fz_r <= 0.0))
    decel = -np.diff(v[:lift]) / np.diff(t[:lift])
    assert decel.max() < 1.03 * b["limit_stoppie_decel_m_s2"]


def test_hard_braking_within_the_limits(tmp_path):
    code, s, _, _ = _cli(tmp_path, "motorcycle_hard_braking")
    b = s["braking"]
    assert code == 0 and b["stopped"]
    a_lim = min(b["limit_stoppie_decel_m_s2"], b["limit_front_grip_decel_m_s2"])
    assert 0.8 * a_lim < b["steady_decel_m_s2"] < a_lim
    assert b["peak_decel_m_s2"] < 1.03 * a_lim
    assert b["stopping_distance_m"] > b["speed_at_onset_m_s"] ** 2 / (2 * a_lim)
    fz_f, fz_r = b["static_loads_n"]
    assert 0.0 <= b["rear_load_min_n"] < 0.15 * fz_r, "the rear tyre unloads towards the lift limit"
    assert b["front_load_max_n"] > fz_f + 0.8 * fz_r, "the load moves to the front"
    # the quasi-static balance m (g b - a h) / L at the measured deceleration
    assert b["rear_load_steady_n"] == pytest.approx(b["rear_load_quasi_static_n"], abs=0.05 * (fz_f + fz_r))
    assert b["fork_dive_m"] > 0.05


@pytest.fixture(scope="module")
def steady_turn():
    ride, sc = prepare(None, load_scenario(SCEN / "motorcycle_steady_turn.toml", check_files=True))
    res = run(ride, sc)
    assert res.status == "ok"
    return ride, sc, res


def test_steady_turn_leans_to_the_crown_corrected_equilibrium(steady_turn):
    _ride, _sc, res = steady_turn
    st = res.summary["steady_turn"]
    phi0 = math.degrees(math.atan(st["speed_m_s"] ** 2 / (G * st["radius_m"])))
    assert st["atan_u2_over_gR_deg"] == pytest.approx(phi0, abs=1e-3)
    assert st["roll_over_reference"] == pytest.approx(1.0, abs=0.05)
    assert st["roll_deg"] > phi0 + 2.0, "past atan(u^2 / g R): the crown moves the contact inward"
    assert abs(st["lateral_error_mean_m"]) < 0.2 and st["roll_std_deg"] < 1.0


def test_inverse_dynamics_steady_torque_matches_the_riders(steady_turn):
    """From the steady turn the rider reached, the inverse problem (no rider gains in the loop: the torque
    that makes the model's roll follow the path's lean) holds the turn with the same steering torque."""
    ride, sc, res = steady_turn
    st = res.summary["steady_turn"]
    spec = sc.spec.rider.model_copy(update={"tyre_lean": tyre_lean_ratio(ride.sim.mm)})
    inv = InverseDynamics(ride.sim, spec.build())
    rows = inv.run(3.0)
    tail = rows[rows[:, 0] > rows[0, 0] + 1.0]
    assert np.abs(rows[:, -1]).max() < 1e-3, "the roll targets are met"
    assert np.abs(rows[:, 8]).max() < 0.6, "the path is followed"
    assert np.mean(tail[:, 1]) == pytest.approx(st["steering_torque_nm"], rel=0.1)
    assert math.degrees(-np.mean(tail[:, 3])) == pytest.approx(st["roll_deg"], abs=1.5)
    assert np.mean(tail[:, 6]) == pytest.approx(15.0, abs=0.1)
