"""A compiled kernel bound to fixed arguments, called without unboxing them.

Every call from Python into a numba kernel unboxes each argument: for the vehicle's model and state
(8 named tuples, 104 arrays and 5 scalars) that costs about 9 us per call, against a 17 us step,
although the arguments are the same objects at every step (arrays mutated in place) and only a few
scalars change. Bound, the fixed part costs about 0.05 us (rtsim bench --suite dispatch).

``f = bind(kernel, *fixed, n_free=K)`` returns ``f(*free)`` equal to ``kernel(*fixed, *free)``, with
the fixed arguments passed as one integer: the address of an int64 table holding, per array, its data
address and shape (and per fixed scalar, its value). A compiled wrapper rebuilds the arrays as views
(``array_at``), the tuples and named tuples around them, and calls the kernel, which therefore gets
exactly the argument types of a direct call (same specialization, same machine code, same results).

The wrapper is generated as Python source from the numba types of the fixed arguments and written to
``$RTSIM_CACHE/boundcall`` (default ``~/.cache/rtsim/boundcall``; ``RTSIM_CACHE=off``: a temporary
folder per process), because numba caches compiled code only for functions that have a source file.
The file is named by a hash of its text and of every source of rtsim, bridge and drivers (and of the
kernel's own file): numba keys a cached function on its own file only, and the wrapper's machine code
includes the kernel's, which would otherwise outlive a change of the kernel. When a new file is
written, the same binding's files of older sources are removed, and so are files unused for
PRUNE_DAYS (each bind sets its file's access time; the modification time numba checks is never
changed). A later process imports the file and loads the wrapper from numba's cache beside it,
without compiling (tens of milliseconds for the vehicle step; compiling it takes seconds).

Supported fixed arguments: tuples and named tuples (the class importable by module and name), nested
at will, of numpy arrays (0-d to any rank; bool, signed/unsigned integers, floats, complex; native
byte order; C-contiguous and aligned; readonly ones are rebuilt readonly), and scalars (Python bool,
int in the int64 range, float, and numpy bool/integer/floating scalars), whose values are fixed at
bind time.
The kernel must be importable by module and name (a module-level dispatcher, not ``__main__``).

Safety: the binding keeps a reference to every fixed object, so no bound array is freed while it is
bound. It holds addresses, so it goes stale if the owner puts a *different* array in its place
(``states = states._replace(effects=new)``, a rebuilt ``Data``): the kernel would keep working on
the old one. Rebind after any such replacement (about 0.6 ms once the wrapper is loaded in the
process); ``f.is_bound_to(*fixed)`` checks that given tuples are (or hold) the bound arrays (0.4 us
when they are the bound tuples themselves). Arrays must not be resized or reshaped in place
(``ndarray.resize`` refuses while the binding holds a reference unless told ``refcheck=False``;
``a.shape = ...`` would go unseen).
"""
from __future__ import annotations

import atexit
import functools
import hashlib
import importlib.util
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numba
import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from rtsim.sources import ROOT, SOURCE_TREES, sources_digest    # hashed into every generated file's name

PRUNE_DAYS = 30                                      # generated files unused this long are removed

_DTYPES = {np.dtype(n): n for n in ("bool_", "int8", "int16", "int32", "int64", "uint8", "uint16",
                                    "uint32", "uint64", "float32", "float64", "complex64", "complex128")}
_INT64 = (-2 ** 63, 2 ** 63 - 1)


class BindError(ValueError):
    """A kernel or fixed argument that bind() does not support; the message names which and why."""


def _view_intrinsic(readonly: bool):
    """An intrinsic (address, shape, dtype) -> C-contiguous array view on that memory (see array_at)."""

    def view(typingctx, address, shape, dtype):
        if not isinstance(address, types.Integer):
            return None
        if isinstance(shape, types.UniTuple) and isinstance(shape.dtype, types.Integer):
            ndim = shape.count
        elif isinstance(shape, types.Tuple) and len(shape) == 0:
            ndim = 0
        else:
            return None
        if not isinstance(dtype, (types.NumberClass, types.DType)):
            return None
        aryty = types.Array(dtype.dtype, ndim, "C", readonly=readonly)

        def codegen(context, builder, sig, args):
            addr, shp, _ = args
            intp = context.get_value_type(types.intp)
            eltype = context.get_data_type(aryty.dtype)
            itemsize = context.get_constant(types.intp, context.get_abi_sizeof(eltype))
            dims = [context.cast(builder, builder.extract_value(shp, i), sig.args[1][i], types.intp)
                    for i in range(ndim)]
            strides, s = [None] * ndim, itemsize
            for i in reversed(range(ndim)):
                strides[i] = s
                s = builder.mul(s, dims[i])
            ary = make_array(aryty)(context, builder)
            populate_array(ary, data=builder.inttoptr(addr, eltype.as_pointer()),
                           shape=cgutils.pack_array(builder, dims, ty=intp),
                           strides=cgutils.pack_array(builder, strides, ty=intp),
                           itemsize=itemsize, meminfo=None)
            return ary._getvalue()

        return aryty(address, shape, dtype), codegen

    view.__name__ = view.__qualname__ = "readonly_array_at" if readonly else "array_at"
    return intrinsic(view)


array_at = _view_intrinsic(False)
array_at.__doc__ = """In compiled code: ``array_at(address, shape, dtype)``, a C-contiguous array view of ``shape``
(a tuple of ints) and ``dtype`` (e.g. np.float64) on the memory at ``address`` (int64). No allocation
and no owner: whoever calls it keeps the memory alive."""
readonly_array_at = _view_intrinsic(True)
readonly_array_at.__doc__ = "As array_at, typed readonly (numba refuses writes at compile time)."


# -- layout of the fixed arguments -----------------------------------------------------------------

def _importable(obj, what: str, where: str) -> tuple[str, str]:
    """(module, name) under which ``obj`` is found again by an import, else BindError."""
    mod, name = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if (not mod or not name or mod == "__main__" or "." in name or "<" in name
            or getattr(sys.modules.get(mod), name, None) is not obj):
        raise BindError(f"{where}: {what} {obj!r} is not importable as module.name (define it at module "
                        f"level in an importable module, not in __main__ or a function)")
    return mod, name


class _Layout:
    """Walks the fixed arguments once: fills the table and writes the expression that rebuilds each."""

    def __init__(self):
        self.table: list[int] = []
        self.imports: dict[tuple[str, str], str] = {}
        self.floats = False

    def expr(self, x, where: str, ind: str = "    ") -> str:
        """Python source that rebuilds ``x`` inside the wrapper from the table ``t`` (``r``: as float64)."""
        i = len(self.table)
        if isinstance(x, np.ndarray):
            self.table.append(_array_check(x, where))
            self.table.extend(x.shape)
            shape = ", ".join(f"t[{i + 1 + k}]" for k in range(x.ndim)) + ("," if x.ndim == 1 else "")
            return f"{'_at' if x.flags.writeable else '_ro'}(t[{i}], ({shape}), _np.{_DTYPES[x.dtype]})"
        if isinstance(x, (bool, np.bool_)):
            self.table.append(int(x))
            return f"t[{i}] != 0"
        if type(x) is int or isinstance(x, np.integer) and x.dtype in _DTYPES:
            if type(x) is int and not _INT64[0] <= x <= _INT64[1]:
                raise BindError(f"{where}: int {x} outside the int64 range")
            self.table.append(int(np.array(x).astype(np.int64)))        # uint64: the same bits
            return f"t[{i}]" if type(x) is int else f"_np.{x.dtype}(t[{i}])"
        if type(x) is float or isinstance(x, np.floating) and x.dtype in _DTYPES:
            self.table.append(int(np.array(x, np.float64).view(np.int64)))
            self.floats = True
            return f"r[{i}]" if type(x) in (float, np.float64) else f"_np.{x.dtype}(r[{i}])"
        if not isinstance(x, tuple):
            raise BindError(f"{where}: {type(x).__name__} is not supported (tuples and named tuples of numpy "
                            f"arrays, bool, int and float scalars)")
        if type(x) is tuple:
            head, names = "(", [f"[{k}]" for k in range(len(x))]
        elif isinstance(getattr(type(x), "_fields", None), tuple):
            head = self.imports.setdefault(_importable(type(x), "named tuple class", where),
                                           f"_c{len(self.imports)}") + "("
            names = ["." + f for f in x._fields]
        else:
            raise BindError(f"{where}: tuple subclass {type(x).__name__} is not a named tuple")
        lines = []
        for v, name in zip(x, names):
            e = self.expr(v, where + name, ind + "    ")
            lines.append(f"{ind}    {e}," + ("" if isinstance(v, tuple) else f"  # {where}{name}"))
        return head + "".join("\n" + line for line in lines) + "\n" + ind + ")"


def _array_check(a: np.ndarray, where: str) -> int:
    """The data address of ``a`` if bind() supports it, else BindError naming the reason."""
    if a.dtype not in _DTYPES:
        raise BindError(f"{where}: dtype {a.dtype} is not supported ({', '.join(_DTYPES.values())})")
    if not a.flags.c_contiguous:
        raise BindError(f"{where}: array is not C-contiguous (pass np.ascontiguousarray of it)")
    if not a.flags.aligned:
        raise BindError(f"{where}: array is not aligned")
    return a.ctypes.data


def _source(kernel_mod: str, kernel_name: str, n_free: int, lay: _Layout, exprs: list[str]) -> str:
    lines = [f'"""Generated by rtsim.boundcall: {kernel_mod}.{kernel_name} bound to {len(exprs)} fixed '
             f'argument(s) and {n_free} free one(s). Do not edit."""',
             "import numpy as _np", "",
             "from rtsim.boundcall import array_at as _at, readonly_array_at as _ro",
             "from rtsim.jit import kernel as _jit",
             f"from {kernel_mod} import {kernel_name} as _kernel"]
    lines += [f"from {m} import {n} as {a}" for (m, n), a in lay.imports.items()]
    free = [f"a{k}" for k in range(n_free)]
    lines += ["", "", "@_jit", f"def bound({', '.join(['tab'] + free)}):",
              f"    t = _at(tab, ({len(lay.table)},), _np.int64)"]
    if lay.floats:
        lines.append(f"    r = _at(tab, ({len(lay.table)},), _np.float64)")
    lines += [f"    x{k} = {e}" for k, e in enumerate(exprs)]
    lines.append(f"    return _kernel({', '.join([f'x{k}' for k in range(len(exprs))] + free)})")
    return "\n".join(lines) + "\n"


# -- the generated module and its cache ------------------------------------------------------------

def _sources_digest() -> bytes:
    """SHA-256 of every .py file of the source trees (rtsim.sources; once per process)."""
    return sources_digest()


def _module_files(mods) -> bytes:
    """Text of the given modules' files that lie outside the hashed source trees (e.g. a test's)."""
    out = b""
    trees = [ROOT / t for t in SOURCE_TREES]
    for m in sorted(set(mods)):
        f = getattr(sys.modules.get(m), "__file__", None)
        if f and not any(Path(f).resolve().is_relative_to(t) for t in trees):
            out += Path(f).read_bytes()
    return out


_TEMP: list[Path] = []


def cache_dir() -> Path:
    """Where generated wrappers and their compiled code live: ``$RTSIM_CACHE/boundcall``, by default
    ``~/.cache/rtsim/boundcall``; with ``RTSIM_CACHE=off`` a temporary folder removed at exit."""
    root = os.environ.get("RTSIM_CACHE", "")
    if root.strip().lower() != "off":
        return (Path(root) if root else Path.home() / ".cache" / "rtsim") / "boundcall"
    if not _TEMP:
        _TEMP.append(Path(tempfile.mkdtemp(prefix="rtsim-boundcall-")))
        atexit.register(shutil.rmtree, _TEMP[0], True)
    return _TEMP[0]


_MODULES: dict[Path, object] = {}
_LOCK = threading.Lock()


def _module(text: str, kernel_name: str, extra: bytes):
    """The generated module for ``text``: written once (atomically, never rewritten, so numba's cache
    beside it stays valid), imported once per process."""
    with _LOCK:
        return _module_locked(text, kernel_name, extra)


def _module_locked(text: str, kernel_name: str, extra: bytes):
    folder = cache_dir()
    key = hashlib.sha256(text.encode() + str(ROOT).encode()).hexdigest()[:12]   # this binding, this checkout
    full = hashlib.sha256(text.encode() + _sources_digest() + extra).hexdigest()[:16]
    stem = f"{kernel_name}_{key}_{full}"
    path = folder / f"{stem}.py"
    mod = _MODULES.get(path)
    if mod is not None:
        return mod
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        try:
            with os.fdopen(fd, "w") as fh:
                fh.write(text)
            os.chmod(tmp, 0o644)
            try:
                os.link(tmp, path)                  # create if absent: a concurrent writer's file stays
            except FileExistsError:
                pass
        finally:
            os.unlink(tmp)
        unused = time.time() - PRUNE_DAYS * 86400
        for old in folder.glob("*.py"):             # this binding of older sources; long unused ones
            try:
                if old != path and (old.name.startswith(f"{kernel_name}_{key}_") or old.stat().st_atime < unused):
                    old.unlink(missing_ok=True)
                    for c in (folder / "__pycache__").glob(f"{old.stem}.*"):
                        c.unlink(missing_ok=True)
            except OSError:                         # a concurrent process removed it first
                pass
    os.utime(path, ns=(time.time_ns(), path.stat().st_mtime_ns))   # last use; the mtime numba checks stays
    spec = importlib.util.spec_from_file_location(stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[stem] = mod
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        del sys.modules[stem]
        raise
    _MODULES[path] = mod
    return mod


# -- the binding -----------------------------------------------------------------------------------

class Bound(functools.partial):
    """``kernel(*fixed, *free)`` as ``self(*free)`` (a functools.partial of the compiled wrapper and the
    table's address, so the Python side of a call is C code). Attributes: ``kernel``, ``fixed`` (the
    bound objects, referenced for the binding's lifetime), ``table`` (the int64 address table),
    ``n_free``, ``wrapper`` (the compiled dispatcher) and ``path`` (its generated source)."""

    def compile(self, *free):
        """Compile (or load from the cache) the wrapper for the types of example free arguments, so the
        first real call does not: ``f.compile(0.001, 1)`` before a real-time loop starts."""
        if len(free) != self.n_free:
            raise TypeError(f"{self.n_free} free argument(s) expected, got {len(free)}")
        self.wrapper.compile((types.int64,) + tuple(numba.typeof(v) for v in free))
        return self

    def is_bound_to(self, *fixed) -> bool:
        """True if calling with ``fixed`` now would be the same call: the very same top-level objects
        (0.4 us: tuples are immutable, so their arrays are the bound ones too), or tuples holding the
        very same arrays with the same addresses and shapes, and equal scalars (a fraction of a ms)."""
        if len(fixed) == len(self.fixed):
            for a, b in zip(fixed, self.fixed):
                if a is not b:
                    break
            else:
                return True
        try:
            lay = _Layout()
            exprs = [lay.expr(x, f"fixed[{k}]") for k, x in enumerate(fixed)]
        except BindError:
            return False
        return (exprs == self._exprs and lay.imports == self._imports
                and np.array_equal(np.asarray(lay.table, np.int64), self.table)
                and all(a is b for a, b in zip(_leaf_arrays(fixed), _leaf_arrays(self.fixed))))


def _leaf_arrays(x):
    if isinstance(x, np.ndarray):
        yield x
    elif isinstance(x, tuple):
        for v in x:
            yield from _leaf_arrays(v)


def bind(kernel, *fixed, n_free: int) -> Bound:
    """``f`` with ``f(*free) == kernel(*fixed, *free)`` for ``n_free`` positional free arguments, the
    fixed ones passed through one address table instead of being unboxed at each call (see the module
    docstring for what is supported and when to rebind). ``kernel``: a module-level numba dispatcher
    (rtsim.jit.kernel). The first call compiles the wrapper unless it is in the cache (``f.compile``)."""
    if not isinstance(kernel, numba.core.registry.CPUDispatcher):
        raise BindError(f"kernel: {kernel!r} is not a numba njit dispatcher")
    if kernel.targetoptions.get("_nrt", True):
        raise BindError(f"kernel: {kernel.__name__} is compiled with the numba runtime on; bind kernels of "
                        f"rtsim.jit.kernel (the rebuilt arrays have no owner to count references on)")
    if not isinstance(n_free, int) or n_free < 0:
        raise BindError(f"n_free: {n_free!r} is not a count")
    mod, name = _importable(kernel, "kernel", "kernel")
    lay = _Layout()
    exprs = [lay.expr(x, f"fixed[{k}]") for k, x in enumerate(fixed)]
    text = _source(mod, name, n_free, lay, exprs)
    gen = _module(text, name, _module_files([mod] + [m for m, _ in lay.imports]))
    table = np.asarray(lay.table, dtype=np.int64) if lay.table else np.zeros(1, np.int64)
    f = Bound(gen.bound, table.ctypes.data)
    f.kernel, f.fixed, f.table, f.n_free = kernel, fixed, table, n_free
    f.wrapper, f.path = gen.bound, Path(gen.__file__)
    f._exprs, f._imports = exprs, lay.imports
    return f
