"""`rtsim bench --suite vehicle --stages`: where a vehicle's step spends its time, stage by stage.

The step is run in a compiled loop that calls the same stage kernels as the vehicle's own step
(rtsim.vehicle.car.step.vehicle_step, rtsim.vehicle.motorcycle.step.two_wheeler_step, and inside them
the ALI3-P stages of rtsim.mbs.integrator.step_with), with the processor's cycle counter read between
stages. The car's force kernel is split the same way into its force stages (rtsim.vehicle.car.forces).
The staged loop computes exactly what the plain step computes (tests/test_bench_stages.py compares the
trajectories bit for bit); reading the counter adds a few nanoseconds per stage, so its total is a little
above the plain step's. Each stage's time is the median over blocks of steps (a shared machine takes the
processor away in bursts). Counts per step come from the integrator's statistics (Newton iterations,
factorizations, projection iterations) and from the loop itself (force evaluations, with tangent)."""
from __future__ import annotations

import numpy as np

from rtsim.jit import cycles_per_second, inline_kernel, kernel, read_cycles
from rtsim.mbs.integrator import (CONTINUE, CONVERGED, finish_evaluates, finish_factor, finish_prepare,
                                  finish_projections, finish_refactors, newton_factor, newton_failed, newton_increment,
                                  newton_prepare, newton_residual, step_begin, wants_tangent)
from rtsim.mbs.model import ERR_FACTOR, ERR_NONFINITE_FORCE, IS_MAX_ITER, OK, ST_FAIL_INDEX
from rtsim.vehicle.car.effect_kernels import FX_ON
from rtsim.vehicle.car.forces import (aero_stage, brake_stage, chassis_omega, corner_kinematics, drive_stage,
                                      effects_stage, spin_torques, steering_stage, suspension_stage, tyre_stage)
from rtsim.vehicle.car.step import vehicle_after_mbs, vehicle_before_mbs
from rtsim.vehicle.motorcycle.step import _forces_args as two_wheeler_forces_args, two_wheeler_after_mbs

# Stage slots of the cycle counts (the order the report lists them in).
(S_BEFORE, S_PREDICT, S_PREPARE, S_RESIDUAL, S_FACTOR, S_SOLVE, S_FINISH, S_PROJ_FACTOR, S_PROJECT, S_AFTER,
 F_SUSPENSION, F_KINEMATICS, F_BRAKE_DRIVE, F_TYRE, F_STEERING, F_AERO_EFFECTS, F_CHECK, F_ALL,
 N_FORCE_EVALS, N_TANGENT_EVALS, NSLOTS) = range(21)
STAGE_NAMES = {
    S_BEFORE: "subsystems before the step (brake, steering control, powertrain)",
    S_PREDICT: "ALI3-P predictor",
    S_PREPARE: "Newton: velocities, constraints and Jacobian, multipliers",
    S_RESIDUAL: "Newton: residual (M qdd + Phi_q^T lambda - Q)",
    S_FACTOR: "Newton: factorization of the tangent",
    S_SOLVE: "Newton: increment (solves) and convergence test",
    S_FINISH: "finish: velocities, constraints, multipliers at the converged q",
    S_PROJ_FACTOR: "finish: factorization for the projections",
    S_PROJECT: "finish: velocity and acceleration projections",
    S_AFTER: "commits after the step (brake modes, tyre deflections, signals)",
}
FORCE_NAMES = {
    F_SUSPENSION: "forces: suspension (springs, dampers, stops, anti-roll bars)",
    F_KINEMATICS: "forces: corner kinematics (spin axes, knuckle rates)",
    F_BRAKE_DRIVE: "forces: brakes and drive torques",
    F_TYRE: "forces: tyres (road contact, MF 5.2, transient slip)",
    F_STEERING: "forces: steering (column, rack, EPS)",
    F_AERO_EFFECTS: "forces: aero and effects",
    F_CHECK: "forces: finiteness check",
}


@inline_kernel
def _lap(cyc, slot, c0):
    c1 = read_cycles()
    cyc[slot] += c1 - c0
    return c1


@inline_kernel
def _car_forces_staged(m, d, a, tangent, bq, hc):
    """The staged car's force kernel as the Newton step calls it; a = (veh, vd, road, parts, states,
    cycles)."""
    return car_forces_staged(m, d, a[0], a[1], a[2], a[3], a[4], a[5], tangent, bq, hc)


@kernel
def car_forces_staged(m, d, veh, vd, road, parts, states, cyc, tangent, bq, hc):
    """rtsim.vehicle.car.forces.vehicle_forces stage by stage, with the cycles of each stage added to
    cyc. A compiled function of its own, called from the Newton iteration and the finish (the plain step
    inlines the forces' body into its Newton iteration, rtsim.vehicle.car.step._car_forces): inlined, it
    was compiled into the staged loop twice, and the loop's first compile took more than twice as long."""
    c = read_cycles()
    c_all = c
    fx = parts.effects
    f = d.force
    rec = vd.audit[0] > 0.5
    if rec:
        vd.pf[:, :] = 0.0
    om = chassis_omega(veh, d.q, d.qd)
    for i in range(4):
        suspension_stage(m, d, veh, vd, i, rec, tangent, bq, hc)
        c = _lap(cyc, F_SUSPENSION, c)
        kin = corner_kinematics(m, d, veh, vd, i, om)
        a_dot_tz = kin[0] * kin[3] + kin[1] * kin[4] + kin[2] * kin[5]
        c = _lap(cyc, F_KINEMATICS, c)
        tb = brake_stage(m, d, veh, vd, parts.brake, states.brake, i, rec, tangent, bq, hc)
        drive = drive_stage(m, d, veh, vd, fx, states.effects, i, a_dot_tz, rec, tangent, bq, hc)
        spin_torques(veh, f, i, tb, drive, a_dot_tz)
        c = _lap(cyc, F_BRAKE_DRIVE, c)
        tyre_stage(m, d, veh, vd, road, parts.tyre, fx, i, kin, rec, tangent, bq, hc)
        c = _lap(cyc, F_TYRE, c)
    steering_stage(m, d, veh, vd, parts.steering, states.steering, rec, tangent, bq, hc)
    c = _lap(cyc, F_STEERING, c)
    aero_stage(m, d, veh, vd, fx, rec, tangent, hc)
    if fx[FX_ON] > 0.5:
        effects_stage(m, d, veh, vd, fx, rec, tangent)
    c = _lap(cyc, F_AERO_EFFECTS, c)
    bad = -1
    for i in range(m.nq):
        if not np.isfinite(f[i]):
            bad = i
            break
    c = _lap(cyc, F_CHECK, c)
    _count_evaluation(cyc, c - c_all, tangent)
    return bad


@inline_kernel
def _count_evaluation(cyc, cycles, tangent):
    cyc[F_ALL] += cycles
    cyc[N_FORCE_EVALS] += 1
    if tangent:
        cyc[N_TANGENT_EVALS] += 1


@inline_kernel
def _two_wheeler_forces_staged(m, d, a, tangent, bq, hc):
    """The two-wheeler's force kernel as one stage; a = (its arguments..., cycles)."""
    cyc = a[7]
    c = read_cycles()
    bad = two_wheeler_forces_args(m, d, (a[0], a[1], a[2], a[3], a[4], a[5], a[6]), tangent, bq, hc)
    _count_evaluation(cyc, read_cycles() - c, tangent)
    return bad


# The split stages of rtsim.mbs.integrator's newton_update and finish_project (inline kernels there) as
# compiled functions of their own: inlined, they were compiled again into each vehicle's staged loop; so
# they are compiled once, for every vehicle. Each call costs the staged loop a little (it passes the
# model and the state), which the plain step, where they are compiled in, does not pay.
@kernel
def _newton_residual(m, d, h):
    newton_residual(m, d, h)


@kernel
def _newton_factor(m, d, h):
    return newton_factor(m, d, h)


@kernel
def _newton_increment(m, d, h):
    return newton_increment(m, d, h)


@kernel
def _finish_factor(m, d, h):
    return finish_factor(m, d, h)


@kernel
def _finish_projections(m, d, h):
    return finish_projections(m, d, h)


@inline_kernel
def _mbs_step_staged(m, d, h, add_forces, args, cyc):
    """rtsim.mbs.integrator.step_with stage by stage, the cycles of each stage added to cyc (the force
    kernel adds its own, and they are taken off the stage they run in by the report)."""
    bq = 0.25 * h * h
    hc = 0.5 * h
    c = read_cycles()
    step_begin(m, d, h)
    c = _lap(cyc, S_PREDICT, c)
    converged = False
    for _ in range(m.iset[IS_MAX_ITER]):
        status = newton_prepare(m, d, h)
        if status != OK:
            return status
        c = _lap(cyc, S_PREPARE, c)
        bad = add_forces(m, d, args, wants_tangent(m, d), bq, hc)
        c = read_cycles()
        if bad >= 0:
            d.stats[ST_FAIL_INDEX] = bad
            return ERR_NONFINITE_FORCE
        _newton_residual(m, d, h)
        c = _lap(cyc, S_RESIDUAL, c)
        if _newton_factor(m, d, h) != OK:
            return ERR_FACTOR
        c = _lap(cyc, S_FACTOR, c)
        status = _newton_increment(m, d, h)
        c = _lap(cyc, S_SOLVE, c)
        if status == CONVERGED:
            converged = True
            break
        if status != CONTINUE:
            return status
    if not converged:
        return newton_failed(m, d)
    status = finish_prepare(m, d, h)
    if status != OK:
        return status
    c = _lap(cyc, S_FINISH, c)
    if finish_evaluates(m, d):
        bad = add_forces(m, d, args, finish_refactors(m, d), bq, hc)
        c = read_cycles()
        if bad >= 0:
            d.stats[ST_FAIL_INDEX] = bad
            return ERR_NONFINITE_FORCE
    if _finish_factor(m, d, h) != OK:
        return ERR_FACTOR
    c = _lap(cyc, S_PROJ_FACTOR, c)
    status = _finish_projections(m, d, h)
    _lap(cyc, S_PROJECT, c)
    return status


@kernel
def car_steps_staged(m, d, veh, vd, road, parts, states, io, h, nsteps, cyc):
    """nsteps of rtsim.vehicle.car.step.vehicle_step, stage by stage (cycles into cyc). Returns
    (status, steps done)."""
    args = (veh, vd, road, parts, states, cyc)
    for n in range(nsteps):
        c = read_cycles()
        vehicle_before_mbs(m, d, veh, vd, parts, states, io, h)
        cyc[S_BEFORE] += read_cycles() - c
        status = _mbs_step_staged(m, d, h, _car_forces_staged, args, cyc)
        if status != OK:
            return status, n
        c = read_cycles()
        vehicle_after_mbs(m, d, veh, vd, parts, states, io, h)
        cyc[S_AFTER] += read_cycles() - c
    return OK, nsteps


@kernel
def two_wheeler_steps_staged(m, d, h, idx, par, tab, u, tp, slip, tyre, nsteps, cyc):
    """nsteps of rtsim.vehicle.motorcycle.step.two_wheeler_step, stage by stage (cycles into cyc)."""
    args = (idx, par, tab, u, tp, slip, tyre, cyc)
    for n in range(nsteps):
        status = _mbs_step_staged(m, d, h, _two_wheeler_forces_staged, args, cyc)
        if status != OK:
            return status, n
        c = read_cycles()
        two_wheeler_after_mbs(h, par, tp, slip, tyre)
        cyc[S_AFTER] += read_cycles() - c
    return OK, nsteps


def _blocks(run, steps: int, blocks: int) -> np.ndarray:
    """Cycle counts of `blocks` blocks of steps // blocks steps each (run(n, cyc) steps n); per slot the
    median over the blocks, times the blocks (the machine is shared: a block the process lost its core in
    is an outlier, not the step's cost); the counts (N_*) summed."""
    per = np.zeros((blocks, NSLOTS), dtype=np.int64)
    n = steps // blocks
    for b in range(blocks):
        run(n, per[b])
    cyc = (np.median(per, axis=0) * blocks).astype(np.int64)
    cyc[N_FORCE_EVALS:] = per[:, N_FORCE_EVALS:].sum(axis=0)
    return cyc


def stage_report(name: str, cyc: np.ndarray, stats0: np.ndarray, stats1: np.ndarray, steps: int,
                 car: bool) -> dict:
    """Microseconds per step of each stage (the force kernel's time taken off the stages it ran in) and
    the counts per step."""
    us = 1e6 / cycles_per_second() / steps
    stages = {}
    for k, label in STAGE_NAMES.items():
        stages[label] = cyc[k] * us
    # the force kernel runs between the prepare and the residual laps (Newton) and between the finish and
    # the projection-factor laps; its cycles are in none of them (each lap restarts after it)
    if car:
        for k, label in FORCE_NAMES.items():
            stages[label] = cyc[k] * us
    else:
        stages["forces: the two-wheeler's force kernel (tyres, suspension, steering, chain, aero)"] = cyc[F_ALL] * us
    total = sum(stages.values())
    return {
        "vehicle": name,
        "steps": steps,
        "us_per_step": total,
        "stages_us": stages,
        "share": {k: v / total for k, v in stages.items()},
        "formulation_us": sum(v for k, v in stages.items() if not k.startswith(("forces:", "subsystems", "commits"))),
        "forces_us": cyc[F_ALL] * us,
        "newton_iterations_per_step": float(stats1[1] - stats0[1]) / steps,
        "factorizations_per_step": float(stats1[2] - stats0[2]) / steps,
        "projection_iterations_per_step": float(stats1[8] - stats0[8]) / steps,
        "force_evaluations_per_step": float(cyc[N_FORCE_EVALS]) / steps,
        "tangent_evaluations_per_step": float(cyc[N_TANGENT_EVALS]) / steps,
    }


def profile_car(vehicle: str, speed: float, steer: float, steps: int = 3000, blocks: int = 10) -> dict:
    """The car (configs/vehicles/<vehicle>.toml) on a plane at `speed` m/s with throttle 0.2 and the
    steering-wheel angle `steer` rad held, as in `rtsim bench --suite vehicle`, stage by stage."""
    from rtsim.benchmarks.vehicle import _vehicle
    from rtsim.vehicle.car.sim import VehicleSim
    from rtsim.vehicle.car.step import CMD_STEER, CMD_THROTTLE

    model, road = _vehicle(None, vehicle)
    sim = VehicleSim(model, road, 1e-3, speed=speed, position=(2.0, 0.0))
    sim.io.commands[CMD_THROTTLE] = 0.2
    sim.io.commands[CMD_STEER] = steer
    sim.step(200)                                   # compile/load, settle (as the benchmark)
    args = (sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states, sim.io, sim.dt)
    return _profile(vehicle, car_steps_staged, args, sim.data.stats, steps, blocks, car=True)


def _profile(name: str, loop, args, stats, steps: int, blocks: int, car: bool) -> dict:
    """The stage report of `loop(*args, n, cycles)` (a staged loop) over `steps` steps in `blocks`
    blocks, after one step that compiles or loads it; `stats`: the integrator's statistics array."""
    loop(*args, 1, np.zeros(NSLOTS, dtype=np.int64))
    s0 = stats.copy()

    def run(n, cyc):
        status, _ = loop(*args, n, cyc)
        if status != OK:
            raise RuntimeError(f"{name}: staged step failed with status {status}")
    steps -= steps % blocks
    return stage_report(name, _blocks(run, steps, blocks), s0, stats, steps, car=car)


def profile_motorcycle(steps: int = 3000, blocks: int = 10) -> dict:
    """The motorcycle at 20 m/s with 2 N m of steering torque held, as in `rtsim bench --suite vehicle`."""
    from rtsim.benchmarks.vehicle import motorcycle_turning

    sim = motorcycle_turning()
    p = sim.parts
    args = (sim.model, sim.data, 1e-3, p.idx, p.par, p.tab, p.u, p.tp, p.slip, p.tyre)
    two_wheeler_steps_staged(*args, 200, np.zeros(NSLOTS, dtype=np.int64))   # compile/load, settle
    return _profile("motorcycle", two_wheeler_steps_staged, args, sim.data.stats, steps, blocks, car=False)


def stages_suite() -> list[dict]:
    return [profile_car("xbw", 22.22, np.radians(35.0)), profile_car("eps_car", 22.22, np.radians(35.0)),
            profile_motorcycle()]


def format_stages(results: list[dict]) -> str:
    lines = []
    for r in results:
        lines.append(f"{r['vehicle']}: {r['us_per_step']:.1f} us/step staged; per step "
                     f"{r['newton_iterations_per_step']:.2f} Newton iterations, "
                     f"{r['factorizations_per_step']:.2f} factorizations, "
                     f"{r['force_evaluations_per_step']:.2f} force evaluations "
                     f"({r['tangent_evaluations_per_step']:.2f} with tangent), "
                     f"{r['projection_iterations_per_step']:.2f} projection iterations")
        for k, v in r["stages_us"].items():
            lines.append(f"    {k:<70} {v:6.2f} us  {100 * r['share'][k]:5.1f} %")
        lines.append(f"    {'formulation (ALI3-P stages) / forces':<70} {r['formulation_us']:6.2f} us / "
                     f"{r['forces_us']:.2f} us")
    return "\n".join(lines)
