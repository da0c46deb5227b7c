"""The validation workflow's units of parallel work and where they run: forked worker processes that
inherit the iteration's context (the compiled model is shared, never rebuilt), or Ray tasks that get it
shipped once per worker (`RayWorkers`: the executor the command passes in, rtsim.batch.executors'
ray_init and ray_map; this layer does not import the batch's). A task that fails with an RtsimError comes back
as `Failed` (its text), never as an exception the pool would have to unpickle."""
from __future__ import annotations

import multiprocessing as mp
from dataclasses import dataclass
from typing import Callable

from rtsim.errors import RtsimError

from .identify import Context, fit_joint, fit_model_effect, joint_run_estimate, run_estimate


class Quiet:
    """A progress sink that shows nothing (the workflow's default)."""

    def stage(self, text: str, total: int | None = None) -> None:
        pass

    def advance(self, n: int = 1) -> None:
        pass


_CTX: Context | None = None


@dataclass
class Failed:
    """A task's RtsimError, as text: SimulationError and its kind cannot be unpickled (their __init__
    takes more than the message), and an exception that fails to unpickle in the parent kills the
    pool's result thread and hangs the workflow."""
    message: str


def run_task(ctx: Context, task: tuple):
    """One unit of parallel work on the iteration's context: ("fit", name, budget, seed),
    ("run", candidate, run index), ("inputs", run index): that run's replay inputs with the steering
    command matched at the model's step, ("replay", effects, run index): the model's outputs under
    that run's inputs, or ("raw", effects, run index): the same before the sensor model. An RtsimError
    comes back as Failed."""
    try:
        if task[0] == "fit":
            return fit_model_effect(ctx, *task[1:])
        if task[0] == "joint":
            return fit_joint(ctx, *task[1:])
        if task[0] == "jrun":
            return joint_run_estimate(ctx, *task[1:])
        if task[0] == "inputs":
            inp = ctx.replayer.inputs(ctx.bench, run=task[1])
            ctx.replayer.steering_command(inp, ctx.replayer.dt)
            return inp
        if task[0] in ("replay", "raw"):
            effects, i = task[1], task[2]
            inp = ctx.replayer.inputs(ctx.bench, run=i)
            raw = ctx.replayer.simulate(inp, effects)
            return raw if task[0] == "raw" else ctx.replayer.reported(raw, inp.t, effects)
        return run_estimate(ctx, task[1], task[2])
    except RtsimError as exc:
        return Failed(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")


def _task(task: tuple):
    """run_task on the context a forked worker inherited."""
    return run_task(_CTX, task)


def _kept(ctx: Context | None):
    """The replays a context's replayer keeps (its `replays` method), or None."""
    return getattr(getattr(ctx, "replayer", None), "replays", None)


def _forked_task(task: tuple) -> tuple:
    """_task in a forked worker, with the replays it made (digest -> outputs, Replayer.replays) for the
    workflow to keep: a later task that asks for the same replay, in this process or a later worker,
    then costs no simulation."""
    kept = _kept(_CTX)
    memo = kept() if kept is not None else {}
    known = set(memo)
    res = run_task(_CTX, task)
    return res, {k: memo[k] for k in memo.keys() - known}


def _same(ctx: Context) -> Context:
    """A Ray worker's context: the one shipped (built once per worker by ray_map)."""
    return ctx


@dataclass(frozen=True)
class RayWorkers:
    """Where `map_tasks` runs its tasks when the workflow runs on Ray: the cluster `address` ("auto": a
    local instance on 127.0.0.1), connected once by the workflow's `run` with `init(address)`; `map(fn,
    tasks, setup, setup_args, address=)` runs the tasks, each worker building its context once with
    `setup(*setup_args)` (rtsim.batch.executors.ray_init and ray_map)."""
    address: str
    init: Callable
    map: Callable


def map_tasks(ctx: Context, tasks: list[tuple], workers: int | RayWorkers, progress) -> list:
    """The tasks' results, in order, computed by `workers` forked processes or by Ray tasks."""
    global _CTX
    if isinstance(workers, RayWorkers):
        out = workers.map(run_task, tasks, _same, (ctx,), address=workers.address)
        progress.advance(len(out))
        return out
    _CTX = ctx
    out = []
    try:
        if workers > 1 and len(tasks) > 1 and "fork" in mp.get_all_start_methods():
            kept = _kept(ctx)
            with mp.get_context("fork").Pool(min(workers, len(tasks))) as pool:
                for res, made in pool.imap(_forked_task, tasks):
                    out.append(res)
                    if kept is not None:
                        kept().update(made)
                    progress.advance()
        else:
            for t in tasks:
                out.append(_task(t))
                progress.advance()
    finally:
        _CTX = None
    return out


def raise_failed(results: list) -> list:
    """The results, or the first failure raised as an RtsimError."""
    for r in results:
        if isinstance(r, Failed):
            raise RtsimError(r.message)
    return results
