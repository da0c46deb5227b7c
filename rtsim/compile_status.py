"""Tell the user when a process compiles the numba kernels, and show progress while it does.

The kernels (``rtsim/jit.py``: ``njit(cache=True)``) compile lazily at their first call and are cached
in ``__pycache__`` beside their sources, so only the first run on a machine (or after a source change)
compiles: about ``FIRST_COMPILE_S`` seconds for the service on a 2-core machine, during which nothing
else is printed. ``CompileProgress`` wraps the code that may compile (building the service and its
warm-up): it prints one line when compiling starts, a line every few seconds with the elapsed time
and the kernel being compiled (plain lines, no terminal codes), and one line at the end; when every
kernel is already cached it prints nothing.

Two sources of truth: ``kernels_cached`` reads numba's cache index of the main kernels before
anything runs (so the first line appears at once, before the seconds of model building that precede
the first compilation); numba's ``numba:compile`` event, which fires only on a cache miss, catches
anything the index check did not predict.
"""
from __future__ import annotations

import importlib
import os
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator

#: s; the service's first build and compile on a fresh clone (2-core machine, the demo ECU compiling
#: its own kernels beside it): what `rtsim demo` took with empty caches (`./tools/run` in a new clone
#: prints "kernels compiled in ... s"; 322 s and 386 s in two such runs)
FIRST_COMPILE_S = 330


def _duration(s: float) -> str:
    """A duration as people say it: seconds below two minutes, else whole minutes ("5 min")."""
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min"


#: the kernels the service calls from Python, "module:name"; the largest compile (~90 % of the time)
SERVICE_KERNELS = ("rtsim.service.kernel:loop_run", "rtsim.vehicle.car.step:vehicle_step",
                   "rtsim.vehicle.kit.powertrain:powertrain_step")


def kernel_cached(dispatcher) -> bool:
    """True when numba's on-disk cache holds machine code of ``dispatcher`` that this process would
    load: the index file exists, was written by this numba version for the current source file, and
    has an entry for this CPU and this function's bytecode whose data file exists. False otherwise,
    also when the cache layout is not the one expected (numba internals: checked by a test)."""
    try:
        cache = dispatcher._cache
        index_file = cache._cache_file
        overloads = index_file._load_index()
        if not overloads:
            return False
        _, magic, code = cache._index_key(None, dispatcher.targetctx.codegen())
        folder = os.path.dirname(index_file._index_path)
        return any(key[1] == magic and key[2] == code and os.path.exists(os.path.join(folder, name))
                   for key, name in overloads.items())
    except Exception:  # noqa: BLE001  (an unexpected layout means "unknown": say it compiles)
        return False


def kernels_cached(names: Iterable[str] = SERVICE_KERNELS) -> bool:
    """True when every kernel named ``"module:function"`` is cached for this machine."""
    for name in names:
        module, _, attr = name.partition(":")
        if not kernel_cached(getattr(importlib.import_module(module), attr)):
            return False
    return True


def _is_project_kernel(dispatcher) -> bool:
    """False for numba's own helpers (overloads of builtins it compiles along the way)."""
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return module.split(".", 1)[0] != "numba"


def _listener_class():
    from numba.core import event

    class _Listener(event.Listener):
        """Forwards numba's compile start/end events (cache misses only) to a CompileProgress."""

        def __init__(self, progress: "CompileProgress"):
            self.progress = progress

        def on_start(self, ev):
            self.progress._started(ev.data["dispatcher"])

        def on_end(self, ev):
            self.progress._ended(ev.data["dispatcher"])

    return _Listener


class CompileProgress:
    """Context manager: progress lines while the body compiles numba kernels, nothing if it does not.

    ``prefix``: the program name the lines start with (``rtsim``, ``ecu_demo``); ``out``: prints one
    line; ``what``: what compiles (``"kernels"``); ``expect_s``: the announced duration, s (None: not
    announced); ``every``: s between progress lines (None: only the first and last line);
    ``predict``: ``"module:function"`` kernels whose cache is checked on entry (empty: wait for the
    first compilation to say anything).
    """

    def __init__(self, prefix: str = "rtsim", out: Callable[[str], None] = print, *, what: str = "kernels",
                 expect_s: float | None = FIRST_COMPILE_S, every: float | None = 5.0,
                 predict: Iterable[str] = SERVICE_KERNELS):
        self.prefix, self.out, self.what = prefix, out, what
        self.expect_s, self.every, self.predict = expect_s, every, tuple(predict)
        self.compiled = 0                   # project kernels compiled so far (cache misses)
        self.announced = False
        self._held = 0                      # inside configs_first(): a compile start is announced later
        self._pending = False               # a compile started while held
        self._stack: list[str] = []         # project kernels being compiled, outermost first
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._ticker: threading.Thread | None = None
        self._listener = None
        self._t0 = 0.0

    # -- holding the announcement (configs_first) ----------------------------------------------------
    def hold(self) -> None:
        """Announce no compile start until the matching ``release``: it is remembered instead."""
        with self._lock:
            self._held += 1

    def release(self, announce: bool = True) -> None:
        """End one ``hold``; after the last one a compile start remembered in between is announced now
        (with ``announce``; without it, dropped)."""
        with self._lock:
            self._held -= 1
            due = self._held == 0 and self._pending
            self._pending = self._pending and self._held > 0
        if due and announce and not self.announced:
            self._announce()

    # -- context -------------------------------------------------------------------------------------
    def __enter__(self) -> "CompileProgress":
        from numba.core import event

        self._t0 = time.monotonic()
        self._listener = _listener_class()(self)
        event.register("numba:compile", self._listener)
        _ACTIVE.append(self)
        if self.predict and not kernels_cached(self.predict):
            self._announce()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        if self in _ACTIVE:
            _ACTIVE.remove(self)
        self._done.set()
        if self._ticker is not None:
            self._ticker.join(1.0)
        if self.announced and exc_type is None:
            self.out(f"{self.prefix}: {self.what} compiled in {self.elapsed:.0f} s "
                     f"({self.compiled} compiled; cached for the next runs)")

    @property
    def elapsed(self) -> float:
        """s since the context was entered."""
        return time.monotonic() - self._t0

    # -- events (the compiling thread) ----------------------------------------------------------------
    def _started(self, dispatcher) -> None:
        if not _is_project_kernel(dispatcher):
            return
        with self._lock:
            self._stack.append(dispatcher.py_func.__name__)
            if self._held:
                self._pending = True
                return
        if not self.announced:
            self._announce()

    def _ended(self, dispatcher) -> None:
        if not _is_project_kernel(dispatcher):
            return
        with self._lock:
            name = dispatcher.py_func.__name__
            if name in self._stack:
                del self._stack[len(self._stack) - 1 - self._stack[::-1].index(name)]
            self.compiled += 1

    # -- output --------------------------------------------------------------------------------------
    def _announce(self) -> None:
        with self._lock:
            if self.announced:
                return
            self.announced = True
        about = "" if self.expect_s is None else f", about {_duration(self.expect_s)} on a 2-core machine"
        self.out(f"{self.prefix}: compiling {self.what} (first run only{about})...")
        if self.every is not None:
            self._ticker = threading.Thread(target=self._tick, name="compile-progress", daemon=True)
            self._ticker.start()

    def status(self) -> str:
        """One progress line: elapsed s, kernels compiled, the kernel being compiled."""
        with self._lock:
            stack = list(self._stack)
            n = self.compiled
        now = "" if not stack else f"; now {stack[0]}" + (f" > {stack[-1]}" if len(stack) > 1 else "")
        return f"{self.prefix}: compiling {self.what}: {self.elapsed:.0f} s, {n} compiled{now}"

    def _tick(self) -> None:
        while not self._done.wait(self.every):
            self.out(self.status())


#: the CompileProgress contexts entered in this process, innermost last
_ACTIVE: list[CompileProgress] = []


@contextmanager
def configs_first() -> Iterator[None]:
    """Around the reading and validation of a command's configuration files (scenario, vehicle): a
    kernel compiled in there (a scenario's profiles are range-checked by sampling them with a kernel) is
    announced only once every file has loaded, so that a bad value's error is the only line a command
    prints, on a cold kernel cache too. Nothing is held when no CompileProgress is active."""
    progress = _ACTIVE[-1] if _ACTIVE else None
    if progress is None:
        yield
        return
    progress.hold()
    loaded = False
    try:
        yield
        loaded = True
    finally:
        progress.release(announce=loaded)     # announced only when the files loaded (no exception)


#: the commands that may compile kernels and show `command_progress` lines (serve and demo show their
#: own, predicted from the service's kernels)
COMPILING_COMMANDS = ("run", "resim", "validate", "batch", "eigen", "statics", "energy", "feel", "bench",
                      "inverse", "describe")


def command_progress(command: str) -> CompileProgress:
    """The compile progress of one ``rtsim <command>``: plain lines on stderr (so a command's JSON or
    CSV on stdout stays clean), announced at the first kernel numba actually compiles, so a run whose
    kernels are all cached prints nothing. numba saves each kernel to its cache as soon as that
    kernel's own compilation ends (callees before their callers), so an interrupted first start keeps
    every kernel that finished and the next start compiles only the rest."""
    import sys

    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)
    return CompileProgress("rtsim " + command, say, expect_s=None, every=10.0, predict=())


def worker_progress(command: str) -> CompileProgress:
    """``command_progress`` for a worker process of ``rtsim <command>`` (batch, test): numba's compile
    events fire in the process that compiles, so each worker reports its own compiles, its lines named
    by its process id (``rtsim batch (worker 4711): compiling kernels: 30 s, 12 compiled; now ...``)."""
    return command_progress(f"{command} (worker {os.getpid()})")


class CompileClock:
    """Context manager: ``seconds``, the wall time numba spent compiling inside the body (outermost
    compilations only, so a callee compiled inside its caller is not counted twice; loads from the
    cache are not compilations). A loop's time per step excludes it: ``(wall - clock.seconds) / steps``."""

    def __init__(self):
        self.seconds = 0.0
        self._depth = 0
        self._t = 0.0
        self._listener = None

    def __enter__(self) -> "CompileClock":
        from numba.core import event

        clock = self

        class _Clock(event.Listener):
            def on_start(self, ev):
                if clock._depth == 0:
                    clock._t = time.monotonic()
                clock._depth += 1

            def on_end(self, ev):
                clock._depth -= 1
                if clock._depth == 0:
                    clock.seconds += time.monotonic() - clock._t

        self._listener = _Clock()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)
