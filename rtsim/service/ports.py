"""The TCP ports `rtsim serve` and `rtsim demo` will listen on, checked before anything is built or compiled.

Each port comes from one flag (or settings key): the loopback CAN hub's (``--can-hub-port``, else
``$RTSIM_CAN_HUB_PORT``, else 54701; only when the service starts the hub: no ``--can-interface``, no
vcan0), Zenoh's listen endpoints (``--zenoh-listen``; the demo's ``--zenoh-port``) and the Foxglove
server's (``--foxglove-port``). Port 0 (any free port) is not checked. A port is free when a socket can
bind and listen on it here and now (``SO_REUSEADDR`` set, as servers do, so a closed connection's
TIME_WAIT does not count); when it is not, one line names the port, its flag and, when /proc tells,
the process that holds it. A hub already running on the hub's port is joined by `rtsim serve` (the
port is then not "taken": ``hub_port`` tells the caller); `rtsim demo` needs a bus of its own and
refuses it.
"""
from __future__ import annotations

import os
import re
import socket
from dataclasses import dataclass
from pathlib import Path

from bridge.can_bus import HUB_HOST, HUB_PORT_ENV, default_hub_port, socketcan_available
from rtsim.errors import RtsimError


@dataclass(frozen=True)
class Port:
    """One port a program will listen on: ``what`` (e.g. "Zenoh"), host, port and the flag that sets it."""
    what: str
    host: str
    port: int
    flag: str


class PortTaken(RtsimError):
    """A port a program would listen on is held by another socket; the message is one line."""


def hub_port(opts) -> int | None:
    """The loopback hub's port when the service would start (or join) the hub, else None."""
    if opts.can_interface is not None or opts.can_channel is not None or not opts.start_hub:
        return None
    if socketcan_available("vcan0"):
        return None
    return opts.can_hub_port or default_hub_port()


def service_ports(opts, zenoh_flag: str = "--zenoh-listen") -> list[Port]:
    """Every port ``opts`` (ServeOptions) makes the service listen on, the hub's included (see ``hub_port``)."""
    out = []
    hp = hub_port(opts)
    if hp is not None:
        out.append(Port("CAN hub", HUB_HOST, hp, f"--can-hub-port or ${HUB_PORT_ENV}"))
    if opts.zenoh:
        for e in opts.zenoh_listen:
            m = re.fullmatch(r"tcp/(?:\[([^\]]+)\]|([^:\[\]]+)):(\d+)", e)
            if m and int(m.group(3)) != 0:
                out.append(Port("Zenoh", m.group(1) or m.group(2), int(m.group(3)), zenoh_flag))
    if opts.foxglove_port:
        out.append(Port("Foxglove", opts.foxglove_host, opts.foxglove_port, "--foxglove-port"))
    return out


def is_free(host: str, port: int) -> bool:
    """True when a listening socket could be opened on (host, port) now (see the module docstring)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError:
        return True                     # an address that does not resolve: the server itself will say
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
            s.listen(1)
        except OSError:
            return False
    return True


def holder(port: int) -> str | None:
    """"pid N (command line)" of a process with a socket listening on TCP ``port``, read from /proc
    (Linux; None elsewhere, or when the process is not visible to this user)."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if len(f) > 9 and f[3] == "0A" and int(f[1].rsplit(":", 1)[1], 16) == port:
                inodes.add(f"socket:[{f[9]}]")
    if not inodes:
        return None
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
            if not any(os.readlink(f"/proc/{pid}/fd/{fd}") in inodes for fd in fds):
                continue
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:
            continue
        return f"pid {pid} ({cmd[:120]})" if cmd else f"pid {pid}"
    return None


def taken_message(program: str, p: Port) -> str:
    who = holder(p.port)
    return (f"{program}: the {p.what} port {p.host}:{p.port} ({p.flag}) is in use"
            + (f" by {who}" if who else " by another program")
            + "; stop that or choose another port")


def check_ports(ports: list[Port], program: str, join_hub: bool = False) -> list[str]:
    """Raise PortTaken for the first port of ``ports`` not free (and two uses of one port). With
    ``join_hub`` a taken CAN hub port is not an error (the service joins that hub): its line is returned."""
    notes = []
    seen: dict[int, Port] = {}
    for p in ports:
        if p.port in seen:
            raise PortTaken(f"{program}: the {p.what} port {p.port} ({p.flag}) is also the {seen[p.port].what} "
                            f"port ({seen[p.port].flag}); give each its own")
        seen[p.port] = p
        if is_free(p.host, p.port):
            continue
        if join_hub and p.what == "CAN hub":
            who = holder(p.port)
            notes.append(f"{program}: joining the CAN hub already on {p.host}:{p.port}"
                         + (f" ({who})" if who else "") + f"; {p.flag} chooses another port")
            continue
        raise PortTaken(taken_message(program, p))
    return notes
