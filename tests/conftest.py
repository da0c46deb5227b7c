"""Shared pytest set-up for the rtsim suite.

tests/references.py holds independent minimal-coordinate reference solutions (numpy + scipy only);
make it importable as `references` whatever the import mode or working directory.

Markers ``can_e2e`` (CAN end to end across processes; tests/test_vcan.py reruns them over a real
vcan0) and ``vm`` (boots a qemu VM); the ``can_bus_factory`` fixture gives a test its CAN segment.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

TESTS_DIR = Path(__file__).resolve().parent
if str(TESTS_DIR) not in sys.path:
    sys.path.insert(0, str(TESTS_DIR))


# --------------------------------------------------------------------------------------------------
# CAN segment of a test: SocketCAN (e.g. vcan0 inside tools/vcan_vm.py's VM) or a loopback hub

CAN_INTERFACE_ENV = "RTSIM_CAN_INTERFACE"
CAN_CHANNEL_ENV = "RTSIM_CAN_CHANNEL"


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "can_e2e: CAN end-to-end test across processes; runs over the bus given by "
                   "RTSIM_CAN_INTERFACE/RTSIM_CAN_CHANNEL (e.g. socketcan/vcan0) or a loopback hub; "
                   "tests/test_vcan.py runs these again over a real vcan0")
    config.addinivalue_line(
        "markers", "realtime_e2e: service end to end in real time across processes (host only: the VM's "
                   "emulated CPU cannot keep real time)")
    config.addinivalue_line(
        "markers", "vm: boots a qemu VM (software emulation, minutes); deselect with -m 'not vm'")


class CanSegment:
    """The CAN segment of one test: call it to open a bus on it (``**kw`` goes to ``open_bus``).

    ``interface``/``channel`` name the segment for child processes (``child_args()`` gives
    ``--can-interface I --can-channel C``, ``child_env()`` the ``RTSIM_CAN_*`` variables); ``hub`` is
    the :class:`bridge.can_bus.LoopbackHub` behind it, or None on SocketCAN. Buses opened through the
    segment are shut down when the test ends."""

    def __init__(self, interface: str, channel: str, hub=None):
        self.interface, self.channel, self.hub = interface, channel, hub
        self._buses: list = []

    def __call__(self, **kw):
        from bridge.can_bus import open_bus
        bus = open_bus(self.interface, self.channel, **kw)
        self._buses.append(bus)
        return bus

    @property
    def socketcan(self) -> bool:
        return self.interface == "socketcan"

    def child_args(self) -> list[str]:
        return ["--can-interface", self.interface, "--can-channel", self.channel]

    def child_env(self) -> dict[str, str]:
        return {CAN_INTERFACE_ENV: self.interface, CAN_CHANNEL_ENV: self.channel}

    def close(self) -> None:
        while self._buses:
            try:
                self._buses.pop().shutdown()
            except Exception:  # noqa: BLE001  (a bus the test already shut down)
                pass

    def __repr__(self) -> str:
        return f"CanSegment({self.interface}, {self.channel})"


@pytest.fixture
def can_bus_factory():
    """A :class:`CanSegment` for the test: ``$RTSIM_CAN_INTERFACE``/``$RTSIM_CAN_CHANNEL`` when set
    (channel defaults to vcan0 for socketcan), else a LoopbackHub on 127.0.0.1 started for this test
    and stopped after it. python-can and python-can-remote are hard dependencies: without them, or
    with a hub that cannot start, the test fails (an environment that cannot run a process listening on
    127.0.0.1 cannot run the service either); a configured interface that fails to open is an error too."""
    import can  # noqa: F401  (hard dependencies: an ImportError fails the test, never skips it)
    import can_remote  # noqa: F401

    interface = os.environ.get(CAN_INTERFACE_ENV, "").strip()
    if interface:
        channel = os.environ.get(CAN_CHANNEL_ENV, "").strip() or ("vcan0" if interface == "socketcan" else "")
        if not channel:
            pytest.fail(f"{CAN_INTERFACE_ENV}={interface} needs {CAN_CHANNEL_ENV}")
        seg = CanSegment(interface, channel)
        try:
            yield seg
        finally:
            seg.close()
        return
    from bridge.can_bus import LoopbackHub
    from waits import HUB_START
    hub = LoopbackHub(start_timeout=HUB_START)
    seg = CanSegment("remote", hub.channel, hub)
    try:
        yield seg
    finally:
        seg.close()
        hub.close()
