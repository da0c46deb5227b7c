"""An interrupted first compile keeps the kernels that finished: numba saves each kernel to its cache
when that kernel's own compilation ends (a callee, compiled while its caller is typed, before the
caller), so a start killed while its outermost kernel compiles resumes with only that kernel left.
The child process compiles a two-kernel module into a temporary NUMBA_CACHE_DIR under the commands'
compile progress (rtsim.compile_status.command_progress); the first child hangs once the callee has
finished and the caller is still compiling, and is killed when the callee's cache files appear."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

from service_harness import ROOT

KERNELS = textwrap.dedent("""
    from rtsim.jit import kernel

    @kernel
    def inner(x):
        return 3.0 * x

    @kernel
    def outer(x):
        return inner(x) + 1.0
""")

CHILD = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, sys.argv[1])
    from numba.core import event
    from rtsim.compile_status import command_progress

    class Hang(event.Listener):          # the first start is killed half-way: hang in the caller's compile
        def on_start(self, ev):
            pass
        def on_end(self, ev):
            if sys.argv[2] == "hang" and ev.data["dispatcher"].py_func.__name__ == "outer":
                print("hanging", flush=True)
                time.sleep(300)

    event.register("numba:compile", Hang())
    import twokernels
    with command_progress("test"):
        assert twokernels.outer(2.0) == 7.0
    print("done", flush=True)
""")


def _cache_files(cache_dir, name):
    return [f for _, _, files in os.walk(cache_dir) for f in files if f".{name}-" in f and f.endswith(".nbc")]


def _start(folder, cache_dir, mode):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    return subprocess.Popen([sys.executable, "-c", CHILD, str(folder), mode], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_killed_first_compile_resumes_with_only_the_unfinished_kernel(tmp_path):
    (tmp_path / "twokernels.py").write_text(KERNELS)
    cache = tmp_path / "cache"
    first = _start(tmp_path, cache, "hang")
    try:
        deadline = time.monotonic() + 240         # a bound for a stuck child, not a timing assertion
        while not _cache_files(cache, "inner"):
            assert first.poll() is None, first.communicate()
            assert time.monotonic() < deadline, "the callee never reached the cache"
            time.sleep(0.05)
    finally:
        first.kill()
        first.communicate()
    assert _cache_files(cache, "inner") and not _cache_files(cache, "outer")

    second = _start(tmp_path, cache, "run")
    out, err = second.communicate(timeout=240)
    assert second.returncode == 0, err
    assert "done" in out
    lines = err.splitlines()
    assert lines[0] == "rtsim test: compiling kernels (first run only)...", lines
    assert "(1 compiled;" in lines[-1], lines                       # outer only: inner came from the cache
    assert _cache_files(cache, "outer")

    third = _start(tmp_path, cache, "run")
    out, err = third.communicate(timeout=240)
    assert third.returncode == 0 and err == "", err                 # all cached: nothing printed


STALE_CHILD = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    import caller
    print(caller.outer(2.0), flush=True)
""")


def test_numba_keeps_a_caller_compiled_against_a_callee_that_changed(tmp_path):
    """Why a numba cache that outlives a checkout is keyed by the content of every source (tools/setup
    drops the cache beside the sources, tools/vcan_vm keeps one folder per sources' digest): numba keys
    a cached kernel on its own file's text only, so a caller whose file did not change keeps the code of
    its callee as it was when the caller was compiled."""
    (tmp_path / "callee.py").write_text("from rtsim.jit import kernel\n\n@kernel\ndef inner(x):\n    return 3.0 * x\n")
    (tmp_path / "caller.py").write_text("from rtsim.jit import kernel\nfrom callee import inner\n\n"
                                        "@kernel\ndef outer(x):\n    return inner(x) + 1.0\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))

    def outer_of_two():
        r = subprocess.run([sys.executable, "-c", STALE_CHILD, str(tmp_path)], cwd=ROOT, env=env,
                           capture_output=True, text=True, timeout=240)
        assert r.returncode == 0, r.stderr
        return float(r.stdout)

    assert outer_of_two() == 7.0
    (tmp_path / "callee.py").write_text((tmp_path / "callee.py").read_text().replace("3.0 * x", "5.0 * x"))
    assert outer_of_two() == 7.0                    # stale: 5 * 2 + 1 = 11 from fresh code
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "fresh")
    assert outer_of_two() == 11.0
