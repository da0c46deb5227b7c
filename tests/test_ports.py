"""`rtsim serve` and `rtsim demo` check every port they will listen on before anything is built or compiled
(rtsim.service.ports): a port another socket holds ends the program at once with one line naming the port,
the flag that sets it and the process holding it. The ordering is asserted, not timed: in process, the
build, the compile progress and the demo ECU are replaced by traps that fail the test if reached; as a
child process, the error line comes with no line of the ECU's start or of compiling before it."""
from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from rtsim.service import ports
from rtsim.service.config import ServeOptions
from service_harness import ROOT, free_port
from waits import EVENT


@pytest.fixture
def held():
    """A socket listening on a free port of 127.0.0.1 (this process holds it)."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(1)
    try:
        yield s.getsockname()[1]
    finally:
        s.close()


@pytest.fixture
def no_vcan(monkeypatch):
    monkeypatch.setattr(ports, "socketcan_available", lambda channel: False)


def test_the_ports_a_service_listens_on_and_their_flags(no_vcan):
    o = ServeOptions(can_hub_port=50001, zenoh_listen=["tcp/127.0.0.1:50002", "tcp/[::1]:50003", "tcp/127.0.0.1:0"],
                     foxglove_port=50004)
    got = [(p.what, p.host, p.port, p.flag) for p in ports.service_ports(o)]
    assert got == [("CAN hub", "127.0.0.1", 50001, "--can-hub-port or $RTSIM_CAN_HUB_PORT"),
                   ("Zenoh", "127.0.0.1", 50002, "--zenoh-listen"), ("Zenoh", "::1", 50003, "--zenoh-listen"),
                   ("Foxglove", "127.0.0.1", 50004, "--foxglove-port")]
    # a given bus, no hub, no Zenoh: nothing of those is listened on
    o = ServeOptions(can_interface="virtual", can_channel="x", zenoh=False)
    assert ports.service_ports(o) == []


def test_a_taken_port_names_itself_its_flag_and_who_holds_it(held, no_vcan):
    o = ServeOptions(can_hub_port=free_port(), zenoh_listen=[f"tcp/127.0.0.1:{held}"])
    with pytest.raises(ports.PortTaken) as e:
        ports.check_ports(ports.service_ports(o), "rtsim serve")
    msg = str(e.value)
    assert "\n" not in msg and f"Zenoh port 127.0.0.1:{held} (--zenoh-listen) is in use" in msg, msg
    assert f"pid {os.getpid()}" in msg, msg            # /proc names the holder: this test's process
    # the same port twice
    hp = free_port()
    o = ServeOptions(can_hub_port=hp, zenoh_listen=[f"tcp/127.0.0.1:{hp}"])
    with pytest.raises(ports.PortTaken, match="also the CAN hub port"):
        ports.check_ports(ports.service_ports(o), "rtsim serve")


def test_serve_joins_a_hub_already_on_its_port_and_the_demo_refuses_it(held, no_vcan):
    o = ServeOptions(can_hub_port=held, zenoh=False)
    notes = ports.check_ports(ports.service_ports(o), "rtsim serve", join_hub=True)
    assert len(notes) == 1 and f"joining the CAN hub already on 127.0.0.1:{held}" in notes[0]
    with pytest.raises(ports.PortTaken, match=r"CAN hub port .* \(--can-hub-port or \$RTSIM_CAN_HUB_PORT\) is in use"):
        ports.check_ports(ports.service_ports(o), "rtsim demo")


def _trap(what):
    def fail(*a, **k):
        raise AssertionError(f"{what} was reached before the port check failed")
    return fail


@pytest.mark.parametrize("which", ["zenoh", "hub"])
def test_demo_fails_before_starting_the_ecu_or_compiling(held, no_vcan, monkeypatch, capsys, tmp_path, which):
    from rtsim import cli
    from rtsim.service import demo, server

    monkeypatch.setattr(demo, "EcuProcess", _trap("the demo ECU's start"))
    monkeypatch.setattr(demo, "CompileProgress", _trap("the compile progress"))
    monkeypatch.setattr(demo, "Service", _trap("the service's build"))
    monkeypatch.setattr(server, "build_sim", _trap("the model's build"))
    zport, hport = (held, free_port()) if which == "zenoh" else (free_port(), held)
    rc = cli.main(["demo", "--zenoh-port", str(zport), "--can-hub-port", str(hport), "--record",
                   str(tmp_path / "d.mcap")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    flag = "--zenoh-port" if which == "zenoh" else "--can-hub-port"
    assert f":{held} ({flag}" in err[0] and f"pid {os.getpid()}" in err[0], err


def test_serve_fails_before_compiling(held, monkeypatch, capsys):
    from rtsim import cli
    from rtsim.service import cli as serve_cli

    monkeypatch.setattr("rtsim.compile_status.CompileProgress", _trap("the compile progress"))
    monkeypatch.setattr(serve_cli, "Service", _trap("the service's build"))
    rc = cli.main(["serve", "--can-interface", "virtual", "--can-channel", "t", "--zenoh-listen",
                   f"tcp/127.0.0.1:{free_port()}", "--foxglove-port", str(held)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and f"Foxglove port 127.0.0.1:{held} (--foxglove-port) is in use" in err[0], err


def test_demo_as_a_program_says_it_first_and_only(held, tmp_path):
    """The command as a user runs it: exit 2, one line on stderr, nothing started or compiled before it."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "RTSIM_CAN_HUB_PORT": str(free_port())}
    r = subprocess.run([sys.executable, "-m", "rtsim.cli", "demo", "--zenoh-port", str(held), "--record",
                        str(tmp_path / "d.mcap")], cwd=ROOT, env=env, capture_output=True, text=True, timeout=EVENT * 6)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stdout == "", r.stdout                   # no ECU started, no compile line
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"Zenoh port 127.0.0.1:{held} (--zenoh-port) is in use by pid {os.getpid()}" in lines[0]
    assert not (tmp_path / "d.mcap").exists()
