"""An independent vehicle simulator for the validation tests: a pitch-plane (half-car) model written
from textbook equations, sharing nothing with rtsim's multibody model but the car's data (the vehicle
TOML and the .tir file, read here with tomllib and a few lines of parsing).

Model (SI units, x forward, pitch theta positive nose down):
- sprung body: heave z and pitch theta on linear springs/dampers at the axles, the sprung mass's load
  transfer all through the springs (no anti-dive geometry); vehicle speed v from the sum of the tyre
  forces and aerodynamic drag 0.5 rho CdA v|v|. Ride rate per wheel: the spring's rate times the square
  of its installation ratio, in series with the tyre's vertical stiffness (Milliken & Milliken, "Race
  Car Vehicle Dynamics", ch. 16-17). The installation ratio comes from a front-view (y-z) instant-centre
  analysis of the config's hardpoints (`installation_ratio`): a few lines of plane geometry, not the
  multibody model's 3-D linkage solution; the damper's likewise;
- two axles (left = right in a straight line), each a wheel pair of spin inertia 2 J: drive torque,
  tyre force Fx acting at the loaded radius r_l = R0 - Fz / Cz (the contact point's depth below the
  wheel centre: the wheel's moment balance J omega' = T - Fx r_l - My), rolling resistance
  My = Fz R0 (QSY1 + QSY3 |v| / V_ref + QSY4 (v / V_ref)^4) (MF 5.2; its sign smoothed through
  standstill with tanh(2 omega r_e / VXLOW), VXLOW being the tyre file's low-speed blending speed), brake
  torque with stiction (Karnopp: a wheel at rest stays locked while the torque it
  needs stays below the breakaway torque mu_s/mu times the sliding torque);
- tyre: a tanh law Fx = mu Fz tanh(Kx kappa' / (mu Fz)) with the MF 5.2 slip stiffness at the axle
  load, Kx = Fz (PKX1 + PKX2 dfz) exp(PKX3 dfz), and a first-order transient slip
  sigma d kappa'/dt + |v| kappa' = omega r_e - v (Pacejka, "Tyre and Vehicle Dynamics", sec. 7.2),
  relaxation length sigma = PTX1 R0 Fz / Fz0, and below V_LOW a damping of the contact spring that
  fades with speed (as MF-Tyre's low-speed damping); effective rolling radius from the MF formula
  r_e = R0 - (Fz0 / Cz)(DREFF atan(BREFF Fz / Fz0) + FREFF Fz / Fz0);
- brake: line pressure from the command through a first-order lag and a rate limit (config
  [brakes.actuator]), per-wheel sliding torque n mu A R p (seed eq. 5), the rear through the
  proportioning valve;
- accelerometer at the sprung centre of mass: a_x cos(theta) - g sin(theta).
Integration: semi-implicit Euler at 0.5 ms. Hidden effects of its own: added mass at the centre of
mass, a brake friction scale, an added rolling-resistance coefficient (a force c Fz at each contact
patch, the catalogue's definition), a road grade (gravity's component m g sin(atan(grade)) against the
motion, and the accelerometer tilted with the road), an accelerometer bias.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

G = 9.81
V_LOW = 1.0                 # m/s, below which the tyre contact is damped
LOW_SPEED_DAMPING = 0.15    # fraction of critical damping of the contact spring at standstill


def read_tir(path: Path) -> dict[str, float]:
    out = {}
    for line in path.read_text().splitlines():
        line = line.split("$")[0].strip()
        if "=" in line and not line.startswith(("!", "[", "$")):
            k, v = (s.strip() for s in line.split("=", 1))
            try:
                out[k] = float(v.strip("'"))
            except ValueError:
                pass
    return out



def _yz(p) -> np.ndarray:
    return np.array([p[1], p[2]], dtype=float)


def _cross_line(p1, d1, p2, d2) -> np.ndarray:
    """Intersection of the plane lines p1 + s d1 and p2 + t d2."""
    s = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)[0]
    return p1 + s * d1


def _rot(w: float, r: np.ndarray) -> np.ndarray:
    """Velocity of a point at r from a plane rotation's centre, rate w (rad/s, about +x)."""
    return w * np.array([-r[1], r[0]])


def installation_ratio(kind: str, hp: dict) -> float:
    """Spring compression per unit of wheel-centre rise at design height, from the front view (y-z plane)
    of the left corner's hardpoints: the knuckle turns about its instant centre (double wishbone: where
    the two arm lines cross; strut: where the lower arm line crosses the normal to the strut at its top
    mount), the lower arm about its inner pivot axis."""
    pivot = 0.5 * (_yz(hp["lower_front"]) + _yz(hp["lower_rear"]))
    ball = _yz(hp["lower_ball"])
    centre = _yz(hp["wheel_centre"])
    if kind == "double_wishbone":
        upper = 0.5 * (_yz(hp["upper_front"]) + _yz(hp["upper_rear"]))
        ic = _cross_line(pivot, ball - pivot, upper, _yz(hp["upper_ball"]) - upper)
        # lower arm rate for a unit knuckle rate: the ball's velocity is the same on both bodies
        w_arm = np.linalg.norm(ball - ic) / np.linalg.norm(ball - pivot) * np.sign(np.dot(ball - ic, ball - pivot))
        lo, up = _yz(hp["spring_lower"]), _yz(hp["spring_upper"])
        v_mount = _rot(w_arm, lo - pivot)
    else:
        top, lo = _yz(hp["strut_top"]), _yz(hp["strut_lower"])
        axis = top - lo
        ic = _cross_line(pivot, ball - pivot, top, np.array([axis[1], -axis[0]]))
        up = top
        v_mount = _rot(1.0, lo - ic)
    u = (up - lo) / np.linalg.norm(up - lo)
    rise = _rot(1.0, centre - ic)[1]
    return float(np.dot(v_mount, u) / rise)


@dataclass
class Car:
    m_s: float          # sprung mass, kg
    m_u: float          # unsprung mass per corner, kg
    a: float            # CG to front axle, m
    b: float            # CG to rear axle, m
    h: float            # sprung CG height, m
    iyy: float          # kg m^2
    j_f: float          # wheel spin inertia, front, kg m^2
    j_r: float
    k_f: float          # ride rate per wheel (suspension and tyre in series), N/m
    k_r: float
    c_f: float          # damping at the wheel per wheel, N s/m
    c_r: float
    gain_f: float       # brake N m per kPa per wheel
    gain_r: float
    brk_ratio_f: float  # mu_s / mu
    brk_ratio_r: float
    knee: float         # kPa
    prop: float
    act_tau: float      # s
    act_rate: float     # kPa/s
    cda: float          # m^2
    rho: float
    tir: dict

    @classmethod
    def from_config(cls, path: Path) -> "Car":
        cfg = tomllib.loads(path.read_text())
        tir = read_tir(path.parent / cfg["tyres"]["property_file"])
        xf = cfg["front"]["hardpoints"]["wheel_centre"][0]
        xr = cfg["rear"]["hardpoints"]["wheel_centre"][0]
        cg = cfg["chassis"]["cg_m"]
        br = cfg["brakes"]

        def gain(ax):
            return ax["pads"] * ax["mu"] * ax["piston_area"] * ax["effective_radius"] * 1000.0

        mf = installation_ratio(cfg["front"]["suspension"], cfg["front"]["hardpoints"])
        mr = installation_ratio(cfg["rear"]["suspension"], cfg["rear"]["hardpoints"])
        fs, rs = cfg["front"]["spring"], cfg["rear"]["spring"]
        k_tyre = tir["VERTICAL_STIFFNESS"]

        def ride(k_spring, ratio):              # spring at the wheel in series with the tyre
            k_w = k_spring * ratio ** 2
            return k_w * k_tyre / (k_w + k_tyre)

        return cls(m_s=cfg["chassis"]["mass_kg"], m_u=cfg["front"]["unsprung_mass_kg"], a=xf - cg[0],
                   b=cg[0] - xr, h=cg[2], iyy=cfg["chassis"]["inertia_kgm2"][1],
                   j_f=cfg["front"]["wheel_spin_inertia_kgm2"], j_r=cfg["rear"]["wheel_spin_inertia_kgm2"],
                   k_f=ride(fs["stiffness_n_per_m"], mf), k_r=ride(rs["stiffness_n_per_m"], mr),
                   c_f=0.5 * (fs["damping_bump_ns_per_m"] + fs["damping_rebound_ns_per_m"]) * mf ** 2,
                   c_r=0.5 * (rs["damping_bump_ns_per_m"] + rs["damping_rebound_ns_per_m"]) * mr ** 2,
                   gain_f=gain(br["front"]), gain_r=gain(br["rear"]),
                   brk_ratio_f=br["front"]["mu_static"] / br["front"]["mu"],
                   brk_ratio_r=br["rear"]["mu_static"] / br["rear"]["mu"],
                   knee=br["proportioning_knee"], prop=br["proportioning_ratio"],
                   act_tau=br["actuator"]["time_constant"], act_rate=br["actuator"]["rate_limit"],
                   cda=cfg["aero"]["drag_area_m2"], rho=cfg["aero"]["air_density_kg_m3"], tir=tir)

    def r_e(self, fz: float) -> float:
        t = self.tir
        fr = max(fz, 0.0) / t["FNOMIN"]
        return t["UNLOADED_RADIUS"] - t["FNOMIN"] / t["VERTICAL_STIFFNESS"] * (
            t["DREFF"] * math.atan(t["BREFF"] * fr) + t["FREFF"] * fr)

    def r_l(self, fz: float) -> float:
        return self.tir["UNLOADED_RADIUS"] - max(fz, 0.0) / self.tir["VERTICAL_STIFFNESS"]

    def kx(self, fz: float) -> float:
        t = self.tir
        dfz = fz / t["FNOMIN"] - 1.0
        return fz * (t["PKX1"] + t["PKX2"] * dfz) * math.exp(t["PKX3"] * dfz)

    def sigma(self, fz: float) -> float:
        t = self.tir
        return max(t["PTX1"] * t["UNLOADED_RADIUS"] * fz / t["FNOMIN"], 0.02)


def simulate(car: Car, brake_cmd, torque_cmd, duration: float, rate: float = 500.0, dt: float = 5e-4,
             added_mass: float = 0.0, brake_scale: float = 1.0, rr_added: float = 0.0, grade: float = 0.0,
             settle: float = 1.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Run the manoeuvre (commands: functions of time, kPa and N m per rear wheel); samples at `rate`
    after `settle` s standing on the first commands. Returns (time, channels)."""
    ms = car.m_s + added_mass
    m = ms + 4 * car.m_u
    L = car.a + car.b
    # static axle loads (both wheels) of the car as built: its springs' preload carries them at zero
    # deflection; an added mass's weight (at the sprung CG) deflects the springs: the car sags and,
    # its front being softer, pitches nose down
    gam = math.atan(grade)          # road slope, uphill positive: the body pitches nose up with the road
    fz0_f = G * (car.m_s * car.b / L + 2 * car.m_u)
    fz0_r = G * (car.m_s * car.a / L + 2 * car.m_u)
    dw = added_mass * G
    qsy1 = car.tir.get("QSY1", 0.0)
    qsy3, qsy4 = car.tir.get("QSY3", 0.0), car.tir.get("QSY4", 0.0)
    r0, v_ref = car.tir["UNLOADED_RADIUS"], car.tir["LONGVL"]
    vx_low = car.tir.get("VXLOW", 1.0)
    mu = car.tir.get("PDX1", 1.0)
    kf, kr = 2 * car.k_f, 2 * car.k_r
    cf, cr = 2 * car.c_f, 2 * car.c_r
    # state
    v = 0.0
    w = q = 0.0
    # start at the static equilibrium with the added mass: spring forces dw b / L and dw a / L
    d_f0, d_r0 = dw * car.b / L / kf, dw * car.a / L / kr       # compressions
    th = (d_f0 - d_r0) / L
    z = car.a * th - d_f0
    om = [0.0, 0.0]
    phi = [0.0, 0.0]
    kap = [0.0, 0.0]
    locked = [True, True]
    p_line = brake_cmd(0.0)
    jj = [2 * car.j_f, 2 * car.j_r]
    nset = int(round(settle / dt))
    nrun = int(round(duration / dt))
    every = int(round(1.0 / (rate * dt)))
    rows = []
    ax_prev = 0.0
    for n in range(-nset, nrun + 1):
        t = max(n, 0) * dt
        if n >= 0 and n % every == 0:
            fx_tot = ax_prev
            rows.append((t, fx_tot * math.cos(th - gam) - G * math.sin(th - gam), phi[0], phi[1], p_line,
                         torque_cmd(t), th))
        # actuator: first-order lag with rate limit
        target = p_line + (brake_cmd(t) - p_line) * (1.0 - math.exp(-dt / car.act_tau))
        step = max(-car.act_rate * dt, min(car.act_rate * dt, target - p_line))
        p_line = max(0.0, p_line + step)
        p_f = p_line
        p_r = p_line if p_line <= car.knee else car.knee + car.prop * (p_line - car.knee)
        # suspension (compression positive) and wheel loads
        d_f, d_r = -z + car.a * th, -z - car.b * th
        dd_f, dd_r = -w + car.a * q, -w - car.b * q
        f_sf = kf * d_f + cf * dd_f
        f_sr = kr * d_r + cr * dd_r
        fz = [fz0_f + f_sf, fz0_r + f_sr]
        tq = torque_cmd(t)
        fx = [0.0, 0.0]
        for i in (0, 1):
            fzw = fz[i] / 2                   # per wheel
            re, rl = car.r_e(fzw), car.r_l(fzw)
            sig = car.sigma(fzw)
            # transient slip
            kap[i] += dt * ((om[i] * re - v) - abs(v) * kap[i]) / sig
            f1 = mu * fzw * math.tanh(car.kx(fzw) * kap[i] / max(mu * fzw, 1e-9))
            # low-speed damping of the contact spring (standstill: the tread deflection kappa' sigma
            # acts as a spring Kx / sigma; damped at LOW_SPEED_DAMPING of critical with a quarter of the car's mass)
            fade = max(0.0, 1.0 - abs(v) / V_LOW)
            if fade > 0.0:
                c_d = LOW_SPEED_DAMPING * 2.0 * math.sqrt(car.kx(fzw) / sig * m / 4.0)
                f1 += fade * c_d * (om[i] * re - v)
            fx[i] = 2 * f1
            t_drive = 2 * tq if i == 1 else 0.0
            vr = abs(v) / v_ref
            # smooth signs of the rolling speed: over the tyre file's VXLOW for the tyre's own moment, over
            # 0.1 m/s for the added resistance (the catalogue's definition of rolling_resistance)
            t_rr = ((qsy1 + qsy3 * vr + qsy4 * vr ** 4) * r0 * math.tanh(2.0 * om[i] * re / vx_low)
                    + rr_added * rl * math.tanh(om[i] * re / 0.05)) * fz[i]
            gain = (car.gain_f if i == 0 else car.gain_r) * brake_scale
            p = p_f if i == 0 else p_r
            t_slide = 2 * gain * p
            t_break = t_slide * (car.brk_ratio_f if i == 0 else car.brk_ratio_r)
            t_other = t_drive - fx[i] * rl - t_rr
            if locked[i]:
                if abs(t_other) <= t_break:
                    om[i] = 0.0
                    continue
                locked[i] = False
            new = om[i] + dt / jj[i] * (t_other - math.copysign(t_slide, om[i] if om[i] != 0.0 else t_other))
            if om[i] != 0.0 and (new * om[i] < 0.0) and t_break > abs(t_other):
                om[i] = 0.0
                locked[i] = True
            else:
                om[i] = new
        for i in (0, 1):
            phi[i] += dt * om[i]
        # body
        f_aero = 0.5 * car.rho * car.cda * v * abs(v)
        ax = (fx[0] + fx[1] - f_aero) / m - G * math.sin(gam)
        v += dt * ax
        ax_prev = ax
        # heave and pitch of the sprung mass: springs, dampers, and its inertia force at the CG against
        # the ground forces (no anti-dive / anti-squat geometry: the whole load transfer of the sprung
        # mass goes through the springs)
        m_pitch = -car.a * f_sf + car.b * f_sr - ms * ax * car.h
        w += dt * (f_sf + f_sr - dw) / ms
        q += dt * m_pitch / car.iyy
        z += dt * w
        th += dt * q
    arr = np.array(rows)
    t = arr[:, 0]
    out = {"accel_x": arr[:, 1], "wheel_angle_fl": arr[:, 2], "wheel_angle_fr": arr[:, 2].copy(),
           "wheel_angle_rl": arr[:, 3], "wheel_angle_rr": arr[:, 3].copy(), "brake_pressure": arr[:, 4],
           "wheel_torque_rl": arr[:, 5], "wheel_torque_rr": arr[:, 5].copy(), "pitch": arr[:, 6]}
    return t, out


# ------------------------------------------------------------------------------------- field data
BRAKE_T = (0.0, 1.0, 2.5, 7.0, 10.0)
BRAKE_P = (2500.0, 2500.0, 0.0, 0.0, 1800.0)
TORQUE = (2.6, 0.5, 2.0, 0.5, 250.0)     # t0, rise, width, fall s; N m per rear wheel
NOISE = {"accel_x": 0.2, "wheel_angle_fl": 0.002, "wheel_angle_fr": 0.002, "wheel_angle_rl": 0.002,
         "wheel_angle_rr": 0.002, "brake_pressure": 4.0, "wheel_torque_rl": 1.0, "wheel_torque_rr": 1.0}


def sensor_reading(t: np.ndarray, x: np.ndarray, bias: float = 0.0, scale: float = 1.0,
                   delay: float = 0.0) -> np.ndarray:
    """A hidden sensor effect on a recorded channel: y = scale x(t - delay) + bias (linear interpolation;
    the first value held before the start)."""
    y = np.interp(t - delay, t, x) if delay else x
    return scale * y + bias


def write_runs(folder: Path, car: Car, n: int = 7, seed: int = 0, duration: float = 12.0,
               accel_bias: float = 0.0, sensor: dict | None = None, **hidden) -> list[Path]:
    """n repetitions with run-to-run variation, noise and logger offsets, as CSV files. `sensor`: channel
    -> {"bias": b, "scale": s, "delay": d} hidden in the recorded channel (sensor_reading)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for k in range(n):
        bt = np.array(BRAKE_T) + np.concatenate([[0.0], rng.normal(0.0, 0.015, len(BRAKE_T) - 1)])
        bp = np.array(BRAKE_P) * np.concatenate([[1.0] * (len(BRAKE_P) - 1), [1.0 + rng.normal(0.0, 0.015)]])
        t0, rise, width, fall, amp = TORQUE
        t0 += rng.normal(0.0, 0.015)
        amp *= 1.0 + rng.normal(0.0, 0.015)
        tt = np.array([t0, t0 + rise, t0 + rise + width, t0 + rise + width + fall])
        tv = np.array([0.0, amp, amp, 0.0])
        t, ch = simulate(car, lambda s: float(np.interp(s, bt, bp)), lambda s: float(np.interp(s, tt, tv)),
                         duration, **hidden)
        ch["accel_x"] = ch["accel_x"] + accel_bias
        for c, eff in (sensor or {}).items():
            ch[c] = sensor_reading(t, ch[c], **eff)
        paths.append(log_run(folder / f"peer{k + 1}.csv", t, ch, NOISE, rng, 50.0 * (k + 1)))
    return paths


def log_run(path: Path, t: np.ndarray, ch: dict, noise: dict, rng, clock: float,
            declare: dict | None = None) -> Path:
    """A field logger's CSV of one run: `time` on the logger's own clock (t + clock + up to 1 s, s), then
    the channels of `noise` with their white noise (standard deviation in the channel's unit) added,
    started and stopped up to 125 samples late and early (draws from `rng` in that order). `declare`:
    the logger's configuration written as `# key: value` lines before the header (e.g. accel_frame)."""
    names = list(noise)
    x = np.column_stack([ch[c] + rng.normal(0.0, noise[c], t.size) for c in names])
    k0 = int(rng.integers(0, 125))
    k1 = t.size - int(rng.integers(0, 125))
    clock = clock + rng.uniform(0.0, 1.0)
    with path.open("w") as fh:
        fh.writelines(f"# {k}: {v}\n" for k, v in (declare or {}).items())
        fh.write(",".join(("time", *names)) + "\n")
        np.savetxt(fh, np.column_stack([t[k0:k1] + clock, x[k0:k1]]), delimiter=",", fmt="%.9g")
    return path
