"""Offline runs of the motorcycle's scenarios (a scenario file with [rider] and/or [two_wheeler], loaded by
drivers.scenario and handed in: the vehicle never imports its drivers): the rider or the open-loop profiles on
the two-wheeler sim, as fast as the machine allows, logged at the scenario's output rate to CSV or MCAP
(`CHANNELS`: the car's state names where the quantity is the same, `_f`/`_r` for the front and rear wheel),
and a summary of what the manoeuvre measures against its analytic reference:

- every run: status (`ok`, or `fall` with the time and the reason: roll past 70 deg, both tyres off the
  road, pitched over), distance, speeds, peak roll;
- a rider: the lateral error to the path (RMS after the first second, peak);
- a steering-torque profile (open loop): the counter-steering signs, the first yaw rate after the torque
  step and the last (`counter_steering`);
- a circle: the steady turn over the last third of the run: roll against atan(u^2 kappa / g) and its
  crown correction (`steady_turn`), the steady steering torque;
- brakes: deceleration, loads, fork travel and stopping distance against mu g and g b / h
  (`braking`).

A fall never leaves a NaN or a traceback: the run stops, the rows so far are written, the summary says
`fall` and the command exits non-zero.
"""
from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .rider import RiderState
from rtsim.channels import TWO_WHEELER_STATE, Channel, ChannelDictionary
from rtsim.compile_status import CompileClock
from rtsim.errors import ConfigError, SimulationError
from rtsim.model_fault import ModelFault, describe_error, force_failure, test_fault_step, test_fault_time
from rtsim.configfile import problem
from rtsim.mbs.model import gravity

from .build import build_motorcycle, combine
from .config import Body, load_motorcycle, refuse_effects
from .layout import K_E1, K_P
from .plant import plant_state
from .ride import Ride, tyre_lean_ratio
from .sim import Fall, TwoWheelerSim, static_pose
from .step import MP_MU, TO_FZ, U_BRAKE_FRONT, U_BRAKE_REAR

PITCH_OVER = math.radians(45.0)      # rad: the rear frame pitched nose-down past this has gone over the front


def _c(name, unit, text):
    return Channel(name, unit, text)


#: The columns of a run (after `time`): the two-wheeler's state channels (rtsim.channels, as the HIL
#: service publishes them), then what only an offline run reports.
OFFLINE_ONLY = (
    _c("accel_forward", "m/s^2", "forward acceleration of the swingarm pivot, heading frame"),
    _c("pitch_change", "rad", "rear frame pitch from the static pose, positive nose down"),
    _c("brake_torque_front", "N*m", "front brake torque"),
    _c("brake_torque_rear", "N*m", "rear brake torque"),
    _c("roll_reference", "rad", "rider: lean reference"),
)
CHANNELS = ChannelDictionary(sensors=(), commands=(), state=TWO_WHEELER_STATE + OFFLINE_ONLY)
COLUMNS = ("time", *CHANNELS.state_names)


@dataclass
class MotorcycleRun:
    columns: tuple[str, ...]
    data: np.ndarray
    wall_s: float
    steps: int
    status: str = "ok"
    message: str = ""
    fall_time: float | None = None
    summary: dict = field(default_factory=dict)
    fault: ModelFault | None = None     # a model failure (not a fall) that ended the run: step, time, coordinate
    step_s: float = 0.0                 # s of wall time inside the two-wheeler's steps (Ride.step_s), compilations excluded

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.columns.index(name)]


def check_flat_road(sc) -> float:
    """The road's friction scale; ConfigError unless it is the flat plane z = 0 (the two-wheeler's
    contact is computed on that plane only)."""
    from rtsim.road.config import FlatRoadConfig, read_road_config

    cfg = read_road_config(sc.road_path)
    if not isinstance(cfg, FlatRoadConfig) or cfg.height != 0.0 or cfg.rolling_resistance != 0.0:
        raise problem(sc.path, "road", sc.spec.road, "the two-wheeler runs on a flat road at height 0 without "
                      "surface rolling resistance only (its tyres carry their own)")
    return cfg.mu


def prepare(vehicle: str | Path | None, sc, mm=None) -> tuple[Ride, object]:
    """The ride of a motorcycle scenario ``sc`` (a loaded drivers.scenario.Scenario): the vehicle
    (argument, else the scenario's), its static pose with the rider on, straight running at the initial
    speed from the origin heading +x, the rider (its tyre-crown lean ratio from the vehicle unless the
    scenario sets `tyre_lean`) and the open-loop profiles. ``mm``: the vehicle's model when already built
    (rtsim.vehicle.registry), else built from its file."""
    if not sc.two_wheeler:
        raise ConfigError(f"{sc.path}: not a two-wheeler scenario (no [rider] or [two_wheeler])")
    ini = sc.spec.initial
    if ini.x != 0.0 or ini.y != 0.0 or ini.yaw != 0.0:
        raise problem(sc.path, "initial", f"x = {ini.x}, y = {ini.y}, yaw = {ini.yaw}",
                      "a two-wheeler starts at the origin heading +x (paths are given in that frame)")
    mu = check_flat_road(sc)
    vpath = vehicle if vehicle is not None else sc.vehicle_path
    if vpath is None:
        raise problem(sc.path, "vehicle", None, "a two-wheeler scenario names its vehicle file (or give --vehicle)")
    if mm is None:
        cfg, base = load_motorcycle(vpath)
        refuse_effects(cfg, vpath, "the offline ride")
        mm = build_motorcycle(cfg, base)
    refuse_effects(mm.config, vpath, "the offline ride")
    q, loads = static_pose(mm, dt=sc.dt)
    sim = TwoWheelerSim(mm, dt=sc.dt, speed=ini.speed, q=q, mu=mu)
    rider = None
    if sc.spec.rider is not None:
        spec = sc.spec.rider
        if "tyre_lean" not in spec.model_fields_set:
            spec = spec.model_copy(update={"tyre_lean": tyre_lean_ratio(mm)})
        rider = spec.model_copy(update={"period": sc.dt}).build() if "period" not in spec.model_fields_set \
            else spec.build()
    tw = sc.spec.two_wheeler
    gear = None if tw is None else tw.gear
    ride = Ride(sim, rider, gear=gear, open_loop=sc.open_loop())
    ride.pitch0 = _pitch(sim)
    ride.static_loads = loads
    sim.parts.tyre[:, TO_FZ] = loads       # the first row's loads: the static pose's
    return ride, sc


def _pitch(sim: TwoWheelerSim) -> float:
    """Nose-down angle of the frame's forward axis below the horizontal, rad."""
    k = sim.parts.idx[K_E1]
    return math.asin(max(-1.0, min(1.0, -float(sim.data.q[k + 2]))))


def _row(ride: Ride, row: np.ndarray) -> None:
    """One output row: time, the state channels (rtsim.vehicle.motorcycle.plant.plant_state), OFFLINE_ONLY."""
    s = ride.sim
    idx, u = s.parts.idx, s.parts.u
    st = ride.rider.st if ride.rider is not None else None
    n = len(TWO_WHEELER_STATE)
    plant_state(s.data, idx, s.parts.par, ride.params.pp, s.parts.tyre, ride.state.inp, ride.engine_state,
                st[RiderState.N] if st is not None else 0.0, row[1:1 + n])
    kp = idx[K_P]
    qdd = s.data.qdd
    yaw = s.yaw
    row[0] = s.time
    row[1 + n:] = (qdd[kp] * math.cos(yaw) + qdd[kp + 1] * math.sin(yaw), _pitch(s) - ride.pitch0,
                   u[U_BRAKE_FRONT], u[U_BRAKE_REAR], st[RiderState.PHI_REF] if st is not None else 0.0)


def run(ride: Ride, sc, progress=None) -> MotorcycleRun:
    """Run to the scenario's duration or a fall; rows at the output rate; the summary filled in."""
    dt = sc.dt
    nsteps = int(round(sc.duration / dt))
    every = max(1, int(round(1.0 / (sc.spec.output_rate * dt))))
    rows = np.zeros((nsteps // every + 2, len(COLUMNS)))
    nrow = 0
    status, message, t_fall = "ok", "", None
    forced = test_fault_step(test_fault_time(), dt)     # rtsim.model_fault's test-only hook
    fault = None
    t0 = time.perf_counter()
    n = 0
    step0 = ride.step_s
    with CompileClock() as clock:      # a first run compiles in its first steps: neither step time nor the run's
        try:
            for n in range(nsteps + 1):
                if n % every == 0:
                    _row(ride, rows[nrow])
                    nrow += 1
                    if progress is not None and nrow % 50 == 0:
                        progress(n / nsteps)
                if n == nsteps:
                    break
                if forced == n + 1:
                    force_failure(ride.sim)
                ride.step()
                if abs(_pitch(ride.sim) - ride.pitch0) > PITCH_OVER:
                    raise Fall(f"{ride.sim.mm.config.id}: pitched over at t = {ride.sim.time:.3f} s", ride.sim.time)
        except SimulationError as exc:
            status = "fall" if isinstance(exc, Fall) else "failed"
            message, t_fall = str(exc), ride.sim.time
            if status == "failed":
                fault = describe_error(ride.sim, exc, n + 1)
            if np.all(np.isfinite(ride.sim.data.q)):
                _row(ride, rows[nrow])
                nrow += 1
    wall = time.perf_counter() - t0
    res = MotorcycleRun(COLUMNS, rows[:nrow], max(wall - clock.seconds, 0.0), n, status, message, t_fall, fault=fault,
                        step_s=max(ride.step_s - step0 - clock.seconds, 0.0))
    res.summary = summarise(res, ride, sc)
    return res


# ---- the summary -------------------------------------------------------------------------------------


def mass_centre(mm) -> tuple[float, float, float]:
    """(mass kg, x, z m) of the whole machine with the rider at the design position (x from the rear
    contact)."""
    cfg = mm.config
    wheels = [Body(mass_kg=w.mass_kg, cg_m=(x, w.radius_m)) for w, x in
              ((cfg.front_wheel, cfg.geometry.wheelbase_m), (cfg.rear_wheel, 0.0))]
    bodies = [b for b in (cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork) if b is not None]
    m, cg, _ = combine(*bodies, *wheels)
    return float(m), float(cg[0]), float(cg[2])


def _f(x, nd=4):
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def summarise(res: MotorcycleRun, ride: Ride, sc) -> dict:
    c = res.column
    t = c("time")
    out: dict = {"scenario": sc.name, "status": res.status, "simulated_s": _f(t[-1] if t.size else 0.0, 3)}
    if res.status != "ok":
        out["message"], out["fall_time_s"] = res.message, _f(res.fall_time, 3)
    if res.fault is not None:
        out["model_fault"] = res.fault.as_dict()
    if t.size < 2:
        return out
    out["distance_m"] = _f(float(np.sum(np.hypot(np.diff(c("pos_x")), np.diff(c("pos_y"))))), 2)
    out["speed_start_end_m_s"] = [_f(c("speed")[0], 3), _f(c("speed")[-1], 3)]
    out["peak_roll_deg"] = _f(math.degrees(float(np.max(np.abs(c("roll_angle"))))), 2)
    if ride.rider is not None:
        n = c("path_offset")[t > 1.0]
        if n.size:
            out["lateral_error_rms_m"] = _f(float(np.sqrt(np.mean(n ** 2))), 4)
            out["lateral_error_peak_m"] = _f(float(np.max(np.abs(n))), 4)
        out["peak_steering_torque_nm"] = _f(float(np.max(np.abs(c("steering_torque")))), 2)
    tw = sc.spec.two_wheeler
    if tw is not None and tw.steering_torque is not None:
        out["counter_steering"] = _counter_steering(res)
    if sc.spec.rider is not None and sc.spec.rider.circle is not None:
        out["steady_turn"] = _steady_turn(res, ride, sc.spec.rider.circle.radius)
    if tw is not None and (tw.brake_front is not None or tw.brake_rear is not None):
        out["braking"] = _braking(res, ride)
    return out


def _counter_steering(res: MotorcycleRun) -> dict:
    c = res.column
    t, tau, r = c("time"), c("steering_torque"), c("yaw_rate")
    on = np.nonzero(np.abs(tau) > 1e-9)[0]
    if on.size == 0:
        return {}
    i0 = on[0]
    sign = float(np.sign(tau[i0]))
    after = np.nonzero(np.abs(r[i0:]) > 5e-3)[0]
    first = float(r[i0 + after[0]]) if after.size else 0.0
    last = float(r[-1])
    return {"torque_onset_s": _f(t[i0], 3), "torque_nm": _f(tau[i0 + min(10, t.size - 1 - i0)], 3),
            "first_yaw_rate_rad_s": _f(first, 5), "final_yaw_rate_rad_s": _f(last, 5),
            "final_roll_deg": _f(math.degrees(c("roll_angle")[-1]), 3),
            "initial_turn_with_the_steer": bool(np.sign(first) == sign),
            "final_turn_against_the_steer": bool(np.sign(last) == -sign)}


def _g(mm) -> float:
    """The magnitude of the two-wheeler's gravity, m/s^2: the multibody model's (its vector is vertical)."""
    return float(-gravity(mm.mech.model)[2])


def _steady_turn(res: MotorcycleRun, ride: Ride, radius: float) -> dict:
    c = res.column
    t = c("time")
    win = t >= t[-1] - t[-1] / 3.0
    u = float(np.mean(c("speed")[win]))
    roll = float(np.mean(c("roll_angle")[win]))
    phi0 = math.atan(u * u / (_g(ride.sim.mm) * radius))
    k = tyre_lean_ratio(ride.sim.mm)
    ref = phi0 + math.asin(k * math.sin(phi0))
    return {"window_s": [_f(t[win][0], 2), _f(t[-1], 2)], "radius_m": radius, "speed_m_s": _f(u, 4),
            "roll_deg": _f(-math.degrees(roll), 3), "roll_std_deg": _f(math.degrees(float(np.std(c("roll_angle")[win]))), 3),
            "atan_u2_over_gR_deg": _f(math.degrees(phi0), 3), "crown_corrected_reference_deg": _f(math.degrees(ref), 3),
            "roll_over_reference": _f(-roll / ref, 4),
            "steer_deg": _f(math.degrees(float(np.mean(c("steer_angle")[win]))), 3),
            "steering_torque_nm": _f(float(np.mean(c("steering_torque")[win])), 3),
            "lateral_error_mean_m": _f(float(np.mean(c("path_offset")[win])), 4)}


def braking_limits(ride: Ride) -> dict:
    """The analytic limits of a straight-line stop: the front tyre's grip with all the weight on it, and
    the stoppie, where the rear load reaches zero: a = g b / h (b: the mass centre's distance behind
    the front contact, h its height) -- from the design geometry."""
    mm = ride.sim.mm
    g = _g(mm)
    m, x, h = mass_centre(mm)
    b = mm.config.geometry.wheelbase_m - x
    from .parts import make_parts
    from ..kit.tyre.two_wheel import two_wheel_friction

    tp = make_parts(mm).tp
    mu_front = two_wheel_friction(tp[0], m * g, ride.sim.parts.par[MP_MU])[0] / (m * g)
    return {"mass_kg": _f(m, 2), "cg_height_m": _f(h, 4), "cg_to_front_contact_m": _f(b, 4),
            "stoppie_decel_m_s2": _f(g * b / h, 4), "front_grip_decel_m_s2": _f(mu_front * g, 4)}


def _braking(res: MotorcycleRun, ride: Ride) -> dict:
    c = res.column
    t, v = c("time"), c("speed")
    braking = (c("brake_torque_front") + c("brake_torque_rear")) > 1.0
    if not braking.any():
        return {}
    i0 = int(np.argmax(braking))
    stopped = np.nonzero((v < 0.5) & (t > t[i0]))[0]
    i1 = int(stopped[0]) if stopped.size else t.size - 1
    x, y = c("pos_x"), c("pos_y")
    dist = float(np.sum(np.hypot(np.diff(x[i0:i1 + 1]), np.diff(y[i0:i1 + 1]))))
    seg = slice(i0, i1 + 1)
    decel = -c("accel_forward")[seg]
    # the deceleration of the speed itself over 50 ms (the pivot's acceleration also holds the pitch motion)
    k = max(1, int(round(0.05 / max(t[1] - t[0], 1e-9))))
    vs, ts = v[seg], t[seg]
    d_speed = (vs[:-k] - vs[k:]) / (ts[k:] - ts[:-k]) if vs.size > k else np.zeros(1)
    # the steady phase: pressure at its final value and above 3 m/s (below the brakes' regularisation and
    # low-speed tyre terms act)
    full = (c("brake_torque_front")[seg] >= 0.98 * np.max(c("brake_torque_front"))) & (v[seg] > 3.0)
    lim = braking_limits(ride)
    a_lim = min(lim["stoppie_decel_m_s2"], lim["front_grip_decel_m_s2"])
    v0 = float(v[i0])
    m = lim["mass_kg"]
    out = {"brake_onset_s": _f(t[i0], 3), "speed_at_onset_m_s": _f(v0, 3), "stopped": bool(stopped.size),
           "stop_time_s": _f(t[i1] - t[i0], 3), "stopping_distance_m": _f(dist, 3),
           "mean_decel_m_s2": _f(v0 ** 2 / (2.0 * dist) if stopped.size and dist > 0 else None, 4),
           "steady_decel_m_s2": _f(float(np.mean(decel[full])) if full.any() else None, 4),
           "peak_decel_m_s2": _f(float(np.max(d_speed)), 4),
           "front_load_max_n": _f(float(np.max(c("tyre_fz_front")[seg])), 1),
           "rear_load_min_n": _f(float(np.min(c("tyre_fz_rear")[seg])), 1),
           "static_loads_n": [_f(ride.static_loads[0], 1), _f(ride.static_loads[1], 1)],
           "rear_lifted_s": _f(float(np.sum(c("tyre_fz_rear")[seg] <= 0.0)) * (t[1] - t[0]), 3),
           "front_locked_s": _f(float(np.sum(c("tyre_slip_ratio_front")[seg] < -0.5)) * (t[1] - t[0]), 3),
           "fork_travel_max_m": _f(float(np.max(c("fork_travel")[seg])), 4),
           "fork_dive_m": _f(float(np.max(c("fork_travel")[seg]) - c("fork_travel")[0]), 4),
           "pitch_max_deg": _f(math.degrees(float(np.max(c("pitch_change")[seg]))), 3),
           **{f"limit_{k}": val for k, val in lim.items() if k != "mass_kg"},
           "limit_decel_m_s2": _f(a_lim, 4),
           "limit_stopping_distance_m": _f(v0 ** 2 / (2.0 * a_lim), 3)}
    on_ground = (c("tyre_fz_rear")[seg] > 0.0) & (v[seg] > 3.0) & (decel > 1.0)
    if on_ground.sum() > 10 and np.ptp(decel[on_ground]) > 1.0:
        # rear load against deceleration, a straight line through the braking: where it reaches zero
        slope, icpt = np.polyfit(decel[on_ground], c("tyre_fz_rear")[seg][on_ground], 1)
        out["rear_load_zero_at_decel_m_s2"] = _f(-icpt / slope, 4)
    if full.any():
        a = decel[full]
        # the rear load the quasi-static balance predicts at the measured deceleration
        h, b = lim["cg_height_m"], lim["cg_to_front_contact_m"]
        wb = ride.sim.mm.config.geometry.wheelbase_m
        out["rear_load_quasi_static_n"] = _f(float(np.mean(m * (_g(ride.sim.mm) * b - a * h) / wb)), 1)
        out["rear_load_steady_n"] = _f(float(np.mean(c("tyre_fz_rear")[seg][full])), 1)
    return out


def write_csv(res: MotorcycleRun, path: str | Path) -> None:
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(res.columns)
        for r in res.data:
            w.writerow([f"{v:.9g}" for v in r])


def scene_source(mm):
    """What bridge.mcap_log.write_run draws the 3D scene from (its ``sim``): the built two-wheeler `mm`
    (the road plane, the machine's body, fork, swingarm and wheels every 10 ms), as a served session
    records it."""
    from types import SimpleNamespace

    from .drawing import two_wheeler_drawing

    return SimpleNamespace(vm=SimpleNamespace(model=mm, channels=CHANNELS), road=None,
                           drawing=two_wheeler_drawing(mm.config))
