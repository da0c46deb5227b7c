"""Shared pytest set-up for the rtsim suite.

tests/references.py holds independent minimal-coordinate reference solutions (numpy + scipy only);
make it importable as `references` whatever the import mode or working directory.

Markers ``can_e2e`` (CAN end to end across processes; tests/test_vcan.py reruns them over a real
vcan0) and ``vm`` (boots a qemu VM); the ``can_bus_factory`` fixture gives a test its CAN segment.
"""
from __future__ import annotations

import os
import sys
from collections import Counter
from pathlib import Path

import pytest

TESTS_DIR = Path(__file__).resolve().parent
if str(TESTS_DIR) not in sys.path:
    sys.path.insert(0, str(TESTS_DIR))


# --------------------------------------------------------------------------------------------------
# The order of the test files: the longest first

#: The files that take longest on a fresh clone (tools/test's --durations log: a numba compile in their first
#: test, a VM, many re-simulations), collected first, in this order. tools/test runs the files on two processes
#: (pytest-xdist, ``--dist loadfile --no-loadscope-reorder``: each process takes the next file in the collected
#: order when it runs short of tests), so a long file collected late would leave one process working alone at
#: the end; pytest-xdist's own order (most tests first) put the VM's file, three tests, among the last. The
#: first two start together: the VM's (its kernels are compiled for the VM, none for this host) beside the one
#: that compiles the car's kernels, so the files after it load them from the cache rather than both processes
#: compiling them at once.
SLOW_FILES = (
    "test_vcan.py",                 # a qemu VM under software emulation: one process for 7-9 minutes
    "test_bench_stages.py",         # the car's step and the staged steps: compiled here only
    "test_validate_independent_longitudinal.py",    # (the VM's process takes it with the VM's file)
    "test_fuzz_commands.py",
    "test_batch_plain.py",
    "test_every_vehicle.py",
    "test_faults_inject.py",
    "test_validate_independent.py",
    "test_validate_effects.py",
    "test_validate_lateral.py",
    "test_validate_peer.py",
    "test_validate_two_wheeler.py",
    "test_validate_cli.py",
    "test_viewer.py",
    "test_service_e2e.py",
    "test_viewer_ride.py",
    "test_batch.py",
    "test_fmu_bench.py",            # compiles the car FMU's step, before test_fmu_export.py loads it
)


def pytest_collection_modifyitems(config, items):
    """The files in SLOW_FILES' order, then the others, most tests first (pytest-xdist's own order); a
    file's tests stay together and in their order."""
    rank = {name: i for i, name in enumerate(SLOW_FILES)}
    count = Counter(item.path.name for item in items)
    first: dict[str, int] = {}
    for i, item in enumerate(items):
        first.setdefault(item.path.name, i)
    where = {id(item): i for i, item in enumerate(items)}
    items.sort(key=lambda item: (rank.get(item.path.name, len(rank)), -count[item.path.name],
                                 first[item.path.name], where[id(item)]))


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
