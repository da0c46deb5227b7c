"""The CAN end-to-end tests (marker ``can_e2e``) again, over a real SocketCAN ``vcan0``.

Where this kernel has vcan0, every ``can_e2e`` test runs on the host with ``RTSIM_CAN_INTERFACE=socketcan
RTSIM_CAN_CHANNEL=vcan0``; otherwise inside the qemu VM of ``tools/vcan_vm.py`` (Debian's kernel with
the vcan module, software emulation, packages fetched with apt-get on first use and cached); where
neither works the test skips with the reason. The inner run must report a passed test for each target
and no failed, errored or skipped one, so it can never pass silently. Its output is printed (``-s``).

What runs in the VM by default: ``VM_DEFAULT``, one test per way rtsim uses SocketCAN: a test
process's buses with classic and CAN FD frames both ways, and the car's HIL service (``rtsim serve``
in lockstep, a child process on vcan0) driven by an ECU over the bus (commands, sensor frames, the
watchdog's safe values). Every ``can_e2e`` test, these included, already runs on the host in the
default suite over the loopback hub through the same rtsim code (``bridge.can_bus.open_bus``, the
service's CAN reader and writer); only python-can's interface underneath differs. Under emulation
each service test costs about two minutes, so the other ones run in the VM only on request:
``RTSIM_VCAN_ALL=1`` runs every file that mentions ``can_e2e`` there, ``RTSIM_VCAN_TESTS`` the
space-separated test files/node ids it names.

Before booting, the same tests run once on the host with the guest's numba settings
(``vcan_vm.numba_env``: generic x86-64 code, shared cache folder) so the guest loads compiled kernels
instead of compiling them under emulation (and rtsim's other caches, e.g. the suspension fits, are
filled); they must pass there (over the loopback hub), or the test fails with that run's output before
booting. ``RTSIM_VCAN_WARMUP=0`` skips that. Inside the guest ``RTSIM_IN_VM=1`` is set (waits.py: every
wait's bound 5 times longer).

Knobs: ``RTSIM_VCAN_ALL=1`` and ``RTSIM_VCAN_TESTS`` (above), ``RTSIM_VCAN_TIMEOUT`` (s, whole VM run,
default 1200), ``RTSIM_VCAN_SMP`` (guest CPUs, default 1), ``RTSIM_VCAN_VM=0`` (never boot). Deselect
with ``-m "not vm"``.
"""
from __future__ import annotations

import ast
import importlib.util
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TESTS = ROOT / "tests"
VCAN_ENV = {"RTSIM_CAN_INTERFACE": "socketcan", "RTSIM_CAN_CHANNEL": "vcan0"}
GUEST_ENV = {**VCAN_ENV, "RTSIM_IN_VM": "1"}  # lets a test shorten itself under emulation
INNER_PYTEST = ["-m", "pytest", "-q", "-s", "-m", "can_e2e", "-p", "no:cacheprovider", "-rfEs", "--durations=5"]


def _vcan_vm():
    spec = importlib.util.spec_from_file_location("vcan_vm", ROOT / "tools" / "vcan_vm.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# The VM's default set (node ids relative to the repository root; each must carry the can_e2e marker)
VM_DEFAULT = (
    "tests/test_can_bus.py::test_segment_two_buses_classic_and_fd_lossless_both_ways",
    "tests/test_service_e2e.py::test_lockstep_brake_latency_and_watchdog_over_can",
)


def _e2e_targets(every: bool = False) -> list[str]:
    """``$RTSIM_VCAN_TESTS`` if set; with ``every`` (or ``RTSIM_VCAN_ALL=1``) the test files that
    mention the ``can_e2e`` marker (collecting only those keeps the emulated run from importing the
    whole suite); else ``VM_DEFAULT``."""
    raw = os.environ.get("RTSIM_VCAN_TESTS", "").split()
    if raw:
        return raw
    if not (every or os.environ.get("RTSIM_VCAN_ALL", "") == "1"):
        return list(VM_DEFAULT)
    me = Path(__file__).resolve()
    return [str(p.relative_to(ROOT)) for p in sorted(TESTS.glob("test_*.py"))
            if p.resolve() != me and "can_e2e" in p.read_text(errors="replace")]


def _marks(path: Path, name: str) -> set[str] | None:
    """The decorators of test function ``name`` in ``path`` as source text (None: no such function)."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return {ast.unparse(d) for d in node.decorator_list}
    return None


def test_vm_default_set_names_can_e2e_tests():
    """The default VM set cannot rot silently: each entry is a test function marked can_e2e (the inner
    run selects ``-m can_e2e``: an unmarked one would be deselected)."""
    for node_id in VM_DEFAULT:
        file, _, name = node_id.partition("::")
        marks = _marks(ROOT / file, name)
        assert marks is not None, f"{node_id}: no such test function"
        assert "pytest.mark.can_e2e" in marks, f"{node_id}: not marked can_e2e ({sorted(marks)})"


def test_generic_cache_folder_is_keyed_by_the_sources(tmp_path):
    """The guest's kernel cache outlives a checkout, so it is one folder per content of the kernels'
    sources (a kernel whose file is unchanged would otherwise load code built against older callees:
    tests/test_compile_resume.py shows numba doing so); other contents' folders unused for
    GENERIC_KEEP_DAYS days, and anything else in there (the old flat layout), are removed."""
    vm = _vcan_vm()
    tree = tmp_path / "tree"
    for rel in ("rtsim/a.py", "drivers/b.py", "tests/c.py"):
        (tree / rel).parent.mkdir(parents=True, exist_ok=True)
        (tree / rel).write_text("x = 1\n")
    d0 = vm.sources_digest(tree)
    (tree / "tests/c.py").write_text("x = 2\n")
    assert vm.sources_digest(tree) == d0                       # not a source of kernels the guest runs
    (tree / "drivers/b.py").write_text("x = 2\n")
    assert vm.sources_digest(tree) != d0

    base = tmp_path / "cache" / "numba-generic"
    old, recent = base / "0123456789abcdef", base / "fedcba9876543210"
    for d in (old, recent, base / "rtsim_0a1b"):               # a kernel folder of the flat layout
        d.mkdir(parents=True)
    (base / "index.nbi").write_text("")
    stale = time.time() - (vm.GENERIC_KEEP_DAYS + 1) * 86400
    os.utime(old, (stale, stale))
    env = vm.numba_env(tmp_path / "cache")
    assert env["NUMBA_CPU_NAME"] == "generic"
    assert Path(env["NUMBA_CACHE_DIR"]) == base / vm.sources_digest()
    assert sorted(p.name for p in base.iterdir()) == sorted([vm.sources_digest(), recent.name])


_COUNT = re.compile(r"(\d+) (passed|failed|errors?|skipped|xfailed|xpassed|deselected|warnings?)")


def summary_counts(output: str) -> dict[str, int] | None:
    """Counts of pytest's final summary line ("3 passed, 1 skipped, 40 deselected in 9.1s"), or None."""
    for line in reversed(output.splitlines()):
        if re.search(r"\bin [\d.]+s\b", line) and _COUNT.search(line):
            counts = {}
            for n, what in _COUNT.findall(line):
                key = {"error": "errors", "warning": "warnings"}.get(what, what)
                counts[key] = counts.get(key, 0) + int(n)
            return counts
    return None


def test_summary_counts_parser():
    out = "....\n=== short test summary info ===\nSKIPPED [1] x: y\n3 passed, 1 skipped, 40 deselected in 9.12s\n"
    assert summary_counts(out) == {"passed": 3, "skipped": 1, "deselected": 40}
    assert summary_counts("1 failed, 2 passed, 1 error, 2 warnings in 1.00s") == {
        "failed": 1, "passed": 2, "errors": 1, "warnings": 2}
    assert summary_counts("no tests ran in 0.01s") is None
    assert summary_counts("Traceback ...") is None


def _check_inner(rc: int, output: str, where: str, targets: list[str]) -> None:
    """Exit 0, no failed/errored/skipped test, and at least one passed test per node id among the
    targets (a deselected one, e.g. not marked can_e2e, would be missing), at least one in all."""
    counts = summary_counts(output)
    assert counts is not None, f"{where}: no pytest summary line in the output (exit {rc})"
    bad = {k: counts.get(k, 0) for k in ("failed", "errors", "skipped", "xfailed", "xpassed")}
    want = max(1, sum("::" in t for t in targets))
    assert rc == 0 and counts.get("passed", 0) >= want and not any(bad.values()), (
        f"{where}: exit {rc}, {counts}: every can_e2e test run there must pass (at least {want}), none skipped")


@pytest.mark.vm
def test_can_e2e_over_socketcan_vcan0():
    if os.environ.get("RTSIM_IN_VM"):
        pytest.skip("already inside the vcan VM")
    timeout = float(os.environ.get("RTSIM_VCAN_TIMEOUT", "1200"))
    from bridge.can_bus import socketcan_available
    host_vcan = socketcan_available("vcan0")
    targets = _e2e_targets(every=host_vcan)   # no emulation on the host: all of them there
    if not targets:                        # a suite without them would pass here silently
        pytest.fail("no test file mentions the can_e2e marker: nothing to run over vcan0")
    inner = [*INNER_PYTEST, *targets]

    if host_vcan:
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, *inner], cwd=ROOT, env={**os.environ, **VCAN_ENV},
                           stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, timeout=timeout)
        print(f"\n[vcan0 on this host] {time.monotonic() - t0:.1f} s\n{r.stdout}")
        _check_inner(r.returncode, r.stdout, "host vcan0", targets)
        return

    vm = _vcan_vm()
    ok, why = vm.available()
    if not ok:
        pytest.skip(f"no SocketCAN vcan0 on this kernel and no qemu VM for it: {why}")
    print(f"\n[vcan VM] {why}; tests: {' '.join(targets)}")
    try:
        vm.prepare(log=lambda s: print(s, flush=True))
    except vm.VMUnavailable as exc:
        pytest.skip(f"no SocketCAN vcan0 on this kernel and the VM image cannot be fetched: {exc}")

    if os.environ.get("RTSIM_VCAN_WARMUP", "1") != "0":
        t0 = time.monotonic()
        rc, out = vm.warm_numba_cache([sys.executable, *inner], cwd=ROOT, timeout=1.5 * timeout)
        print(f"[vcan VM] numba warm-up on the host (generic x86-64 code, shared cache): exit {rc}, "
              f"{time.monotonic() - t0:.1f} s", flush=True)
        # the same tests on the host's loopback bus: what fails there fails in the guest too, much slower
        if rc != 0:
            print(out)
        _check_inner(rc, out, "the warm-up on the host (loopback bus, generic code)", targets)

    res = vm.run([sys.executable, *inner], cwd=ROOT, env=GUEST_ENV, timeout=timeout,
                 smp=int(os.environ.get("RTSIM_VCAN_SMP", "1")), stream=lambda line: print(line, flush=True))
    print(f"[vcan VM] exit {res.returncode}; boot {res.boot_s:.1f} s, wall {res.wall_s:.1f} s")
    _check_inner(res.returncode, res.output, "inside the vcan VM", targets)
