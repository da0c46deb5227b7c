"""The CAN end-to-end tests (marker ``can_e2e``) again, over a real SocketCAN ``vcan0``.

Where this kernel has vcan0, they run on the host with ``RTSIM_CAN_INTERFACE=socketcan
RTSIM_CAN_CHANNEL=vcan0``; otherwise inside the qemu VM of ``tools/vcan_vm.py`` (Debian's kernel with
the vcan module, software emulation, packages fetched with apt-get on first use and cached); where
neither works the test skips with the reason. The inner run must report at least one passed test and
no failed, errored or skipped one, so it can never pass silently. Its output is printed (``-s``).

Before booting, the same tests run once on the host with the guest's numba settings
(``vcan_vm.numba_env``: generic x86-64 code, shared cache folder) so the guest loads compiled kernels
instead of compiling them under emulation (and rtsim's other caches, e.g. the suspension fits, are
filled); ``RTSIM_VCAN_WARMUP=0`` skips that. Inside the guest ``RTSIM_IN_VM=1`` is set.

Knobs: ``RTSIM_VCAN_TIMEOUT`` (s, whole VM run, default 1200), ``RTSIM_VCAN_SMP`` (guest CPUs,
default 1), ``RTSIM_VCAN_TESTS`` (space-separated test files/node ids instead of every file that
mentions ``can_e2e``), ``RTSIM_VCAN_VM=0`` (never boot). Deselect with ``-m "not vm"``.
"""
from __future__ import annotations

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


def _e2e_targets() -> list[str]:
    """Test files that mention the ``can_e2e`` marker (collecting only those keeps the emulated run
    from importing the whole suite), or ``$RTSIM_VCAN_TESTS``."""
    raw = os.environ.get("RTSIM_VCAN_TESTS", "").split()
    if raw:
        return raw
    me = Path(__file__).resolve()
    return [str(p.relative_to(ROOT)) for p in sorted(TESTS.glob("test_*.py"))
            if p.resolve() != me and "can_e2e" in p.read_text(errors="replace")]


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


def _check_inner(rc: int, output: str, where: str) -> None:
    counts = summary_counts(output)
    assert counts is not None, f"{where}: no pytest summary line in the output (exit {rc})"
    bad = {k: counts.get(k, 0) for k in ("failed", "errors", "skipped", "xfailed", "xpassed")}
    assert rc == 0 and counts.get("passed", 0) >= 1 and not any(bad.values()), (
        f"{where}: exit {rc}, {counts}: every can_e2e test must pass there, none skipped")


@pytest.mark.vm
def test_can_e2e_over_socketcan_vcan0():
    if os.environ.get("RTSIM_IN_VM"):
        pytest.skip("already inside the vcan VM")
    targets = _e2e_targets()
    if not targets:                        # a suite without them would pass here silently
        pytest.fail("no test file mentions the can_e2e marker: nothing to run over vcan0")
    inner = [*INNER_PYTEST, *targets]
    timeout = float(os.environ.get("RTSIM_VCAN_TIMEOUT", "1200"))

    from bridge.can_bus import socketcan_available
    if socketcan_available("vcan0"):
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, *inner], cwd=ROOT, env={**os.environ, **VCAN_ENV},
                           stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, timeout=timeout)
        print(f"\n[vcan0 on this host] {time.monotonic() - t0:.1f} s\n{r.stdout}")
        _check_inner(r.returncode, r.stdout, "host vcan0")
        return

    vm = _vcan_vm()
    ok, why = vm.available()
    if not ok:
        pytest.skip(f"no SocketCAN vcan0 on this kernel and no qemu VM for it: {why}")
    print(f"\n[vcan VM] {why}")
    try:
        vm.prepare(log=lambda s: print(s, flush=True))
    except vm.VMUnavailable as exc:
        pytest.skip(f"no SocketCAN vcan0 on this kernel and the VM image cannot be fetched: {exc}")

    if os.environ.get("RTSIM_VCAN_WARMUP", "1") != "0":
        t0 = time.monotonic()
        rc = vm.warm_numba_cache([sys.executable, *inner], cwd=ROOT, timeout=timeout)
        print(f"[vcan VM] numba warm-up on the host (generic x86-64 code, shared cache): exit {rc}, "
              f"{time.monotonic() - t0:.1f} s", flush=True)

    res = vm.run([sys.executable, *inner], cwd=ROOT, env=GUEST_ENV, timeout=timeout,
                 smp=int(os.environ.get("RTSIM_VCAN_SMP", "1")), stream=lambda line: print(line, flush=True))
    print(f"[vcan VM] exit {res.returncode}; boot {res.boot_s:.1f} s, wall {res.wall_s:.1f} s")
    _check_inner(res.returncode, res.output, "inside the vcan VM")
