"""Bus factory of the CAN bridge: the one place where rtsim creates python-can buses.

``open_bus(interface=None, channel=None, **kw)`` picks the bus:

1. an explicit ``interface`` (and ``channel``) wins, e.g. ``open_bus("socketcan", "vcan0")`` on a
   Linux bench, ``open_bus("virtual", "x")`` inside one process, ``open_bus("remote",
   "127.0.0.1:54701")`` for a python-can-remote hub;
2. otherwise SocketCAN ``vcan0`` if the kernel has it (``socket.AF_CAN`` exists, an AF_CAN raw
   socket opens and ``/sys/class/net/vcan0`` exists);
3. otherwise the embedded default: a python-can-remote client (``interface="remote"``) of a hub on
   ``127.0.0.1:<port>``, port ``$RTSIM_CAN_HUB_PORT`` or 54701 (python-can-remote's default). Start
   that hub with :class:`LoopbackHub` (or ``python -m can_remote -H 127.0.0.1 ...``: note that the
   package's own command line listens on 0.0.0.0 unless ``-H`` is given).

Every failure (unknown interface, package missing, hub not reachable, device missing) is raised as
``rtsim.errors.RtsimError`` with a one-line message naming the interface, the channel and what to do.
A failure that may pass by itself, because the hub is not (yet) there, is a :class:`BusUnavailable`
(a client waiting for a starting service retries those and nothing else).

``LoopbackHub(port=0)`` runs a python-can-remote hub (``can_remote.RemoteServer``) that listens on
**127.0.0.1 only** (never 0.0.0.0), by default in a child process (``mode="subprocess"``) or in a
daemon thread of this process (``mode="thread"``). Behind the hub every connected client gets its own
python-can ``virtual`` bus on one channel private to the hub, so every frame a client sends reaches
every other client (not the sender), in order and without loss (TCP + unbounded in-process queues).
Port 0 lets the OS pick a free port inside the hub itself (no probe-then-bind race); the chosen
port is in ``hub.port`` and the client channel in ``hub.channel`` (``"127.0.0.1:PORT"``).
``close()`` stops it (idempotent; the child process is asked to stop by closing its stdin, then
terminated, then killed, each step bounded); the child also exits by itself when its parent dies
(its stdin reaches EOF). Usable as a context manager.
"""
from __future__ import annotations

import os
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid

from rtsim.errors import RtsimError

HUB_HOST = "127.0.0.1"
DEFAULT_HUB_PORT = 54701  # can_remote.DEFAULT_PORT
HUB_PORT_ENV = "RTSIM_CAN_HUB_PORT"
SOCKETCAN_DEFAULT_CHANNEL = "vcan0"


class BusUnavailable(RtsimError):
    """The bus could not be opened because its hub is not reachable (yet): worth retrying while a
    service starts. ``reason`` is the short cause (e.g. ``[Errno 111] Connection refused``)."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def default_hub_port() -> int:
    """The port of the embedded default hub: ``$RTSIM_CAN_HUB_PORT`` or 54701."""
    raw = os.environ.get(HUB_PORT_ENV, "")
    if not raw:
        return DEFAULT_HUB_PORT
    try:
        port = int(raw)
        if not 0 < port < 65536:
            raise ValueError
    except ValueError:
        raise RtsimError(f"{HUB_PORT_ENV}={raw!r}: expected a TCP port 1-65535") from None
    return port


def socketcan_available(channel: str = SOCKETCAN_DEFAULT_CHANNEL) -> bool:
    """True if the kernel has SocketCAN (an AF_CAN raw socket opens) and ``channel`` exists."""
    if not hasattr(socket, "AF_CAN") or not os.path.exists(f"/sys/class/net/{channel}"):
        return False
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError:
        return False
    s.close()
    return True


def _split_hostport(channel: str) -> tuple[str, int] | None:
    rest = channel.split("://", 1)[-1].split("/", 1)[0]
    host, sep, port = rest.rpartition(":")
    if not sep:
        return None
    try:
        return host.strip("[]") or HUB_HOST, int(port)
    except ValueError:
        return None


def open_bus(interface: str | None = None, channel: str | None = None, **kw):
    """Open a python-can bus (see the module docstring for the choice). ``kw`` goes to ``can.Bus``
    (e.g. ``receive_own_messages``, ``bitrate``; for ``remote`` it is sent to the hub as config).
    Raises RtsimError with a one-line message."""
    try:
        import can
    except ImportError:
        raise RtsimError("CAN: python-can is not installed; run `pip install python-can`") from None

    if interface is None:
        if socketcan_available(channel or SOCKETCAN_DEFAULT_CHANNEL):
            interface = "socketcan"
        else:
            interface = "remote"
    if channel is None:
        if interface == "socketcan":
            channel = SOCKETCAN_DEFAULT_CHANNEL
        elif interface == "remote":
            channel = f"{HUB_HOST}:{default_hub_port()}"
    where = f"CAN interface {interface!r} channel {channel!r}"

    if interface not in can.VALID_INTERFACES:
        raise RtsimError(f"{where}: unknown interface; expected one of "
                         f"{', '.join(sorted(can.VALID_INTERFACES))}")

    if interface == "remote":
        hp = _split_hostport(str(channel))
        if hp is None:
            raise RtsimError(f"{where}: the channel must be HOST:PORT (e.g. 127.0.0.1:{DEFAULT_HUB_PORT})")
        try:  # bounded reachability check first: a clear message instead of a hang or a traceback
            socket.create_connection(hp, timeout=2.0).close()
        except OSError as exc:
            raise BusUnavailable(f"{where}: hub not reachable ({_one_line(exc)}); start one with "
                                 f"bridge.can_bus.LoopbackHub(port={hp[1]}) or "
                                 f"`python -m can_remote -H 127.0.0.1 -p {hp[1]} -i virtual -c rtsim`",
                                 _one_line(exc)) from None
    try:
        return can.Bus(interface=interface, channel=channel, **kw)
    except can.CanInterfaceNotImplementedError as exc:
        hint = ("install python-can-remote (`pip install python-can-remote`)" if interface == "remote"
                else "install the driver/package of this interface or pick another one")
        raise RtsimError(f"{where}: not available here ({_one_line(exc)}); {hint}") from None
    except Exception as exc:  # noqa: BLE001  (backends raise many types)
        hint = {"socketcan": "check the device exists and is up (`ip link show`); this kernel may have no "
                             "SocketCAN: use the embedded hub (interface='remote')",
                "remote": "check the hub is running (bridge.can_bus.LoopbackHub)"}.get(
            interface, "check the interface's driver, device and channel")
        if interface == "remote":   # reachable a moment ago: a hub starting or stopping
            raise BusUnavailable(f"{where}: cannot open ({type(exc).__name__}: {_one_line(exc)}); {hint}",
                                 f"{type(exc).__name__}: {_one_line(exc)}") from None
        raise RtsimError(f"{where}: cannot open ({type(exc).__name__}: {_one_line(exc)}); {hint}") from None


# --------------------------------------------------------------------------------------------------
# Loopback hub

_HUB_SCRIPT = r"""
import os, sys, threading
from can_remote.server import RemoteServer
host, port, iface, chan = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
srv = RemoteServer(host, port, interface=iface, channel=chan)
def _watch_parent():
    try:
        sys.stdin.buffer.read()  # EOF: the parent closed it or died
    finally:
        os._exit(0)
threading.Thread(target=_watch_parent, daemon=True).start()
sys.stdout.write("%s %d\n" % srv.server_address[:2])
sys.stdout.flush()
srv.serve_forever(poll_interval=0.1)
"""


class LoopbackHub:
    """A python-can-remote hub listening on 127.0.0.1 only (see the module docstring).

    ``hub.host`` is always ``"127.0.0.1"``; ``hub.port`` the bound port; ``hub.channel`` the channel
    for ``open_bus("remote", hub.channel)``. ``mode``: ``"subprocess"`` (default: the hub's threads do
    not compete for this process's GIL) or ``"thread"``.
    """

    host = HUB_HOST

    def __init__(self, port: int = 0, *, mode: str = "subprocess", start_timeout: float = 60.0,
                 backend: str = "virtual", backend_channel: str | None = None):
        if mode not in ("subprocess", "thread"):
            raise ValueError(f"mode {mode!r}: expected 'subprocess' or 'thread'")
        self.mode = mode
        self.backend = backend
        # a channel private to this hub: virtual buses of the same name in one process share frames
        self.backend_channel = backend_channel or f"rtsim-hub-{uuid.uuid4().hex[:12]}"
        self.port: int | None = None
        self._proc: subprocess.Popen | None = None
        self._errlog = None
        self._server = None
        self._thread: threading.Thread | None = None
        self._closed = False
        try:
            if mode == "subprocess":
                self._start_subprocess(int(port), start_timeout)
            else:
                self._start_thread(int(port))
            self._wait_accepting(start_timeout)
        except BaseException:
            self.close()
            raise

    # -- start --------------------------------------------------------------------------------------
    def _fail(self, what: str) -> RtsimError:
        return RtsimError(f"CAN hub on {self.host}:{self.port if self.port is not None else '?'}: {what}")

    def _start_subprocess(self, port: int, timeout: float) -> None:
        self._errlog = tempfile.TemporaryFile()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", _HUB_SCRIPT, self.host, str(port), self.backend, self.backend_channel],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._errlog, close_fds=True)
        except OSError as exc:
            raise self._fail(f"cannot start the hub process ({_one_line(exc)})") from None
        fd = self._proc.stdout.fileno()
        buf = b""
        deadline = time.monotonic() + timeout
        while b"\n" not in buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise self._fail(f"the hub process did not report its port within {timeout:g} s")
            ready, _, _ = select.select([fd], [], [], min(left, 0.2))
            if ready:
                chunk = os.read(fd, 256)
                if not chunk:
                    break
                buf += chunk
            elif self._proc.poll() is not None:
                break
        if b"\n" not in buf:
            self._errlog.seek(0)
            err = self._errlog.read().decode(errors="replace").strip().splitlines()
            raise self._fail(f"the hub process exited ({err[-1] if err else 'no message'}); "
                             f"is python-can-remote installed (`pip install python-can-remote`)?")
        host, port_s = buf.split(b"\n", 1)[0].decode().split()
        if host != self.host:
            raise self._fail(f"the hub bound {host}, not {self.host}")
        self.port = int(port_s)

    def _start_thread(self, port: int) -> None:
        try:
            from can_remote.server import RemoteServer
        except ImportError:
            raise self._fail("python-can-remote is not installed; run `pip install python-can-remote`") from None
        try:
            self._server = RemoteServer(self.host, port, interface=self.backend, channel=self.backend_channel)
        except OSError as exc:
            raise self._fail(f"cannot listen ({_one_line(exc)})") from None
        self.port = self._server.server_address[1]
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.1},
                                        name=f"can-hub-{self.port}", daemon=True)
        self._thread.start()

    def _wait_accepting(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            try:
                socket.create_connection((self.host, self.port), timeout=0.5).close()
                return
            except OSError as exc:
                last = exc
                time.sleep(0.02)
        raise self._fail(f"not accepting connections within {timeout:g} s ({_one_line(last)})")

    # -- use ----------------------------------------------------------------------------------------
    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the hub listens on: host is always 127.0.0.1."""
        return self.host, self.port

    @property
    def channel(self) -> str:
        """The channel of ``can.Bus(interface="remote", channel=...)`` clients: ``"127.0.0.1:PORT"``."""
        return f"{self.host}:{self.port}"

    @property
    def pid(self) -> int:
        """PID of the process that holds the listening socket."""
        return self._proc.pid if self._proc is not None else os.getpid()

    def alive(self) -> bool:
        if self._closed:
            return False
        if self._proc is not None:
            return self._proc.poll() is None
        return self._thread is not None and self._thread.is_alive()

    def open_bus(self, **kw):
        """A client bus of this hub (``open_bus("remote", self.channel, **kw)``)."""
        return open_bus("remote", self.channel, **kw)

    # -- stop ---------------------------------------------------------------------------------------
    def close(self, timeout: float = 3.0) -> None:
        """Stop the hub (idempotent). Clients still connected see their connection closed."""
        if self._closed:
            return
        self._closed = True
        proc, self._proc = self._proc, None
        if proc is not None:
            try:
                if proc.stdin is not None:
                    proc.stdin.close()  # the hub exits on stdin EOF
                proc.wait(timeout)
            except (subprocess.TimeoutExpired, OSError):
                proc.terminate()
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout)
            finally:
                if proc.stdout is not None:
                    proc.stdout.close()
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()  # returns once serve_forever has stopped (poll interval 0.1 s)
            server.server_close()
            for client in list(server.clients):  # end the per-client handler threads
                try:
                    client.running = False
                    client._ws.close()
                except Exception:  # noqa: BLE001
                    pass
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        if self._errlog is not None:
            self._errlog.close()
            self._errlog = None

    def __enter__(self) -> "LoopbackHub":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close(timeout=1.0)
        except Exception:  # noqa: BLE001
            pass

    def __repr__(self) -> str:
        state = "alive" if self.alive() else "closed"
        return f"LoopbackHub({self.host}:{self.port}, mode={self.mode}, {state})"
