"""rtsim.boundcall: a bound call is the direct call (bit-identical results and side effects, on the
vehicle and on synthetic kernels of mixed dtypes, ranks and nesting), unsupported input is refused by
name, the binding holds its arrays, and the generated wrapper is loaded from numba's cache by a
second process."""
from __future__ import annotations

import gc
import json
import os
import re
import subprocess
import sys
import time
from collections import namedtuple
from pathlib import Path

import numba as nb
import numpy as np
import pytest

import boundcall_kernels as bk
from rtsim import boundcall
from rtsim.boundcall import BindError, bind

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


def _copy(x):
    """Deep copy of tuples / named tuples of arrays (readonly arrays stay readonly)."""
    if isinstance(x, np.ndarray):
        c = x.copy()
        c.setflags(write=x.flags.writeable)
        return c
    if isinstance(x, tuple):
        items = [_copy(v) for v in x]
        return type(x)(*items) if hasattr(type(x), "_fields") else tuple(items)
    return x


def _leaves(x, where=""):
    if isinstance(x, tuple):
        for name, v in zip(getattr(type(x), "_fields", None) or range(len(x)), x):
            yield from _leaves(v, f"{where}.{name}")
    else:
        yield where, x


def _assert_bit_identical(a, b):
    for (wa, x), (wb, y) in zip(_leaves(a), _leaves(b), strict=True):
        assert wa == wb
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, wa
            assert x.tobytes() == y.tobytes(), f"{wa} differs"
        else:
            assert type(x) is type(y) and x == y, wa


# -- the vehicle ---------------------------------------------------------------------------------

def test_vehicle_advance_bound_is_bit_identical_to_the_direct_call():
    from rtsim.service.config import DEFAULT_SCENARIO
    from rtsim.service.server import build_sim
    from rtsim.vehicle.car.step import CMD_STEER, CMD_THROTTLE, vehicle_advance

    sim, _ = build_sim(DEFAULT_SCENARIO)
    fixed = (sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states, sim.io)
    direct, bound = _copy(fixed), _copy(fixed)
    f = bind(vehicle_advance, *bound, n_free=2)
    assert f.is_bound_to(*bound) and not f.is_bound_to(*direct)
    h = sim.dt
    known = set(vehicle_advance.signatures)          # another test in this process may have made others
    for n in range(300):                              # drive off, steering: commands change between calls
        for io in (direct[7], bound[7]):
            io.commands[CMD_THROTTLE] = min(0.4, n / 200)
            io.commands[CMD_STEER] = 0.2 * np.sin(n / 50)
        assert vehicle_advance(*direct, h, 1) == f(h, 1)
    assert vehicle_advance(*direct, h, 200) == f(h, 200)
    _assert_bit_identical(direct, bound)
    assert not np.array_equal(bound[1].q, fixed[1].q)            # it did move
    # one specialization serves both: the bound call made none beside the direct call's
    direct_sig = tuple(vehicle_advance.typeof_pyval(a) for a in (*direct, h, 1))
    assert set(vehicle_advance.signatures) - known <= {direct_sig} and direct_sig in vehicle_advance.signatures


# -- synthetic kernels -----------------------------------------------------------------------------

SCALARS = (np.int32(-3), True, 0.75, np.uint64(2 ** 64 - 1), np.float32(1.5))


def test_mixed_dtypes_ranks_and_nesting_are_bit_identical():
    o = bk.make_outer(1)
    direct, bound = _copy(o), _copy(o)
    out_d, out_b = np.zeros(5), np.zeros(5)
    f = bind(bk.mix, bound, *SCALARS, n_free=2)
    for k in range(3):
        rd = bk.mix(direct, *SCALARS, out_d, 0.1 * k)
        rb = f(out_b, 0.1 * k)
        assert repr(rd) == repr(rb) and rd == rb
        assert out_d.tobytes() == out_b.tobytes()
    _assert_bit_identical(direct, bound)
    assert rb[-3:] == (True, 2 ** 64 - 1, -3)
    assert len(bk.mix.signatures) == 1


def test_no_fixed_and_no_free_arguments():
    assert bind(bk.total, n_free=2)(1.5, 2.25) == 3.75
    x = np.zeros(4)
    g = bind(bk.fill, x, 2.5, n_free=0)
    assert g() is None and np.all(x == 2.5)


def test_binding_holds_its_arrays():
    f = bind(bk.mix, bk.make_outer(2), *SCALARS, n_free=2)       # the only reference is the binding's
    expect = bk.mix(bk.make_outer(2), *SCALARS, np.zeros(5), 0.0)
    gc.collect()
    junk = [np.full(100, 7.0) for _ in range(1000)]              # reuse any freed memory
    assert f(np.zeros(5), 0.0) == expect
    del junk


def test_is_bound_to_detects_replaced_arrays():
    o = bk.make_outer(3)
    f = bind(bk.mix, o, *SCALARS, n_free=2)
    assert f.is_bound_to(o, *SCALARS)
    assert f.is_bound_to(bk.Outer(*o), *SCALARS)                 # a new tuple holding the same arrays
    assert not f.is_bound_to(o._replace(x=o.x.copy()), *SCALARS)
    assert not f.is_bound_to(o._replace(inner=o.inner._replace(count=4)), *SCALARS)
    assert not f.is_bound_to(o, *SCALARS[:-1], np.float32(2.5))
    assert not f.is_bound_to(o)
    assert not f.is_bound_to(o._replace(x=[1.0]), *SCALARS)


Local = namedtuple("Local", ["a"])


@pytest.mark.parametrize("x, message", [
    (np.arange(10.0)[::2], "fixed[0]: array is not C-contiguous"),
    (np.ones((3, 4), order="F"), "not C-contiguous"),
    (np.array([object()]), "dtype object is not supported"),
    (np.zeros(3, dtype=[("a", "f8")]), "is not supported"),
    (np.zeros(3, ">f8"), "dtype >f8 is not supported"),
    (np.zeros(3, "M8[s]"), "is not supported"),
    (np.frombuffer(bytearray(81), np.float64, count=10, offset=1), "not aligned"),
    ([1.0, 2.0], "fixed[0]: list is not supported"),
    (None, "NoneType is not supported"),
    (2 ** 70, "outside the int64 range"),
    (1 + 2j, "complex is not supported"),
    ((np.zeros(2), {"a": 1}), "fixed[0][1]: dict is not supported"),
    (bk.Inner(np.zeros(2), np.zeros(3)[::2], 1, np.zeros(1)), "fixed[0].img: array is not C-contiguous"),
])
def test_unsupported_fixed_arguments_are_refused_by_name(x, message):
    with pytest.raises(BindError, match=re.escape(message)):
        bind(bk.first, x, n_free=1)


def test_unsupported_kernels_and_classes_are_refused():
    def plain(x, a):
        return a

    local = nb.njit(cache=False, _nrt=False)(plain)
    Tmp = namedtuple("Tmp", ["a"])
    with pytest.raises(BindError, match="not a numba njit dispatcher"):
        bind(plain, np.zeros(2), n_free=1)
    with pytest.raises(BindError, match="kernel: .* is not importable"):
        bind(local, np.zeros(2), n_free=1)
    with pytest.raises(BindError, match="numba runtime on"):
        bind(bk.with_nrt, np.zeros(2), n_free=1)
    with pytest.raises(BindError, match=r"fixed\[0\]: named tuple class .* is not importable"):
        bind(bk.first, Tmp(np.zeros(2)), n_free=1)
    with pytest.raises(BindError, match="n_free"):
        bind(bk.first, np.zeros(2), n_free=-1)


# -- the on-disk cache -----------------------------------------------------------------------------

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import boundcall_kernels as bk
from rtsim.boundcall import bind
bk.total(1.0, 2.0)                       # numba's first load in a process (~0.3 s) is not the wrapper's
f = bind(bk.mix, bk.make_outer(4), *__import__("test_boundcall").SCALARS, n_free=2)
t1 = time.perf_counter()
f.compile(f.fixed[0].x.copy(), 0.5)
t2 = time.perf_counter()
r = f(f.fixed[0].x.copy()[:3], 0.5)
st = f.wrapper.stats
print(json.dumps({"path": str(f.path), "hits": sum(st.cache_hits.values()), "misses": sum(st.cache_misses.values()),
                  "bind_s": t1 - t0, "compile_s": t2 - t1, "result": repr(r)}))
"""


def _child(cache: Path) -> dict:
    env = dict(os.environ, RTSIM_CACHE=str(cache), PYTHONPATH=os.pathsep.join([str(TESTS), str(ROOT)]))
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_second_process_loads_the_wrapper_from_the_cache(tmp_path):
    first, second = _child(tmp_path), _child(tmp_path)
    print(f"\nboundcall cache: first process compiles the wrapper in {first['compile_s']:.2f} s, "
          f"the second loads it in {second['compile_s']:.3f} s")
    assert (first["misses"], first["hits"]) == (1, 0)
    assert (second["misses"], second["hits"]) == (0, 1)
    assert first["path"] == second["path"] and first["result"] == second["result"]
    assert Path(first["path"]).parent == tmp_path / "boundcall"
    assert list((tmp_path / "boundcall" / "__pycache__").glob(Path(first["path"]).stem + ".*.nbc"))


def test_changed_sources_make_a_new_wrapper_and_drop_the_old(tmp_path, monkeypatch):
    monkeypatch.setenv("RTSIM_CACHE", str(tmp_path))
    x = np.zeros(3)
    f = bind(bk.fill, x, n_free=1)
    f(1.0)
    assert list((tmp_path / "boundcall" / "__pycache__").glob(f.path.stem + ".*"))
    unused = tmp_path / "boundcall" / "gone_000000000000_0000000000000000.py"
    unused.write_text("")
    old = time.time() - (boundcall.PRUNE_DAYS + 1) * 86400
    os.utime(unused, (old, old))
    monkeypatch.setattr(boundcall, "_sources_digest", lambda: b"edited sources")
    g = bind(bk.fill, x, n_free=1)
    assert g.path != f.path and g.path.exists() and not f.path.exists() and not unused.exists()
    assert not list((tmp_path / "boundcall" / "__pycache__").glob(f.path.stem + ".*"))
    other = bind(bk.first, x, n_free=1)                           # another binding's file stays
    assert other.path.exists() and g.path.exists()
    st = other.path.stat()
    os.utime(other.path, ns=(int(old * 1e9), st.st_mtime_ns))
    monkeypatch.setattr(boundcall, "_MODULES", {})                # as in a new process
    again = bind(bk.first, x, n_free=1)                           # marks its use, keeps numba's stamp
    assert again.path == other.path
    assert again.path.stat().st_mtime_ns == st.st_mtime_ns and again.path.stat().st_atime > old + 86400
    g(2.0)
    assert np.all(x == 2.0)


def test_cache_off_uses_a_temporary_folder(monkeypatch):
    monkeypatch.setenv("RTSIM_CACHE", "off")
    assert boundcall.cache_dir() != Path.home() / ".cache" / "rtsim" / "boundcall"
    assert bind(bk.total, n_free=2).path.parent == boundcall.cache_dir()


def test_dispatch_benchmark_reports_every_case():
    """`rtsim bench --suite dispatch` at a small size; prints its figures (no timing is asserted)."""
    from rtsim.benchmarks.dispatch import dispatch_costs, format_report

    res = dispatch_costs(reps=2000, repeats=3)
    print("\n" + format_report(res))
    assert res["fixed_tuples"] == 8 and res["fixed_arrays"] > 100
    assert len(res["us_per_call"]) == 5
    assert all(v["best"] > 0 for v in res["us_per_call"].values())
