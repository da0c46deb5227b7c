"""`rtsim bench --suite vehicle`: the cost per step of the full vehicle model (MF tyres, suspension
kinematics, brakes, powertrain, steer-by-wire) on each road kind, in compiled stepping loops, with the
share of each part measured by timing its kernels alone on the same state."""
from __future__ import annotations

import time
from pathlib import Path

import numba as nb
import numpy as np

from rtsim.jit import cycles_per_second, read_cycles

from rtsim.road.config import load_road
from rtsim.road.model import make_plane
from rtsim.road.query import NCONTACT, wheel_contact
from rtsim.vehicle.kit.brake import brake_step
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.step import CMD_STEER, CMD_THROTTLE, vehicle_forces, TyreOut
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.layout import CI_WX
from rtsim.vehicle.kit.powertrain import powertrain_step
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.kit.steering import steering_control
from rtsim.vehicle.kit.tyre.magic_formula import mf52_forces, transient_slip
from rtsim.vehicle.motorcycle.step import two_wheeler_step
from drivers.rider import rider_step

ROOT = Path(__file__).resolve().parents[2]


def _clock(fn, reps: int) -> float:
    fn(1)
    t0 = time.perf_counter()
    fn(reps)
    return (time.perf_counter() - t0) / reps


def _vehicle(road_path: Path | None, vehicle: str = "xbw"):
    cfg, base = load_vehicle(ROOT / "configs" / "vehicles" / f"{vehicle}.toml")
    model = build_vehicle(cfg, base)
    road = load_road(road_path) if road_path is not None else make_plane()
    return model, road


def run_scenario(name: str, road_path: Path | None, speed: float, steer: float, steps: int = 3000,
                 vehicle: str = "xbw", audit: bool = False) -> dict:
    """Steps of a car (configs/vehicles/<vehicle>.toml) at 1 ms with the commands held; `audit`: with
    the power audit on (rtsim.vehicle.car.energy). The parts' shares are timed for the steer-by-wire car."""
    model, road = _vehicle(road_path, vehicle)
    sim = VehicleSim(model, road, 1e-3, speed=speed, position=(2.0, 0.0))
    if audit:
        sim.start_energy_audit()
    sim.io.commands[CMD_THROTTLE] = 0.2
    sim.io.commands[CMD_STEER] = steer
    sim.step(200)                                   # compile/load, settle
    s0 = sim.data.stats.copy()
    t0 = time.perf_counter()
    sim.step(steps)
    wall = time.perf_counter() - t0
    if np.any(sim.vd.tyre[:, TyreOut.FZ] <= 0.0):
        raise RuntimeError(f"{name}: a wheel left the road during the benchmark")
    s1 = sim.data.stats
    shares = {} if sim.has_eps else _shares(sim)
    per_step = wall / steps
    # the formulation (constraints, factorizations, Newton, projections) is what remains of the step
    if shares:
        shares["formulation (ALI3-P: constraints, factorizations, Newton, projections)"] = max(
            0.0, per_step - sum(shares.values()))
    total_parts = sum(shares.values()) or 1.0
    return {
        "scenario": name,
        "road": "plane" if road_path is None else road_path.stem,
        "dt": 1e-3,
        "steps": steps,
        "wall_s": wall,
        "us_per_step": per_step * 1e6,
        "newton_iterations_per_step": float(s1[1] - s0[1]) / steps,
        "factorizations_per_step": float(s1[2] - s0[2]) / steps,
        "share": {k: v / total_parts for k, v in shares.items()},
        "parts_us_per_step": {k: v * 1e6 for k, v in shares.items()},
    }


def _shares(sim: VehicleSim) -> dict:
    """Seconds per step of each part but the formulation, from its kernels timed alone on the current
    state, times their calls per step (Newton iterations + the finishing evaluation)."""
    m, d, veh, vd, road = sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road
    parts, states, io = sim.parts, sim.states, sim.io
    h = sim.dt
    bq, hc = 0.25 * h * h, 0.5 * h
    iters = max(1.0, float(d.stats[1]) / max(1.0, float(d.stats[0])))
    reps = 2000
    out = {}
    bs, ps, ss = states.brake.copy(), states.powertrain.copy(), states.steering.copy()
    out["subsystems (brake, powertrain, steering)"] = _clock(
        lambda n: _subsystems(parts, states, io, vd, h, n), reps)
    states.brake[:], states.powertrain[:], states.steering[:] = bs, ps, ss
    t_contact = _clock(lambda n: _contacts(m, d, veh, road, n), reps)
    t_tyre = _clock(lambda n: _tyres(parts.tyre, vd, n), reps)
    t_forces = _clock(lambda n: _forces(m, d, veh, vd, road, parts, states, bq, hc, n), reps)
    calls = iters + 1.0                                  # Newton iterations + the finishing evaluation
    out["road contact"] = t_contact * calls
    out["tyres (MF 5.2 + transient slip)"] = t_tyre * calls
    out["other vehicle forces (suspension, brakes, aero)"] = max(0.0, t_forces - t_contact - t_tyre) * calls
    return out


@nb.njit(cache=True)
def _subsystems(parts, states, io, vd, h, n):
    for _ in range(n):
        brake_step(parts.brake, states.brake, vd.brake_in, h, vd.brake_out)
        steering_control(parts.steering, states.steering, io.commands[2], 0.0, 0.0, h)
        powertrain_step(parts.powertrain, states.powertrain, io.pt_in, h, io.pt_out)


@nb.njit(cache=True)
def _contacts(m, d, veh, road, n):
    ct = np.empty(NCONTACT)
    for _ in range(n):
        for i in range(4):
            k = veh.corner_idx[i, CI_WX]
            wheel_contact(road, d.q[k], d.q[k + 1], d.q[k + 2], 0.0, 1.0, 0.0, 0.289, ct)


@nb.njit(cache=True)
def _tyres(tp, vd, n):
    for _ in range(n):
        for i in range(4):
            k, a = transient_slip(tp, vd.slip, i, 2000.0, 0.0, 20.0, 0.1, 71.0, 0.28)
            mf52_forces(tp, 2000.0, k, a, 0.0, 20.0, 1.0)


@nb.njit(cache=True)
def _forces(m, d, veh, vd, road, parts, states, bq, hc, n):
    for _ in range(n):
        for i in range(m.nq):
            d.force[i] = 0.0
        vehicle_forces(m, d, veh, vd, road, parts, states, False, bq, hc)


@nb.njit(cache=True, _nrt=False)
def _two_wheeler_loop_timed(m, d, h, idx, par, tab, u, tp, slip, tyre, cycles):
    """One step per entry of `cycles`, each step's cost in processor cycles stored there."""
    for k in range(cycles.shape[0]):
        c0 = read_cycles()
        status = two_wheeler_step(m, d, h, idx, par, tab, u, tp, slip, tyre)
        cycles[k] = read_cycles() - c0
        if status != 0:
            return status
    return 0


@nb.njit(cache=True, _nrt=False)
def _rider_loop(r, view, out, n):
    for k in range(n):
        view[0] = k * 1e-3
        rider_step(r, view, out)


def motorcycle_turning():
    """The sport motorcycle (configs/vehicles/motorcycle.toml) at 20 m/s with 2 N m of steering torque held."""
    from rtsim.vehicle.motorcycle.build import build_motorcycle
    from rtsim.vehicle.motorcycle.config import load_motorcycle
    from rtsim.vehicle.motorcycle.sim import TwoWheelerSim, static_pose
    from rtsim.vehicle.motorcycle.step import U_STEER_TORQUE

    cfg, base = load_motorcycle(ROOT / "configs" / "vehicles" / "motorcycle.toml")
    mm = build_motorcycle(cfg, base)
    q, _ = static_pose(mm)
    sim = TwoWheelerSim(mm, speed=20.0, q=q)
    sim.parts.u[U_STEER_TORQUE] = 2.0
    return sim


def run_motorcycle(steps: int = 3000) -> dict:
    """The sport motorcycle at 20 m/s with a steering torque held (leaning into a turn), its step in a
    compiled loop, and the rider's kernel on the figure-eight timed alone on a fixed view.

    The step's cost is the median of the steps' own costs (each timed with the processor's cycle
    counter inside the loop): the bar is a median, and on a shared machine the steps the process lost
    its core in are outliers, not the step's cost. The mean over the run's wall time is given beside it."""
    from rtsim.road.paths import figure_eight
    from drivers.rider import NRO, NRV, RV_U, rider

    sim = motorcycle_turning()
    p = sim.parts
    args = (p.idx, p.par, p.tab, p.u, p.tp, p.slip, p.tyre)
    _two_wheeler_loop_timed(sim.model, sim.data, 1e-3, *args, np.zeros(200, dtype=np.int64))   # compile/load, settle
    s0 = sim.data.stats.copy()
    cycles = np.zeros(steps, dtype=np.int64)
    t0 = time.perf_counter()
    status = _two_wheeler_loop_timed(sim.model, sim.data, 1e-3, *args, cycles)
    wall = time.perf_counter() - t0
    if status != 0:
        raise RuntimeError(f"motorcycle benchmark: step failed with status {status}")
    s1 = sim.data.stats
    px, py = figure_eight(20.0, straight=20.0)
    r = rider(px, py, closed=True, speed=10.0)
    view, out = np.zeros(NRV), np.zeros(NRO)
    view[RV_U] = 10.0
    rider_s = _clock(lambda n: _rider_loop(r, view, out, n), 20000)
    step = float(np.median(cycles)) / cycles_per_second()
    return {
        "scenario": "motorcycle 20 m/s, steering torque held, rider kernel (median step)",
        "road": "plane", "dt": 1e-3, "steps": steps, "wall_s": wall,
        "us_per_step": (step + rider_s) * 1e6,
        "us_per_step_mean": (wall / steps + rider_s) * 1e6,
        "newton_iterations_per_step": float(s1[1] - s0[1]) / steps,
        "factorizations_per_step": float(s1[2] - s0[2]) / steps,
        "share": {"two-wheeler step": step / (step + rider_s), "rider": rider_s / (step + rider_s)},
        "parts_us_per_step": {"two-wheeler step": step * 1e6, "rider": rider_s * 1e6},
    }


def suite() -> list[dict]:
    campus = ROOT / "configs" / "roads" / "campus.toml"
    return [
        run_scenario("straight 30 km/h, campus mesh", campus, 8.33, 0.0),
        run_scenario("step steer 80 km/h, flat", None, 22.22, np.radians(35.0)),
        # the surveyed lane is ~6 m wide: a mild steer keeps the car on it for the 1.5 s measured
        run_scenario("steer 80 km/h, campus mesh", campus, 22.22, np.radians(4.0), steps=1500),
        # the 16-DOF car with electric power steering, the study's first life situation's steer
        run_scenario("EPS car, 35 deg step steer 80 km/h, flat", None, 22.22, np.radians(35.0), vehicle="eps_car"),
        run_scenario("EPS car, same, power audit on", None, 22.22, np.radians(35.0), vehicle="eps_car", audit=True),
        run_motorcycle(),
    ]
