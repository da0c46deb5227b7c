"""The demo ECU as a supervised child process of `rtsim demo`.

``EcuProcess(cmd, cwd, on_exit)`` starts it with its stdout (the one-line JSON summary it prints
last) and stderr captured by reader threads; stderr lines are passed on to this process's stderr as
they come (the ECU says there what it waits for) and the last ones are kept for the failure message.
A watcher thread calls ``on_exit(self)`` once, as soon as the process has ended and its output is
read, whatever ended it (done, error, signal), unless ``stop()`` asked it to end first.

The child ignores SIGINT (a Ctrl-C in the terminal is for `rtsim demo`, which then stops the ECU
itself) and, on Linux, gets SIGTERM when this process dies, so it never outlives the demo.
"""
from __future__ import annotations

import collections
import json
import signal
import subprocess
import sys
import threading
import time
from typing import Callable


def _child_setup() -> None:
    """Runs in the child before exec: ignore SIGINT; SIGTERM when the parent dies (Linux)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if _LIBC is not None:
        _LIBC.prctl(1, int(signal.SIGTERM))         # PR_SET_PDEATHSIG


def _load_libc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes
        return ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


_LIBC = _load_libc()


class EcuProcess:
    """A started ECU process (see the module docstring). ``pid``; ``returncode`` once ended;
    ``result``: the last JSON object it printed on stdout ({} if none); ``stderr_tail``: its last
    stderr lines; ``runtime``: s from start to end (or to now)."""

    def __init__(self, cmd: list[str], cwd, on_exit: Callable[["EcuProcess"], None] | None = None,
                 echo: Callable[[str], None] | None = None, keep: int = 20):
        self.on_exit = on_exit
        self.echo = echo if echo is not None else (lambda line: print(line, file=sys.stderr, flush=True))
        self.stderr_tail: collections.deque[str] = collections.deque(maxlen=keep)
        self.result: dict = {}
        self.returncode: int | None = None
        self._stopping = threading.Event()
        self._ended_at: float | None = None
        self.started_at = time.monotonic()
        self.proc = subprocess.Popen(cmd, cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, errors="replace",
                                     preexec_fn=_child_setup)
        self.pid = self.proc.pid
        self._readers = [threading.Thread(target=self._read_stdout, daemon=True, name="ecu-stdout"),
                         threading.Thread(target=self._read_stderr, daemon=True, name="ecu-stderr")]
        for t in self._readers:
            t.start()
        self._watcher = threading.Thread(target=self._watch, daemon=True, name="ecu-watch")
        self._watcher.start()

    # -- threads -------------------------------------------------------------------------------------
    def _read_stdout(self) -> None:
        for line in self.proc.stdout:
            line = line.strip()
            if line.startswith("{"):
                try:
                    self.result = json.loads(line)
                except ValueError:
                    pass

    def _read_stderr(self) -> None:
        for line in self.proc.stderr:
            line = line.rstrip("\n")
            self.stderr_tail.append(line)
            self.echo(line)

    def _watch(self) -> None:
        self.returncode = self.proc.wait()
        self._ended_at = time.monotonic()
        for t in self._readers:           # the pipes close with the process; bounded in case a
            t.join(1.0)                   # grandchild kept them open
        if self.on_exit is not None and not self._stopping.is_set():
            self.on_exit(self)

    # -- state ---------------------------------------------------------------------------------------
    @property
    def ended(self) -> bool:
        return self._ended_at is not None

    @property
    def runtime(self) -> float:
        return (self._ended_at if self._ended_at is not None else time.monotonic()) - self.started_at

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the process has ended and its end was handled; True if it has."""
        self._watcher.join(timeout)
        return not self._watcher.is_alive()

    def last_message(self) -> str:
        """The last non-empty stderr line (a traceback's last line is the exception), or ''."""
        for line in reversed(self.stderr_tail):
            if line.strip():
                return line.strip()
        return ""

    def describe_end(self, when: str = "") -> str:
        """One line: how the process ended, after how long (``when``: e.g. ", while ..."), and its
        last stderr line."""
        rc = self.returncode
        how = f"exited with code {rc}"
        if rc is not None and rc < 0:
            try:
                how += f" ({signal.Signals(-rc).name})"
            except ValueError:
                pass
        last = self.last_message()
        return (f"the demo ECU process (pid {self.pid}) {how} after {self.runtime:.1f} s{when}"
                + (f"; its last stderr line: {last}" if last else "; nothing on its stderr"))

    # -- stop ----------------------------------------------------------------------------------------
    def stop(self, timeout: float = 5.0) -> None:
        """End the process on purpose (no ``on_exit`` call): SIGTERM, then SIGKILL after ``timeout`` s."""
        self._stopping.set()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout)
        self.wait(timeout)
