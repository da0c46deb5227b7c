"""The field-data simulators: numba kernels written from textbook equations (SI units, ISO 8855 axes: x
forward, y left, z up; yaw rate positive to the left; roll positive right side down; pitch positive nose
down), integrated by semi-implicit (symplectic) Euler at `DT`. They share no code with rtsim's vehicle.

Tyre laws (`TYRE_TANH`, `TYRE_BRUSH`), per wheel, from the linear forces Cx kappa and -Cy tan(alpha):
- tanh: both saturated together on a friction circle, mu Fz tanh(|F| / (mu Fz)) / |F|; cornering
  stiffness with a load degression Cy(Fz) = Cy0 (Fz/Fz0)(1 - 0.3 (Fz/Fz0 - 1));
- brush (Fiala, parabolic pressure): psi = |F_lin| / (3 mu Fz), |F| = mu Fz (3 psi - 3 psi^2 + psi^3)
  below full sliding; Cy(Fz) = Cy0 (Fz/Fz0)^0.7.
Slip stiffness Cx proportional to the load (describe's value at the front static load).

Lateral (`lateral`): a two-track car, states vx, vy, r and the four wheel spins; front wheels steered by
(steering-wheel angle) / (steering ratio), no compliance; a PI speed controller on the rear wheel
torques (recorded, as a logger records measured torques). Without roll (`roll=False`) the load transfer
is quasi-static from the last step's accelerations, the lateral part shared `ROLL_SHARE_FRONT` / rest
between the axles, and the accelerometer reads ground-plane (level-frame) accelerations. With roll, the
sprung mass rolls about the roll axis (roll centres from the front-view geometry) on the axles' roll
stiffness and damping, I_roll phi'' = m_s h' (a_y cos phi + g sin phi) - K phi - C phi'; each axle's load
transfer is its roll moment over the track plus its lateral force times its roll-centre height over the
track; the accelerometer at the sprung centre of mass reads body-frame specific force
(a_y - h' phi'') cos phi + g sin phi, and the roll angle is recorded.

Longitudinal (`pitch`): the pitch-plane half car (heave and pitch on ride springs and dampers at the
axles, the load transfer through the springs), two wheel pairs with a first-order transient slip
(relaxation length from the tyre file), brake line pressure through a first-order lag and a rate limit,
the rear through the proportioning valve, per-wheel sliding torque gain times pressure with Karnopp
stiction (a wheel at rest stays locked while the torque it needs stays below the breakaway torque),
rolling resistance c Fz r, aerodynamic drag 0.5 rho CdA v|v|; the accelerometer at the sprung centre of
mass reads a_x cos(theta - gamma) - g sin(theta - gamma) on a grade gamma.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

DT = 5e-4                    # s, integrator step
RATE = 500.0                 # Hz, logger rate
G = 9.81
ROLL_SHARE_FRONT = 0.6
TYRE_TANH, TYRE_BRUSH = 0, 1
TYRES = {"tanh": TYRE_TANH, "brush": TYRE_BRUSH}

# lateral parameter vector
(L_M, L_IZZ, L_A, L_B, L_H, L_TF, L_TR, L_RE, L_JF, L_JR, L_CYF, L_CYR, L_CX, L_FZF, L_FZR, L_REFF, L_REFR, L_MU,
 L_RR, L_CDA, L_RHO, L_RATIO, L_KP, L_KI, L_ROLL, L_TYRE, L_MS, L_HP, L_IXX, L_KRF, L_KRR, L_CRF, L_CRR, L_RCF,
 L_RCR, L_CROSS, NLAT) = range(37)
#: lateral output columns
(O_STEER, O_TQ, O_PHI, O_AX, O_AY, O_GZ, O_ROLL, O_OM, O_FZ, O_TANA, O_FY, O_AYG, O_VX) = (0, 1, 2, 6, 7, 8, 9, 10,
                                                                                         14, 18, 22, 26, 27)
NOUT_LAT = 28


@njit(cache=True)
def _tyre(law, mu_fz, flx, fly):
    """Saturated forces of the linear forces (flx, fly) under the tyre law; returns (fx, fy, slope factor)."""
    f = math.sqrt(flx * flx + fly * fly)
    if f < 1e-9:
        return flx, fly, 1.0
    if law == 0:
        sat = mu_fz * math.tanh(f / mu_fz) / f
    else:
        psi = f / (3.0 * mu_fz)
        mag = mu_fz * (3.0 * psi - 3.0 * psi * psi + psi ** 3) if psi < 1.0 else mu_fz
        sat = mag / f
    return flx * sat, fly * sat, sat


@njit(cache=True)
def _cy(law, cy0, load):
    if law == 0:
        return cy0 * load * (1.0 - 0.3 * (load - 1.0))
    return cy0 * max(load, 0.0) ** 0.7


@njit(cache=True)
def _lateral(p, steer, v0, dt, every, nsettle):
    m, izz, a, b, h = p[L_M], p[L_IZZ], p[L_A], p[L_B], p[L_H]
    L = a + b
    re = p[L_RE]
    law = int(p[L_TYRE])
    roll = p[L_ROLL] > 0.5
    xs = np.array([a, a, -b, -b])
    ys = np.array([p[L_TF] / 2, -p[L_TF] / 2, p[L_TR] / 2, -p[L_TR] / 2])
    jw = np.array([p[L_JF], p[L_JF], p[L_JR], p[L_JR]])
    fz0 = np.array([p[L_FZF], p[L_FZF], p[L_FZR], p[L_FZR]])
    fref = np.array([p[L_REFF], p[L_REFF], p[L_REFR], p[L_REFR]])
    cy0 = np.array([p[L_CYF], p[L_CYF], p[L_CYR], p[L_CYR]])
    cx0 = p[L_CX] / p[L_REFF]
    mu = p[L_MU]
    ms, hp = p[L_MS], p[L_HP]
    iroll = p[L_IXX] + ms * hp * hp
    nsteps = steer.size
    nout = (nsteps - nsettle - 1) // every + 1
    out = np.zeros((nout, NOUT_LAT))
    vx, vy, r = v0, 0.0, 0.0
    phi_r, dphi, ddphi = 0.0, 0.0, 0.0
    om = np.full(4, v0 / re)
    ang = np.zeros(4)
    ax, ay = 0.0, 0.0
    integ = 0.0
    tff = 0.5 * (p[L_RR] * m * G * re + 0.5 * p[L_RHO] * p[L_CDA] * v0 * v0 * re)
    fx = np.zeros(4)
    fy = np.zeros(4)
    fz = np.zeros(4)
    tana = np.zeros(4)
    k = 0
    for n in range(nsteps):
        err = v0 - vx
        integ += err * dt
        tq = tff + p[L_KP] * err * re + p[L_KI] * integ * re
        delta = steer[n] / p[L_RATIO]
        cd, sd = math.cos(delta), math.sin(delta)
        dlong = m * ax * h / L / 2.0
        fyf = fy[0] + fy[1]
        fyr = fy[2] + fy[3]
        for i in range(4):
            front = i < 2
            track = p[L_TF] if front else p[L_TR]
            side = 1.0 if ys[i] > 0 else -1.0
            if roll:
                kr = p[L_KRF] if front else p[L_KRR]
                cr = p[L_CRF] if front else p[L_CRR]
                rc = p[L_RCF] if front else p[L_RCR]
                dlat = (kr * phi_r + cr * dphi) / track + (fyf if front else fyr) * rc / track
            else:
                share = ROLL_SHARE_FRONT if front else 1.0 - ROLL_SHARE_FRONT
                dlat = m * ay * h / track * share
            f = fz0[i] + (-dlong if front else dlong) - side * dlat
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
            tana[i] = vyt / den
            load = fz[i] / fref[i]
            cy = _cy(law, cy0[i], load)
            cx = cx0 * fz[i]
            fxi, fyi, sat = _tyre(law, mu * fz[i], cx * kap, -cy * tana[i])
            fx[i] = fxi
            fy[i] = fyi
            drive = tq if i >= 2 else 0.0
            my = p[L_RR] * fz[i] * re
            slope = cx * sat * re / den
            om[i] = om[i] + dt * (drive - fx[i] * re - my) / jw[i] / (1.0 + dt * slope * re / jw[i])
            ang[i] += dt * om[i]
            fbx = fx[i] * c - fy[i] * s
            fby = fx[i] * s + fy[i] * c
            sumx += fbx
            sumy += fby
            mz += xs[i] * fby - ys[i] * fbx
        drag = 0.5 * p[L_RHO] * p[L_CDA] * vx * abs(vx)
        ax = (sumx - drag) / m
        ay = sumy / m
        if roll:
            ddphi = (ms * hp * (ay * math.cos(phi_r) + G * math.sin(phi_r))
                     - (p[L_KRF] + p[L_KRR]) * phi_r - (p[L_CRF] + p[L_CRR]) * dphi) / iroll
            dphi += dt * ddphi
            phi_r += dt * dphi
        r += dt * mz / izz
        vx += dt * (ax + r * vy)
        vy += dt * (ay - r * vx)
        if n >= nsettle and (n - nsettle) % every == 0 and k < nout:
            out[k, O_STEER] = steer[n]
            out[k, O_TQ] = tq
            for i in range(4):
                out[k, O_PHI + i] = ang[i]
                out[k, O_OM + i] = om[i]
                out[k, O_FZ + i] = fz[i]
                out[k, O_TANA + i] = tana[i]
                out[k, O_FY + i] = fy[i]
            if roll:
                out[k, O_AY] = (ay - hp * ddphi) * math.cos(phi_r) + G * math.sin(phi_r)
                out[k, O_GZ] = r * math.cos(phi_r)
                out[k, O_ROLL] = phi_r
            else:
                out[k, O_AY] = ay
                out[k, O_GZ] = r
            out[k, O_AX] = ax + p[L_CROSS] * out[k, O_AY]
            out[k, O_AYG] = ay
            out[k, O_VX] = vx
            k += 1
    return out


def lateral_params(car: dict, roll: bool, tyre: str, stiffness_scale: float = 1.0, added_mass: float = 0.0,
                   yaw_inertia_scale: float = 1.0, cross_axis: float = 0.0) -> np.ndarray:
    """The lateral kernel's parameter vector. Hidden effects: the tyres' stiffnesses scaled, a point mass at
    the centre of mass (static loads in proportion, no inertia), the yaw inertia scaled, an accelerometer
    cross-axis sensitivity (accel_x reads that share of accel_y)."""
    p = np.zeros(NLAT)
    m0 = car["mass"]
    m = m0 + added_mass
    p[L_M], p[L_IZZ], p[L_A], p[L_B], p[L_H] = m, car["izz"] * yaw_inertia_scale, car["a"], car["b"], car["h"]
    p[L_TF], p[L_TR], p[L_RE] = car["track_front"], car["track_rear"], car["radius"]
    p[L_JF], p[L_JR] = car["j_front"], car["j_rear"]
    p[L_CYF], p[L_CYR], p[L_CX] = (car["cy_front"] * stiffness_scale, car["cy_rear"] * stiffness_scale,
                                   car["cx"] * stiffness_scale)
    p[L_FZF], p[L_FZR] = car["fz_front"] * m / m0, car["fz_rear"] * m / m0
    p[L_REFF], p[L_REFR] = car["fz_front"], car["fz_rear"]
    p[L_MU] = 0.5 * (car["mu_x"] + car["mu_y"])
    p[L_RR], p[L_CDA], p[L_RHO] = car["rolling_resistance"], car["drag_area"], car["air_density"]
    p[L_RATIO] = car["steering_ratio"]
    p[L_KP], p[L_KI] = 400.0, 400.0
    p[L_ROLL], p[L_TYRE] = float(roll), float(TYRES[tyre])
    ms = car["sprung_mass"] + added_mass
    L = car["a"] + car["b"]
    h_axis = (car["roll_centre_f"] * car["b"] + car["roll_centre_r"] * car["a"]) / L
    p[L_MS], p[L_HP], p[L_IXX] = ms, car["sprung_h"] - h_axis, car["ixx"]
    p[L_KRF], p[L_KRR], p[L_CRF], p[L_CRR] = (car["roll_stiffness_f"], car["roll_stiffness_r"],
                                              car["roll_damping_f"], car["roll_damping_r"])
    p[L_RCF], p[L_RCR] = car["roll_centre_f"], car["roll_centre_r"]
    p[L_CROSS] = cross_axis
    return p


def lateral(p: np.ndarray, steer: np.ndarray, speed: float, nsettle: int) -> np.ndarray:
    """Run the lateral kernel: steer (rad, steering wheel) at every DT step, the first `nsettle` before the
    logger starts; samples at RATE (columns O_*)."""
    return _lateral(p, np.ascontiguousarray(steer, dtype=float), float(speed), DT, int(round(1.0 / (RATE * DT))),
                    int(nsettle))


# pitch-plane parameter vector
(P_MS, P_MU4, P_A, P_B, P_H, P_IYY, P_JF, P_JR, P_KF, P_KR, P_CF, P_CR, P_GF, P_GR, P_BRF, P_BRR, P_KNEE, P_PROP,
 P_TAU, P_RATE, P_CDA, P_RHO, P_R0, P_CZ, P_FNOM, P_CXN, P_MU, P_RR, P_SIG, P_ADD, P_RRADD, P_GRADE, P_BLAG,
 P_GROW, P_TYRE, P_DREFF, P_BREFF, P_FREFF, NPITCH) = range(39)
NOUT_PITCH = 10     # accel_x, angle front, angle rear, line pressure, torque, pitch, omega f, omega r, v, unused


@njit(cache=True)
def _pitch(p, brake_cmd, torque_cmd, dt, every, nsettle):
    ms = p[P_MS] + p[P_ADD]
    m = ms + p[P_MU4]
    a, b = p[P_A], p[P_B]
    L = a + b
    gam = math.atan(p[P_GRADE])
    ms0 = p[P_MS]
    fz0f = G * (ms0 * b / L + p[P_MU4] / 2)
    fz0r = G * (ms0 * a / L + p[P_MU4] / 2)
    dw = p[P_ADD] * G
    kf, kr, cf, cr = 2 * p[P_KF], 2 * p[P_KR], 2 * p[P_CF], 2 * p[P_CR]
    law = int(p[P_TYRE])
    r0, cz, fnom = p[P_R0], p[P_CZ], p[P_FNOM]
    v = 0.0
    w = 0.0
    q = 0.0
    d_f0, d_r0 = dw * b / L / kf, dw * a / L / kr
    th = (d_f0 - d_r0) / L
    z = a * th - d_f0
    om = np.zeros(2)
    ang = np.zeros(2)
    kap = np.zeros(2)
    tbrk = np.zeros(2)
    locked = np.array([True, True])
    jj = np.array([2 * p[P_JF], 2 * p[P_JR]])
    p_line = brake_cmd[0]
    nsteps = brake_cmd.size
    nout = (nsteps - nsettle - 1) // every + 1
    out = np.zeros((nout, NOUT_PITCH))
    ax_prev = 0.0
    k = 0
    for n in range(nsteps):
        if n >= nsettle and (n - nsettle) % every == 0 and k < nout:
            out[k, 0] = ax_prev * math.cos(th - gam) - G * math.sin(th - gam)
            out[k, 1] = ang[0]
            out[k, 2] = ang[1]
            out[k, 3] = p_line
            out[k, 4] = torque_cmd[n]
            out[k, 5] = th
            out[k, 6] = om[0]
            out[k, 7] = om[1]
            out[k, 8] = v
            k += 1
        target = p_line + (brake_cmd[n] - p_line) * (1.0 - math.exp(-dt / p[P_TAU]))
        step = max(-p[P_RATE] * dt, min(p[P_RATE] * dt, target - p_line))
        p_line = max(0.0, p_line + step)
        p_r = p_line if p_line <= p[P_KNEE] else p[P_KNEE] + p[P_PROP] * (p_line - p[P_KNEE])
        d_f, d_r = -z + a * th, -z - b * th
        dd_f, dd_r = -w + a * q, -w - b * q
        f_sf = kf * d_f + cf * dd_f
        f_sr = kr * d_r + cr * dd_r
        fzs = (fz0f + f_sf, fz0r + f_sr)
        tq = torque_cmd[n]
        fxs = np.zeros(2)
        for i in range(2):
            fzw = max(fzs[i] / 2, 10.0)
            fr = fzw / fnom
            re = r0 - fnom / cz * (p[P_DREFF] * math.atan(p[P_BREFF] * fr) + p[P_FREFF] * fr)
            re *= 1.0 + p[P_GROW] * v * v
            rl = r0 - fzw / cz
            sig = max(p[P_SIG] * fzw / fnom, 0.02)
            kap[i] += dt * ((om[i] * re - v) - abs(v) * kap[i]) / sig
            kx = p[P_CXN] * fzw
            f1, _, _ = _tyre(law, p[P_MU] * fzw, kx * kap[i], 0.0)
            fade = max(0.0, 1.0 - abs(v) / 1.0)
            if fade > 0.0:
                c_d = 0.15 * 2.0 * math.sqrt(kx / sig * m / 4.0)
                f1 += fade * c_d * (om[i] * re - v)
            fxs[i] = 2 * f1
            t_drive = 2 * tq if i == 1 else 0.0
            t_rr = (p[P_RR] * r0 * math.tanh(2.0 * om[i] * re) + p[P_RRADD] * rl * math.tanh(om[i] * re / 0.05)) * fzs[i]
            gain = p[P_GF] if i == 0 else p[P_GR]
            pr = p_line if i == 0 else p_r
            t_want = 2 * gain * pr
            if p[P_BLAG] > 0.0:
                tbrk[i] += (t_want - tbrk[i]) * (1.0 - math.exp(-dt / p[P_BLAG]))
            else:
                tbrk[i] = t_want
            t_slide = tbrk[i]
            t_break = t_slide * (p[P_BRF] if i == 0 else p[P_BRR])
            t_other = t_drive - fxs[i] * rl - t_rr
            if locked[i]:
                if abs(t_other) <= t_break:
                    om[i] = 0.0
                    continue
                locked[i] = False
            sgn = om[i] if om[i] != 0.0 else t_other
            new = om[i] + dt / jj[i] * (t_other - math.copysign(t_slide, sgn))
            if om[i] != 0.0 and new * om[i] < 0.0 and t_break > abs(t_other):
                om[i] = 0.0
                locked[i] = True
            else:
                om[i] = new
        for i in range(2):
            ang[i] += dt * om[i]
        f_aero = 0.5 * p[P_RHO] * p[P_CDA] * v * abs(v)
        ax = (fxs[0] + fxs[1] - f_aero) / m - G * math.sin(gam)
        v += dt * ax
        ax_prev = ax
        m_pitch = -a * f_sf + b * f_sr - ms * ax * p[P_H]
        w += dt * (f_sf + f_sr - dw) / ms
        q += dt * m_pitch / p[P_IYY]
        z += dt * w
        th += dt * q
    return out


def pitch_params(car: dict, tyre: str, added_mass: float = 0.0, brake_scale: float = 1.0, rr_added: float = 0.0,
                 grade: float = 0.0, brake_lag: float = 0.0, brake_balance: float = 1.0,
                 radius_growth: float = 0.0) -> np.ndarray:
    """The pitch-plane kernel's parameter vector. Hidden effects: added mass at the sprung centre of mass,
    brake friction scale, added rolling-resistance coefficient (c Fz at each patch), road grade, a
    first-order lag from line pressure to brake torque; outside the catalogue: the rear brakes' gain times
    `brake_balance` with the front's raised to keep the total at equal pressure, the effective rolling
    radius growing with speed, r_e (1 + radius_growth v^2)."""
    p = np.zeros(NPITCH)
    p[P_MS], p[P_MU4] = car["sprung_mass"], 2 * (car["unsprung_front"] + car["unsprung_rear"])
    L = car["a"] + car["b"]
    # the sprung mass's own centre: the describe numbers are of the whole car; the unsprung masses sit at
    # the axles, so the sprung centre is where the whole car's is, shifted for them
    mu_f, mu_r = 2 * car["unsprung_front"], 2 * car["unsprung_rear"]
    a_s = (car["mass"] * car["a"] - mu_r * L) / car["sprung_mass"]
    p[P_A], p[P_B], p[P_H], p[P_IYY] = a_s, L - a_s, car["sprung_h"], car["iyy"]
    p[P_JF], p[P_JR] = car["j_front"], car["j_rear"]
    p[P_KF], p[P_KR], p[P_CF], p[P_CR] = car["ride_f"], car["ride_r"], car["damp_f"], car["damp_r"]
    rear = brake_balance
    front = 1.0 + (1.0 - rear) * car["brake_gain_rear"] / car["brake_gain_front"]
    p[P_GF] = car["brake_gain_front"] * brake_scale * front
    p[P_GR] = car["brake_gain_rear"] * brake_scale * rear
    p[P_BRF], p[P_BRR] = car["brake_ratio_front"], car["brake_ratio_rear"]
    p[P_KNEE], p[P_PROP], p[P_TAU], p[P_RATE] = car["knee"], car["prop"], car["act_tau"], car["act_rate"]
    p[P_CDA], p[P_RHO] = car["drag_area"], car["air_density"]
    p[P_R0], p[P_CZ], p[P_FNOM] = car["unloaded_radius"], car["tyre_vertical"], car["fnomin"]
    p[P_CXN] = car["cx"] / car["fz_front"]
    p[P_MU] = car["mu_x"]
    p[P_RR] = car["rolling_resistance"]
    p[P_SIG] = car["relax_x"]
    p[P_ADD], p[P_RRADD], p[P_GRADE], p[P_BLAG], p[P_GROW] = added_mass, rr_added, grade, brake_lag, radius_growth
    p[P_TYRE] = TYRES[tyre]
    p[P_DREFF], p[P_BREFF], p[P_FREFF] = car["dreff"], car["breff"], car["freff"]
    return p


def pitch(p: np.ndarray, brake: np.ndarray, torque: np.ndarray, nsettle: int) -> np.ndarray:
    """Run the pitch-plane kernel: brake command (kPa) and drive torque per rear wheel (N m) at every DT step,
    the first `nsettle` before the logger starts; samples at RATE (columns: NOUT_PITCH)."""
    return _pitch(p, np.ascontiguousarray(brake, dtype=float), np.ascontiguousarray(torque, dtype=float), DT,
                  int(round(1.0 / (RATE * DT))), int(nsettle))
