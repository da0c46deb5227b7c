"""Where runs execute. Both executors take run specs and call `on_row` in the submitting process with each
result row as it arrives (any order); results do not depend on the executor or the worker (each run is
seeded by its spec).

- `local_pool`: concurrent.futures.ProcessPoolExecutor, one worker per core by default; each worker
  dies with the batch process (`die_with_parent`: a SIGKILLed batch leaves no worker behind, and then
  no resource tracker either: it ends when the last holder of its pipe does); its
  initializer loads the numba kernels once (a 20 ms run of each kind of vehicle in the plan), not per
  run; on an empty cache the workers compile different kinds side by side (`_init`). A worker that dies
  (BrokenProcessPool) takes the pool with it: the runs not yet back are submitted again to a fresh pool,
  up to `retries` times.
- `ray_cluster`: Ray (an optional extra, `pip install 'rtsim[ray]'`; `require_ray` says so in one line)
  tasks (`max_retries`: a lost worker's run is run again elsewhere); `address="auto"`
  starts a Ray instance on this machine bound to 127.0.0.1 with usage statistics off, else connects to
  the cluster at `address`.
"""
from __future__ import annotations

import gc
import os
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Callable

from .run import lost_row, mark_ready, run_one, warm

def die_with_parent(parent: int) -> None:
    """End this process when its parent (pid `parent`) ends, however it ends (SIGKILL included): on
    Linux the kernel sends it SIGKILL when its parent dies (prctl PR_SET_PDEATHSIG); on every system a
    daemon thread also checks os.getppid() each second. A parent already gone ends it at once."""
    import signal
    import threading

    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass                                  # the thread below still does it
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        import time
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)
    threading.Thread(target=watch, name="rtsim-parent-watch", daemon=True).start()


def _init(warm_specs: list[dict], job: dict, turn=None, lock_dir: str | None = None, parent: int | None = None,
          scenario_specs: list[dict] = ()) -> None:
    """Die with the batch process (`parent`, first thing), then load (or compile) the kernels of every
    kind of vehicle in the plan, build the plan's other vehicles (``warm_specs``), read its scenarios
    (``scenario_specs``: one run of each, rtsim.batch.models keeps them) and make one whole run of the
    first warm spec. Worker k starts with warm spec k (``turn``: a shared counter) and warms each spec
    holding that spec's file lock in ``lock_dir``: on an empty numba cache the workers compile different
    vehicles side by side instead of the same ones twice, and a worker that reaches a spec another one is
    compiling waits for it and loads the result from the cache (measured in one process: the car's
    kernels about 82 s of CPU, the motorcycle's 20 s more)."""
    if parent is not None:
        die_with_parent(parent)
    from rtsim.compile_status import worker_progress

    with worker_progress("batch"):
        _warm_all(warm_specs[:KERNEL_SPECS], job, turn, lock_dir)
        for spec in warm_specs[KERNEL_SPECS:]:           # the kernels are loaded: builds only, no locks
            warm(spec, job)
        keep_scenarios(scenario_specs)
        if warm_specs:      # a worker's first whole run spent 0.4 ms more outside its steps than the next
            warm(warm_specs[0], job, full=True)     # (2.1-2.3 ms against 1.8): that one is dropped
    # what the warm-up made (the kernels, the config schemas, the kept vehicles and roads) lives as long
    # as the worker: out of the collector's full passes, which otherwise traverse it all in one run
    # (about 0.1 s measured: a run's share outside its steps jumped to 60-70 %)
    gc.collect()
    gc.freeze()
    mark_ready()


def _warm_all(warm_specs: list[dict], job: dict, turn, lock_dir: str | None) -> None:
    if turn is None or lock_dir is None or len(warm_specs) < 2:
        for spec in warm_specs:
            warm(spec, job)
        return
    import fcntl

    with turn.get_lock():
        k = turn.value
        turn.value += 1
    for i in range(len(warm_specs)):
        j = (k + i) % len(warm_specs)
        with open(Path(lock_dir) / f"warm-{j}.lock", "w") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)               # released when the file closes
            warm(warm_specs[j], job)


#: warm specs that load the kernels (one per scenario and vehicle file), at most
KERNEL_SPECS = 4
#: vehicles a worker builds before its first run, at most (fewer than the vehicles it keeps,
#: rtsim.batch.models.KEEP, and than the started cars a vehicle's simulation keeps, 16)
WARM_VEHICLES = 12


def warm_specs(specs: list[dict]) -> list[dict]:
    """The specs a worker runs for 20 ms before its first run: first one per scenario and vehicle file (at
    most KERNEL_SPECS) to load each kind of vehicle's kernels with; then, up to WARM_VEHICLES in all, one
    per further vehicle of the plan (its file and vehicle overrides: a swept mass is another vehicle), in
    plan order. Each of those vehicles is built, started on its scenario's road and kept
    (rtsim.batch.models) like the kernels, so the runs that find it spend their time in their steps; a
    plan with more distinct vehicles builds the rest in their first runs."""
    from .inputs import split_overrides
    from .models import overrides_key

    seen, kernels, vehicles = set(), [], []
    for s in specs:
        key = (s["scenario"], s["vehicle"])
        if key not in seen and len(kernels) < KERNEL_SPECS:
            seen.add(key)
            kernels.append(s)

    def vehicle(spec: dict) -> tuple:
        return spec["scenario"], spec["vehicle"], overrides_key(split_overrides(spec["overrides"])[0])

    built = {vehicle(s) for s in kernels}
    for s in specs:
        if len(kernels) + len(vehicles) >= WARM_VEHICLES:
            break
        key = vehicle(s)
        if key not in built:
            built.add(key)
            vehicles.append(s)
    return kernels + vehicles


def scenario_specs(specs: list[dict]) -> list[dict]:
    """One spec per distinct scenario of the plan (its file and scenario overrides), in plan order, at most
    as many as a worker keeps (rtsim.batch.models.KEEP_SCENARIOS)."""
    from .inputs import split_overrides
    from .models import KEEP_SCENARIOS, overrides_key

    seen, out = set(), []
    for s in specs:
        key = (s["scenario"], overrides_key(split_overrides(s["overrides"])[1]))
        if key not in seen and len(out) < KEEP_SCENARIOS:
            seen.add(key)
            out.append(s)
    return out


def keep_scenarios(specs: list[dict]) -> None:
    """Read each spec's scenario into this worker's kept ones (rtsim.batch.models.WORKER), as its run would
    read it: in the sweeps of a steering input every run has a scenario of its own, and reading one is
    about 0.6 ms of a run of 15 ms in its steps."""
    from rtsim.configfile import keeping_tables

    from . import run
    from .inputs import keep_scenario

    with keeping_tables(run.WORKER.tables):
        for spec in specs:
            keep_scenario(spec["scenario"], spec["overrides"], run.WORKER)


def local_pool(specs: list[dict], job: dict, on_row: Callable[[dict], None], workers: int | None = None,
               retries: int = 2) -> None:
    import multiprocessing as mp
    import tempfile

    workers = workers or os.cpu_count() or 1
    pending = {s["run_id"]: s for s in specs}
    ctx = mp.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="rtsim-batch-warm-") as lock_dir:
        for _ in range(retries + 1):
            if not pending:
                return
            pool = ProcessPoolExecutor(max_workers=min(workers, len(pending)), mp_context=ctx, initializer=_init,
                                       initargs=(warm_specs(list(pending.values())), job, ctx.Value("i", 0), lock_dir,
                                                 os.getpid(), scenario_specs(list(pending.values()))))
            try:
                futures = {pool.submit(run_one, s, job): rid for rid, s in pending.items()}
                while futures:
                    done, _ = wait(futures, return_when=FIRST_COMPLETED)
                    for f in done:
                        rid = futures.pop(f)
                        try:
                            row = f.result()
                        except BrokenProcessPool:
                            continue
                        pending.pop(rid, None)
                        on_row(row)
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)
                raise
            pool.shutdown(wait=True)
    for s in list(pending.values()):     # a run that kills its worker every time: recorded as such
        on_row(lost_row(s, job, f"its worker process died on each of {retries + 1} attempts"))


def _code_path() -> str:
    """The folder holding the rtsim package this process runs (workers put it first on their path)."""
    return str(Path(__file__).resolve().parents[2])


def ray_environment(address: str) -> None:
    """The environment Ray reads when it is imported (so: before `import ray`), inherited by the
    processes it starts: usage statistics off; for "auto" Ray's single-machine mode, in which it keeps
    the node address 127.0.0.1 and binds its servers there (otherwise it replaces 127.0.0.1 by the
    machine's routable address and listens on every interface), and token authentication with a
    token of this batch's own, held in that environment (Ray's default would write one into ~/.ray)."""
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    if address == "auto":
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        if "RAY_AUTH_MODE" not in os.environ:
            import secrets
            os.environ["RAY_AUTH_MODE"] = "token"
            os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(16))


RAY_MISSING = "Ray is not installed; it is an optional extra of rtsim: pip install 'rtsim[ray]'"


def require_ray() -> None:
    """RtsimError (one line: how to install it) when Ray cannot be imported; Ray itself is not imported
    (its environment must be set first, `ray_environment`)."""
    import importlib.util

    from rtsim.errors import RtsimError

    try:
        found = importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise RtsimError(RAY_MISSING)


def ray_started() -> bool:
    """Whether this process is connected to Ray already (then it is not ours to shut down)."""
    ray = sys.modules.get("ray")
    return ray is not None and ray.is_initialized()


def ray_init(address: str):
    """Connect Ray: "auto" starts a local instance on 127.0.0.1 (no dashboard, usage statistics off);
    anything else is a cluster address (host:port, ray://...). RtsimError when Ray is not installed."""
    require_ray()
    ray_environment(address)
    import ray
    if address == "auto" and ray._private.ray_constants.ENABLE_RAY_CLUSTER:
        raise RuntimeError("ray was imported before its environment was set: it would not bind to 127.0.0.1")

    env = {"env_vars": {"PYTHONPATH": os.pathsep.join([_code_path(), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
                        "RAY_USAGE_STATS_ENABLED": "0"}}
    if address == "auto":
        return ray.init(address="local", _node_ip_address="127.0.0.1", include_dashboard=False,
                        runtime_env=env, log_to_driver=False, configure_logging=False)
    return ray.init(address=address, runtime_env=env, log_to_driver=False, configure_logging=False)


def ray_cluster(specs: list[dict], job: dict, on_row: Callable[[dict], None], address: str = "auto",
                retries: int = 3) -> None:
    started = not ray_started()
    if started:
        ray_init(address)
    import ray

    try:
        task = ray.remote(num_cpus=1, max_retries=retries)(run_one)
        refs = {task.remote(s, job): s["run_id"] for s in specs}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                rid = refs.pop(ref)
                try:
                    on_row(ray.get(ref))
                except ray.exceptions.RayError as exc:      # retries exhausted: recorded, the batch goes on
                    spec = next(s for s in specs if s["run_id"] == rid)
                    on_row(lost_row(spec, job, f"lost after {retries} retries: {type(exc).__name__}: {exc}"))
    finally:
        if started:
            ray.shutdown()
        sys.stdout.flush()


# ---- an ordered map with a per-worker context (for re-simulation workflows) -------------------------
_CONTEXTS: dict = {}


def _with_context(key: str, setup: Callable, setup_blob: bytes, fn: Callable, task):
    ctx = _CONTEXTS.get(key)
    if ctx is None:                                      # once per worker process and setup
        from ray import cloudpickle
        ctx = _CONTEXTS[key] = setup(*cloudpickle.loads(setup_blob))
    return fn(ctx, task)


def ray_map(fn: Callable, tasks: list, setup: Callable, setup_args: tuple = (), address: str = "auto",
            retries: int = 3) -> list:
    """[fn(ctx, task) for task in tasks] computed by Ray tasks, in task order, where ctx = setup(*setup_args)
    is built once in each worker process (a model, a replayer: what is costly to build and to ship with
    every task), the setup's arguments shipped once through Ray's object store as one pickled blob:
    numpy arrays Ray stores itself come back read-only, which numba types as other signatures than
    the writable arrays the cached kernels were compiled for, so every worker would compile them all
    again (measured: `rtsim validate --ray auto` after the same validation without Ray had filled the
    cache compiled 37 kernel variants and took 140 s; with the blob it compiled none and took 25 s);
    unpickled from the blob they are writable copies, like the caller's. A task lost with its
    worker runs again (`retries`); an exception raised by `fn` comes back as Ray's error for that task.
    Connects as `ray_cluster` does when Ray is not yet initialised (and shuts it down after)."""
    import hashlib

    started = not ray_started()
    if started:
        ray_init(address)
    import ray
    try:
        from ray import cloudpickle
        blob = cloudpickle.dumps(setup_args)
        key = hashlib.sha256(getattr(setup, "__qualname__", repr(setup)).encode() + blob).hexdigest()
        args_ref = ray.put(blob)
        task_fn = ray.remote(num_cpus=1, max_retries=retries)(_with_context)
        return ray.get([task_fn.remote(key, setup, args_ref, fn, t) for t in tasks])
    finally:
        if started:
            ray.shutdown()
