#!/usr/bin/env python3
"""Run a command inside a minimal Linux VM (qemu, software emulation) that has a real SocketCAN ``vcan0``.

Why: this host kernel has no SocketCAN, so the CAN end-to-end tests could only ever run over the
python-can-remote hub. This module boots Debian's own kernel under qemu TCG with the ``vcan`` module,
mounts the host's ``/`` read-only over virtio-9p, and runs the command in a chroot of it: same
Python, same venv, same sources, but a kernel with ``vcan0`` up (MTU 72, CAN FD capable).

What it does, all without installing anything on the host (stdlib only):

1. **Fetch** (once, cached): ``apt-get download`` of ``qemu-system-x86`` and the shared libraries the
   host lacks (the ``apt-get -s install`` closure), ``seabios``, the kernel package that
   ``linux-image-amd64`` points to, and ``busybox-static``; ``dpkg-deb`` unpacks them into the cache
   (``$RTSIM_CACHE/vcan-vm``, default ``~/.cache/rtsim/vcan-vm``); the ``.deb`` files and the unused part of the
   kernel package are dropped (about 95 MB stay; 88 MB fetched). An ``flock`` on ``<cache>/.lock`` keeps two test
   processes from building it at once; the finished image is published by an atomic rename.
2. **Initramfs** (built in Python, cpio "newc"): busybox and the virtio/9p/overlay/CAN modules in
   dependency order (read from each module's ``.modinfo``), cached; per run a second archive appended
   to it carries the command and an ``/init`` that loads the modules, creates
   ``vcan0``, mounts the host root read-only and lays a RAM overlay over it (so HOME, /tmp, pytest's
   and numba's writes work and vanish at power-off, the host tree is never written), mounts rtsim's
   cache root (``$RTSIM_CACHE`` or ``~/.cache/rtsim``: numba kernels, kinematics fits) read-write at
   the same path, chroots and runs the command.
3. **Boot**: ``qemu-system-x86_64 -accel tcg -cpu max -m 1024 -smp 1 -nodefaults -nic none``: no guest
   network device at all. Output of the command streams over the serial console; its exit code comes
   back on a marker line. Timeouts bound the boot and the whole run; qemu is killed on every exit
   path (normal, timeout, exception, KeyboardInterrupt) and when this process dies (PDEATHSIG).

Numba in the guest: the host's caches beside the sources are compiled for the host CPU (znver4 with
AVX-512 here), which TCG cannot emulate and numba's cache index keys on, so they never load in the
guest (measured: ``rtsim bench --problem pendulum --t-end 0.01`` took 11.4 min in the guest with
them, as long as with no cache at all). The guest therefore uses ``NUMBA_CPU_NAME=generic`` and a
cache folder shared read-write with the host, ``<cache_root>/vcan-vm/numba-generic/<digest of the
sources>``. :func:`numba_env` gives that environment: run the same command on the host with it first
(:func:`warm_numba_cache`) and the guest loads the kernels instead of compiling them (same bench: 75 s
instead of 11.3 min; the guest also saves what it compiles there, for the next run).

API: :func:`available` (cheap check, no boot), :func:`prepare` (fetch/unpack, idempotent),
:func:`run` (boot, run, return :class:`VMResult`), :func:`numba_env`, :func:`warm_numba_cache`.
CLI::

    python tools/vcan_vm.py [--timeout S] [--cwd DIR] [--env K=V ...] [--mem MB] [--smp N] -- CMD ...
    python tools/vcan_vm.py --check | --prepare
"""
from __future__ import annotations

import argparse
import ctypes
import fcntl
import hashlib
import io
import os
import platform
import re
import selectors
import shlex
import shutil
import signal
import struct
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable, Iterable, Mapping, NamedTuple, Sequence

try:  # one error family with rtsim when it is importable; this file also works stand-alone
    from rtsim.errors import RtsimError as _Base
except ImportError:  # pragma: no cover
    _Base = Exception

CACHE_ENV = "RTSIM_CACHE"
REPO_ROOT = Path(__file__).resolve().parent.parent
DISABLE_ENV = "RTSIM_VCAN_VM"  # "0" disables the VM (available() says so)
IMAGE_VERSION = "2"            # bump when the image layout or the init script changes
QEMU_PACKAGES = ("qemu-system-x86", "qemu-system-common", "qemu-system-data", "seabios")
KERNEL_META = "linux-image-amd64"
BUSYBOX_PACKAGE = "busybox-static"
# modules the guest needs (their dependencies are added from .modinfo)
GUEST_MODULES = ("virtio_pci", "9pnet_virtio", "9p", "overlay", "vcan", "can_raw", "can_bcm",
                 "can_isotp", "can_gw")
EXIT_MARK = "RTSIM-VM-EXIT"
READY_MARK = "RTSIM-VM-READY"
FAIL_MARK = "RTSIM-VM-FAIL"
GUEST_HOME = "/tmp/rtsim-home"  # not /root: the host's Python may live under /root (pyenv)


class VMError(_Base):
    """The VM could not boot or run the command (one-line message)."""


class VMUnavailable(VMError):
    """This machine cannot provide the VM (no apt-get/dpkg, packages not fetchable, qemu does not run)."""


class VMResult(NamedTuple):
    """Outcome of :func:`run`: the command's exit code and output (console text, CR removed);
    ``boot_s`` wall time from qemu start to vcan0 up and root mounted, ``wall_s`` in all (s)."""
    returncode: int
    output: str
    boot_s: float
    wall_s: float


# --------------------------------------------------------------------------------------------------
# cache layout

def cache_root() -> Path:
    """rtsim's cache root, as ``rtsim.vehicle.kit.linkage_cache`` uses it: ``$RTSIM_CACHE`` or
    ``~/.cache/rtsim`` (also when ``RTSIM_CACHE=off``: the VM image is not a cached result)."""
    raw = os.environ.get(CACHE_ENV, "").strip()
    if raw and raw.lower() != "off":
        return Path(raw).expanduser().resolve()
    return Path.home() / ".cache" / "rtsim"


def cache_dir() -> Path:
    """Where the VM image lives: ``<cache_root()>/vcan-vm``."""
    return cache_root() / "vcan-vm"


class Image(NamedTuple):
    """A prepared image: the unpacked qemu tree, the kernel and the base initramfs."""
    root: Path

    @property
    def qemu(self) -> Path:
        return self.root / "qemu" / "usr" / "bin" / "qemu-system-x86_64"

    @property
    def kernel(self) -> Path:
        return self.root / "vmlinuz"

    @property
    def initramfs(self) -> Path:
        return self.root / "initramfs.cpio"

    def qemu_env(self) -> dict:
        q = self.root / "qemu"
        libs = [str(q / "usr/lib/x86_64-linux-gnu"), str(q / "lib/x86_64-linux-gnu")]
        old = os.environ.get("LD_LIBRARY_PATH")
        return dict(os.environ, LD_LIBRARY_PATH=os.pathsep.join(libs + ([old] if old else [])))

    def firmware_args(self) -> list[str]:
        q = self.root / "qemu"
        out = []
        for d in ("usr/share/qemu", "usr/share/seabios", "usr/lib/ipxe/qemu"):
            if (q / d).is_dir():
                out += ["-L", str(q / d)]
        return out


def _image_path(cache: Path) -> Path:
    return cache / f"image-v{IMAGE_VERSION}"


def _ready(cache: Path) -> Image | None:
    img = Image(_image_path(cache))
    return img if (img.root / "READY").is_file() else None


class _Lock:
    """Exclusive ``flock`` on ``<cache>/.lock``, bounded wait (s)."""

    def __init__(self, cache: Path, timeout: float):
        self.path, self.timeout, self.fd = cache / ".lock", timeout, None

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return self
            except BlockingIOError:
                if time.monotonic() > deadline:
                    os.close(self.fd)
                    raise VMError(f"vcan VM: cache {self.path.parent} locked by another process for "
                                  f"more than {self.timeout:g} s") from None
                time.sleep(0.2)

    def __exit__(self, *exc):
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)


# --------------------------------------------------------------------------------------------------
# availability

def _one_line(text: object, limit: int = 300) -> str:
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _sh(cmd: Sequence[str], timeout: float, cwd: Path | None = None) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(list(cmd), cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              stdin=subprocess.DEVNULL, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise VMUnavailable(f"vcan VM: `{' '.join(cmd[:3])} ...` took more than {timeout:g} s") from None
    except OSError as exc:
        raise VMUnavailable(f"vcan VM: cannot run {cmd[0]} ({_one_line(exc)})") from None


def _qemu_runs(img: Image) -> tuple[bool, str]:
    try:
        r = subprocess.run([str(img.qemu), "--version"], env=img.qemu_env(), stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, f"the cached qemu does not run ({_one_line(exc)})"
    if r.returncode != 0:
        return False, f"the cached qemu does not run: {_one_line(r.stdout)}"
    return True, r.stdout.splitlines()[0].strip()


def available(cache: Path | None = None) -> tuple[bool, str]:
    """Whether the VM can work here, without booting it (and without network if nothing is cached):
    ``(True, what will be used)`` or ``(False, why not)``."""
    if os.environ.get(DISABLE_ENV, "") == "0":
        return False, f"disabled by {DISABLE_ENV}=0"
    if sys.platform != "linux" or platform.machine() not in ("x86_64", "AMD64"):
        return False, f"needs Linux x86_64 (this is {sys.platform} {platform.machine()})"
    cache = cache or cache_dir()
    img = _ready(cache)
    if img is not None:
        ok, msg = _qemu_runs(img)
        return (True, f"cached image {img.root} ({msg})") if ok else (False, msg)
    for tool in ("apt-get", "apt-cache", "dpkg-deb"):
        if shutil.which(tool) is None:
            return False, f"no cached image in {cache} and no {tool} to fetch one (Debian/Ubuntu tools)"
    try:
        names = [*QEMU_PACKAGES, KERNEL_META, BUSYBOX_PACKAGE]
        r = _sh(["apt-cache", "policy", *names], 30)
    except VMUnavailable as exc:
        return False, str(exc)
    missing = [n for n in names if not re.search(rf"^{re.escape(n)}:\n(?:.*\n)*?\s+Candidate: (?!\(none\))",
                                                 r.stdout, re.M)]
    if missing:
        return False, f"apt knows no candidate for {', '.join(missing)} (run `apt-get update`?)"
    return True, f"will fetch {', '.join(names)} with apt-get into {cache}"


# --------------------------------------------------------------------------------------------------
# fetch and unpack

def _new_packages(names: Sequence[str]) -> list[str]:
    """Packages ``apt-get install`` would add (not upgrade) for ``names``: the libraries the host lacks."""
    r = _sh(["apt-get", "-s", "-q", "install", "--no-install-recommends", *names], 120)
    if r.returncode != 0:
        raise VMUnavailable(f"vcan VM: apt-get cannot resolve {' '.join(names)}: {_one_line(r.stderr)}")
    return re.findall(r"^Inst (\S+) \(", r.stdout, re.M)  # "Inst pkg [old] (new ...)" = upgrade: skip


def _kernel_package() -> str:
    r = _sh(["apt-cache", "depends", KERNEL_META], 60)
    m = re.search(r"Depends: (linux-image-\S+)", r.stdout)
    if r.returncode != 0 or m is None:
        raise VMUnavailable(f"vcan VM: cannot resolve {KERNEL_META}: {_one_line(r.stderr or r.stdout)}")
    return m.group(1)


def _download(names: Sequence[str], dest: Path, timeout: float) -> list[Path]:
    cmd = ["apt-get", "download", "-q"]
    if os.geteuid() == 0:  # apt's _apt sandbox user cannot write into our private staging folder
        cmd += ["-o", "APT::Sandbox::User=root"]
    r = _sh([*cmd, *names], timeout, cwd=dest)
    if r.returncode != 0:
        raise VMUnavailable(f"vcan VM: apt-get download failed ({_one_line(r.stderr)}); "
                            f"check the network and run `apt-get update`")
    debs = sorted(dest.glob("*.deb"))
    if len(debs) < len(set(names)):
        raise VMUnavailable(f"vcan VM: apt-get download gave {len(debs)} of {len(set(names))} packages")
    return debs


def _fsys_tar(deb: Path, timeout: float):
    """Iterate (tarinfo, fileobj) over a .deb's data via ``dpkg-deb --fsys-tarfile``."""
    proc = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(deb)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
    timer = threading.Timer(timeout, proc.kill)
    timer.start()
    complete = False
    try:
        with tarfile.open(fileobj=proc.stdout, mode="r|") as tf:
            for ti in tf:
                yield ti, tf
        complete = True
    finally:
        timer.cancel()
        if not complete:  # the caller stopped early (or failed): dpkg-deb is not needed any more
            proc.kill()
        proc.stdout.close()
        err = proc.stderr.read().decode(errors="replace")
        proc.stderr.close()
        if proc.wait() != 0 and complete:
            raise VMUnavailable(f"vcan VM: dpkg-deb cannot unpack {deb.name} ({_one_line(err)})")


def _extract_kernel(deb: Path, out: Path) -> tuple[Path, dict[str, Path]]:
    """Extract vmlinuz and every ``.ko`` of the kernel package; returns (vmlinuz, name -> .ko path)."""
    vmlinuz, modules = None, {}
    for ti, tf in _fsys_tar(deb, 300):
        name = ti.name.lstrip("./")
        if not ti.isfile():
            continue
        if re.fullmatch(r"boot/vmlinuz-.*", name) or (name.startswith("lib/modules/") and name.endswith(".ko")):
            target = out / name
            target.parent.mkdir(parents=True, exist_ok=True)
            with tf.extractfile(ti) as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst, 1 << 20)
            if name.startswith("boot/"):
                vmlinuz = target
            else:
                modules[Path(name).stem.replace("-", "_")] = target
    if vmlinuz is None or not modules:
        raise VMUnavailable(f"vcan VM: {deb.name} holds no vmlinuz or no plain .ko modules")
    return vmlinuz, modules


def _extract_busybox(deb: Path, out: Path) -> Path:
    for ti, tf in _fsys_tar(deb, 120):
        if ti.isfile() and ti.name.lstrip("./") == "bin/busybox":
            out.write_bytes(tf.extractfile(ti).read())
            out.chmod(0o755)
            return out
    raise VMUnavailable(f"vcan VM: {deb.name} has no bin/busybox")


def _modinfo(path: Path) -> dict[str, str]:
    """The ``.modinfo`` section of a kernel module (ELF64): key -> value (last one wins)."""
    data = path.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2:
        raise VMUnavailable(f"vcan VM: {path.name} is not an ELF64 kernel module")
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x3A)
    def sect(i):
        name, _typ, _fl, _addr, off, size = struct.unpack_from("<IIQQQQ", data, shoff + i * shentsize)
        return name, off, size
    _, stroff, _ = sect(shstrndx)
    for i in range(shnum):
        name, off, size = sect(i)
        if data[stroff + name: data.index(b"\0", stroff + name)] == b".modinfo":
            info = {}
            for item in data[off: off + size].split(b"\0"):
                k, sep, v = item.decode(errors="replace").partition("=")
                if sep:
                    info[k] = v
            return info
    return {}


def _module_order(wanted: Iterable[str], modules: Mapping[str, Path]) -> list[Path]:
    """The ``.ko`` files of ``wanted`` and their dependencies, dependencies first."""
    order: list[Path] = []
    state: dict[str, int] = {}
    def visit(name: str, chain: tuple[str, ...]):
        name = name.replace("-", "_")
        if state.get(name) == 2:
            return
        if name in chain:
            raise VMUnavailable(f"vcan VM: module dependency cycle {' -> '.join(chain + (name,))}")
        if name not in modules:
            raise VMUnavailable(f"vcan VM: the kernel package has no module {name} "
                                f"(needed by {chain[-1] if chain else 'the guest'}); built in?")
        for dep in filter(None, _modinfo(modules[name]).get("depends", "").split(",")):
            visit(dep, chain + (name,))
        state[name] = 2
        order.append(modules[name])
    for w in wanted:
        visit(w, ())
    return order


# --------------------------------------------------------------------------------------------------
# initramfs

def _cpio(entries: Iterable[tuple[str, int, bytes]]) -> bytes:
    """A cpio "newc" archive of (path, mode, data) entries (mode includes the file type bits)."""
    out = io.BytesIO()
    def put(name: str, mode: int, data: bytes, ino: int):
        nb = name.encode() + b"\0"
        hdr = "070701" + "".join(f"{v:08X}" for v in (ino, mode, 0, 0, 1, 0, len(data), 0, 0, 0, 0, len(nb), 0))
        out.write(hdr.encode() + nb + b"\0" * (-(110 + len(nb)) % 4))
        out.write(data + b"\0" * (-len(data) % 4))
    ino = 1
    for name, mode, data in entries:
        put(name, mode, data, ino)
        ino += 1
    put("TRAILER!!!", 0, b"", 0)
    return out.getvalue()


_DIR, _FILE, _LINK = 0o040755, 0o100755, 0o120777

# /init of the guest (busybox sh). $1.. are unused; the per-run part comes from /run.env and /run.cmd.
_INIT = r"""#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev
fail() { echo "@FAIL@ $*"; poweroff -f; }
for m in $(cat /modules.order); do insmod "/lib/modules/$m" || fail "insmod $m"; done
ip link set lo up
ip link add dev vcan0 type vcan || fail "ip link add vcan0 type vcan"
ip link set vcan0 mtu 72 || fail "vcan0 mtu 72 (CAN FD)"
ip link set vcan0 up || fail "vcan0 up"
mkdir -p /lower /rw /newroot
mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=512000 hostroot /lower || fail "mount host root (9p)"
mount -t tmpfs -o size=60% tmpfs /rw && mkdir -p /rw/upper /rw/work || fail "tmpfs"
mount -t overlay overlay -o lowerdir=/lower,upperdir=/rw/upper,workdir=/rw/work /newroot || fail "overlay"
mount -t proc proc /newroot/proc; mount -t sysfs sys /newroot/sys; mount -t devtmpfs dev /newroot/dev
mkdir -p /newroot/dev/pts /newroot/dev/shm
mount -t devpts devpts /newroot/dev/pts; mount -t tmpfs shm /newroot/dev/shm
mount -t tmpfs run /newroot/run 2>/dev/null   # /tmp stays the host's (via the overlay): a checkout may live there
. /run.env
i=0
for d in $VM_SHARES; do
  mkdir -p "/newroot$d" && mount -t 9p -o trans=virtio,version=9p2000.L,cache=loose,msize=512000 "share$i" "/newroot$d" || fail "mount shared dir $d"
  i=$((i + 1))
done
cp /run.cmd /newroot/tmp/.rtsim-vm-run.sh
echo "@READY@ $(cat /proc/uptime)"
chroot /newroot /bin/sh /tmp/.rtsim-vm-run.sh </dev/null
echo "@EXIT@ $?"
sync
poweroff -f
"""


def _build_image(cache: Path, log: Callable[[str], None], timeout: float) -> Image:
    cache.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix="staging-", dir=cache))
    try:
        t0 = time.monotonic()
        kernel_pkg = _kernel_package()
        names = list(dict.fromkeys([*QEMU_PACKAGES, *_new_packages(["qemu-system-x86"]), kernel_pkg,
                                    BUSYBOX_PACKAGE]))
        debdir = staging / "debs"
        debdir.mkdir()
        log(f"vcan VM: fetching {len(names)} packages with apt-get into {cache}")
        debs = _download(names, debdir, timeout)
        log(f"vcan VM: fetched {sum(d.stat().st_size for d in debs) / 1e6:.0f} MB in "
            f"{time.monotonic() - t0:.1f} s; unpacking")
        img = Image(staging / "image")
        (img.root / "qemu").mkdir(parents=True)
        kernel_deb = busybox_deb = None
        for deb in debs:
            if deb.name.startswith(kernel_pkg + "_"):
                kernel_deb = deb
            elif deb.name.startswith(BUSYBOX_PACKAGE + "_"):
                busybox_deb = deb
            else:
                r = _sh(["dpkg-deb", "-x", str(deb), str(img.root / "qemu")], 300)
                if r.returncode != 0:
                    raise VMUnavailable(f"vcan VM: dpkg-deb cannot unpack {deb.name} ({_one_line(r.stderr)})")
        if kernel_deb is None or busybox_deb is None:
            raise VMUnavailable("vcan VM: the kernel or busybox package was not downloaded")
        ok, msg = _qemu_runs(img)
        if not ok:
            raise VMUnavailable(f"vcan VM: {msg}")
        ktree = staging / "kernel"
        vmlinuz, modules = _extract_kernel(kernel_deb, ktree)
        busybox = _extract_busybox(busybox_deb, staging / "busybox")
        order = _module_order(GUEST_MODULES, modules)
        entries = [(d, _DIR, b"") for d in ("bin", "dev", "proc", "sys", "lib", "lib/modules", "tmp")]
        entries.append(("bin/busybox", _FILE, busybox.read_bytes()))
        entries.append(("bin/sh", _LINK, b"busybox"))
        entries += [(f"lib/modules/{p.name}", 0o100644, p.read_bytes()) for p in order]
        entries.append(("modules.order", 0o100644, "".join(p.name + "\n" for p in order).encode()))
        img.initramfs.write_bytes(_cpio(entries))
        shutil.copyfile(vmlinuz, img.kernel)
        (img.root / "PACKAGES").write_text("".join(d.name + "\n" for d in debs))
        (img.root / "READY").write_text(f"{msg}\nkernel {kernel_pkg}\nmodules {' '.join(p.stem for p in order)}\n")
        shutil.rmtree(debdir)
        shutil.rmtree(ktree)
        final = _image_path(cache)
        if final.exists():
            shutil.rmtree(final)
        os.rename(img.root, final)
        log(f"vcan VM: image ready in {final} ({time.monotonic() - t0:.1f} s; {msg})")
        return Image(final)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def prepare(cache: Path | None = None, *, log: Callable[[str], None] = print, timeout: float = 600.0) -> Image:
    """Fetch and unpack the image into the cache unless it is there already (idempotent, locked).
    Raises :class:`VMUnavailable` when it cannot be fetched or does not run here."""
    cache = cache or cache_dir()
    img = _ready(cache)
    if img is not None:
        return img
    with _Lock(cache, timeout):
        img = _ready(cache)
        if img is not None:
            return img
        for old in cache.glob("staging-*"):  # left by a process killed while building
            shutil.rmtree(old, ignore_errors=True)
        return _build_image(cache, log, timeout)


# --------------------------------------------------------------------------------------------------
# numba in the guest

#: the source trees whose kernels the guest runs; any change to their files gives a new cache folder
KERNEL_TREES = ("rtsim", "bridge", "drivers")
GENERIC_KEEP_DAYS = 2.0        # another sources' folder unused this long is removed


def sources_digest(root: Path = REPO_ROOT) -> str:
    """16 hex digits of SHA-256 over every .py file of ``KERNEL_TREES`` under ``root`` (path and text)."""
    h = hashlib.sha256()
    for tree in KERNEL_TREES:
        for p in sorted((root / tree).rglob("*.py")):
            h.update(str(p.relative_to(root)).encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def numba_env(cache: Path | None = None) -> dict[str, str]:
    """Environment that makes numba compile for a CPU the emulator runs (``generic`` x86-64) into a
    cache folder shared by host and guest, so the host can compile what the guest will load.

    The folder is ``numba-generic/<sources_digest()>``: numba keys a cached kernel on the text of its
    own file only, so a kernel whose file did not change would load machine code built against an
    older version of the kernels it calls and the slot layouts it imports (stale code that can read and
    write the model's arrays out of their bounds). This cache outlives a checkout (it lies under the
    cache root, not beside the sources that ``tools/setup`` cleans), so it is one folder per content of
    the sources; other contents' folders unused for ``GENERIC_KEEP_DAYS`` days are removed."""
    base = (cache or cache_dir()) / "numba-generic"
    d = base / sources_digest()
    d.mkdir(parents=True, exist_ok=True)
    os.utime(d)                                             # its last use, for the pruning below
    unused = time.time() - GENERIC_KEEP_DAYS * 86400
    for old in base.iterdir():
        try:
            if old != d and (not old.is_dir() or not re.fullmatch(r"[0-9a-f]{16}", old.name)
                             or old.stat().st_mtime < unused):
                shutil.rmtree(old) if old.is_dir() else old.unlink()
        except OSError:                                     # a concurrent run removed it first
            pass
    return {"NUMBA_CPU_NAME": "generic", "NUMBA_CACHE_DIR": str(d)}


def warm_numba_cache(cmd: Sequence[str], *, cwd: str | Path | None = None, env: Mapping[str, str] | None = None,
                     timeout: float = 600.0, cache: Path | None = None) -> tuple[int, str]:
    """Run ``cmd`` on the host with :func:`numba_env` so every kernel it compiles lands in the shared
    cache for the guest; returns its exit code and its output (stdout and stderr together): a command
    that fails on the host would fail in the guest as well, many times slower, so the caller can stop here."""
    full = dict(os.environ, **(env or {}), **numba_env(cache))
    try:
        r = subprocess.run(list(cmd), cwd=cwd, env=full, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise VMError(f"vcan VM: numba warm-up `{shlex.join(cmd)[:80]}` took more than {timeout:g} s") from None
    return r.returncode, r.stdout


# --------------------------------------------------------------------------------------------------
# boot and run

_PRCTL = []


def _prctl():
    """libc's prctl, looked up in the parent (a library load after fork could deadlock)."""
    if not _PRCTL:
        try:
            _PRCTL.append(ctypes.CDLL(None, use_errno=True).prctl)
        except (OSError, AttributeError):
            _PRCTL.append(None)
    return _PRCTL[0]


def _pdeathsig():  # child side of Popen: qemu gets SIGKILL when this process dies
    if _PRCTL and _PRCTL[0] is not None:
        _PRCTL[0](1, signal.SIGKILL)  # PR_SET_PDEATHSIG


_PASS_ENV = ("LANG", "LC_ALL", "TZ", "PYTHONPATH", "PYTHONHASHSEED")


def run(cmd: Sequence[str], *, cwd: str | Path | None = None, env: Mapping[str, str] | None = None,
        timeout: float = 900.0, boot_timeout: float = 120.0, mem_mb: int = 1024, smp: int = 1,
        stream: Callable[[str], None] | None = None, cache: Path | None = None,
        share_caches: bool = True, qemu_args: Sequence[str] = ()) -> VMResult:
    """Boot the VM and run ``cmd`` (argv) in ``cwd`` (default: this process's) with ``vcan0`` up.

    The guest environment: ``PATH`` of this process, ``HOME`` in the RAM overlay, ``PYTHONDONTWRITEBYTECODE``,
    a few locale variables, with ``share_caches`` :func:`numba_env` and ``RTSIM_CACHE`` (rtsim's cache
    root, e.g. the suspension kinematics fits, exported read-write at the same path: writes elsewhere
    land in the guest's RAM overlay and vanish), then ``env``. Each output
    line goes to ``stream`` (if given) as it arrives. Timeouts (s): ``boot_timeout`` until the command
    starts, ``timeout`` for the whole run. ``qemu_args`` are appended to qemu's command line.
    ``smp`` defaults to 1: on this 2-core host (busy) one vCPU ran the CAN tests about twice as fast
    as two (multi-threaded TCG competes with the host's own load). Raises :class:`VMUnavailable` if the image cannot be
    prepared, :class:`VMError` if boot or run fails or times out; qemu is always killed."""
    if not cmd:
        raise VMError("vcan VM: empty command")
    t0 = time.monotonic()
    cache = cache or cache_dir()
    img = prepare(cache, log=stream or (lambda s: None))
    cwd = Path(cwd or os.getcwd()).resolve()
    genv = {"PATH": os.environ.get("PATH", "/usr/local/bin:/usr/bin:/bin"), "HOME": GUEST_HOME,
            "TERM": "dumb", "PYTHONDONTWRITEBYTECODE": "1", "PYTHONUNBUFFERED": "1"}
    genv.update({k: os.environ[k] for k in _PASS_ENV if k in os.environ})
    shares: list[str] = []
    if share_caches:
        genv.update(numba_env(cache))
        root = cache_root()
        root.mkdir(parents=True, exist_ok=True)
        genv[CACHE_ENV] = os.environ.get(CACHE_ENV, "").strip() or str(root)
        shares = [str(root)]
        if not Path(genv["NUMBA_CACHE_DIR"]).resolve().is_relative_to(root.resolve()):
            shares.append(genv["NUMBA_CACHE_DIR"])
    genv.update(env or {})
    for k in genv:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", k):
            raise VMError(f"vcan VM: bad environment variable name {k!r}")
    script = "".join([
        f"mkdir -p {shlex.quote(GUEST_HOME)}\n",
        "".join(f"export {k}={shlex.quote(v)}\n" for k, v in genv.items()),
        f"cd {shlex.quote(str(cwd))} || exit 125\n",
        f"exec {shlex.join(map(str, cmd))}\n"])
    if any(any(c.isspace() for c in d) for d in shares):
        raise VMError(f"vcan VM: cache folders with blanks are not supported: {shares}")
    run_env = f"VM_SHARES={shlex.quote(' '.join(shares))}\n"
    nonce = os.urandom(4).hex()  # markers the command's own output cannot forge by accident
    marks = (f"{READY_MARK}-{nonce}", f"{EXIT_MARK}-{nonce}", f"{FAIL_MARK}-{nonce}")
    init = _INIT.replace("@READY@", marks[0]).replace("@EXIT@", marks[1]).replace("@FAIL@", marks[2])
    tail = _cpio([("init", _FILE, init.encode()), ("run.cmd", 0o100644, script.encode()),
                  ("run.env", 0o100644, run_env.encode())])

    with tempfile.TemporaryDirectory(prefix="rtsim-vcan-vm-") as tmp:
        initrd = Path(tmp) / "initrd.cpio"
        with open(initrd, "wb") as f:  # the kernel unpacks concatenated cpio archives in order
            f.write(img.initramfs.read_bytes())
            f.write(tail)
        qcmd = [str(img.qemu), *img.firmware_args(), "-accel", "tcg,thread=multi", "-cpu", "max",
                "-m", str(int(mem_mb)), "-smp", str(int(smp)), "-nodefaults", "-display", "none",
                "-no-reboot", "-nic", "none", "-serial", "stdio", "-monitor", "none",
                "-kernel", str(img.kernel), "-initrd", str(initrd),
                "-append", "console=ttyS0 quiet loglevel=1 panic=-1 rdinit=/init",
                "-virtfs", "local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap"]
        for i, d in enumerate(shares):  # read-write: only rtsim's caches (content-keyed, atomic writes)
            qcmd += ["-virtfs", f"local,path={d},mount_tag=share{i},security_model=none,multidevs=remap"]
        qcmd += list(qemu_args)
        _prctl()  # resolved before fork: nothing is loaded in the child
        try:
            proc = subprocess.Popen(qcmd, env=img.qemu_env(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, preexec_fn=_pdeathsig)
        except OSError as exc:
            raise VMUnavailable(f"vcan VM: cannot start qemu ({_one_line(exc)})") from None
        return _supervise(proc, t0, timeout, boot_timeout, stream, marks)


def _supervise(proc: subprocess.Popen, t0: float, timeout: float, boot_timeout: float,
               stream: Callable[[str], None] | None, marks: tuple[str, str, str]) -> VMResult:
    """Read qemu's console until the exit marker; kill qemu on every way out."""
    lines: list[str] = []
    boot_s = None
    rc = None
    fail = None
    buf = b""
    fd = proc.stdout.fileno()
    os.set_blocking(fd, False)
    ready_mark, exit_mark, fail_mark = marks
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    try:
        while rc is None:
            now = time.monotonic()
            limit = t0 + (timeout if boot_s is not None else min(timeout, boot_timeout))
            if now > limit:
                stage = "booting (vcan0 and the host root not up yet)" if boot_s is None else "running the command"
                raise VMError(f"vcan VM: timed out after {now - t0:.0f} s {stage}; last output: "
                              f"{_one_line(' | '.join(lines[-5:]))}")
            if not sel.select(min(1.0, limit - now)):
                if proc.poll() is not None:
                    break
                continue
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            buf += chunk
            *done, buf = buf.split(b"\n")
            for raw in done:
                line = raw.decode(errors="replace").replace("\r", "")
                if line.startswith(ready_mark):
                    boot_s = time.monotonic() - t0
                    continue
                if line.startswith(fail_mark):
                    fail = line[len(fail_mark):].strip()
                    continue
                if exit_mark in line:  # the command's last line may lack its newline
                    line, _, code = line.partition(exit_mark)
                    rc = int(code.split()[0])
                    if not line:
                        break
                lines.append(line)
                if stream is not None:
                    stream(line)
                if rc is not None:
                    break
    finally:
        sel.close()
        _kill(proc, grace=5.0 if rc is not None else 0.0)
    if rc is None:
        why = f"guest set-up failed: {fail}" if fail else f"qemu exited with {proc.returncode} before the command ended"
        raise VMError(f"vcan VM: {why}; last output: {_one_line(' | '.join(lines[-5:]))}")
    return VMResult(rc, "\n".join(lines), boot_s if boot_s is not None else float("nan"), time.monotonic() - t0)


def _kill(proc: subprocess.Popen, grace: float) -> None:
    """Give qemu ``grace`` seconds to power off by itself (after the exit marker it already is),
    then kill it; a KeyboardInterrupt while waiting still kills it."""
    try:
        try:
            proc.wait(grace) if grace > 0 else None
        except subprocess.TimeoutExpired:
            pass
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10.0)
        if proc.stdout is not None:
            proc.stdout.close()


# --------------------------------------------------------------------------------------------------
# command line

def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="tools/vcan_vm.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="say whether the VM can work here (no boot)")
    p.add_argument("--prepare", action="store_true", help="fetch and unpack the image into the cache")
    p.add_argument("--timeout", type=float, default=900.0, help="whole run, s (default 900)")
    p.add_argument("--boot-timeout", type=float, default=120.0, help="until the command starts, s")
    p.add_argument("--cwd", default=None, help="guest working directory (default: this one)")
    p.add_argument("--env", action="append", default=[], metavar="K=V", help="guest environment variable")
    p.add_argument("--mem", type=int, default=1024, help="guest memory, MB")
    p.add_argument("--smp", type=int, default=1, help="guest CPUs (default 1: faster than 2 on a busy 2-core host)")
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="-- CMD ARGS...")
    a = p.parse_args(argv)
    cmd = a.cmd[1:] if a.cmd[:1] == ["--"] else a.cmd
    try:
        if a.check:
            ok, why = available()
            print(("available: " if ok else "not available: ") + why)
            return 0 if ok else 1
        if a.prepare:
            prepare(log=lambda s: print(s, file=sys.stderr))
            return 0
        if not cmd:
            p.error("no command (give it after --)")
        env = {}
        for kv in a.env:
            k, sep, v = kv.partition("=")
            if not sep:
                p.error(f"--env {kv!r}: expected K=V")
            env[k] = v
        res = run(cmd, cwd=a.cwd, env=env, timeout=a.timeout, boot_timeout=a.boot_timeout, mem_mb=a.mem,
                  smp=a.smp, stream=lambda s: print(s, flush=True))
        print(f"[vcan VM] exit {res.returncode}; boot {res.boot_s:.1f} s, wall {res.wall_s:.1f} s",
              file=sys.stderr)
        return res.returncode
    except VMError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
