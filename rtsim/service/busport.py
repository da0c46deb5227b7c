"""The service's CAN port: one python-can bus, a reader thread, error counting and reconnection.

Received frames go into the service's inbox (a ``queue.SimpleQueue`` of ``("can", msg)`` items) from a
reader thread, so the real-time thread never blocks on the bus and lockstep mode can wait on CAN and
Zenoh requests alike. ``send``/``send_batch`` are called from the real-time thread: they copy the
frames (id, payload, time stamp) into a transmit queue, in order, and a writer thread puts them on the
bus (``bridge.can_batch``: one write per batch where the transport allows). So the socket work of
sending (a system call that, on loopback, also delivers into the receiver) runs beside the loop, as a
CAN controller's transmit path would, not inside its period; its CPU is measured in ``tx_cpu``. Nothing
here raises: a failing send (bus error, vanished interface, hub gone) is counted, the port is marked
down and the reader thread re-opens the bus every ``retry_interval`` seconds until it is back. Meanwhile
frames are dropped and counted (the simulation keeps its pace), as are frames beyond ``tx_max`` waiting.
Error frames on the bus are counted as bus errors too.
"""
from __future__ import annotations

import collections
import threading
import time

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
        self._tx: collections.deque = collections.deque()
        self._tx_ready = threading.Event()
        self.tx_max = 20_000                    # batches waiting before new ones are dropped
        self.tx_dropped = 0
        self.tx_cpu = 0.0                       # s of writer-thread CPU spent sending
        self._reader = threading.Thread(target=self._read_loop, name="can-reader", daemon=True)
        self._reader.start()
        self._writer = threading.Thread(target=self._write_loop, name="can-writer", daemon=True)
        self._writer.start()

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
        """Queue one frame for sending; False (counted) when the bus is down or the queue is full."""
        return self.send_batch((msg,))

    def send_batch(self, msgs) -> bool:
        """Queue several frames, sent in order in one write where the transport allows. The messages
        are copied: the caller may reuse them at once. Never raises."""
        if not self._up:
            self.dropped_while_down += len(msgs)
            return False
        if len(self._tx) >= self.tx_max:
            self.tx_dropped += len(msgs)
            return False
        self._tx.append(tuple((m.arbitration_id, bytes(m.data), m.timestamp) for m in msgs))
        self._tx_ready.set()
        return True

    # -- writer thread -----------------------------------------------------------------------------
    def _write_loop(self) -> None:
        import can

        tx = self._tx
        while True:
            self._tx_ready.wait(0.05)
            self._tx_ready.clear()
            while tx:
                batch = tx.popleft()
                c0 = time.thread_time()
                msgs = [can.Message(arbitration_id=i, data=d, is_extended_id=False, timestamp=t)
                        for i, d, t in batch]
                if not self._up:
                    self.dropped_while_down += len(msgs)
                else:
                    try:
                        self._send_all(msgs)
                        self.sent += len(msgs)
                    except Exception as exc:  # noqa: BLE001  (can.CanError, OSError, websocket errors...)
                        self.send_errors += 1
                        self._mark_down(exc)
                self.tx_cpu += time.thread_time() - c0
            if self._closed.is_set() and not tx:
                return

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
        self._tx_ready.set()
        self._writer.join(timeout)               # what the loop queued last (status, ack) goes out
        self._reader.join(timeout)
        try:
            self.bus.shutdown()
        except Exception:  # noqa: BLE001
            pass

    def stats(self) -> dict:
        return {"interface": self.description, "up": self._up, "sent": self.sent, "received": self.received,
                "send_errors": self.send_errors, "recv_errors": self.recv_errors,
                "error_frames": self.error_frames, "dropped_while_down": self.dropped_while_down,
                "reconnects": self.reconnects, "tx_dropped": self.tx_dropped, "tx_cpu_s": self.tx_cpu,
                "last_error": self.last_error}

