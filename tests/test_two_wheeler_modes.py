"""The eigenvalue analysis of two-wheelers with slip tyres and free suspension (rtsim.analyses.eigen with
the vehicle file's forces, rtsim.analyses.applied): the tyres' relaxation rates are those the simulation
integrates; a linear-tyre bicycle converges to the knife-edge Whipple bicycle (Meijaard et al. 2007,
Table 2) as its tyres stiffen; the sport motorcycle shows the textbook weave and wobble (Sharp 1971,
"The stability and control of motorcycles", J. Mech. Eng. Sci. 13; Cossalter, Motorcycle Dynamics,
ch. 9), the steering damper's trade between them, and the in-plane modes of its suspension."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rtsim.analyses.applied import AppliedForces, slip_rates
from rtsim.analyses.eigen import TwoWheelerLinearisation
from rtsim.configfile import load_toml, validate
from rtsim.vehicle.motorcycle.build import build_motorcycle
from rtsim.vehicle.motorcycle.config import MotorcycleConfig, load_motorcycle
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim
from rtsim.vehicle.motorcycle.step import U_DRIVE_TORQUE, U_STEER_TORQUE

REPO = Path(__file__).resolve().parents[1]
SPORT = REPO / "configs/vehicles/motorcycle.toml"
# Meijaard et al. 2007, Table 2 (1/s): the knife-edge benchmark bicycle at 2 and 5 m/s
WHIPPLE = {2.0: [2.68234517512745 + 1.68066296590675j, 2.68234517512745 - 1.68066296590675j,
                 -3.07158645641514, -8.67387984831735],
           5.0: [-0.77534188219585 + 4.46486771378823j, -0.77534188219585 - 4.46486771378823j,
                 -0.32286642900409, -14.07838969279820]}


@pytest.fixture(scope="module")
def sport():
    cfg, base = load_motorcycle(SPORT)
    return cfg, base


def _by_name(result):
    out = {}
    for m in result.modes:
        out.setdefault(m.name, []).append(m)
    return out


def test_relaxation_rates_are_those_the_simulation_integrates(sport):
    """d(slip)/dt of the analysis at a transient state (steer and drive torque steps, deflections far from
    steady) against the deflections' change over one short simulation step from that state."""
    mm = build_motorcycle(*sport)
    lin = TwoWheelerLinearisation(mm)
    x0 = lin.operating_point(20.0)
    sim = TwoWheelerSim(mm, dt=1e-3, speed=20.0, q=x0[:lin.nq])
    sim.parts.u[U_STEER_TORQUE] = 20.0
    sim.parts.u[U_DRIVE_TORQUE] = 300.0
    sim.run(0.03)
    h = 1e-5
    sim.sim.set_step(h)
    sim.dt = h
    before = sim.parts.slip.copy()
    sim.step()
    # advance_two_wheel_slip integrates exactly with the inputs of the step's end state
    rates = slip_rates(AppliedForces(mm), sim.data.q, sim.data.qd, before.ravel())
    stepped = (sim.parts.slip - before).ravel() / h
    assert np.all(np.abs(rates) > 1e-3), rates          # all four deflections in transient
    np.testing.assert_allclose(stepped, rates, rtol=3e-3)


def _linear_tyre_bicycle(stiffen: float):
    """The benchmark bicycle on linear, disc-profile tyres (no camber thrust, trail or rolling resistance):
    slip stiffnesses 20 Fz and radial stiffness 1e7 N/m times `stiffen`, relaxation lengths 0.1 m over it
    (beyond the file's ranges for stiffen > 1: the limit is the point)."""
    raw = load_toml(REPO / "configs/vehicles/whipple_benchmark.toml")
    raw["tyres"] = {"model": "linear"}
    cfg = validate(MotorcycleConfig, raw, "linear-tyre bicycle")
    upd = dict(crown_radius_m=0.0, radial_stiffness_n_per_m=1e7 * stiffen, radial_damping_ns_per_m=2e3,
               cornering_stiffness_per_load=20.0 * stiffen, cornering_stiffness_load_sensitivity=0.0,
               longitudinal_stiffness_per_load=20.0 * stiffen, camber_stiffness_per_load=0.0,
               pneumatic_trail_m=0.0, twisting_torque_m_per_rad=0.0, overturning_factor=0.0,
               rolling_resistance=0.0, rolling_resistance_speed_s2_per_m2=0.0,
               relaxation_length_long_m=0.1 / stiffen, relaxation_length_lat_m=0.1 / stiffen)
    tyres = cfg.tyres.model_copy(update={"front": cfg.tyres.front.model_copy(update=upd),
                                         "rear": cfg.tyres.rear.model_copy(update=upd)})
    return build_motorcycle(cfg.model_copy(update={"tyres": tyres}), REPO / "configs/vehicles")


def test_linear_tyre_bicycle_converges_to_the_knife_edge_bicycle():
    """Stiffer tyres with shorter relaxation lengths: the bicycle's out-of-plane eigenvalues approach the
    Whipple bicycle's (no side slip, rigid wheels), the error falling in proportion to the compliance,
    under the same names; the tyres' own modes run off to -V/sigma."""
    errors = []
    for stiffen in (1.0, 10.0, 100.0):
        lin = TwoWheelerLinearisation(_linear_tyre_bicycle(stiffen))
        worst = 0.0
        for speed, ref in WHIPPLE.items():
            r = lin.modes(speed)
            names = _by_name(r)
            assert {"weave", "capsize", "castering", "speed"} <= names.keys()
            got = []
            for m in r.modes:
                got += [m.eigenvalue, m.eigenvalue.conjugate()] if m.eigenvalue.imag else [m.eigenvalue]
            got = np.array(got)
            worst = max(worst, max(np.min(np.abs(got - lam)) / abs(lam) for lam in ref))
            weave = names["weave"][0].eigenvalue
            assert abs(weave - ref[0]) < 0.05 * abs(ref[0])
            if stiffen >= 10.0:       # both tyres' lateral modes, far from the bicycle's own
                tyre_modes = [m.eigenvalue for n in ("front tyre lateral", "rear tyre lateral") for m in names[n]]
                assert min(abs(t) for t in tyre_modes) > stiffen * max(abs(lam) for lam in ref)
        errors.append(worst)
    assert errors[0] < 0.1
    assert errors[1] < errors[0] / 5 and errors[2] < errors[1] / 5, errors
    assert errors[2] < 1e-3, errors


@pytest.fixture(scope="module")
def sport_modes(sport):
    cfg, base = sport
    free = TwoWheelerLinearisation(build_motorcycle(cfg, base))
    locked_cfg = cfg.model_copy(update={"suspension": cfg.suspension.model_copy(update={"locked": True})})
    locked = TwoWheelerLinearisation(build_motorcycle(locked_cfg, base))
    damped_cfg = cfg.model_copy(update={"steering": cfg.steering.model_copy(update={"damper_nms_per_rad": 20.0})})
    damped = TwoWheelerLinearisation(build_motorcycle(damped_cfg, base))
    return ({v: _by_name(free.modes(v)) for v in (10.0, 30.0, 45.0)},
            {v: _by_name(locked.modes(v)) for v in (10.0, 30.0)},
            _by_name(damped.modes(45.0)))


def test_sport_motorcycle_weave_and_wobble(sport_modes):
    """Sharp (1971) and Cossalter (ch. 9): weave a roll-yaw-steer oscillation whose frequency rises with
    speed to a few hertz and whose damping falls at high speed; wobble a steer oscillation of the front
    assembly at 6-10 Hz whose damping falls with speed (a rigid frame); capsize a slow real mode."""
    free, _locked, _damped = sport_modes
    weave = {v: m["weave"][0] for v, m in free.items()}
    wobble = {v: m["wobble"][0] for v, m in free.items()}
    f_weave = [weave[v].frequency_hz for v in (10.0, 30.0, 45.0)]
    assert f_weave == sorted(f_weave) and f_weave[0] < 1.5 and f_weave[-1] < 4.5
    assert weave[30.0].eigenvalue.real < weave[45.0].eigenvalue.real < 0
    for v, m in wobble.items():
        assert 6.0 < m.frequency_hz < 10.0
        assert abs(m.shape["steer"]) > 3 * abs(m.shape["roll"])
        assert abs(weave[v].shape["roll"]) > 0.3 * abs(weave[v].shape["steer"])
    re_wobble = [wobble[v].eigenvalue.real for v in (10.0, 30.0, 45.0)]
    assert re_wobble == sorted(re_wobble)
    assert wobble[30.0].eigenvalue.real / abs(wobble[30.0].eigenvalue) > -0.15      # lightly damped
    for m in free.values():
        capsize = m["capsize"][0].eigenvalue
        assert capsize.imag == 0 and abs(capsize) < 0.5


def test_steering_damper_trades_wobble_for_weave(sport_modes):
    """A stiffer steering damper stabilises the high-speed wobble and takes damping from the weave
    (Sharp 1971; Cossalter ch. 9): the damper is in the analysis."""
    free, _locked, damped = sport_modes
    assert damped["wobble"][0].eigenvalue.real < free[45.0]["wobble"][0].eigenvalue.real - 1.0
    assert damped["weave"][0].eigenvalue.real > free[45.0]["weave"][0].eigenvalue.real + 0.1


def test_locked_and_free_suspension(sport, sport_modes):
    """Locking the suspension leaves the out-of-plane modes nearly unchanged and takes away the in-plane
    modes of the suspension: with it free, the frame bounces at the frequency of the sprung mass on the
    suspension and tyres in series, and each wheel hops on its suspension."""
    cfg, _base = sport
    free, locked, _damped = sport_modes
    for v in (10.0, 30.0):
        for name in ("weave", "wobble", "capsize"):
            a, b = free[v][name][0].eigenvalue, locked[v][name][0].eigenvalue
            assert abs(a - b) < 0.05 * abs(a) + 0.02, (v, name, a, b)
        assert "front hop" in free[v] and "rear hop" in free[v]
        assert "front hop" not in locked[v] and "rear hop" not in locked[v]
    # the bounce's undamped frequency against the sprung mass on the wheel rates in series with the tyres
    eps = cfg.caster_rad
    k_front = cfg.suspension.fork.spring.stiffness_n_per_m / np.cos(eps) ** 2       # axial travel / cos(eps)
    pivot, frame_eye = np.array(cfg.geometry.swingarm_pivot_m), np.array(cfg.suspension.shock.frame_mount_m)
    arm_eye, axle = np.array(cfg.suspension.shock.swingarm_mount_m), np.array([0.0, cfg.rear_wheel.radius_m])

    def turned(p, th):
        r = p - pivot
        return pivot + np.array([np.cos(th) * r[0] - np.sin(th) * r[1], np.sin(th) * r[0] + np.cos(th) * r[1]])
    h = 1e-6
    shock_rate = (np.linalg.norm(frame_eye - turned(arm_eye, h)) - np.linalg.norm(frame_eye - turned(arm_eye, -h))) / (2 * h)
    axle_rate = (turned(axle, h)[1] - turned(axle, -h)[1]) / (2 * h)
    k_rear = cfg.suspension.shock.spring.stiffness_n_per_m * (shock_rate / axle_rate) ** 2
    series = lambda a, b: 1.0 / (1.0 / a + 1.0 / b)   # noqa: E731
    k = series(k_front, cfg.tyres.front.radial_stiffness_n_per_m) + series(k_rear, cfg.tyres.rear.radial_stiffness_n_per_m)
    sprung = cfg.rear_frame.mass_kg + cfg.rider.mass_kg + cfg.upper_fork.mass_kg
    bounce = free[10.0]["bounce"][0].eigenvalue
    assert bounce.imag > 0 and abs(abs(bounce) - np.sqrt(k / sprung)) < 0.1 * np.sqrt(k / sprung)


def test_eigen_command_on_the_sport_motorcycle(tmp_path):
    """`rtsim eigen` on the motorcycle file: the operating point (sag, drive torque, loads) and the named
    modes at each speed."""
    from rtsim.cli import main

    out = tmp_path / "modes.json"
    assert main(["eigen", "--vehicle", str(SPORT), "--speeds", "20,25", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    for r in data["modes"]:
        op = r["operating_point"]
        assert op["drive_torque_nm"] > 0 and abs(op["load_front_n"] + op["load_rear_n"] - 275.0 * 9.81) < 0.05 * 275 * 9.81
        names = {m["name"] for m in r["modes"]}
        assert {"weave", "wobble", "capsize", "bounce", "pitch", "front hop", "rear hop", "speed",
                "front tyre lateral", "rear tyre lateral"} <= names
