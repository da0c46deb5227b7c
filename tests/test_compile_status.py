"""rtsim.compile_status: the cache check reads numba's index correctly (it uses numba internals, so
this test pins the behaviour), and the progress lines appear when a process compiles and not when
its kernels are cached. Each case runs a tiny kernel module of its own, in a fresh process."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap

from service_harness import ROOT

KERNEL_MODULE = textwrap.dedent("""
    from rtsim.jit import kernel

    @kernel
    def twice(x):
        return 2.0 * x
""")

SCRIPT = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    from rtsim.compile_status import CompileProgress, kernels_cached
    print("cached before:", kernels_cached(["tinykernel:twice"]))
    import tinykernel
    with CompileProgress("test", print, what="tiny kernels", expect_s=3, every=0.01,
                         predict=sys.argv[2:]):
        assert tinykernel.twice(2.0) == 4.0
    print("cached after:", kernels_cached(["tinykernel:twice"]))
""")


def _run(folder, *predict) -> list[str]:
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(folder), *predict], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


def test_a_first_run_shows_progress_and_a_cached_run_shows_nothing(tmp_path):
    (tmp_path / "tinykernel.py").write_text(KERNEL_MODULE)
    first = _run(tmp_path, "tinykernel:twice")
    assert first[0] == "cached before: False"
    assert first[1] == "test: compiling tiny kernels (first run only, about 3 s on a 2-core machine)..."
    assert first[-2].startswith("test: tiny kernels compiled in ") and "(1 compiled;" in first[-2]
    assert first[-1] == "cached after: True"

    second = _run(tmp_path, "tinykernel:twice")
    assert second == ["cached before: True", "cached after: True"]


def test_a_compile_the_index_did_not_predict_is_still_announced(tmp_path):
    (tmp_path / "tinykernel.py").write_text(KERNEL_MODULE)
    lines = _run(tmp_path)                      # no prediction: the numba compile event speaks
    assert any(line.startswith("test: compiling tiny kernels (first run only") for line in lines), lines
    assert any("(1 compiled;" in line for line in lines), lines


def test_a_changed_source_is_not_cached(tmp_path):
    (tmp_path / "tinykernel.py").write_text(KERNEL_MODULE)
    _run(tmp_path, "tinykernel:twice")
    (tmp_path / "tinykernel.py").write_text(KERNEL_MODULE.replace("2.0 * x", "2.0 * x + 0.0"))
    lines = _run(tmp_path, "tinykernel:twice")
    assert lines[0] == "cached before: False"
    assert lines[-1] == "cached after: True"


WORKER_MODULE = KERNEL_MODULE + textwrap.dedent("""

    def os_pid():
        import os
        return os.getpid()


    def compile_in_worker():
        from rtsim.compile_status import worker_progress
        with worker_progress("batch"):
            return twice(2.0)
""")

POOL_SCRIPT = textwrap.dedent("""
    import multiprocessing as mp
    import sys
    from concurrent.futures import ProcessPoolExecutor
    sys.path.insert(0, sys.argv[1])
    import tinyworker
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        print("worker pid:", pool.submit(tinyworker.os_pid).result(), "result:",
              pool.submit(tinyworker.compile_in_worker).result())
""")


def test_a_worker_process_reports_its_own_compiles_on_stderr(tmp_path):
    """numba's compile events fire in the process that compiles: a batch or test worker names itself."""
    (tmp_path / "tinyworker.py").write_text(WORKER_MODULE)
    out = subprocess.run([sys.executable, "-c", POOL_SCRIPT, str(tmp_path)], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    pid = out.stdout.split()[2]
    assert out.stdout.split()[-1] == "4.0"
    lines = out.stderr.splitlines()
    assert f"rtsim batch (worker {pid}): compiling kernels (first run only)..." in lines, lines
    assert any(l.startswith(f"rtsim batch (worker {pid}): kernels compiled in ") for l in lines), lines


HOLD_SCRIPT = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    from rtsim.compile_status import CompileProgress, configs_first
    import tinykernel
    with CompileProgress("test", print, what="tiny kernels", expect_s=None, every=None, predict=()):
        try:
            with configs_first():
                tinykernel.twice(2.0)                   # compiles while the files load
                print("loaded")
                if sys.argv[2] == "bad":
                    raise ValueError("a bad value")
        except ValueError as exc:
            print("error:", exc)
""")


def test_a_compile_while_the_configs_load_is_announced_after_them(tmp_path):
    """configs_first(): a kernel compiled while a command's files load is announced once they have all
    loaded; when one of them is refused, its error is the only line (no compile notice before it)."""
    (tmp_path / "tinykernel.py").write_text(KERNEL_MODULE)
    for case in ("good", "bad"):
        shutil.rmtree(tmp_path / "__pycache__", ignore_errors=True)      # a cold cache each time
        out = subprocess.run([sys.executable, "-c", HOLD_SCRIPT, str(tmp_path), case], cwd=ROOT,
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        lines = out.stdout.splitlines()
        if case == "good":
            assert lines[:2] == ["loaded", "test: compiling tiny kernels (first run only)..."], lines
            assert lines[2].startswith("test: tiny kernels compiled in ") and "(1 compiled;" in lines[2], lines
        else:
            assert lines == ["loaded", "error: a bad value"], lines
