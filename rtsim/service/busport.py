"""The service's CAN port: one python-can bus, a reader thread, error counting and reconnection.

Received frames go into the service's inbox (a ``queue.SimpleQueue`` of ``("can", msg)`` items) from a
reader thread, so the real-time thread never blocks on the bus and lockstep mode can wait on CAN and
Zenoh requests alike. ``send`` is called from the real-time thread; it never raises: a failing send
(bus error, vanished interface, hub gone) is counted, the port is marked down and a background thread
re-opens the bus every ``retry_interval`` seconds until it is back. Meanwhile sends are dropped and
counted (the simulation keeps its pace). Error frames on the bus are counted as bus errors too.
"""
from __future__ import annotations

import threading

from bridge.can_batch import batch_sender
from bridge.can_bus import open_bus
from rtsim.errors import RtsimError


class BusPort:
    def __init__(self, inbox, interface: str | None = None, channel: str | None = None,
                 retry_interval: float = 1.0, recv_timeout: float = 0.05):
        self.inbox = inbox
        self.interface = interface
        self.channel = channel
        self.retry_interval = float(retry_interval)
        self.recv_timeout = float(recv_timeout)
        self.bus = open_bus(interface, channel)         # the first open must work: raises RtsimError
        self._send_all = batch_sender(self.bus)
        self.description = f"{self.bus.__class__.__name__} {getattr(self.bus, 'channel_info', channel)}"
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.recv_errors = 0
        self.error_frames = 0
        self.dropped_while_down = 0
        self.reconnects = 0
        self.last_error = ""
        self._up = True
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read_loop, name="can-reader", daemon=True)
        self._reader.start()

    # -- state -----------------------------------------------------------------------------------
    @property
    def up(self) -> bool:
        return self._up

    @property
    def errors(self) -> int:
        """Bus errors of every kind so far (send, receive, error frames)."""
        return self.send_errors + self.recv_errors + self.error_frames

    # -- real-time side --------------------------------------------------------------------------
    def send(self, msg) -> bool:
        """Send one frame; False (counted) when the bus is down or the send failed. Never raises."""
        if not self._up:
            self.dropped_while_down += 1
            return False
        try:
            self.bus.send(msg)
        except Exception as exc:  # noqa: BLE001  (can.CanError, OSError, websocket errors...)
            self.send_errors += 1
            self._mark_down(exc)
            return False
        self.sent += 1
        return True

    def send_batch(self, msgs) -> bool:
        """Send several frames in one write where the transport allows (bridge.can_batch); counted
        like ``send``. Never raises."""
        if not self._up:
            self.dropped_while_down += len(msgs)
            return False
        try:
            self._send_all(msgs)
        except Exception as exc:  # noqa: BLE001
            self.send_errors += 1
            self._mark_down(exc)
            return False
        self.sent += len(msgs)
        return True

    # -- reader / reconnect thread ---------------------------------------------------------------
    def _mark_down(self, exc: BaseException) -> None:
        with self._lock:
            self.last_error = f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:200]
            self._up = False

    def _read_loop(self) -> None:
        put = self.inbox.put
        while not self._closed.is_set():
            if not self._up:
                self._reconnect()
                continue
            try:
                msg = self.bus.recv(self.recv_timeout)
            except Exception as exc:  # noqa: BLE001
                if self._closed.is_set():
                    return
                self.recv_errors += 1
                self._mark_down(exc)
                continue
            if msg is None:
                continue
            if msg.is_error_frame:
                self.error_frames += 1
                continue
            self.received += 1
            put(("can", msg))

    def _reconnect(self) -> None:
        try:
            self.bus.shutdown()
        except Exception:  # noqa: BLE001  (already broken)
            pass
        while not self._closed.wait(self.retry_interval):
            try:
                bus = open_bus(self.interface, self.channel)
            except RtsimError as exc:
                self.last_error = str(exc)[:200]
                continue
            with self._lock:
                self.bus = bus
                self._send_all = batch_sender(bus)
                self._up = True
                self.reconnects += 1
            return

    def close(self, timeout: float = 1.0) -> None:
        """Stop the reader and shut the bus down (idempotent)."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._reader.join(timeout)
        try:
            self.bus.shutdown()
        except Exception:  # noqa: BLE001
            pass

    def stats(self) -> dict:
        return {"interface": self.description, "up": self._up, "sent": self.sent, "received": self.received,
                "send_errors": self.send_errors, "recv_errors": self.recv_errors,
                "error_frames": self.error_frames, "dropped_while_down": self.dropped_while_down,
                "reconnects": self.reconnects, "last_error": self.last_error}

