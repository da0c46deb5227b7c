"""Helpers for the service end-to-end tests: the CAN segment to use, the service as a child process,
and a bus reader that keeps every frame (with its arrival time, for printing only) and the latest
simulation time the sensor frames carry. Every process started here is stopped by the caller's
``finally`` (``ServiceProcess.close`` kills what did not stop). Timeouts bound waits only (waits.py)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from waits import EVENT, PROCESS

ROOT = Path(__file__).resolve().parent.parent
READY = "stop with Ctrl-C"
_ELAPSED = re.compile(r"\b\d+ s\b")        # "compiling kernels: 35 s, ..." -> its state


def segment_from_env() -> tuple[str, str] | None:
    """(interface, channel) when the run targets a given bus (e.g. socketcan vcan0 in the VM)."""
    iface = os.environ.get("RTSIM_CAN_INTERFACE")
    if not iface:
        return None
    return iface, os.environ.get("RTSIM_CAN_CHANNEL", "vcan0")


@contextmanager
def can_segment():
    """The CAN segment a service test runs on, as (interface, channel): the bus the environment names
    (``segment_from_env``), else a loopback hub of its own, closed when the block ends."""
    env = segment_from_env()
    if env is not None:
        yield env
        return
    from bridge.can_bus import LoopbackHub
    from waits import HUB_START

    hub = LoopbackHub(0, start_timeout=HUB_START)
    try:
        yield "remote", hub.channel
    finally:
        hub.close()


class ServiceProcess:
    """`rtsim serve` in a child process; ``lines`` collects its stdout. The start is waited for while it
    makes progress: a start is called hung (and the process killed) only when ``stall`` s of wall time
    (default waits.PROCESS) pass without a new line of output other than a compile progress line that
    repeats the previous one's count and kernel (a first compile of every kernel on a loaded machine takes
    many minutes, but it names a new kernel or count at least every kernel it finishes)."""

    def __init__(self, iface: str, channel: str, *args: str, stall: float = PROCESS):
        cmd = [sys.executable, "-m", "rtsim.cli", "serve", "--can-interface", iface, "--can-channel", channel,
               "--no-hub", *args]
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._progress = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        last = time.monotonic()
        while not self._ready.is_set() and self._reader.is_alive() and time.monotonic() - last < stall:
            if self._progress.wait(1.0):
                self._progress.clear()
                last = time.monotonic()
        if not self._ready.is_set() or self.proc.poll() is not None:
            if self._reader.is_alive():
                why = f"no progress for {stall:g} s"
                self.dump_stacks()
            else:
                why = f"its output ended; {_exit_text(self._wait(EVENT))}"
            self.close()
            out = "\n".join(self.lines)
            raise RuntimeError(f"rtsim serve did not start ({why}):\n{out}")

    def _read(self) -> None:
        last = None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))
            if READY in line:
                self._ready.set()
            state = _ELAPSED.sub("", line)          # a compile progress line's count and kernel
            if state != last:
                last = state
                self._progress.set()

    def stop(self, sig=signal.SIGTERM, timeout: float = EVENT) -> tuple[int | None, float]:
        """Send ``sig``; returns (exit code or None if it did not end within ``timeout`` s, seconds
        until the process ended: for printing, not a criterion)."""
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        rc = self._wait(timeout)
        dt = time.monotonic() - t0
        if rc is None:
            self.dump_stacks()
            self.lines.append(f"[test harness] the service had not ended {timeout:g} s after signal {sig}")
        self._reader.join(EVENT)
        return rc, dt

    def dump_stacks(self, settle: float = 5.0) -> None:
        """Ask the running service for every thread's Python stack (SIGUSR1: rtsim prints them on its
        stderr, which ``lines`` collects) and give it ``settle`` s to print them; first, each thread's
        signal state as the kernel has it (``signal_state``)."""
        if self.proc.poll() is None:
            self.lines.append(f"[test harness] signal state of pid {self.proc.pid}:\n{signal_state(self.proc.pid)}")
            self.proc.send_signal(signal.SIGUSR1)
            time.sleep(settle)

    def _wait(self, timeout: float) -> int | None:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(EVENT)

    @property
    def output(self) -> str:
        return "\n".join(self.lines)


def signal_state(pid: int) -> str:
    """One line per thread of ``pid`` from /proc (Linux): name, state, and the signal masks as hex
    (SigPnd pending for the thread, ShdPnd for the process, SigBlk blocked, SigIgn ignored, SigCgt
    caught; bit n-1 is signal n: SIGTERM 0x4000, SIGINT 0x2); '' where /proc cannot tell."""
    out = []
    for f in sorted(Path(f"/proc/{pid}/task").glob("*/status")):
        try:
            d = dict(line.split(":", 1) for line in f.read_text().splitlines() if ":" in line)
        except OSError:
            continue
        out.append(f"  {f.parent.name} {d.get('Name', '').strip()} {d.get('State', '').strip()} " + " ".join(
            f"{k} {d.get(k, '').strip()}" for k in ("SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt")))
    return "\n".join(out)


def _exit_text(rc: int | None) -> str:
    """How a process ended, from its return code (None: it had not)."""
    if rc is None:
        return "still running"
    if rc < 0:
        try:
            return f"killed by signal {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exit {rc}"


class Listener:
    """Reads a bus in a thread: every frame with its arrival time (monotonic s). ``sim_ms`` is the
    simulation time (ms) of the latest sensor frame seen, unwrapped from the frames' 16-bit
    ``sim_time_ms`` (bytes 0-1), or None before the first; give ``sensor_ids`` to track it."""

    def __init__(self, bus, sensor_ids=()):
        self.bus = bus
        self.frames: list[tuple[float, int, bytes]] = []
        self.sensor_ids = frozenset(sensor_ids)
        self.sim_ms: int | None = None
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.05)
            except Exception:  # noqa: BLE001  (bus closed under us at the end)
                return
            if msg is not None:
                data = bytes(msg.data)
                self.frames.append((time.monotonic(), msg.arbitration_id, data))
                if msg.arbitration_id in self.sensor_ids:
                    ms = int.from_bytes(data[0:2], "little")
                    if self.sim_ms is None:
                        self.sim_ms = ms
                    else:
                        self.sim_ms += (ms - self.sim_ms) % 65536

    def wait_sim_ms(self, ms: int, timeout: float = EVENT) -> bool:
        """Wait until a sensor frame at simulation time ``ms`` or later has arrived (bounded wait)."""
        deadline = time.monotonic() + timeout
        while self.sim_ms is None or self.sim_ms < ms:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def close(self) -> None:
        self._stop.set()
        self._t.join(EVENT)


def free_port() -> int:
    """A free TCP port on 127.0.0.1 (for a test's own CAN hub: RTSIM_CAN_HUB_PORT), so that a test never
    shares the default hub with another run on the machine."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: the car's three command frames, in the order a lockstep test's command tuple gives them
CAR_COMMANDS = ("throttle_angle_cmd", "brake_pressure_cmd", "steering_wheel_angle_cmd")


def send_lockstep_cycle(bus, codec, ctr: list, cmd, steps: int) -> None:
    """One lockstep cycle's frames on `bus`: the car's commands `cmd` (values in CAR_COMMANDS order; None:
    none sent) and a SIM_STEP_REQ of `steps`; `ctr` the four alive counters (commands, step request),
    advanced in place. The caller waits for the SIM_STEP_ACK carrying ctr[3]."""
    import can

    if cmd is not None:
        for i, name in enumerate(CAR_COMMANDS):
            ctr[i] = (ctr[i] + 1) & 0xF
            fid, data = codec.encode_command(name, cmd[i], ctr[i])
            bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
    ctr[3] = (ctr[3] + 1) & 0xF
    fid, data = codec.encode_step_request(steps, ctr[3])
    bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))

