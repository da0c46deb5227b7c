"""The Whipple benchmark bicycle from the two-wheeler assembly: eigenvalues of the full nonlinear model,
linearised numerically about straight running, against the published values of Meijaard, Papadopoulos,
Ruina and Schwab (2007), Table 2, and the weave and capsize speeds of their section 5; and the model in
the time domain: energy of the knife-edge (conservative) bicycle."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.analyses.eigen import TwoWheelerLinearisation
from rtsim.analyses.stability import sweep
from rtsim.mbs.simulation import Simulation
from rtsim.vehicle.motorcycle.build import build_motorcycle, straight_running_velocity
from rtsim.vehicle.motorcycle.config import load_motorcycle
from rtsim.vehicle.motorcycle.layout import D_ROLL, NDOF

REPO = Path(__file__).resolve().parents[1]

# Meijaard et al. 2007, Table 2: speed (m/s) and the four eigenvalues (1/s)
TABLE2 = {
    0: [5.53094371765393, 3.13164324790656, -3.13164324790656, -5.53094371765393],
    1: [3.52696170990070 + 0.80774027519930j, 3.52696170990070 - 0.80774027519930j, -3.13423125066578,
        -7.11008014637442],
    2: [2.68234517512745 + 1.68066296590675j, 2.68234517512745 - 1.68066296590675j, -3.07158645641514,
        -8.67387984831735],
    3: [1.70675605663975 + 2.31582447384325j, 1.70675605663975 - 2.31582447384325j, -2.63366137253667,
        -10.35101467245920],
    4: [0.41325331521125 + 3.07910818603206j, 0.41325331521125 - 3.07910818603206j, -1.42944427361326,
        -12.15861426576450],
    5: [-0.77534188219585 + 4.46486771378823j, -0.77534188219585 - 4.46486771378823j, -0.32286642900409,
        -14.07838969279820],
    6: [-1.52644486584142 + 5.87673060598709j, -1.52644486584142 - 5.87673060598709j, -0.00406690076970,
        -16.08537123098030],
    7: [-2.13875644258362 + 7.19525913329805j, -2.13875644258362 - 7.19525913329805j, 0.10268170574766,
        -18.15788466125260],
    8: [-2.69348683581097 + 8.46037971396931j, -2.69348683581097 - 8.46037971396931j, 0.14327879765713,
        -20.27940894394570],
    9: [-3.21675402252485 + 9.69377351531791j, -3.21675402252485 - 9.69377351531791j, 0.15790184030917,
        -22.43788559040860],
    10: [-3.72016840437287 + 10.90681139476290j, -3.72016840437287 - 10.90681139476290j, 0.16105338653172,
         -24.62459635017400],
}
WEAVE_SPEED, CAPSIZE_SPEED = 4.29238253634111, 6.02426201538837   # section 5


@pytest.fixture(scope="module")
def whipple():
    cfg, base = load_motorcycle(REPO / "configs/vehicles/whipple_benchmark.toml")
    return build_motorcycle(cfg, base)


def _with_conjugates(modes):
    out = []
    for m in modes:
        out.append(m.eigenvalue)
        if abs(m.eigenvalue.imag) > 1e-9:
            out.append(m.eigenvalue.conjugate())
    return np.array(out)


def test_published_eigenvalues_at_every_tabulated_speed(whipple):
    lin = TwoWheelerLinearisation(whipple)
    for speed, ref in TABLE2.items():
        got = _with_conjugates([m for m in lin.modes(float(speed)).modes if m.name != "speed"])
        assert got.size == 4, (speed, got)
        for lam in ref:
            err = np.min(np.abs(got - lam))
            assert err <= 1e-6 * abs(lam), f"v = {speed} m/s: {lam} not found (nearest off by {err:.2e}) in {got}"


def test_the_speed_mode_is_neutral_and_the_modes_are_named(whipple):
    r = TwoWheelerLinearisation(whipple).modes(5.0)
    names = {m.name: m for m in r.modes}
    assert set(names) == {"weave", "capsize", "castering", "speed"}
    assert abs(names["speed"].eigenvalue) < 1e-8
    assert abs(names["weave"].eigenvalue - TABLE2[5][0]) < 1e-6 * abs(TABLE2[5][0])
    assert names["castering"].shape["steer"] != 0 and abs(names["castering"].shape["steer"]) == 1.0


def test_weave_and_capsize_speeds(whipple):
    lin = TwoWheelerLinearisation(whipple)
    _results, crossings = sweep(lin, np.array([3.5, 4.5, 5.5, 6.5]))
    found = {(c.mode, c.becomes): c.speed for c in crossings}
    assert found.keys() == {("weave", "stable"), ("capsize", "unstable")}
    assert abs(found["weave", "stable"] - WEAVE_SPEED) < 1e-3
    assert abs(found["capsize", "unstable"] - CAPSIZE_SPEED) < 1e-3


def _roll_modes(t, roll, scale):
    """Least-squares fit of roll(t) = A e^(a t) + e^(s t) (B cos w t + C sin w t): the capsize rate a and
    the weave's s + i w (1/s), with free rates (started 10 % off the benchmark's values)."""
    from scipy.optimize import least_squares

    def resid(p):
        A, a, B, C, s, w = p
        return (A * np.exp(a * t) + np.exp(s * t) * (B * np.cos(w * t) + C * np.sin(w * t)) - roll) / scale
    lam_c, lam_w = TABLE2[5][2], TABLE2[5][0]
    fit = least_squares(resid, [roll[0], 0.9 * lam_c, 0.0, 0.0, 1.1 * lam_w.real, 0.9 * lam_w.imag],
                        xtol=1e-14, ftol=1e-14)
    _A, a, _B, _C, s, w = fit.x
    return a, complex(s, w), float(np.sqrt(np.mean(resid(fit.x) ** 2)))


def test_knife_edge_bicycle_conserves_energy_and_its_weave_decays_at_the_benchmarks_rates(whipple):
    """No slip and no dissipation: a small roll disturbance (0.03 rad/s of roll rate, about 0.006 rad of
    roll) at 5 m/s decays while the total energy stays constant.

    The decay is required at the benchmark's rates (Meijaard et al. 2007, Table 2 at 5 m/s): from 0.5 s
    on (castering, -14/s, has died out) the roll is fitted with the capsize and weave modes, rates free;
    the fitted capsize rate (-0.3229/s) and the weave's decay rate (-0.7753/s) and frequency (4.4649 rad/s)
    must each be within 0.3 % of the published eigenvalues (measured: 0.03 % and 0.001 %; the nonlinear
    terms shift the rates with the square of the amplitude: ten times this disturbance shifted them by
    2.2 % and 1.2 %), the fit leaving under 0.1 % of the peak roll; and the late envelope (3-4 s) at most
    the early one (1-2 s) times e^(-0.3229 x 1 s), the slowest mode's decay over the second between them.
    A weave that does not decay, or grows, fails every one of these."""
    dof = np.zeros(NDOF)
    q = whipple.coordinates(dof)
    qd = straight_running_velocity(whipple, q, 5.0)
    dof[D_ROLL] = 1e-6
    roll_dir = (whipple.coordinates(dof) - q) / 1e-6
    qd = qd + 0.03 * roll_dir                     # 0.03 rad/s of roll rate
    sim = Simulation(whipple.mech, 1e-3, q0=q, qd0=qd)
    tr = sim.run(4.0, stride=10)
    e = sim.energy(tr)
    assert np.max(np.abs(e - e[0])) < 1e-6 * abs(e[0])
    roll = np.array([whipple.group(qq, "V")[2] for qq in tr.q])
    peak = np.abs(roll).max()
    fit = tr.t >= 0.5
    capsize, weave, residual = _roll_modes(tr.t[fit], roll[fit], peak)
    lam_c, lam_w = TABLE2[5][2], TABLE2[5][0]
    assert residual < 1e-3, residual
    assert capsize == pytest.approx(lam_c, rel=3e-3)
    assert weave.real == pytest.approx(lam_w.real, rel=3e-3)
    assert weave.imag == pytest.approx(lam_w.imag, rel=3e-3)
    late = np.abs(roll[tr.t > 3.0]).max()
    early = np.abs(roll[(tr.t > 1.0) & (tr.t < 2.0)]).max()
    assert late <= early * np.exp(lam_c * 1.0)


def test_eigen_and_statics_commands(tmp_path):
    """`rtsim eigen` writes the modes and the stability changes as JSON and the root locus; `rtsim
    statics` the loads of the motorcycle with its rider, which carry the weight."""
    import json

    from rtsim.cli import main

    out, png = tmp_path / "modes.json", tmp_path / "locus.png"
    assert main(["eigen", "--vehicle", str(REPO / "configs/vehicles/whipple_benchmark.toml"), "--speeds", "4:5:1",
                 "--out", str(out), "--plot", str(png)]) == 0
    data = json.loads(out.read_text())
    assert data["speeds_m_s"] == [4.0, 5.0]
    assert [c["mode"] for c in data["stability_changes"]] == ["weave"]
    assert abs(data["stability_changes"][0]["speed_m_s"] - WEAVE_SPEED) < 1e-3
    assert png.stat().st_size > 10_000
    st = tmp_path / "statics.json"
    assert main(["statics", "--vehicle", str(REPO / "configs/vehicles/motorcycle.toml"), "--out", str(st)]) == 0
    loads = json.loads(st.read_text())["wheel_loads_n"]
    assert abs(loads["front"] + loads["rear"] - 275.0 * 9.81) < 0.5
