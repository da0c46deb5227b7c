"""The steer-by-wire steering inside the multibody step, against analytic results: the free oscillation
of column and rack against a known spring and inertia, unloaded steady state, static torsion-bar torque
under a rack load, the motor torque limit, the command lag block; and on the car, a step of the
steering-wheel command reaching the front wheels with the actuator's own bandwidth.

The rig is a multibody model of the steering alone: the kit part's column and rack coordinates, a known
inertia (the linkage) and a known spring or constant load on the rack, stepped by the same ALI3-P step
as the vehicles (rtsim.mbs.integrator.step_with) with the part's forces inside the Newton iteration."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from rtsim.errors import ConfigError
from rtsim.jit import inline_kernel, kernel
from rtsim.mbs import MechanismBuilder, Simulation
from rtsim.mbs.integrator import step_with
from rtsim.mbs.model import IS_TANGENT_FORCES, OK
from rtsim.vehicle.kit import steering as S

DT = 1e-3


@inline_kernel
def _rig_forces(m, d, a, tangent, bq, hc):
    sp, ss, ic, ir = a
    S.steering_forces(sp, ss, d.q, d.qd, d.force, ic, ir)
    if tangent:
        S.steering_tangent(m, d.w_env, sp, ic, ir, bq, hc)
    return -1


@kernel
def _rig_run(m, d, sp, ss, ic, ir, cmd, h, out):
    """len(cmd) steps with the steering command cmd[k] (rad); outputs SO_* per step into out[k]."""
    for k in range(cmd.shape[0]):
        S.steering_control(sp, ss, cmd[k], d.q[ic], d.qd[ic], h)
        status = step_with(m, d, h, _rig_forces, (sp, ss, ic, ir))
        if status != OK:
            return status
        S.steering_outputs(sp, ss, d.q, ic, ir, out[k])
    return OK


class Rig:
    """Column and rack of the steering kit part; on the rack a linkage of inertia `linkage_mass` (kg),
    a spring `spring` (N/m) and a constant force `load` (N, the force the rack exerts on the linkage
    along +x: the linkage pushes back with -load)."""

    def __init__(self, linkage_mass=100.0, spring=0.0, load=0.0, **cfg):
        self.cfg = S.steering_config(cfg or None)
        self.p = S.steering_params(self.cfg)
        b = MechanismBuilder(dim=3, name="steering rig")
        rack = b.length("rack", 0.0, velocity=0.0)
        b.scalar_inertia(rack, linkage_mass)
        self.ic = S.add_steering(b, self.p, rack).index
        self.ir = rack.index
        if spring or load:
            b.coordinate_force(rack, constant=-load, stiffness=spring)
        mech = b.compile()
        mech.model.iset[IS_TANGENT_FORCES] = 1
        self.sim = Simulation(mech, DT)
        self.s = S.steering_state(self.p, DT)

    def run(self, cmd) -> np.ndarray:
        cmd = np.asarray(cmd, dtype=float)
        out = np.zeros((cmd.shape[0], S.SO_SIZE))
        status = _rig_run(self.sim.model, self.sim.data, self.p, self.s, self.ic, self.ir, cmd, DT, out)
        assert status == OK
        return out

    @property
    def m_rack(self) -> float:
        return float(self.p[S.SbwPar.M_RACK])


def test_free_oscillation_at_the_analytic_frequencies():
    """Undamped column and rack, a linkage inertia and a spring on the rack: after a step of the
    motor's column torque (held by the saturated integral, through the motor lag) the rack oscillates
    in the two modes of M x'' + K x = 0 with M = diag(J_c, m_r + m_l), K = k_tb [[1, -1/r_p],
    [-1/r_p, 1/r_p^2]] + diag(0, k_s). The frequencies fitted to the simulated rack motion match the
    analytic ones within 1 %."""
    m_link, k_s, torque = 100.0, 2.0e4, 2.0
    rig = Rig(linkage_mass=m_link, spring=k_s, kp=0.0, kd=0.0, ki=1e6, integral_limit=torque,
              column_damping=0.0, torsion_bar_damping=0.0, rack_damping=0.0)
    c = rig.cfg
    rp, k = c.rack_travel_per_rad, c.torsion_bar_stiffness
    jc = float(rig.p[S.SbwPar.J_COL])
    mass = np.diag([jc, rig.m_rack + m_link])
    stiff = k * np.array([[1.0, -1.0 / rp], [-1.0 / rp, 1.0 / rp ** 2]]) + np.diag([0.0, k_s])
    w_ref = np.sqrt(np.sort(np.linalg.eigvals(np.linalg.solve(mass, stiff)).real))
    out = rig.run(np.full(20000, 10.0))          # 20 s; the command stays far ahead: T_col = torque
    t = DT * np.arange(1, out.shape[0] + 1)
    x = out[:, S.SO_RACK_POS]
    # static deflection: the column torque reaches the rack through the torsion bar
    assert np.mean(x[t > 1.0]) == pytest.approx(torque / rp / k_s, rel=2e-3)
    keep = t > 0.05                               # the motor lag (2 ms) has settled
    tt, xx = t[keep], x[keep] - np.mean(x[keep])
    spec = np.abs(np.fft.rfft(xx * np.hanning(xx.size), 8 * xx.size))
    freqs = np.fft.rfftfreq(8 * xx.size, DT) * 2 * np.pi
    peaks = [freqs[np.argmax(np.where(np.abs(freqs - w) < 0.5 * w, spec, 0.0))] for w in w_ref]

    def resid(par):
        w1, w2, c0, a1, b1, a2, b2 = par
        return c0 + a1 * np.cos(w1 * tt) + b1 * np.sin(w1 * tt) + a2 * np.cos(w2 * tt) + b2 * np.sin(w2 * tt) - xx

    start = [peaks[0], peaks[1], 0.0, *(np.std(xx),) * 4]
    fit = least_squares(resid, start, x_scale="jac")
    w_fit = np.sort(fit.x[:2])
    assert np.sqrt(np.mean(fit.fun ** 2)) < 1e-3 * np.std(xx)       # two modes are the whole motion
    assert w_fit == pytest.approx(w_ref, rel=0.01)


def test_unloaded_steady_state_follows_command():
    rig = Rig()
    h = rig.run(np.full(6000, 0.5))
    last = h[-1]
    assert last[S.SO_SW_ANGLE] == pytest.approx(0.5, abs=1e-7)
    assert abs(last[S.SO_TORQUE]) < 1e-9
    assert abs(last[S.SO_MOTOR_TORQUE]) < 1e-9
    assert last[S.SO_RACK_POS] == pytest.approx(0.5 * rig.cfg.rack_travel_per_rad, rel=1e-9)
    # a reasonably quick, well damped position loop
    assert np.argmax(h[:, S.SO_SW_ANGLE] > 0.45) * DT < 0.1
    assert h[:, S.SO_SW_ANGLE].max() < 0.5 * 1.1


@pytest.mark.parametrize("force", [1500.0, -800.0])
def test_rack_force_static_torque(force):
    rig = Rig(load=force)
    c = rig.cfg
    last = rig.run(np.full(6000, 0.3))[-1]
    rp = c.rack_travel_per_rad
    assert last[S.SO_TORQUE] == pytest.approx(force * rp, rel=1e-2)
    assert last[S.SO_TORQUE] == pytest.approx(force * rp, rel=1e-8)        # (exactly, in fact)
    # the integral action keeps the steering wheel on the command; the pinion lags by the twist
    assert last[S.SO_SW_ANGLE] == pytest.approx(0.3, abs=1e-7)
    twist = force * rp / c.torsion_bar_stiffness
    assert last[S.SO_PINION_ANGLE] == pytest.approx(0.3 - twist, abs=1e-7)
    # the motor carries it through the reduction
    motor = force * rp / (c.reduction_ratio * c.reduction_efficiency)
    assert last[S.SO_MOTOR_TORQUE] == pytest.approx(motor, rel=1e-8)


def test_motor_torque_limit_respected():
    rig = Rig(load=2500.0)
    c = rig.cfg
    h = rig.run(np.full(3000, 3.0))
    tm = h[:, S.SO_MOTOR_TORQUE]
    assert np.all(np.abs(tm) <= c.motor_torque_limit * (1 + 1e-12))
    assert np.max(np.abs(tm)) == pytest.approx(c.motor_torque_limit)     # it did saturate
    assert h[-1, S.SO_SW_ANGLE] == pytest.approx(3.0, abs=1e-6)
    # a load beyond the motor's capacity: the limit holds and the wheel is pushed back
    cap = S.describe(c)["rack_force_capacity_N"]
    rig = Rig(load=1.5 * cap)
    h = rig.run(np.full(2000, 1.0))
    assert np.all(np.abs(h[:, S.SO_MOTOR_TORQUE]) <= c.motor_torque_limit * (1 + 1e-12))
    assert h[-1, S.SO_SW_ANGLE] < 0.0


def test_command_delay_and_bounds():
    rig = Rig(command={"delay": 0.02, "min": -2.0, "max": 2.0})
    h = rig.run(np.full(100, 5.0))
    assert np.all(h[:19, S.SO_CMD] == 0.0) and np.all(h[20:, S.SO_CMD] == 2.0)


def test_describe_and_config_errors():
    d = S.describe()
    assert d["rack_travel_per_steering_wheel_turn_m"] == pytest.approx(2 * math.pi * 6.4e-3)
    assert d["torsion_bar_Nm_per_deg"] == pytest.approx(1.5)
    with pytest.raises(ConfigError, match=r"steering\.rack_travel_per_rad"):
        S.steering_config({"rack_travel_per_rad": 0.04 * 2 * math.pi * 10})
    with pytest.raises(ConfigError, match=r"steering\.kp"):
        S.steering_config({"kp": -1.0})


def test_a_steering_step_reaches_the_wheels_with_the_actuators_bandwidth():
    """The car rolling at 15 m/s, a 0.5 rad step of the steering-wheel command: the front wheels start
    turning at the first step (no delay, no filter between the steering and the linkage) and their
    steer angle rises (10 % and 90 % of its final value) when the rack of the actuator alone rises,
    driving the same linkage inertia (the rig above): the tyres load the rack, the PID's integral takes
    the load, and the actuator's bandwidth sets the response."""
    from rtsim.road.config import load_road
    from rtsim.vehicle.car.build import build_vehicle
    from rtsim.vehicle.car.config import load_vehicle
    from rtsim.vehicle.car.sensors import S_STEER_FL, S_STEER_FR
    from rtsim.vehicle.car.sim import VehicleSim
    from rtsim.vehicle.car.step import CMD_STEER
    from rtsim.vehicle.kit.linkages import OUT_AXIS, OUT_CENTRE, OUT_ROT_S
    from rtsim.vehicle.offline import default_vehicle_path

    cfg, base = load_vehicle(default_vehicle_path())
    vm = build_vehicle(cfg, base)
    sim = VehicleSim(vm, load_road(default_vehicle_path().parents[1] / "roads" / "flat.toml"), DT, speed=15.0)
    sim.step(300)
    start = sim.sensors()[[S_STEER_FL, S_STEER_FR]].copy()
    sim.io.commands[CMD_STEER] = 0.5
    steer = np.zeros((400, 2))
    for k in range(steer.shape[0]):
        sim.step(1)
        steer[k] = sim.sensors()[[S_STEER_FL, S_STEER_FR]] - start
    # the masses the rack moves: the unsprung masses, sum of m |dW/ds|^2 over the steered wheels, and
    # the wheels' own inertia about a diameter I_d turned at the knuckle's rotation per rack travel R_s
    # (across the spin axis a), sum of I_d (|R_s|^2 - (R_s . a)^2), both at design
    m_link = 0.0
    for corner in vm.corners[:2]:
        terms = [tuple(e) for e in corner.exponents]
        j, j0 = terms.index((0, 1)), terms.index((0, 0))
        m_link += cfg.front.unsprung_mass_kg * float(np.sum(corner.vec_coef[OUT_CENTRE][:, j] ** 2))
        r_s = corner.vec_coef[OUT_ROT_S][:, j0]
        a = corner.vec_coef[OUT_AXIS][:, j0] / np.linalg.norm(corner.vec_coef[OUT_AXIS][:, j0])
        m_link += cfg.front.pivot_inertia_kgm2 * float(r_s @ r_s - (r_s @ a) ** 2)
    rack = Rig(linkage_mass=m_link, **dataclasses.asdict(cfg.steering)).run(np.full(steer.shape[0], 0.5))[:, S.SO_RACK_POS]

    def rise(y):
        return DT * np.argmax(y > 0.1 * y[-1]), DT * np.argmax(y > 0.9 * y[-1])

    assert np.all(steer[0] > 0.0)
    t10, t90 = rise(rack)
    for w in range(2):
        c10, c90 = rise(steer[:, w])
        assert c10 == pytest.approx(t10, abs=0.003) and c90 == pytest.approx(t90, rel=0.15)
