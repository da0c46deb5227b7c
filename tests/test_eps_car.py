"""The 16-DOF car with electric power steering (configs/vehicles/eps_car.toml), against references:
statics (the wheel loads carry the weight), the bond-graph study's two life situations (its qualitative
results: the lateral acceleration settles, the outer wheels load, braking loads the front), a
single-track model from the car's own parameters at the measured road-wheel angles, the statics of the
steering linkage (tie rods, rack, pinion, efficiency) with the assist off, the assist law's fixed point
with it on, and the power audit's balance (stored change = inputs - dissipation) over the life
situations and an on-centre weave."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq, fsolve

from drivers.scenario import load_scenario
from drivers.base import I_BRAKE, I_THROTTLE, NSTATE, DriverView
from drivers.driver import Driver
from drivers.speed_follower import speed_follower
from rtsim.road.config import load_road
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.energy import Balance
from rtsim.vehicle.car.layout import CI_S, G
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, TyreOut
from rtsim.vehicle.kit import eps as E
from rtsim.vehicle.kit.tables import map_2d, map_eval
from rtsim.vehicle.kit.tyre.magic_formula import mf52_forces
from rtsim.vehicle.offline import prepare, run, vehicle_state

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "eps_car.toml"
SCENARIOS = ROOT / "configs" / "scenarios"
FLAT = ROOT / "configs" / "roads" / "flat.toml"


@pytest.fixture(scope="module")
def model():
    cfg, base = load_vehicle(VEHICLE)
    return build_vehicle(cfg, base)


def _sim(model, speed=0.0, brake=0.0):
    sim = VehicleSim(model, load_road(FLAT), 1e-3, brake_pressure=brake, speed=speed)
    sim.io.commands[CMD_BRAKE] = brake
    return sim


def _front_steer(sim) -> float:
    """Mean road-wheel angle of the front knuckles (their coordinates plus the compliance steer), rad."""
    ix = sim.vm.vehicle.corner_idx
    return float(np.mean([sim.data.q[ix[i, CI_S]] + sim.vd.steer_offset[i] for i in (0, 1)]))


def test_model_size_and_static_wheel_loads(model):
    """16 DOF as the study counts them (body 6, four travels and spins, two pivots) plus the rack and the
    column of the EPS, both pivots tied to the rack; at rest the four tyre loads carry the car's weight
    to 0.01 %."""
    m = model.mech.model
    names = model.mech.coordinate_names
    assert {"steer_fl", "steer_fr", "rack", "steering_column"} <= set(names)
    # 12 + 4 x 5 + 2 pivots + rack + column = 36 coordinates; 6 + 4 x 3 + 2 tie rods + 1 driver = 21 rows
    assert (m.nq, m.nc) == (36, 21)
    sim = _sim(model, brake=1500.0)
    sim.step(3000)
    cfg = model.config
    mass = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    loads = sim.vd.tyre[:, TyreOut.FZ]
    assert abs(loads.sum() - mass * G) <= 1e-4 * mass * G
    assert loads[0] == pytest.approx(loads[1], rel=1e-3) and loads[0] > loads[2]   # front-heavy, symmetric


@pytest.fixture(scope="module")
def life_situation_1(model):
    sim, sc = prepare(VEHICLE, load_scenario(SCENARIOS / "step_steer_80kph.toml", check_files=True))
    return sim, run(sim, sc)


@pytest.fixture(scope="module")
def life_situation_2(model):
    sim, sc = prepare(VEHICLE, load_scenario(SCENARIOS / "step_steer_braking_80kph.toml", check_files=True))
    return sim, run(sim, sc)


def _balance(sim) -> Balance:
    return Balance(sim.vd.audit_e, sim.vd.e_base)


@pytest.mark.parametrize("which", ["life_situation_1", "life_situation_2"])
def test_energy_balance_closes_over_the_life_situations(which, request):
    sim, res = request.getfixturevalue(which)
    b = _balance(sim)
    assert b.exchanged > 5e4                      # J: tens of kJ through tyres, drive, aero, brakes
    assert abs(b.residual) <= 1e-6 * b.exchanged
    assert abs(b.joints) <= 1e-6 * b.exchanged    # ideal joints do no work
    assert abs(b.flows["motor_conversion"]) <= 1e-6 * b.exchanged   # gyrator: electrical = mechanical
    # the recorded columns carry the same balance at the last row
    col = {n: res.column(n)[-1] for n in res.columns if n.startswith(("work_", "stored_", "energy_"))}
    assert col["energy_residual"] == pytest.approx(b.residual, abs=1e-9)
    # every dissipative port dissipates
    for port in ("dampers", "aero", "column_friction", "motor_friction", "gear_loss", "pinion_friction",
                 "rack_loss", "rack_friction", "motor_winding"):
        assert b.flows[port] <= 0.0, port


def _lateral_acceleration(res) -> np.ndarray:
    """The body's lateral acceleration (m/s^2, left) from the IMU: in a body rolled by phi (positive right
    side down) the accelerometer's specific force reads a_y cos(phi) + g sin(phi) (+7.7 % in the 0.37 g
    turn here), so a_y = (accel_y - g sin(phi)) / cos(phi)."""
    phi = res.column("roll_angle")
    return (res.column("accel_y") - G * np.sin(phi)) / np.cos(phi)


def test_the_imu_reads_the_lateral_acceleration_and_the_roll_term(life_situation_1):
    """Like with like: in the settled turn the IMU's accel_y is the yaw-rate acceleration v r seen in the
    rolled body plus gravity's component, v r cos(phi) + g sin(phi), within 0.5 % (what is left: the
    IMU's offset from the centre of mass and the side-slip's drift)."""
    _sim, res = life_situation_1
    t = res.column("time")
    s = t > 4.5
    v, r, phi = res.column("speed")[s], res.column("yaw_rate")[s], res.column("roll_angle")[s]
    assert phi.mean() > 0.01                                      # turning left the body rolls right side down
    assert res.column("accel_y")[s].mean() == pytest.approx(np.mean(v * r * np.cos(phi) + G * np.sin(phi)),
                                                            rel=0.005)


def test_life_situation_1_lateral_acceleration_settles_and_the_outer_wheels_load(life_situation_1, single_track):
    """The body's lateral acceleration (the IMU's, less its roll term) and the yaw-rate acceleration v r
    rise to a settled turn (within 2 %) in 0.1-1.5 s after the steer, and neither peaks above the static-load
    single-track's steady value (the car before its body rolls: the elastic load transfer that lowers the
    settled value builds with the roll, so the peak may lie between the two, never above)."""
    sim, res = life_situation_1
    t = res.column("time")
    for ay in (_lateral_acceleration(res), res.column("speed") * res.column("yaw_rate")):
        steady = ay[(t > 4.5)]
        assert np.abs(ay[t < 1.0]).max() < 0.01 * G
        assert steady.mean() > 0.25 * G                               # a left turn
        assert steady.max() - steady.min() < 0.02 * steady.mean()     # settled
        rise = t[np.argmax(ay > 0.9 * steady.mean())]
        assert 1.1 < rise < 2.5
        assert ay.max() <= single_track["static"]
    fz = {w: res.column(f"tyre_fz_{w}")[t > 4.5].mean() for w in ("fl", "fr", "rl", "rr")}
    assert fz["fr"] > fz["fl"] and fz["rr"] > fz["rl"]            # turning left: the right side loads


@pytest.mark.xfail(strict=True, reason=(
    "the model's lateral acceleration overshoots its settled value by 3.2 % (roll term removed; the yaw-rate "
    "acceleration v r by 7.4 %) after the 35 deg step steer at 80 km/h, where the study reports none and the "
    "car's linear single-track, with the same steer ramp, overshoots 0.06 % (v r: 1.2 %). Likely the elastic "
    "load transfer building up with the roll (the load-transfer single-track is 5.5 % below the "
    "static-load one); whether the roll's damping is too low is open"))
def test_life_situation_1_lateral_acceleration_does_not_overshoot(life_situation_1):
    """The study's "rises to the steady value without overshoot", bounded tightly: the peak at most 1 %
    above the settled mean (the settled band is 0.5 %, the linear single-track's overshoot 0.06 %)."""
    _sim, res = life_situation_1
    t = res.column("time")
    ay = _lateral_acceleration(res)
    assert ay.max() <= 1.01 * ay[t > 4.5].mean()


def test_life_situation_2_braking_in_the_curve_loads_the_front(life_situation_2):
    sim, res = life_situation_2
    t = res.column("time")
    fz = {w: res.column(f"tyre_fz_{w}") for w in ("fl", "fr", "rl", "rr")}
    turn = (t > 4.0) & (t < 5.0)
    braking = (t > 6.5) & (t < 7.5)
    front = lambda sel: (fz["fl"][sel] + fz["fr"][sel]).mean()     # noqa: E731
    rear = lambda sel: (fz["rl"][sel] + fz["rr"][sel]).mean()      # noqa: E731
    assert fz["fr"][turn].mean() > fz["fl"][turn].mean()
    assert front(braking) > front(turn) + 1000.0                  # N: load moves to the front
    assert rear(braking) < rear(turn) - 1000.0
    assert res.column("accel_x")[braking].mean() < -2.5           # m/s^2, braking


def _tyre_fy(tp, fz, alpha):
    """Lateral force (N, positive left) of a left tyre at the slip angle alpha (rad, ISO: the force
    opposes it), free rolling, no camber."""
    return mf52_forces(tp, fz, 0.0, alpha, 0.0, 22.0, 1.0)[1]


@pytest.fixture(scope="module")
def single_track(life_situation_1):
    """Steady states of single-track models with the car's mass, CG and wheelbase at the speed and the front
    road-wheel angle measured in the settled turn (t > 4.5 s: so the steering's compliance is in the
    angle), as the yaw-rate acceleration v r (m/s^2) each predicts:

    - ``linear``: each axle's cornering stiffness (the MF tyre's slope at zero slip and the static load,
      two tyres);
    - ``static``: the MF tyre's lateral force at each axle's static load (two tyres);
    - ``load_transfer``: the MF tyre's force at each wheel's load measured in the turn (the outer wheels
      loaded, the inner unloaded: the tyre's force grows less than its load, so the axle gives less).
    Also the measured ``vr``."""
    sim, res = life_situation_1
    t = res.column("time")
    sel = t > 4.5
    v = res.column("speed")[sel].mean()
    delta = _front_steer(sim)
    cfg = sim.vm.config
    m = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    lf = -sim.vm.config.chassis.cg_m[0]
    wb = cfg.front.hardpoints.wheel_centre[0] - cfg.rear.hardpoints.wheel_centre[0]
    lr = wb - lf
    fzf, fzr = m * G * lr / wb / 2, m * G * lf / wb / 2
    fz = {w: res.column(f"tyre_fz_{w}")[sel].mean() for w in ("fl", "fr", "rl", "rr")}
    tp = sim.tp

    def steady_vr(front, rear):
        def eqs(x):
            beta, r = x
            fyf = front(delta - beta - lf * r / v)
            fyr = rear(-beta + lr * r / v)
            return [fyf * math.cos(delta) + fyr - m * v * r, lf * fyf * math.cos(delta) - lr * fyr]
        _beta, r = fsolve(eqs, [0.0, 0.1], xtol=1e-12)
        return v * r

    h = 1e-5
    cf = 2 * (_tyre_fy(tp, fzf, -h) - _tyre_fy(tp, fzf, h)) / (2 * h)
    cr = 2 * (_tyre_fy(tp, fzr, -h) - _tyre_fy(tp, fzr, h)) / (2 * h)
    return {
        "linear": steady_vr(lambda a: cf * a, lambda a: cr * a),
        "static": steady_vr(lambda a: 2 * _tyre_fy(tp, fzf, -a), lambda a: 2 * _tyre_fy(tp, fzr, -a)),
        "load_transfer": steady_vr(lambda a: _tyre_fy(tp, fz["fl"], -a) + _tyre_fy(tp, fz["fr"], -a),
                                   lambda a: _tyre_fy(tp, fz["rl"], -a) + _tyre_fy(tp, fz["rr"], -a)),
        "vr": float(np.mean(res.column("speed")[sel] * res.column("yaw_rate")[sel])),
    }


def test_life_situation_1_steady_turn_against_single_track_models(single_track):
    """Like with like: the model's yaw-rate acceleration v r against the single-track models' (not the
    IMU's accel_y, which also reads the roll's g sin(phi)). The gap each leaves, and why:

    - the linear single-track is above the others (the tyre saturates: 1.6 % here), and the model is 10 %
      below it;
    - the static-load MF single-track is above the load-transfer one (the MF tyre's lateral force grows
      less than its load: 5.5 % here), and the model is 8.6 % below it;
    - the load-transfer single-track, the reference: the model within 4 % below it (3.2 % here). What it
      leaves out lowers the force only: the wheels' camber as the body rolls (the outer wheels lean out)
      and the rear tyres' combined slip under the drive force that holds the speed."""
    st = single_track
    assert st["vr"] < st["load_transfer"] < st["static"] < st["linear"]
    assert st["vr"] > 0.96 * st["load_transfer"]


def _steady_turn(model):
    """80 km/h, a steady steer-in to 40 deg at 20 deg/s (the transmissions' power well above the
    efficiency blend's scale), then held: (sim, per-step log)."""
    sim = _sim(model, speed=22.22)
    log = []
    for n in range(5000):
        t = (n + 1) * 1e-3
        sim.io.commands[CMD_STEER] = math.radians(min(40.0, max(0.0, 20.0 * (t - 0.5))))
        sim.step()
        log.append((t, sim.io.eps_out.copy(), sim.data.qd[sim.vm.vehicle.steer_idx[1]], _rack_load(sim)))
    return sim, log


def _rack_load(sim) -> float:
    """The force the tie rods hold the rack back with (N, positive against a leftward travel), from
    the crank-rod constraints' multipliers: Phi_x lambda."""
    m = sim.m
    d = sim.data
    ir = sim.vm.vehicle.steer_idx[1]
    f = 0.0
    for i in range(m.nc):
        for s in range(m.con_nact[i]):
            slot = m.con_act[i, s]
            if m.con_idx[i, slot] == ir:
                f += d.jac[i, slot] * d.lam[i]
    return f


def _linkage_statics(c, f_load: float, xd: float, w_col: float) -> tuple[float, float]:
    """Statics of the assist-off linkage with the rack sliding leftwards (xd > 0, m/s) against the
    tie rods' load f_load (N), from the declared parameters c (the [eps] table): the pinion drives the
    rack (forward rack efficiency) against the load, the rack's dry and viscous friction; the pinion's
    dry friction; the pinion back-drives the motor's rotor (the motor stays geared to the rack)
    through the worm (back-driven efficiency) against its dry and viscous friction. Returns the
    torsion bar's elastic torque and the driver's torque (N m): the first less the torsion bar's
    damping, the second plus the column's viscous friction (column turning at w_col, rad/s)."""
    rp, n = c.rack_travel_per_rad_m, c.gear_ratio
    w_motor = n * xd / rp
    t_pinion = ((f_load + c.rack_friction_n + c.rack_damping_ns_per_m * xd) * rp / c.rack_efficiency
                + c.pinion_friction_nm
                + n * (c.motor_friction_nm + c.motor_damping_nms_per_rad * w_motor) / c.gear_efficiency_back)
    return (t_pinion - c.torsion_bar_damping_nms_per_rad * (w_col - xd / rp),
            t_pinion + c.column_damping_nms_per_rad * w_col)


def _linkage_stick_band(c, f_load: float) -> tuple[float, float]:
    """The torsion-bar torques (N m) between which the assist-off linkage holds the load f_load (N) at
    rest: every dry friction at its limit, against a leftward (pinion driving the rack, forward
    efficiency) or a rightward (the rack back-driving the pinion, back efficiency) start; the rotor is
    back-driven through the worm either way."""
    rp, n = c.rack_travel_per_rad_m, c.gear_ratio
    t_motor = n * c.motor_friction_nm / c.gear_efficiency_back
    lo = (f_load - c.rack_friction_n) * rp * c.rack_efficiency_back - c.pinion_friction_nm - t_motor
    hi = (f_load + c.rack_friction_n) * rp / c.rack_efficiency + c.pinion_friction_nm + t_motor
    return lo, hi


def test_assist_off_steering_wheel_torque_is_the_linkage_statics(model):
    """Assist off (the power stage's safe state: open winding, no current), 80 km/h held by the speed
    follower, a slow steer-in at 5 deg/s to 40 deg, then held.

    Steering in, the linkage is in steady sliding: the column turns at the commanded rate (the hands'
    lag died out long before) and the rack slides leftwards, its speed above every dry friction's
    band throughout the windows (asserted), so each friction is at its sliding value against the
    motion and each transmission in a known regime: the pinion drives the rack, the pinion back-drives
    the rotor through the worm. The rack still oscillates slightly at the column-rack mode (~11 Hz:
    the torsion bar against the rack, pinion and rotor, 184 kg at the rack of which 178 kg are the
    rotor seen through the worm; lightly damped with the winding open), so a single sample carries
    that mass's inertia force (at 20 deg/s up to ~4 % of the torque, and the rack then dips into the
    friction bands); over windows of many periods the mean rack acceleration, hence the inertia
    term, vanishes (asserted: < 0.1 % of the load), and the mean torques are the statics of the mean
    load, which enters linearly.
    Reference: the tie rods' load on the rack from the crank-rod constraints' multipliers, through
    the pinion radius, the forward rack efficiency, the frictions and the back-driven worm as the
    config declares them (_linkage_statics); the torsion-bar torque and the driver's torque within 2 %.

    Held: the dry frictions stick and their forces are indeterminate within their bands; the rack has
    come to rest (its speed well inside the bands) and the column is at rest, so the driver's torque
    is the torsion bar's, and it lies between the statics of a rightward and of a leftward breakaway
    (_linkage_stick_band) of the load at that moment."""
    sim = _sim(model, speed=22.22)
    sim.assist_off()
    c = sim.vm.config.eps
    rp, n = c.rack_travel_per_rad_m, c.gear_ratio
    m_rack = c.rack_mass_kg + (c.pinion_inertia_kgm2 + n * n * c.motor_inertia_kgm2) / rp ** 2
    driver = Driver(speed=speed_follower([0.0], [22.22]))
    state = np.zeros(NSTATE)
    ic, ir = sim.vm.vehicle.steer_idx
    rate, hold, t0 = 5.0, 40.0, 0.5
    log = []
    for k in range(10500):
        t = (k + 1) * 1e-3
        vehicle_state(sim, state)
        cmd = driver.step(t, state)
        sim.io.commands[CMD_THROTTLE] = cmd[I_THROTTLE]
        sim.io.commands[CMD_BRAKE] = cmd[I_BRAKE]
        sim.io.commands[CMD_STEER] = math.radians(min(hold, rate * max(0.0, t - t0)))
        sim.step()
        out = sim.io.eps_out
        log.append((t, out[E.EO_SW_TORQUE], out[E.EO_TB_TORQUE], _rack_load(sim), sim.data.qd[ir],
                    sim.data.qd[ic], state[DriverView.SPEED], out[E.EO_CURRENT]))
    t, t_drv, t_tb, f_load, xd, w_col, speed, current = np.array(log).T
    assert np.all(current == 0.0)
    band = max(c.rack_friction_band_m_s, c.pinion_friction_band_rad_s * rp,
               c.motor_friction_band_rad_s * rp / n)      # m/s at the rack
    for end in (4.5, 6.5, 8.4):                     # steering-wheel angle ~18, 28, 37 deg
        s = (t > end - 0.8) & (t <= end)
        assert speed[s].mean() == pytest.approx(22.22, rel=0.03)       # the follower holds 80 km/h
        assert np.allclose(w_col[s], math.radians(rate), rtol=1e-6)
        assert xd[s].min() > 1.5 * band                             # sliding: frictions at their limits
        inertia = m_rack * (xd[s][-1] - xd[s][0]) / (t[s][-1] - t[s][0])
        assert abs(inertia) < 1e-3 * f_load[s].mean()
        tb_ref, drv_ref = _linkage_statics(c, f_load[s].mean(), xd[s].mean(), w_col[s].mean())
        assert t_tb[s].mean() == pytest.approx(tb_ref, rel=0.02)
        assert t_drv[s].mean() == pytest.approx(drv_ref, rel=0.02)
    # held: 2 s after the wheel stopped
    assert abs(xd[-1]) < 0.5 * band and w_col[-1] == pytest.approx(0.0, abs=1e-9)
    assert t_drv[-1] == pytest.approx(t_tb[-1], rel=1e-3)
    lo, hi = _linkage_stick_band(c, f_load[-1])
    assert lo < t_tb[-1] < hi


def test_with_assist_the_torsion_bar_torque_sits_at_the_assist_laws_fixed_point(model):
    """Held in a steady turn: the pinion's static balance T_tb + e N Kt i(T_tb, v) = r_p F (e -> 1 at
    rest, frictions within their bands) solved for T_tb with the shipped law, against the simulated
    torsion-bar torque: within 2 %."""
    sim, log = _steady_turn(model)
    p = sim.parts.steering
    law = sim.vm.config.eps.assist
    table = map_2d(law.torque_nm, law.speed_mps, law.current_a)
    t, out, xd, f_load = log[-1]
    v = float(np.linalg.norm(sim.data.qd[sim.vm.vehicle.chassis_idx[:3]]))
    kt, n, rp = p[E.EP_KT], p[E.EP_N], p[E.EP_RP]

    def balance(ttb):
        i = map_eval(table, abs(ttb), v)
        return ttb + n * kt * i - rp * f_load
    t_fixed = brentq(balance, 0.0, rp * f_load)
    assert out[E.EO_TB_TORQUE] == pytest.approx(t_fixed, rel=0.02)
    assert out[E.EO_CURRENT] > 1.0                                 # the motor assists
    assert out[E.EO_TB_TORQUE] < 0.8 * rp * f_load                 # the driver carries less than all


def test_energy_balance_closes_over_an_on_centre_weave(model):
    """0.2 Hz sine steering at 100 km/h, about +-0.2 g, assist on: the balance closes to 1e-6."""
    sim = _sim(model, speed=27.78)
    sim.start_energy_audit()
    amp = math.radians(18.0)
    ay, state = [], np.zeros(NSTATE)
    for k in range(7500):
        t = (k + 1) * 1e-3
        sim.io.commands[CMD_STEER] = amp * math.sin(2 * math.pi * 0.2 * t)
        sim.step()
        vehicle_state(sim, state)
        ay.append(state[DriverView.SPEED] * sim.sensors()[5])      # v r: the yaw-rate acceleration (gyro_z)
    assert 0.12 * G < max(ay) < 0.35 * G
    b = _balance(sim)
    assert abs(b.residual) <= 1e-6 * b.exchanged
    assert b.flows["motor_supply"] > 0.0 and b.flows["driver_angle"] != 0.0


def test_driver_torque_mode_releases_to_centre(model):
    """Torque mode (a driver model or a person in the loop): a steering-wheel torque turns the car,
    released the self-aligning moment brings the wheel back towards the centre."""
    cfg = model.config.model_copy(update={"eps": model.config.eps.model_copy(update={"driver_input": "torque"})})
    vm = build_vehicle(cfg, model.base)
    assert vm.mech.model.nc == 20            # no driver's constraint
    sim = _sim(vm, speed=22.22)
    sim.io.extra[3] = 3.0                    # N m on the wheel
    sim.step(2000)
    held = sim.io.eps_out[E.EO_SW_ANGLE]
    assert held > math.radians(5.0) and sim.sensors()[1] > 0.5
    sim.io.extra[3] = 0.0
    sim.step(3000)
    assert abs(sim.io.eps_out[E.EO_SW_ANGLE]) < 0.3 * held
