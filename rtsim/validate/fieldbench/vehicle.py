"""The car's numbers for the field-data simulators: the dictionary `rtsim describe --json` prints (given
as a dict) and a few values read from the vehicle TOML and its tyre property file with tomllib and a few
lines of parsing. No model code: ride and roll rates come from the springs through a front-view (y-z)
instant-centre analysis of the corner's hardpoints, a few lines of plane geometry."""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np


def read_tir(path: Path) -> dict[str, float]:
    """The numeric `KEY = value` lines of a tyre property file."""
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


def _cross(p1, d1, p2, d2) -> np.ndarray:
    s = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)[0]
    return p1 + s * d1


def front_view(kind: str, hp: dict) -> tuple[float, float]:
    """(installation ratio: spring compression per unit wheel rise, roll-centre height m) of a corner from
    its left hardpoints: the knuckle turns about its instant centre (double wishbone: where the arm lines
    cross; strut: where the lower arm line crosses the normal to the strut at its top mount); the roll
    centre is where the line from the contact patch through that centre crosses the car's centre line."""
    pivot = 0.5 * (_yz(hp["lower_front"]) + _yz(hp["lower_rear"]))
    ball = _yz(hp["lower_ball"])
    centre = _yz(hp["wheel_centre"])
    rot = lambda w, r: w * np.array([-r[1], r[0]])          # noqa: E731  velocity about a centre
    if kind == "double_wishbone":
        upper = 0.5 * (_yz(hp["upper_front"]) + _yz(hp["upper_rear"]))
        ic = _cross(pivot, ball - pivot, upper, _yz(hp["upper_ball"]) - upper)
        w_arm = np.linalg.norm(ball - ic) / np.linalg.norm(ball - pivot) * np.sign(np.dot(ball - ic, ball - pivot))
        lo, up = _yz(hp["spring_lower"]), _yz(hp["spring_upper"])
        v_mount = rot(w_arm, lo - pivot)
    else:
        top, lo = _yz(hp["strut_top"]), _yz(hp["strut_lower"])
        axis = top - lo
        ic = _cross(pivot, ball - pivot, top, np.array([axis[1], -axis[0]]))
        up = top
        v_mount = rot(1.0, lo - ic)
    u = (up - lo) / np.linalg.norm(up - lo)
    ratio = float(np.dot(v_mount, u) / rot(1.0, centre - ic)[1])
    patch = np.array([centre[0], 0.0])
    rc = patch + (ic - patch) * (0.0 - patch[0]) / (ic[0] - patch[0])
    return ratio, float(rc[1])


def numbers(desc: dict, vehicle: Path) -> dict[str, float]:
    """The simulators' car: SI numbers from `desc` (rtsim describe) and the vehicle TOML."""
    vehicle = Path(vehicle)
    cfg = tomllib.loads(vehicle.read_text())
    tir = read_tir(vehicle.parent / cfg["tyres"]["property_file"])
    a, L = desc["cg_to_front_axle"], desc["wheelbase"]
    b = L - a
    mu_f, mu_r = cfg["front"]["unsprung_mass_kg"], cfg["rear"]["unsprung_mass_kg"]
    tf, tr = desc["track_front"], desc["track_rear"]
    izz = (cfg["chassis"]["inertia_kgm2"][2] + 2 * mu_f * (a ** 2 + (tf / 2) ** 2) + 2 * mu_r * (b ** 2 + (tr / 2) ** 2))
    k_tyre = tir["VERTICAL_STIFFNESS"]
    out = {"mass": desc["mass"], "sprung_mass": cfg["chassis"]["mass_kg"], "unsprung_front": mu_f,
           "unsprung_rear": mu_r, "izz": izz, "ixx": cfg["chassis"]["inertia_kgm2"][0],
           "iyy": cfg["chassis"]["inertia_kgm2"][1], "a": a, "b": b, "h": desc["cg_height"],
           "sprung_h": cfg["chassis"]["cg_m"][2], "track_front": tf, "track_rear": tr,
           "radius": desc["wheel_radius"], "j_front": desc["wheel_inertia"],
           "j_rear": cfg["rear"]["wheel_spin_inertia_kgm2"], "cy_front": desc["cornering_stiffness_front"],
           "cy_rear": desc["cornering_stiffness_rear"], "cx": desc["slip_stiffness"],
           "fz_front": desc["static_wheel_loads"][0], "fz_rear": desc["static_wheel_loads"][2],
           "mu_x": tir.get("PDX1", 1.0), "mu_y": tir.get("PDY1", 1.0),
           "rolling_resistance": desc["rolling_resistance_coefficient"], "drag_area": desc["drag_area"],
           "air_density": cfg["aero"]["air_density_kg_m3"], "steering_ratio": desc["steering_ratio"],
           "brake_gain_front": desc["brake_gain_front"], "brake_gain_rear": desc["brake_gain_rear"],
           "unloaded_radius": tir["UNLOADED_RADIUS"], "tyre_vertical": k_tyre, "fnomin": tir["FNOMIN"],
           "relax_x": tir.get("PTX1", 0.6) * tir["UNLOADED_RADIUS"], "dreff": tir.get("DREFF", 0.0),
           "breff": tir.get("BREFF", 0.0), "freff": tir.get("FREFF", 0.0)}
    br = cfg["brakes"]
    out.update(brake_ratio_front=br["front"]["mu_static"] / br["front"]["mu"],
               brake_ratio_rear=br["rear"]["mu_static"] / br["rear"]["mu"], knee=br["proportioning_knee"],
               prop=br["proportioning_ratio"], act_tau=br["actuator"]["time_constant"],
               act_rate=br["actuator"]["rate_limit"])
    for axle, key in (("front", "f"), ("rear", "r")):
        ax = cfg[axle]
        ratio, rc = front_view(ax["suspension"], ax["hardpoints"])
        sp = ax["spring"]
        k_w = sp["stiffness_n_per_m"] * ratio ** 2
        track = tf if axle == "front" else tr
        out[f"ride_{key}"] = k_w * k_tyre / (k_w + k_tyre)       # per wheel, spring and tyre in series
        out[f"damp_{key}"] = 0.5 * (sp["damping_bump_ns_per_m"] + sp["damping_rebound_ns_per_m"]) * ratio ** 2
        out[f"roll_stiffness_{key}"] = (k_w + ax.get("anti_roll_bar_n_per_m", 0.0)) * track ** 2 / 2  # N m/rad
        out[f"roll_damping_{key}"] = out[f"damp_{key}"] * track ** 2 / 2
        out[f"roll_centre_{key}"] = rc
    return {k: float(v) if not isinstance(v, str) else v for k, v in out.items()}


def brush_force(mu_fz: float, fx_lin: float, fy_lin: float) -> tuple[float, float]:
    """The brush tyre law (parabolic pressure, Pacejka "Tyre and Vehicle Dynamics" sec. 3.2) on the linear
    forces: psi = |F_lin| / (3 mu Fz); |F| = mu Fz (3 psi - 3 psi^2 + psi^3) below full sliding, mu Fz
    above; direction of F_lin. (Reference for the kernels' inline copy.)"""
    f = math.hypot(fx_lin, fy_lin)
    if f < 1e-12:
        return fx_lin, fy_lin
    psi = f / (3.0 * mu_fz)
    mag = mu_fz * (3 * psi - 3 * psi ** 2 + psi ** 3) if psi < 1.0 else mu_fz
    return fx_lin * mag / f, fy_lin * mag / f
