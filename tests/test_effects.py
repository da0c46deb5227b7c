"""The switchable physical effects (rtsim.vehicle.car.effects): each against an analytic or independent
reference (coast-down and braking decelerations from Newton's law with the model's own masses, wheel
inertias and radii; a real 5 % grade road for the tilted gravity; first-order and oscillator responses;
the MF slip law), config validation errors, runtime switching, and the nominal model left bit-identical
when no effect is on. Differences between a run with the effect and a nominal run from the same state
cancel everything the effect does not touch."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtsim.channels import SENSOR_NAMES
from rtsim.errors import ConfigError
from rtsim.road.config import load_road
from rtsim.road.model import make_plane
from rtsim.vehicle.kit.actuators import LAG_RATE, LAG_TAU
from rtsim.vehicle.kit.brake import BP_ACT, BP_BREAK_RATIO, BP_GAIN, BP_K, BS_MODE
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_TORQUE_LEFT, EX_TORQUE_RIGHT, TyreOut
from rtsim.vehicle.car.effect_kernels import (BRAKE_STICTION_PRESSURE, DRIVELINE_DAMPING_RATIO, DRIVELINE_INERTIA,
                                              EffectState)
from rtsim.vehicle.car.effects import EFFECTS, effects_toml, validate_effects
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.kit.tyre.magic_formula import (advance_deflections_relaxed, effective_rolling_radius, loaded_radius,
                                              new_slip_state, relaxation_lengths, slip_stiffnesses,
                                              transient_slip_relaxed)

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "xbw.toml"
G = 9.81
DT = 1e-3


@pytest.fixture(scope="module")
def model():
    cfg, base = load_vehicle(VEHICLE)
    return build_vehicle(cfg, base)


@pytest.fixture(scope="module")
def road():
    return make_plane()


@pytest.fixture(scope="module")
def car(model, road):
    """Masses, wheel inertias and radii from the model's own parameters."""
    cfg = model.config
    sim = VehicleSim(model, road, DT)
    loads = model.static_loads
    j = np.array([cfg.front.wheel_spin_inertia_kgm2] * 2 + [cfg.rear.wheel_spin_inertia_kgm2] * 2)
    re = np.array([effective_rolling_radius(sim.tp, f) for f in loads])
    rl = np.array([loaded_radius(sim.tp, f) for f in loads])
    m = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    m_eff = m + float(np.sum(j / (re * rl)))        # translational + rolling wheels (omega = v / re)
    return {"m": m, "m_eff": m_eff, "rl": rl, "re": re, "tp": sim.tp, "rho": cfg.aero.air_density_kg_m3}


def _speed(sim) -> float:
    ci = sim.vm.vehicle.chassis_idx
    q, qd = sim.data.q, sim.data.qd
    u = q[ci[3]:ci[3] + 3]
    return float(qd[ci[0]:ci[0] + 3] @ u)


def _coasting(model, road, speed, effects=None, torque=0.0, pressure=0.0, **kw) -> VehicleSim:
    """A car rolling straight at `speed` with the measured wheel torques (0: coasting, no engine drag)."""
    sim = VehicleSim(model, road, DT, speed=speed, effects=effects, **kw)
    sim.set_torque_mode(True)
    sim.io.extra[EX_TORQUE_LEFT] = torque
    sim.io.extra[EX_TORQUE_RIGHT] = torque
    sim.io.commands[CMD_BRAKE] = pressure
    return sim


def _speeds(sim, t_end, every=10) -> np.ndarray:
    out = [_speed(sim)]
    for _ in range(int(round(t_end / DT)) // every):
        sim.step(every)
        out.append(_speed(sim))
    return np.array(out)


def _delta_accel(model, road, effects, speed, t1=0.5, t2=2.0, **kw) -> float:
    """Mean extra acceleration (m/s^2) the effects cause over [t1, t2] s against a nominal run."""
    v_fx = _speeds(_coasting(model, road, speed, effects, **kw), t2)
    v_0 = _speeds(_coasting(model, road, speed, **kw), t2)
    dv = v_fx - v_0
    i1, i2 = int(round(t1 / DT / 10)), int(round(t2 / DT / 10))
    return (dv[i2] - dv[i1]) / (t2 - t1)


# ---- model effects against analytic references -----------------------------------------------------------
def test_rolling_resistance_coast_down_decelerates_by_c_g(model, road, car):
    """A force c Fz per contact patch: sum c m g, shared by the car's mass and its rolling wheels."""
    c = 0.02
    da = _delta_accel(model, road, {"rolling_resistance": {"coefficient": c}}, 6.0)
    assert da == pytest.approx(-c * G * car["m"] / car["m_eff"], rel=0.02)


def test_aero_drag_decelerates_with_half_rho_cda_v_squared(model, road, car):
    """Extra drag area dA: dv/dt = -0.5 rho dA v^2 / m_eff, integrated along the run's own speeds."""
    da_area, t_end = 0.6, 1.0
    sim = _coasting(model, road, 25.0, {"aero_drag": {"drag_area": da_area}})
    v_fx = _speeds(sim, t_end)
    v_0 = _speeds(_coasting(model, road, 25.0), t_end)
    expected = -np.trapezoid(0.5 * car["rho"] * da_area * v_fx ** 2 / car["m_eff"], dx=10 * DT)
    assert v_fx[-1] - v_0[-1] == pytest.approx(expected, rel=0.03)


def test_road_grade_slows_a_coasting_car_by_g_sin_theta(model, road, car):
    grade = 0.05
    da = _delta_accel(model, road, {"road_grade": {"grade": grade}}, 6.0)
    assert da == pytest.approx(-G * math.sin(math.atan(grade)) * car["m"] / car["m_eff"], rel=0.02)


def test_road_grade_matches_a_real_graded_road(model, road):
    """Independent reference: the same car on the road model's 5 % grade (tilted surface, gravity
    vertical) against a flat road with the effect (tilted gravity): speeds and the inclinometer/
    accelerometer readings agree."""
    graded = load_road(ROOT / "configs" / "roads" / "grade_5pct.toml")
    a = _coasting(model, graded, 6.0, position=(2.0, 0.0))
    b = _coasting(model, road, 6.0, {"road_grade": {"grade": 0.05}}, position=(2.0, 0.0))
    va, vb = _speeds(a, 1.5), _speeds(b, 1.5)
    assert np.max(np.abs(va - vb)) < 0.01 * (va[0] - va[-1])
    ia, ib = SENSOR_NAMES.index("accel_x"), SENSOR_NAMES.index("pitch")
    sa, sb = a.sensors(), b.sensors()
    assert sb[ib] == pytest.approx(sa[ib], abs=2e-4)          # both about -atan(0.05), nose up
    assert sa[ib] == pytest.approx(-math.atan(0.05), abs=0.01)
    assert sb[ia] == pytest.approx(sa[ia], abs=0.01)           # specific force incl. g sin(theta)


def test_road_grade_at_rest_the_accelerometer_senses_the_tilted_gravity(model, road):
    sim = VehicleSim(model, road, DT, brake_pressure=3000.0, effects={"road_grade": {"grade": -0.08}})
    sim.step(1500)
    s = sim.sensors()
    pitch = s[SENSOR_NAMES.index("pitch")]
    assert pitch == pytest.approx(math.atan(0.08), abs=0.01)      # downhill ahead: nose down
    # the specific force at the IMU (at the centre of mass) is r'' - g': along the body x axis u,
    # accel_x = u.r'' + g u.up' = u.r'' - g sin(pitch reading); at rest r'' is only what is left of
    # the settling, and accel_z is about g cos(pitch)
    ci = sim.vm.vehicle.chassis_idx
    u = sim.data.q[ci[3]:ci[3] + 3]
    rdd = sim.data.qdd[ci[0]:ci[0] + 3]
    assert s[SENSOR_NAMES.index("accel_x")] - u @ rdd == pytest.approx(-G * math.sin(pitch), abs=1e-9)
    assert abs(u @ rdd) < 0.01
    assert s[SENSOR_NAMES.index("accel_z")] == pytest.approx(G * math.cos(pitch), abs=0.02)


def test_brake_friction_scales_the_braking_deceleration(model, road):
    """Deceleration due to the brakes (a run minus a coasting run) scales with the friction factor."""
    def dv(effects, pressure):
        v = _speeds(_coasting(model, road, 12.0, effects, pressure=pressure), 1.0)
        return v[100] - v[40]                   # 0.4 .. 1.0 s, after the pressure build-up
    coast = dv(None, 0.0)
    nominal = dv(None, 1500.0) - coast
    scaled = dv({"brake_friction": {"scale": 1.5}}, 1500.0) - coast
    assert scaled / nominal == pytest.approx(1.5, rel=0.02)


def test_brake_lag_step_response_reaches_63_percent_at_tau(model, road):
    """With the pressure actuator bypassed (the line pressure steps), the brake torque of a rolling wheel
    follows x' = (tau_s - x) / tau: 63.2 % of the step at t = tau."""
    tau = 0.08
    out = {}
    for name, eff in (("lag", {"brake_lag": {"time_constant": tau}}), ("nominal", None)):
        sim = _coasting(model, road, 12.0, eff)
        sim.parts.brake[BP_ACT + LAG_TAU] = 0.0
        sim.parts.brake[BP_ACT + LAG_RATE] = math.inf
        sim.step(100)
        sim.io.commands[CMD_BRAKE] = 1000.0
        torque = []
        for _ in range(300):
            sim.step(1)
            torque.append(-sim.vd.brake_torque[0])
        out[name] = np.array(torque)
    final = sim.parts.brake[BP_GAIN + 0] * 1000.0
    assert out["nominal"][0] == pytest.approx(final, rel=1e-9)            # no lag without the effect
    t = (np.arange(300) + 1) * DT
    crossing = t[np.argmax(out["lag"] >= (1 - math.exp(-1)) * final)]
    assert crossing == pytest.approx(tau, abs=1.5 * DT)
    assert out["lag"][-1] == pytest.approx(final * (1 - math.exp(-0.3 / tau)), rel=1e-3)


@pytest.mark.parametrize("pressure", [400.0, 60.0])
def test_brake_stiction_raises_the_breakaway_torque(model, road, pressure):
    """A rear wheel held by its brake breaks away when the drive torque makes the brake carry
    (mu_s/mu) tau_s + T_b min(1, p/p_ref): the largest torque the brake held before it slid."""
    t_b = 40.0
    held = {}
    for name, eff in (("stiction", {"brake_stiction": {"breakaway_torque": t_b}}), ("nominal", None)):
        sim = _coasting(model, road, 0.0, eff, pressure=pressure, brake_pressure=pressure)
        best = 0.0
        for n in range(4000):
            torque = 0.1 * n                       # 100 N*m/s ramp
            sim.io.extra[EX_TORQUE_LEFT] = sim.io.extra[EX_TORQUE_RIGHT] = torque
            sim.step(1)
            best = max(best, abs(sim.vd.brake_torque[2]))     # (the step that slips ends on the limit)
            if sim.states.brake[BS_MODE + 2] < 0.5:
                break
        else:
            pytest.fail("the rear wheel never broke away")
        held[name] = best
    bp = sim.parts.brake
    nominal = bp[BP_GAIN + 2] * pressure * bp[BP_BREAK_RATIO + 2]
    assert held["nominal"] == pytest.approx(nominal, rel=0.01)
    assert held["stiction"] == pytest.approx(nominal + t_b * min(1.0, pressure / BRAKE_STICTION_PRESSURE), rel=0.01)


def test_driveline_compliance_oscillates_at_sqrt_k_over_j(model, road):
    """Wheels held rigidly (stiff brake anchor), a drive-torque step: the shaft torque rings at the
    damped natural frequency of the node on its spring, sqrt(k/J) sqrt(1 - zeta^2), and settles at
    the applied torque."""
    k = 4000.0
    sim = _coasting(model, road, 0.0, {"driveline_compliance": {"stiffness": k}}, pressure=3000.0,
                    brake_pressure=3000.0)
    sim.parts.brake[BP_K] = 3e6                      # a rigid hold: the wheel is the fixed end
    sim.step(100)
    sim.io.extra[EX_TORQUE_LEFT] = sim.io.extra[EX_TORQUE_RIGHT] = 100.0
    shaft = []
    for _ in range(400):
        sim.step(1)
        shaft.append(sim.states.effects[EffectState.DL + 2])
    x = np.array(shaft) - 100.0
    ups = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    frac = -x[ups] / (x[ups + 1] - x[ups])             # linear interpolation of the crossings
    period = np.mean(np.diff(ups + frac)) * DT
    w_expected = math.sqrt(k / DRIVELINE_INERTIA) * math.sqrt(1 - DRIVELINE_DAMPING_RATIO ** 2)
    assert len(ups) >= 4
    assert 2 * math.pi / period == pytest.approx(w_expected, rel=0.02)
    assert abs(x[-1]) < 1.0


def test_tyre_slip_stiffness_scale_shows_in_wheel_slip(model, road, car):
    """Same drive torque, slip stiffness x s: the driven wheels' slip ratio is 1/s of the nominal one,
    and the nominal slip is Fx / Kxk(Fz) (MF slip stiffness) in the linear range."""
    def slips(eff):
        sim = _coasting(model, road, 10.0, eff, torque=150.0)
        sim.step(1000)
        t = sim.vd.tyre[2:4]
        return (t[:, TyreOut.OMEGA] * t[:, TyreOut.RE] - t[:, TyreOut.VX]) / t[:, TyreOut.VX], t
    s = 0.5
    k1, t1 = slips(None)
    ks, _ = slips({"tyre_slip_stiffness": {"scale": s}})
    np.testing.assert_allclose(ks / k1, 1 / s, rtol=0.03)
    kxk = np.array([slip_stiffnesses(car["tp"], fz, 0.0)[0] for fz in t1[:, TyreOut.FZ]])
    np.testing.assert_allclose(k1, t1[:, TyreOut.FX] / kxk, rtol=0.1)


def test_tyre_relaxation_lengthens_the_first_order_slip_response(car):
    """At constant speed and slip velocity the contact deflection obeys u' = -Vsx - |Vx| u / sigma:
    u(t) = -Vsx sigma/|Vx| (1 - exp(-|Vx| t / sigma)) with sigma = sigma_0 + L."""
    tp, fz, vx, vsx, L = car["tp"], 2500.0, 10.0, -0.1, 0.4
    re = effective_rolling_radius(tp, fz)
    omega = (vx - vsx) / re
    sigma = relaxation_lengths(tp, fz, 0.0)[0] + L
    st = new_slip_state(1)
    n = 60
    for _ in range(n):
        advance_deflections_relaxed(tp, st, 0, fz, 0.0, vx, 0.0, omega, re, DT, L)
    u_ss = -vsx * sigma / vx
    assert st[0, 0] == pytest.approx(u_ss * (1 - math.exp(-vx * n * DT / sigma)), rel=1e-9)
    kappa, _ = transient_slip_relaxed(tp, st, 0, fz, 0.0, vx, 0.0, omega, re, L)
    assert kappa < -vsx / vx                        # still building up towards the steady slip


def test_tyre_relaxation_delays_the_yaw_response_but_not_its_steady_state(model, road):
    speed, L = 15.0, 0.6
    rates = {}
    for name, eff in (("relaxed", {"tyre_relaxation": {"length": L}}), ("nominal", None)):
        sim = _coasting(model, road, speed, eff)
        sim.io.extra[EX_TORQUE_LEFT] = sim.io.extra[EX_TORQUE_RIGHT] = 40.0      # about the rolling losses
        sim.step(200)
        sim.io.commands[CMD_STEER] = math.radians(30.0)
        r = []
        for _ in range(250):
            sim.step(8)
            r.append(sim.sensors()[SENSOR_NAMES.index("gyro_z")])
        rates[name] = np.array(r)
    final = rates["nominal"][-1]
    assert rates["relaxed"][-1] == pytest.approx(final, rel=0.03)
    t50 = {k: np.argmax(v >= 0.5 * final) * 8 * DT for k, v in rates.items()}
    assert t50["relaxed"] - t50["nominal"] > 0.3 * L / speed


def test_bearing_drag_coast_down(model, road, car):
    """A drag torque T on each wheel: dv/dt = -sum(T / r_l) / m_eff."""
    t = 5.0
    da = _delta_accel(model, road, {"bearing_drag": {"torque": t}}, 6.0)
    assert da == pytest.approx(-float(np.sum(t / car["rl"])) / car["m_eff"], rel=0.02)


def test_added_mass_carries_its_weight_and_slows_acceleration(model, road, car):
    """dm at the centre of mass: the tyres carry (m + dm) g at rest, and a drive torque's acceleration
    scales by m_eff / (m_eff + dm)."""
    dm = 120.0
    sim = VehicleSim(model, road, DT, brake_pressure=2000.0, effects={"mass": {"added_mass": dm}})
    sim.step(3000)
    assert float(np.sum(sim.vd.tyre[:, TyreOut.FZ])) == pytest.approx((car["m"] + dm) * G, rel=2e-3)

    def drive_part(eff):                     # acceleration due to the drive torque alone
        return _accel(model, road, eff, 200.0) - _accel(model, road, eff, 0.0)
    ratio = drive_part({"mass": {"added_mass": dm}}) / drive_part(None)
    assert ratio == pytest.approx(car["m_eff"] / (car["m_eff"] + dm), rel=0.02)


def _accel(model, road, eff, torque, t1=0.5, t2=1.5) -> float:
    v = _speeds(_coasting(model, road, 8.0, eff, torque=torque), t2)
    return (v[int(t2 / DT / 10)] - v[int(t1 / DT / 10)]) / (t2 - t1)


# ---- sensor effects ----------------------------------------------------------------------------------
def test_sensor_effects_act_exactly_on_their_channels(model, road):
    """Sensor effects leave the dynamics bit-identical; bias and scale are exact, an integer-step delay
    shows exactly the earlier sample, a fractional one the linear interpolation between steps."""
    fx = {"sensor_bias": [{"channel": "gyro_z", "bias": 0.01}],
          "sensor_scale": {"channel": "wheel_angle_fl", "scale": 1.02},
          "sensor_delay": [{"channel": "accel_x", "delay": 0.012}, {"channel": "brake_pressure", "delay": 0.0105}]}
    a = VehicleSim(model, road, DT, speed=5.0, effects=fx)
    b = VehicleSim(model, road, DT, speed=5.0)
    ya, yb = [], []
    for n in range(400):
        for sim in (a, b):
            sim.io.commands[CMD_THROTTLE] = 0.3 * (n > 50)
            sim.io.commands[CMD_BRAKE] = 800.0 * (n > 200)
            sim.io.commands[CMD_STEER] = 0.2 * math.sin(n * 0.02)
            sim.step(1)
        ya.append(a.sensors().copy())
        yb.append(b.sensors().copy())
    ya, yb = np.array(ya), np.array(yb)
    assert np.array_equal(a.data.q, b.data.q) and np.array_equal(a.data.qd, b.data.qd)
    c = {name: SENSOR_NAMES.index(name) for name in ("gyro_z", "wheel_angle_fl", "accel_x", "brake_pressure")}
    np.testing.assert_allclose(ya[:, c["gyro_z"]], yb[:, c["gyro_z"]] + 0.01, rtol=0, atol=1e-15)
    np.testing.assert_allclose(ya[:, c["wheel_angle_fl"]], 1.02 * yb[:, c["wheel_angle_fl"]], rtol=1e-15)
    assert np.array_equal(ya[12:, c["accel_x"]], yb[:-12, c["accel_x"]])
    np.testing.assert_allclose(ya[11:, c["brake_pressure"]],
                               0.5 * (yb[1:-10, c["brake_pressure"]] + yb[:-11, c["brake_pressure"]]), rtol=1e-12)
    others = [i for i in range(len(SENSOR_NAMES)) if i not in c.values()]
    assert np.array_equal(ya[:, others], yb[:, others])


def test_sensor_delay_holds_the_first_value_before_the_history_starts(model, road):
    sim = VehicleSim(model, road, DT, speed=5.0, effects={"sensor_delay": [{"channel": "accel_x", "delay": 0.05}]})
    first = sim.sensors()[0]
    sim.io.commands[CMD_BRAKE] = 2000.0
    sim.step(30)
    assert sim.sensors()[0] == first


# ---- config, validation, switching ---------------------------------------------------------------------
def _vehicle_file(tmp_path, extra: str) -> Path:
    text = VEHICLE.read_text().replace('property_file = "../tyres/', f'property_file = "{ROOT}/configs/tyres/')
    p = tmp_path / "car.toml"
    p.write_text(text + "\n" + extra)
    return p


def test_config_effects_load_and_round_trip_through_toml(tmp_path):
    fx = {"rolling_resistance": {"coefficient": 0.012}, "brake_lag": {"time_constant": 0.03},
          "sensor_bias": [{"channel": "accel_x", "bias": 0.1}, {"channel": "gyro_z", "bias": -0.002}],
          "sensor_delay": [{"channel": "wheel_angle_rl", "delay": 0.01}]}
    cfg, _ = load_vehicle(_vehicle_file(tmp_path, effects_toml(fx)))
    assert cfg.effects == fx
    single = '[effects.sensor_scale]\nchannel = "accel_y"\nscale = 1.1\n'
    cfg, _ = load_vehicle(_vehicle_file(tmp_path, single))
    assert cfg.effects == {"sensor_scale": [{"channel": "accel_y", "scale": 1.1}]}
    cfg, _ = load_vehicle(VEHICLE)
    assert cfg.effects == {}


@pytest.mark.parametrize("text, expect", [
    ("[effects.rolling_resistance]\ncoefficient = 0.2\n",
     ["effects.rolling_resistance.coefficient = 0.2", "allowed 0 <= coefficient <= 0.05"]),
    ("[effects.air_drag]\ndrag_area = 0.2\n", ["effects.air_drag = {", "unknown key", "aero_drag"]),
    ("[effects.aero_drag]\narea = 0.2\n", ["effects.aero_drag.area = 0.2", "unknown key", "drag_area"]),
    ("[effects.brake_lag]\n", ["effects.brake_lag.time_constant: missing"]),
    ("[effects.mass]\nadded_mass = \"heavy\"\n", ["effects.mass.added_mass = 'heavy'", "must be a number"]),
    ("[[effects.sensor_bias]]\nchannel = \"speed\"\nbias = 0.1\n", ["effects.sensor_bias[0].channel = 'speed'",
                                                                      "not a sensor channel"]),
    ("[[effects.sensor_bias]]\nchannel = \"accel_x\"\nbias = 5.0\n",
     ["effects.sensor_bias[0].bias = 5.0", "allowed -2 <= bias <= 2 m/s^2"]),
    ("[[effects.sensor_delay]]\nchannel = \"accel_x\"\ndelay = 0.01\n[[effects.sensor_delay]]\n"
     "channel = \"accel_x\"\ndelay = 0.02\n", ["effects.sensor_delay[1].channel = 'accel_x'", "given twice"]),
    ("[[effects.road_grade]]\ngrade = 0.01\n", ["effects.road_grade", "not an array"]),
    ("[effects.driveline_compliance]\nstiffness = nan\n", ["stiffness = nan", "allowed 300 <= stiffness <= 100000 N*m/rad"]),
])
def test_config_errors_name_file_key_value_and_range(tmp_path, text, expect):
    path = _vehicle_file(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_vehicle(path)
    msg = str(err.value)
    assert str(path) in msg and "\n" not in msg
    for part in expect:
        assert part in msg


def test_set_effects_rejects_bad_values_and_keeps_the_active_set(model, road):
    sim = VehicleSim(model, road, DT, effects={"aero_drag": {"drag_area": 0.2}})
    with pytest.raises(ConfigError, match="tyre_slip_stiffness.scale = 10"):
        sim.set_effects({"tyre_slip_stiffness": {"scale": 10.0}})
    assert sim.effects == {"aero_drag": {"drag_area": 0.2}}


def test_catalogue_has_the_issue_names_and_sane_ranges():
    want = {"rolling_resistance": ("coefficient",), "aero_drag": ("drag_area",), "road_grade": ("grade",),
            "brake_friction": ("scale",), "brake_stiction": ("breakaway_torque",), "brake_lag": ("time_constant",),
            "driveline_compliance": ("stiffness",), "tyre_slip_stiffness": ("scale",), "tyre_relaxation": ("length",),
            "bearing_drag": ("torque",), "mass": ("added_mass",), "sensor_delay": ("delay",),
            "sensor_bias": ("bias",), "sensor_scale": ("scale",)}
    assert {n: e.param_names for n, e in EFFECTS.items()} == want
    for e in EFFECTS.values():
        assert e.kind == ("sensor" if e.name.startswith("sensor_") else "model")
        assert e.description and e.signature
        for p in e.params:
            lo, hi = e.bounds(p.name, "accel_x")
            assert lo < hi and (p.neutral is None or lo <= p.neutral <= hi)
            if e.name != "sensor_bias":
                assert lo <= p.default <= hi
    assert validate_effects(None) == {} and validate_effects({}) == {}


def _trajectory(sim, n=1500) -> tuple:
    rows = []
    for k in range(n):
        sim.io.commands[CMD_THROTTLE] = 0.4 if k < 800 else 0.0
        sim.io.commands[CMD_BRAKE] = 1500.0 if k > 1000 else 0.0
        sim.io.commands[CMD_STEER] = 0.3 if k > 300 else 0.0
        sim.step(1)
        if k % 50 == 0:
            rows.append(sim.sensors().copy())
    return sim.data.q.copy(), sim.data.qd.copy(), np.array(rows), sim.data.stats.copy(), sim.vd.tyre.copy()


def test_no_effect_is_bit_identical_to_the_nominal_model(model, road):
    """No effect, effects={} and effects switched on and off again before the run give identical
    results, bit for bit (the effect code is skipped, not neutralised)."""
    ref = _trajectory(VehicleSim(model, road, DT, speed=3.0))
    runs = [VehicleSim(model, road, DT, speed=3.0, effects={})]
    sim = VehicleSim(model, road, DT, speed=3.0, effects={"mass": {"added_mass": 100.0},
                                                          "sensor_delay": [{"channel": "gyro_z", "delay": 0.1}]})
    sim.set_effects({})
    runs.append(sim)
    for sim in runs:
        for a, b in zip(ref, _trajectory(sim)):
            assert np.array_equal(a, b)


def test_effects_at_start_equal_set_effects_and_switch_at_runtime(model, road):
    fx = {"rolling_resistance": {"coefficient": 0.015}, "brake_friction": {"scale": 1.2},
          "driveline_compliance": {"stiffness": 8000.0}}
    a = VehicleSim(model, road, DT, speed=3.0, effects=fx)
    b = VehicleSim(model, road, DT, speed=3.0)
    b.set_effects(fx)
    cfg = model.config.model_copy(update={"effects": fx})
    c = VehicleSim(replace(model, config=cfg), road, DT, speed=3.0)     # from the config's [effects]
    assert a.effects == b.effects == c.effects == validate_effects(fx)
    ra, rb, rc = _trajectory(a), _trajectory(b), _trajectory(c)
    for x, y, z in zip(ra, rb, rc):
        assert np.array_equal(x, y) and np.array_equal(x, z)
    # switching mid-run: the run with the effect diverges from the nominal one from that step on
    d = _coasting(model, road, 8.0)
    e = _coasting(model, road, 8.0)
    d.step(500)
    e.step(500)
    assert _speed(d) == _speed(e)
    e.set_effects({"aero_drag": {"drag_area": 1.0}})
    d.step(500)
    e.step(500)
    assert _speed(e) < _speed(d) - 0.02
    e.set_effects({})
    d.step(10)
    e.step(10)
    assert e.effects == {}


def test_changing_a_parameter_mid_run_continues_the_effect_states(model, road):
    """Re-setting a lag or a driveline stiffness between steps keeps the lagged brake torque and the
    shaft torque continuous (no reset to the steady value)."""
    sim = _coasting(model, road, 10.0, {"brake_lag": {"time_constant": 0.2},
                                        "driveline_compliance": {"stiffness": 3000.0}}, torque=80.0)
    sim.step(50)
    sim.io.commands[CMD_BRAKE] = 1500.0
    sim.step(60)
    before = -sim.vd.brake_torque[0], sim.states.effects[EffectState.DL + 2]
    sim.step(1)
    one_step = -sim.vd.brake_torque[0] - before[0]
    sim.set_effects({"brake_lag": {"time_constant": 0.1}, "driveline_compliance": {"stiffness": 6000.0}})
    shaft = sim.states.effects[EffectState.DL + 2]
    sim.step(1)
    after = -sim.vd.brake_torque[0]
    assert 0.0 < after - (before[0] + one_step) < 3.0 * one_step          # faster lag, but no jump
    assert abs(sim.states.effects[EffectState.DL + 2] - shaft) < 5.0        # N*m, against 80 applied
    assert before[0] < 0.5 * sim.parts.brake[BP_GAIN] * 1500.0            # still far from the final torque
