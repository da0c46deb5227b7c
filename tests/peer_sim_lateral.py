"""An independent lateral simulator for the validation tests: a planar two-track car written from
textbook equations, sharing nothing with rtsim's multibody model but the car's numbers (the dictionary
`rtsim describe --json` prints, plus the yaw inertia, the rear wheels' spin inertia and the tyre's
friction coefficient read from the vehicle TOML and the .tir file).

Model (SI units, ISO 8855 body axes: x forward, y left, z up; yaw rate r positive to the left):
- body: planar rigid body, states vx, vy, r; yaw inertia = the chassis's Izz plus the unsprung masses
  as points at the wheel centres. No roll, no pitch, no heave, no suspension kinematics, no steering
  compliance: both front wheels turn by (steering-wheel angle) / (steering ratio);
- wheel loads: quasi-static, the static loads plus the longitudinal transfer m ax h / L and the lateral
  transfer m ay h / track shared between the axles in a fixed ratio (`ROLL_SHARE_FRONT`), from the
  previous step's accelerations;
- tyre: its own law, not a Magic Formula: linear stiffnesses Cx kappa and -Cy tan(alpha) (the
  describe numbers at the static loads, scaled with the wheel load and a mild load degression
  `LOAD_DEGRESSION`), saturated together on a friction circle by mu Fz tanh(|F| / (mu Fz)) / |F|;
  a fixed effective rolling radius (describe's wheel_radius), rolling resistance c Fz r;
- wheels: spin J omega' = T_drive - Fx r - My, integrated semi-implicitly in the slip (the tyre's
  slope d Fx / d omega taken implicitly), the body by symplectic Euler at `DT`;
- accelerometer and gyro at the centre of mass (flat road: no gravity components); with no roll or
  pitch its accelerations are the ground-plane (level-frame) ones, and its CSV files declare it
  (`# accel_frame: level`, the declaration rtsim validate reads, as an INS logger's configuration says it).
Hidden effects of its own: tyre stiffness scale (both stiffnesses), added mass (a point mass at the
centre of mass: no yaw inertia), and any sensor bias, scale or delay applied to a recorded channel.

Manoeuvre (`write_runs`): 15 m/s straight, the steering wheel ramps to +0.6 rad, is held 3 s, ramps to
-0.6 rad, held 3 s, back to zero; a speed controller (PI on the speed) sets the rear wheel torques,
which are recorded (the measured torques that hold the speed). Seven repetitions with run-to-run scatter
(steering timing 1 sigma 15 ms and amplitude 1.5 %, start speed 0.5 %), white sensor noise, loggers
triggered at slightly different times on their own clocks. Channels: time, steering_wheel_angle,
brake_pressure, wheel_torque_rl/rr, wheel_angle_fl/fr/rl/rr, accel_x, accel_y, gyro_z.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
from numba import njit

from peer_sim import log_run, read_tir, sensor_reading

DT = 5e-4                    # s, integrator step
RATE = 500.0                 # Hz, logger rate
ROLL_SHARE_FRONT = 0.6       # share of the lateral load transfer carried by the front axle
LOAD_DEGRESSION = 0.3        # Cy(Fz) = Cy0 (Fz/Fz0) (1 - LOAD_DEGRESSION (Fz/Fz0 - 1))
SPEED = 15.0                 # m/s
DURATION = 12.0              # s recorded
SETTLE = 1.5                 # s driven straight before the logger starts
#: steering-wheel nodes (s, rad) of the manoeuvre
STEER_T = (1.0, 1.6, 4.6, 5.8, 8.8, 9.4)
STEER_A = (0.0, 0.6, 0.6, -0.6, -0.6, 0.0)
NOISE = {"steering_wheel_angle": 0.0005, "brake_pressure": 4.0, "wheel_torque_rl": 1.0, "wheel_torque_rr": 1.0,
         "wheel_angle_fl": 0.002, "wheel_angle_fr": 0.002, "wheel_angle_rl": 0.002, "wheel_angle_rr": 0.002,
         "accel_x": 0.1, "accel_y": 0.1, "gyro_z": 0.002}
CHANNELS = tuple(NOISE)
ACCEL_FRAME = "level"        # the frame of the recorded accel_x / accel_y: the ground plane (no roll, no pitch)

# parameter vector layout (one float array for the compiled kernel)
(P_M, P_IZZ, P_A, P_B, P_H, P_TF, P_TR, P_RE, P_JF, P_JR, P_CYF, P_CYR, P_CX, P_FZF, P_FZR, P_MU, P_RR, P_CDA,
 P_RHO, P_RATIO, P_KP, P_KI, P_REFF, P_REFR, NPAR) = range(25)


def car_parameters(desc: dict, vehicle: Path) -> dict:
    """The peer's parameters from `rtsim describe --json` (desc) and the vehicle TOML."""
    cfg = tomllib.loads(vehicle.read_text())
    tir = read_tir(vehicle.parent / cfg["tyres"]["property_file"])
    a = desc["cg_to_front_axle"]
    L = desc["wheelbase"]
    b = L - a
    mu_f, mu_r = cfg["front"]["unsprung_mass_kg"], cfg["rear"]["unsprung_mass_kg"]
    izz = (cfg["chassis"]["inertia_kgm2"][2] + 2 * mu_f * (a ** 2 + (desc["track_front"] / 2) ** 2)
           + 2 * mu_r * (b ** 2 + (desc["track_rear"] / 2) ** 2))
    loads = desc["static_wheel_loads"]
    return {"mass": desc["mass"], "izz": izz, "a": a, "b": b, "h": desc["cg_height"],
            "track_front": desc["track_front"], "track_rear": desc["track_rear"],
            "radius": desc["wheel_radius"], "j_front": desc["wheel_inertia"],
            "j_rear": cfg["rear"]["wheel_spin_inertia_kgm2"],
            "cy_front": desc["cornering_stiffness_front"], "cy_rear": desc["cornering_stiffness_rear"],
            "cx": desc["slip_stiffness"], "fz_front": loads[0], "fz_rear": loads[2],
            "mu": 0.5 * (tir.get("PDX1", 1.0) + tir.get("PDY1", 1.0)),
            "rolling_resistance": desc["rolling_resistance_coefficient"], "drag_area": desc["drag_area"],
            "air_density": cfg["aero"]["air_density_kg_m3"], "steering_ratio": desc["steering_ratio"]}


def _pack(car: dict, stiffness_scale: float, added_mass: float) -> np.ndarray:
    p = np.zeros(NPAR)
    m0 = car["mass"]
    m = m0 + added_mass
    p[P_M], p[P_IZZ], p[P_A], p[P_B], p[P_H] = m, car["izz"], car["a"], car["b"], car["h"]
    p[P_TF], p[P_TR], p[P_RE] = car["track_front"], car["track_rear"], car["radius"]
    p[P_JF], p[P_JR] = car["j_front"], car["j_rear"]
    p[P_CYF], p[P_CYR], p[P_CX] = (car["cy_front"] * stiffness_scale, car["cy_rear"] * stiffness_scale,
                                   car["cx"] * stiffness_scale)
    # static loads of the heavier car: the point mass at the centre of mass keeps the split
    p[P_FZF], p[P_FZR] = car["fz_front"] * m / m0, car["fz_rear"] * m / m0
    p[P_REFF], p[P_REFR] = car["fz_front"], car["fz_rear"]     # loads at which the stiffnesses are given
    p[P_MU], p[P_RR], p[P_CDA], p[P_RHO] = car["mu"], car["rolling_resistance"], car["drag_area"], car["air_density"]
    p[P_RATIO] = car["steering_ratio"]
    p[P_KP], p[P_KI] = 400.0, 400.0          # N m per (m/s), N m per m: the driver's speed controller
    return p


@njit(cache=True)
def _simulate(p, steer, v0, dt, every, nsettle):
    """Integrate the manoeuvre; steer: steering-wheel angle at every step (the first nsettle steps
    before the logger starts). Returns samples (n, 8): steering, torque per rear wheel, wheel angles
    fl fr rl rr, accel_x, accel_y, gyro_z are columns 0..9."""
    m, izz, a, b, h = p[P_M], p[P_IZZ], p[P_A], p[P_B], p[P_H]
    L = a + b
    re = p[P_RE]
    xs = np.array([a, a, -b, -b])
    ys = np.array([p[P_TF] / 2, -p[P_TF] / 2, p[P_TR] / 2, -p[P_TR] / 2])
    jw = np.array([p[P_JF], p[P_JF], p[P_JR], p[P_JR]])
    fz0 = np.array([p[P_FZF], p[P_FZF], p[P_FZR], p[P_FZR]])
    fref = np.array([p[P_REFF], p[P_REFF], p[P_REFR], p[P_REFR]])
    cy0 = np.array([p[P_CYF], p[P_CYF], p[P_CYR], p[P_CYR]])
    cx0 = p[P_CX] / p[P_REFF]                # slip stiffness per newton of load
    mu = p[P_MU]
    nsteps = steer.size
    nout = (nsteps - nsettle - 1) // every + 1
    out = np.zeros((nout, 10))
    vx, vy, r = v0, 0.0, 0.0
    om = np.full(4, v0 / re)
    phi = np.zeros(4)
    ax, ay = 0.0, 0.0
    integ = 0.0
    # feed-forward of the speed controller: rolling resistance and drag at v0, per rear wheel
    tff = 0.5 * (p[P_RR] * m * 9.81 * re + 0.5 * p[P_RHO] * p[P_CDA] * v0 * v0 * re)
    fx = np.zeros(4)
    fy = np.zeros(4)
    fz = np.zeros(4)
    k = 0
    for n in range(nsteps):
        # driver: PI on the speed, torque per rear wheel
        err = v0 - vx
        integ += err * dt
        tq = tff + p[P_KP] * err * re + p[P_KI] * integ * re
        delta = steer[n] / p[P_RATIO]
        cd, sd = math.cos(delta), math.sin(delta)
        # quasi-static loads from the last accelerations
        dlong = m * ax * h / L / 2.0
        for i in range(4):
            share = ROLL_SHARE_FRONT if i < 2 else 1.0 - ROLL_SHARE_FRONT
            track = p[P_TF] if i < 2 else p[P_TR]
            side = 1.0 if ys[i] > 0 else -1.0
            f = fz0[i] + (-dlong if i < 2 else dlong) - side * m * ay * h / track * share
            fz[i] = max(f, 10.0)
        sumx, sumy, mz = 0.0, 0.0, 0.0
        for i in range(4):
            vxw = vx - r * ys[i]
            vyw = vy + r * xs[i]
            c = cd if i < 2 else 1.0
            s = sd if i < 2 else 0.0
            vxt = vxw * c + vyw * s
            vyt = -vxw * s + vyw * c
            den = max(abs(vxt), 0.5)
            kap = (om[i] * re - vxt) / den
            tana = vyt / den
            load = fz[i] / fref[i]
            cy = cy0[i] * load * (1.0 - LOAD_DEGRESSION * (load - 1.0))
            cx = cx0 * fz[i]
            flx = cx * kap
            fly = -cy * tana
            fres = math.sqrt(flx * flx + fly * fly)
            lim = mu * fz[i]
            sat = 1.0 if fres < 1e-9 else lim * math.tanh(fres / lim) / fres
            fx[i] = flx * sat
            fy[i] = fly * sat
            # wheel spin, the tyre's slope in omega implicit
            drive = tq if i >= 2 else 0.0
            my = p[P_RR] * fz[i] * re
            slope = cx * sat * re / den
            om[i] = om[i] + dt * (drive - fx[i] * re - my) / jw[i] / (1.0 + dt * slope * re / jw[i])
            phi[i] += dt * om[i]
            fbx = fx[i] * c - fy[i] * s
            fby = fx[i] * s + fy[i] * c
            sumx += fbx
            sumy += fby
            mz += xs[i] * fby - ys[i] * fbx
        drag = 0.5 * p[P_RHO] * p[P_CDA] * vx * abs(vx)
        ax = (sumx - drag) / m
        ay = sumy / m
        # symplectic Euler of the body (velocities in body axes)
        r += dt * mz / izz
        vx += dt * (ax + r * vy)
        vy += dt * (ay - r * vx)
        if n >= nsettle and (n - nsettle) % every == 0 and k < nout:
            out[k, 0] = steer[n]
            out[k, 1] = tq
            out[k, 2] = tq
            for i in range(4):
                out[k, 3 + i] = phi[i]
            out[k, 7] = ax
            out[k, 8] = ay
            out[k, 9] = r
            k += 1
    return out


def simulate(car: dict, steer_fn, speed: float = SPEED, duration: float = DURATION,
             stiffness_scale: float = 1.0, added_mass: float = 0.0) -> tuple[np.ndarray, dict]:
    """One run: `steer_fn(t)` the steering-wheel angle (rad) on the logger's time (t < 0: before it
    starts). Returns (time, channel -> samples at RATE), noise-free."""
    nset = int(round(SETTLE / DT))
    every = int(round(1.0 / (RATE * DT)))
    nrun = int(round(duration / DT)) + 1
    tt = (np.arange(nset + nrun) - nset) * DT
    steer = np.array([steer_fn(x) for x in tt]) if not isinstance(steer_fn, np.ndarray) else steer_fn
    out = _simulate(_pack(car, stiffness_scale, added_mass), steer, speed, DT, every, nset)
    t = np.arange(out.shape[0]) / RATE
    ch = {"steering_wheel_angle": out[:, 0], "brake_pressure": np.zeros(t.size), "wheel_torque_rl": out[:, 1],
          "wheel_torque_rr": out[:, 2], "wheel_angle_fl": out[:, 3], "wheel_angle_fr": out[:, 4],
          "wheel_angle_rl": out[:, 5], "wheel_angle_rr": out[:, 6], "accel_x": out[:, 7], "accel_y": out[:, 8],
          "gyro_z": out[:, 9]}
    return t, ch


def write_runs(folder: Path, car: dict, n: int = 7, seed: int = 0, stiffness_scale: float = 1.0,
               added_mass: float = 0.0, sensor: dict | None = None) -> list[Path]:
    """n repetitions of the manoeuvre with run-to-run scatter, noise and logger offsets, as CSV files.
    `sensor`: channel -> {"bias": b, "scale": s, "delay": d} hidden in the recorded channel."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for k in range(n):
        shift = rng.normal(0.0, 0.015)
        gain = 1.0 + rng.normal(0.0, 0.015)
        st = np.array(STEER_T) + shift + np.concatenate([[0.0], rng.normal(0.0, 0.015, len(STEER_T) - 1)])
        st = np.maximum.accumulate(st + np.arange(len(st)) * 1e-6)
        sa = np.array(STEER_A) * gain
        speed = SPEED * (1.0 + rng.normal(0.0, 0.005))
        t, ch = simulate(car, lambda x: float(np.interp(x, st, sa)), speed, DURATION + 0.5,
                         stiffness_scale, added_mass)
        for c, eff in (sensor or {}).items():
            ch[c] = sensor_reading(t, ch[c], **eff)
        paths.append(log_run(folder / f"lat{k + 1}.csv", t, ch, {c: NOISE[c] for c in CHANNELS}, rng, 80.0 * (k + 1),
                             declare={"accel_frame": ACCEL_FRAME}))
    return paths


def lateral_force(car: dict, front: bool, stiffness_scale: float, fz: float, alpha: float) -> float:
    """The peer's lateral tyre force (N, positive for a positive slip angle, pure side slip) at load fz
    (N) and slip angle alpha (rad): the law of _simulate."""
    fref = car["fz_front"] if front else car["fz_rear"]
    load = fz / fref
    cy0 = car["cy_front"] if front else car["cy_rear"]
    cy = cy0 * stiffness_scale * load * (1.0 - LOAD_DEGRESSION * (load - 1.0))
    lim = car["mu"] * fz
    return lim * math.tanh(cy * math.tan(alpha) / lim)


def operating_points(car: dict, stiffness_scale: float, front: bool, every: int = 25) -> list[tuple]:
    """The axle's quasi-static operating points over the manoeuvre, (alpha, outer load, inner load, axle
    lateral force), from the peer's noise-free lateral acceleration: the force m ay (the other axle's
    lever)/L, the loads with this axle's share of the lateral transfer, the slip angle at which the
    peer's two tyres give that force (bisection)."""
    t, ch = simulate(car, lambda x: float(np.interp(x, STEER_T, STEER_A)), stiffness_scale=stiffness_scale)
    m, L = car["mass"], car["a"] + car["b"]
    fz0 = car["fz_front"] if front else car["fz_rear"]
    share = ROLL_SHARE_FRONT if front else 1.0 - ROLL_SHARE_FRONT
    lever = car["b"] if front else car["a"]
    track = car["track_front"] if front else car["track_rear"]
    out = []
    for ay in np.abs(ch["accel_y"][::every]):
        dfz = m * ay * car["h"] / track * share
        need = m * ay * lever / L
        lo, hi = 0.0, 0.3
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            f = lateral_force(car, front, stiffness_scale, fz0 + dfz, mid) + \
                lateral_force(car, front, stiffness_scale, fz0 - dfz, mid)
            lo, hi = (mid, hi) if f < need else (lo, mid)
        out.append((lo, fz0 + dfz, fz0 - dfz, need))
    return out


def equivalent_slip_stiffness(car: dict, tyre_params: np.ndarray, stiffness_scale: float) -> float:
    """The model's tyre_slip_stiffness scale (rtsim's Magic Formula tyre, slips fed as atan(s tan alpha))
    that reproduces the peer's axle lateral forces at `stiffness_scale` over the manoeuvre's operating
    points, least squares over both axles: the peer's hidden stiffness in the model's terms. The two tyre
    laws differ (describe's cornering stiffness is the slope at zero slip; over the slip angles driven the
    Magic Formula curve bends otherwise), so this is the value a validation fit should find."""
    from scipy.optimize import minimize_scalar

    from rtsim.vehicle.kit.tyre.magic_formula import mf52_forces

    pts = operating_points(car, stiffness_scale, True) + operating_points(car, stiffness_scale, False)

    def cost(s):
        return sum((-mf52_forces(tyre_params, fo, 0.0, math.atan(s * math.tan(a)), 0.0, SPEED, 1.0)[1]
                    - mf52_forces(tyre_params, fi, 0.0, math.atan(s * math.tan(a)), 0.0, SPEED, 1.0)[1] - f) ** 2
                   for a, fo, fi, f in pts)
    return float(minimize_scalar(cost, bounds=(0.2, 2.0), method="bounded", options={"xatol": 1e-4}).x)
