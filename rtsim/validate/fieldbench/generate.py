"""A benchmark case's field runs: seven repetitions of the case's manoeuvre by its simulator with its hidden
effects, scattered and logged (scatter), written as the CSV files `rtsim validate` reads (`time` in s on
the logger's clock, then channels of rtsim.channels in SI units; a `# accel_frame: level|body` line says
the accelerometer's frame: level for the planar simulator without roll, body for the others).

Manoeuvres. Lateral: the case's speed held by a PI controller on the rear torques, the steering wheel
ramped to +A, held 3 s, ramped to -A, held 3 s, back to zero (nodes `STEER_T`), 12 s logged after 1.5 s
driven straight. Longitudinal: standing on the brake (2500 kPa), released, a drive torque pulse of the
case's amplitude (nodes `TORQUE_T`), coasting, braking to a stop at the case's pressure, 12 s logged
after 1 s standing.

Generated runs are cached on disk under `cache_root()` by the sha256 of the case, the car's numbers,
`VERSION` and the generator's code (every source file of this package: an edited simulator or scatter
gives new runs without a VERSION bump).
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from . import scatter, sims

VERSION = 1                  # raise when the generated data change
N_RUNS = 7
LAT_DURATION, LAT_SETTLE = 12.5, 1.5
LON_DURATION, LON_SETTLE = 12.0, 1.0
STEER_T = (1.0, 1.6, 4.6, 5.8, 8.8, 9.4)
STEER_SHAPE = (0.0, 1.0, 1.0, -1.0, -1.0, 0.0)
BRAKE_T = (0.0, 1.0, 2.5, 7.0, 10.0)
TORQUE_T = (2.6, 3.1, 5.1, 5.6)
LATERAL_CHANNELS = ("steering_wheel_angle", "brake_pressure", "wheel_torque_rl", "wheel_torque_rr",
                    "wheel_angle_fl", "wheel_angle_fr", "wheel_angle_rl", "wheel_angle_rr", "accel_x", "accel_y",
                    "gyro_z")
PITCH_CHANNELS = ("accel_x", "wheel_angle_fl", "wheel_angle_fr", "wheel_angle_rl", "wheel_angle_rr",
                  "brake_pressure", "wheel_torque_rl", "wheel_torque_rr")
#: catalogue effect -> the simulators' parameter
SIM_PARAM = {"tyre_slip_stiffness": "stiffness_scale", "mass": "added_mass", "road_grade": "grade",
             "brake_friction": "brake_scale", "rolling_resistance": "rr_added", "brake_lag": "brake_lag"}
OUTSIDE_PARAM = {"yaw_inertia_scale": "yaw_inertia_scale", "accel_cross_axis": "cross_axis",
                 "brake_balance": "brake_balance", "radius_growth": "radius_growth"}


def accel_frame(case: dict) -> str:
    return "level" if case["sim"] == "planar" else "body"


def channels(case: dict) -> tuple[str, ...]:
    if case["sim"] == "pitch":
        return PITCH_CHANNELS
    return LATERAL_CHANNELS + (("roll",) if case["sim"] == "roll" else ())


def _value(h: dict) -> float:
    return next(v for k, v in h.items() if k not in ("effect", "channel"))


def sim_kwargs(case: dict, model: bool = True, outside: bool = True) -> dict:
    """The simulator's keyword arguments of the case's hidden model effects (`model`) and effects outside
    the catalogue (`outside`)."""
    kw = {}
    if model:
        kw.update({SIM_PARAM[h["effect"]]: _value(h) for h in case["hidden"] if h["effect"] in SIM_PARAM})
    if outside:
        kw.update({OUTSIDE_PARAM[o["name"]]: o["value"] for o in case["outside"]})
    return kw


def sensor_effects(case: dict) -> dict[str, dict]:
    """channel -> {"bias"|"scale"|"delay": value} of the case's hidden sensor effects."""
    out: dict[str, dict] = {}
    for h in case["hidden"]:
        if h["effect"].startswith("sensor_"):
            out.setdefault(h["channel"], {})[h["effect"][len("sensor_"):]] = _value(h)
    return out


def simulate(case: dict, car: dict, sc: scatter.Scatter | None, kw: dict) -> tuple[np.ndarray, dict]:
    """One noise-free run (sc None: the nominal inputs without scatter): (time, channel -> samples at the
    logger rate), plus the simulator's internals under `_`-prefixed keys (wheel speeds, tyre states)."""
    dt = sims.DT
    if case["sim"] == "pitch":
        nset = int(round(LON_SETTLE / dt))
        tt = (np.arange(nset + int(round(LON_DURATION / dt)) + 1) - nset) * dt
        tt = np.maximum(tt, 0.0)
        bt, tq_t = np.array(BRAKE_T, float), np.array(TORQUE_T, float)
        gain = np.ones_like(tt)
        if sc is not None:
            bt, tq_t, gain = sc.nodes(bt), sc.nodes(tq_t), sc.gain(tt)
        brake = np.interp(tt, bt, (2500.0, 2500.0, 0.0, 0.0, case["brake"])) * gain
        torque = np.interp(tt, tq_t, (0.0, 1.0, 1.0, 0.0)) * case["torque"] * gain
        out = sims.pitch(sims.pitch_params(car, case["tyre"], **kw), brake, torque, nset)
        t = np.arange(out.shape[0]) / sims.RATE
        ch = {"accel_x": out[:, 0], "wheel_angle_fl": out[:, 1], "wheel_angle_fr": out[:, 1].copy(),
              "wheel_angle_rl": out[:, 2], "wheel_angle_rr": out[:, 2].copy(), "brake_pressure": out[:, 3],
              "wheel_torque_rl": out[:, 4], "wheel_torque_rr": out[:, 4].copy(),
              "_omega_front": out[:, 6], "_omega_rear": out[:, 7], "_speed": out[:, 8]}
        return t, ch
    nset = int(round(LAT_SETTLE / dt))
    tt = (np.arange(nset + int(round(LAT_DURATION / dt)) + 1) - nset) * dt
    st = np.array(STEER_T, float)
    gain = np.ones_like(tt)
    speed = case["speed"]
    if sc is not None:
        st, gain = sc.nodes(st), sc.gain(tt)
        speed *= 1.0 + sc.rng.normal(0.0, scatter.SPEED_SD)
    steer = np.interp(tt, st, np.array(STEER_SHAPE) * case["steer"]) * gain
    p = sims.lateral_params(car, case["sim"] == "roll", case["tyre"], **kw)
    out = sims.lateral(p, steer, speed, nset)
    t = np.arange(out.shape[0]) / sims.RATE
    ch = {"steering_wheel_angle": out[:, sims.O_STEER], "brake_pressure": np.zeros(t.size),
          "wheel_torque_rl": out[:, sims.O_TQ], "wheel_torque_rr": out[:, sims.O_TQ].copy(),
          **{f"wheel_angle_{w}": out[:, sims.O_PHI + i] for i, w in enumerate(("fl", "fr", "rl", "rr"))},
          "accel_x": out[:, sims.O_AX], "accel_y": out[:, sims.O_AY], "gyro_z": out[:, sims.O_GZ],
          "_fz": out[:, sims.O_FZ:sims.O_FZ + 4], "_tan_alpha": out[:, sims.O_TANA:sims.O_TANA + 4],
          "_fy": out[:, sims.O_FY:sims.O_FY + 4], "_omega": out[:, sims.O_OM:sims.O_OM + 4]}
    if case["sim"] == "roll":
        ch["roll"] = out[:, sims.O_ROLL]
    return t, ch


def write_csv(path: Path, t: np.ndarray, ch: dict, names, frame: str) -> Path:
    with path.open("w") as fh:
        fh.write(f"# accel_frame: {frame}\n")
        fh.write(",".join(("time", *names)) + "\n")
        np.savetxt(fh, np.column_stack([t, *(ch[c] for c in names)]), delimiter=",", fmt="%.9g")
    return path


def write_runs(case: dict, car: dict, folder: Path, n: int = N_RUNS, hidden: bool = True) -> list[Path]:
    """The case's n repetitions as CSV files in `folder` (`hidden` False: the same draws without any hidden
    effect, catalogue or outside)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(case["seed"])
    kw = sim_kwargs(case) if hidden else {}
    sens = sensor_effects(case) if hidden else {}
    names = channels(case)
    paths = []
    for k in range(n):
        sc = scatter.Scatter(rng)
        t, ch = simulate(case, car, sc, kw)
        for c, eff in sens.items():
            ch[c] = scatter.sensor_effect(t, ch[c], **eff)
        logged = {c: scatter.sensor_noise(rng, c, ch[c]) for c in names}
        k0, k1 = int(rng.integers(0, 125)), t.size - int(rng.integers(0, 125))
        clock = 50.0 * (k + 1) + rng.uniform(0.0, 1.0)
        paths.append(write_csv(folder / f"run{k + 1}.csv", t[k0:k1] + clock, {c: v[k0:k1] for c, v in logged.items()},
                               names, accel_frame(case)))
    return paths


def cache_root() -> Path:
    return Path(os.environ.get("RTSIM_FIELDBENCH_CACHE") or Path(tempfile.gettempdir()) / "rtsim_fieldbench")


_CODE: list[str] = []


def code_digest() -> str:
    """SHA-256 of this package's source files (names and bytes; once per process). The package imports
    nothing of rtsim (tests/test_validate_benchmark.py), so it hashes itself rather than use rtsim.sources."""
    if not _CODE:
        h = hashlib.sha256()
        for p in sorted(Path(__file__).resolve().parent.glob("*.py")):
            h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
        _CODE.append(h.hexdigest())
    return _CODE[0]


def key(case: dict, car: dict, extra: str = "") -> str:
    """20 hex digits naming what the case's runs are made of: the case, the car, VERSION, the generator's
    code (code_digest) and `extra` (what else a caller's product depends on)."""
    code = code_digest()
    blob = json.dumps({"case": case, "car": car, "version": VERSION, "code": code, "extra": extra}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def generate(case: dict, car: dict, root: Path | None = None, hidden: bool = True) -> list[Path]:
    """The case's runs, from the cache when there (written to a temporary folder and renamed into place,
    so concurrent callers never see half a set)."""
    root = Path(root or cache_root())
    folder = root / f"{case['id']}_{key(case, car, '' if hidden else 'clean')}"
    if not (folder / "done").exists():
        root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=root, prefix=".tmp_"))
        write_runs(case, car, tmp, hidden=hidden)
        (tmp / "done").write_text("ok\n")
        try:
            os.rename(tmp, folder)
        except OSError:                    # another process was first
            import shutil
            shutil.rmtree(tmp, ignore_errors=True)
    return sorted(folder.glob("run*.csv"), key=lambda p: int(p.stem[3:]))
