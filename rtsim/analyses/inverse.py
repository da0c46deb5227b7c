"""Inverse dynamics of the motorcycle: the steering torque and the rear-wheel drive torque that make the
full nonlinear model follow a path at a speed profile.

Why not a direct inversion. The path is not an output the steering torque can be solved for step by
step: from torque to lateral position the motorcycle is non-minimum-phase (counter-steering: it first
moves the wrong way), so the exact inverse of the path is unstable forward in time, and the machine
is under-actuated (two inputs for eleven degrees of freedom). The roll angle, however, answers the
steering torque directly (torque left, lean right, from the first instant), and the path fixes the
roll it needs: the quasi-steady lean of the curvature ahead. So the problem is split as a rider does:

1. Reference from the path (the rider's tracking, rtsim.vehicle.motorcycle.rider, its gains): the lean
   phi_ref = -atan(u^2 kappa(s + preview) / g) + asin(k sin(.)) (the tyres' crown correction) plus a
   small lean correction from the lateral and heading errors (which keeps the path error bounded: the
   roll reference alone would let it drift), and the target speed u_ref.
2. Inversion of roll and speed on the full model (a shooting method, predictive functional control):
   every `interval` the inputs (tau, T) are held constant over a horizon H and chosen so that the
   model, simulated from the current state, reaches at t + H the points of first-order approaches to
   the references, phi(t + H) = phi_ref + (phi(t) - phi_ref) exp(-H / t_roll) and likewise the speed
   with t_speed. Two equations in two unknowns, solved by Newton's method with a finite-difference
   Jacobian (the model copied and re-run: no linearisation is assumed); the Jacobian is refreshed
   every `jacobian_every` intervals and the Newton iteration repeated until the roll misses its target
   by less than `tol`. The first `interval` of the solution is applied to the model and the horizon
   moves on.

In a steady state both targets are reached with the inputs held, so the solved torque is the model's
own steady steering torque of that turn, independent of any gains (the test compares it with the
rider's). The outputs: t, steering torque, drive torque, roll, steer, speed, the lateral error and the
solver's residual.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtsim.errors import SimulationError
from rtsim.vehicle.motorcycle.rider import (NRO, NRV, RiderState, RV_DELTA, RV_DELTADOT, RV_PHI, RV_PHIDOT, RV_R, RV_T,
                                            RV_U, RV_V, RV_X, RV_Y, RV_YAW, Rider, rider_step)
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim, rear_contact
from rtsim.vehicle.motorcycle.step import U_BRAKE_FRONT, U_BRAKE_REAR, U_DRIVE_TORQUE, U_STEER_TORQUE

COLUMNS = ("time", "steering_torque", "drive_torque", "roll_angle", "roll_reference", "steer_angle", "speed",
           "speed_reference", "lateral_error", "roll_residual")


@dataclass(frozen=True)
class InverseOptions:
    horizon: float = 0.3         # s, H (shorter: the roll overshoots between the coincidence points)
    interval: float = 0.05       # s, inputs re-solved this often
    t_roll: float = 0.3          # s, approach of the roll to its reference
    t_speed: float = 0.5         # s, approach of the speed to its reference
    jacobian_every: int = 4      # intervals between Jacobian refreshes
    tol: float = 2e-4            # rad, roll miss at t + H that ends the Newton iteration
    max_newton: int = 3
    max_torque: float = 150.0    # N m, |steering torque|
    drive_range: tuple[float, float] = (-1500.0, 3000.0)   # N m at the rear wheel


class _Snapshot:
    """The sim's whole state (integrator data, tyre slip states and outputs, inputs), copied and restored."""

    def __init__(self, sim: TwoWheelerSim):
        self.sim = sim
        self.arrays = [a.copy() for a in sim.data] + [sim.parts.slip.copy(), sim.parts.tyre.copy(), sim.parts.u.copy()]

    def restore(self) -> None:
        s = self.sim
        for dst, src in zip(list(s.data) + [s.parts.slip, s.parts.tyre, s.parts.u], self.arrays):
            np.copyto(dst, src)


def _view(sim: TwoWheelerSim, v: np.ndarray) -> None:
    x, y = rear_contact(sim)
    u, lat = sim.velocity
    v[RV_T], v[RV_X], v[RV_Y], v[RV_YAW] = sim.time, x, y, sim.yaw
    v[RV_U], v[RV_V], v[RV_R] = u, lat, sim.yaw_rate
    v[RV_PHI], v[RV_PHIDOT], v[RV_DELTA], v[RV_DELTADOT] = sim.roll, sim.roll_rate, sim.steer, sim.steer_rate


class InverseDynamics:
    """Solve (steering torque, drive torque) for `sim` to follow the path and speed of `reference` (a
    drivers.rider Rider: only its path tracking and lean reference are used)."""

    def __init__(self, sim: TwoWheelerSim, reference: Rider, options: InverseOptions = InverseOptions()):
        self.sim, self.ref, self.opt = sim, reference, options
        self.view = np.zeros(NRV)
        self.out = np.zeros(NRO)
        self.x = np.zeros(2)             # (tau, T) of the last interval
        self.jac: np.ndarray | None = None
        self.k = 0
        self.rows: list[tuple] = []
        self.h_steps = max(1, int(round(options.horizon / sim.dt)))
        self.i_steps = max(1, int(round(options.interval / sim.dt)))
        self.newton_iterations = 0
        self.simulated_steps = 0

    def _predict(self, snap: _Snapshot, x) -> np.ndarray:
        """(roll, speed) at t + H with the inputs x held; the state restored afterwards."""
        s = self.sim
        u = s.parts.u
        u[U_STEER_TORQUE], u[U_DRIVE_TORQUE], u[U_BRAKE_FRONT], u[U_BRAKE_REAR] = x[0], x[1], 0.0, 0.0
        try:
            for _ in range(self.h_steps):
                s.step()
            y = np.array([s.roll, s.velocity[0]])
        except SimulationError:
            y = np.array([np.nan, np.nan])
        self.simulated_steps += self.h_steps
        snap.restore()
        return y

    def _jacobian(self, snap, x, y0) -> np.ndarray:
        d = (0.5, 20.0)
        jac = np.zeros((2, 2))
        for j in range(2):
            xp = x.copy()
            xp[j] += d[j]
            jac[:, j] = (self._predict(snap, xp) - y0) / d[j]
        return jac

    def solve_interval(self) -> None:
        """Solve the inputs for the next interval and advance the model over it."""
        s, o = self.sim, self.opt
        _view(s, self.view)
        rider_step(self.ref, self.view, self.out)          # updates the path tracking and the lean reference
        st = self.ref.st
        phi_r, u_r = st[RiderState.PHI_REF], st[RiderState.V_REF]
        u_now = s.velocity[0]
        target = np.array([phi_r + (s.roll - phi_r) * math.exp(-o.horizon / o.t_roll),
                           u_r + (u_now - u_r) * math.exp(-o.horizon / o.t_speed)])
        snap = _Snapshot(s)
        x = self.x.copy()
        y = self._predict(snap, x)
        if self.jac is None or self.k % o.jacobian_every == 0 or not np.all(np.isfinite(y)):
            self.jac = self._jacobian(snap, x, y)
        for _ in range(o.max_newton):
            if np.all(np.isfinite(y)) and abs(y[0] - target[0]) < o.tol:
                break
            step = np.linalg.solve(self.jac, target - y) if np.all(np.isfinite(y)) else -0.5 * (x - self.x)
            x = x + step
            x[0] = min(max(x[0], -o.max_torque), o.max_torque)
            x[1] = min(max(x[1], o.drive_range[0]), o.drive_range[1])
            y = self._predict(snap, x)
            self.newton_iterations += 1
        self.x = x
        u = s.parts.u
        u[U_STEER_TORQUE], u[U_DRIVE_TORQUE], u[U_BRAKE_FRONT], u[U_BRAKE_REAR] = x[0], x[1], 0.0, 0.0
        resid = float(y[0] - target[0])
        for _ in range(self.i_steps):
            s.step()
            self.rows.append((s.time, x[0], x[1], s.roll, phi_r, s.steer, s.velocity[0], u_r, st[RiderState.N], resid))
        self.simulated_steps += self.i_steps
        self.k += 1

    def run(self, seconds: float) -> np.ndarray:
        n = int(round(seconds / (self.i_steps * self.sim.dt)))
        for _ in range(n):
            self.solve_interval()
        return np.array(self.rows)


# ---- the command ----------------------------------------------------------------------------------------


def add_arguments(p) -> None:
    p.add_argument("--scenario", metavar="FILE",
                   help="a motorcycle scenario with [rider]: its path, speed and vehicle")
    p.add_argument("--vehicle", metavar="FILE", help="motorcycle TOML (default: the scenario's)")
    p.add_argument("--path", metavar="CSV", help="instead of a scenario: the path, a CSV with columns x and y (m), "
                   "starting at the origin heading +x")
    p.add_argument("--closed", action="store_true", help="--path is a closed loop")
    p.add_argument("--speed", type=float, metavar="M/S",
                   help="target speed, m/s (with --path; default: the scenario's)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="s (default: the scenario's, else the path's length / speed)")
    p.add_argument("--out", required=True, metavar="FILE.csv",
                   help="CSV of t, steering torque, drive torque, roll, steer, ...")
    p.add_argument("--summary", metavar="JSON", help="also write the summary to this file")


def main(args) -> int:
    import json
    from pathlib import Path

    from drivers.replay import parse_column, read_csv_table
    from rtsim.vehicle.motorcycle.rider import rider as make_rider
    from drivers.scenario import load_scenario
    from rtsim.compile_status import configs_first
    from rtsim.errors import ConfigError

    from rtsim.vehicle.motorcycle.build import build_motorcycle
    from rtsim.vehicle.motorcycle.config import load_motorcycle
    from rtsim.vehicle.motorcycle.ride import tyre_lean_ratio
    from rtsim.vehicle.motorcycle.sim import static_pose

    sc = None
    with configs_first():       # both files validated before a compile notice (the scenario's check compiles)
        if args.scenario:
            sc = load_scenario(args.scenario, check_files=True)
            if sc.spec.rider is None:
                raise ConfigError(f"{args.scenario}: the inverse problem needs a [rider] section (path and speed)")
        elif not args.path or args.speed is None:
            raise ConfigError("give --scenario, or --path CSV and --speed")
        vpath = args.vehicle or (sc.vehicle_path if sc is not None else None)
        if vpath is None:
            raise ConfigError("give --vehicle (or a scenario that names its vehicle)")
        loaded = load_motorcycle(vpath)
    mm = build_motorcycle(*loaded)
    k = tyre_lean_ratio(mm)
    if sc is not None:
        spec = sc.spec.rider
        if "tyre_lean" not in spec.model_fields_set:
            spec = spec.model_copy(update={"tyre_lean": k})
        if args.speed is not None:
            spec = spec.model_copy(update={"speed": float(args.speed), "time": None, "distance": None})
        ref = spec.build()
        speed0 = sc.spec.initial.speed if args.speed is None else args.speed
        duration = args.duration or sc.duration
        dt = sc.dt
    else:
        header, rows, lines = read_csv_table(Path(args.path))
        x = parse_column(Path(args.path), header, rows, lines, "x")
        y = parse_column(Path(args.path), header, rows, lines, "y")
        try:
            ref = make_rider(x, y, closed=args.closed, speed=args.speed, tyre_lean=k)
        except ValueError as exc:
            raise ConfigError(f"{args.path}: {exc}") from None
        speed0, dt = args.speed, 1e-3
        length = float(ref.ps[-1])
        duration = args.duration or max(length / max(args.speed, 0.1) - 1.0, 1.0)
    if not (duration > 0 and math.isfinite(duration)):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration}")
    q, _ = static_pose(mm, dt=dt)
    sim = TwoWheelerSim(mm, dt=dt, speed=speed0, q=q)
    inv = InverseDynamics(sim, ref)
    status, message = "ok", ""
    try:
        inv.run(duration)
    except SimulationError as exc:
        status, message = ("fall" if "fell" in str(exc) else "failed"), str(exc)
    data = np.array(inv.rows) if inv.rows else np.zeros((0, len(COLUMNS)))
    with open(args.out, "w") as fh:
        fh.write(",".join(COLUMNS) + "\n")
        for r in data[::10]:
            fh.write(",".join(f"{v:.9g}" for v in r) + "\n")
    summary = {"status": status, "simulated_s": round(sim.time, 3), "method": "horizon shooting on the full model "
               f"(H = {inv.opt.horizon} s, every {inv.opt.interval} s)",
               "model_steps_per_real_step": round(inv.simulated_steps / max(len(inv.rows), 1), 2)}
    if message:
        summary["message"] = message
    if data.shape[0]:
        n = data[:, COLUMNS.index("lateral_error")]
        tail = data[data[:, 0] >= data[-1, 0] - min(3.0, 0.3 * data[-1, 0])]
        summary.update({
            "lateral_error_rms_m": round(float(np.sqrt(np.mean(n ** 2))), 4),
            "lateral_error_peak_m": round(float(np.max(np.abs(n))), 4),
            "roll_residual_max_rad": round(float(np.max(np.abs(data[:, -1]))), 6),
            "peak_steering_torque_nm": round(float(np.max(np.abs(data[:, 1]))), 3),
            "last_window": {"from_s": round(float(tail[0, 0]), 3),
                            "steering_torque_nm": round(float(np.mean(tail[:, 1])), 3),
                            "drive_torque_nm": round(float(np.mean(tail[:, 2])), 2),
                            "roll_deg": round(math.degrees(float(np.mean(tail[:, 3]))), 3),
                            "steer_deg": round(math.degrees(float(np.mean(tail[:, 5]))), 3),
                            "speed_m_s": round(float(np.mean(tail[:, 6])), 3)}})
    text = json.dumps(summary, indent=2)
    if args.summary:
        Path(args.summary).write_text(text + "\n")
    print(text)
    print(f"{len(data[::10])} rows -> {args.out}")
    return 0 if status == "ok" else 3
