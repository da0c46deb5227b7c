"""The service's CAN port: one python-can bus, a reader thread, a writer thread, error counting and
reconnection.

The reader thread puts every received frame (id, payload bytes and its format: extended id, remote,
CAN FD) into the receive ring of
``rtsim.service.rings``, which the compiled step empties at its next step, so the real-time thread never
blocks on the bus; ``notify`` (lockstep mode) is called after each frame to wake a waiting loop. The
step queues the frames it sends (id, payload, time stamp) in the transmit ring and calls ``wake()``; the
writer thread puts everything queued on the bus in one write where the transport allows
(``bridge.can_batch``). So the socket work of sending (a system call that, on loopback, also delivers
into the receiver) runs beside the loop, as a CAN controller's transmit path would, not inside its
period; its CPU is measured in ``tx_cpu``. Nothing here raises: a failing send (bus error, vanished
interface, hub gone) is counted, the port is marked down and the reader thread re-opens the bus every
``retry_interval`` seconds until it is back. Meanwhile frames are dropped and counted (the simulation
keeps its pace), as are frames the writer fell a ring's length behind on and frames received while the
receive ring is full. Error frames on the bus are counted as bus errors too.
The bus is opened without ``receive_own_messages``, so the reader never gets this port's own frames
back: a frame with one of the simulator's own ids is another sender's (the step counts it; python-can's
``is_rx`` cannot tell, SocketCAN marks every frame sent on this host, vcan0's included, as not received).
"""
from __future__ import annotations

import threading
import time

from bridge.can_batch import frame_sender
from bridge.can_bus import open_bus
from bridge.can_e2e import FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE
from rtsim.errors import RtsimError

from .rings import H_RX_DROPPED, H_TX, RingReader, Rings, RxWriter


class BusPort:
    def __init__(self, rings: Rings, interface: str | None = None, channel: str | None = None,
                 retry_interval: float = 1.0, recv_timeout: float = 0.05, notify=None):
        self.rings = rings
        self.notify = notify
        self.interface = interface
        self.channel = channel
        self.retry_interval = float(retry_interval)
        self.recv_timeout = float(recv_timeout)
        self.bus = open_bus(interface, channel)         # the first open must work: raises RtsimError
        self._send_frames = frame_sender(self.bus)
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
        self._rx = RxWriter(rings)
        self._tx = RingReader(rings.heads, H_TX, rings.tx_id.shape[0])
        self._tx_ready = threading.Event()
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

    @property
    def tx_dropped(self) -> int:
        """Frames the writer fell more than the transmit ring behind on (lost)."""
        return self._tx.skipped

    @property
    def rx_dropped(self) -> int:
        """Frames received while the receive ring was full (lost)."""
        return int(self.rings.heads[H_RX_DROPPED])

    # -- real-time side --------------------------------------------------------------------------
    def wake(self) -> None:
        """Frames were queued in the transmit ring: let the writer send them."""
        self._tx_ready.set()

    # -- writer thread -----------------------------------------------------------------------------
    def _write_loop(self) -> None:
        while True:
            self._tx_ready.wait(0.05)
            self._tx_ready.clear()
            closing = self._closed.is_set()         # what was queued before close() still goes out
            c0 = time.thread_time()
            self._send_pending()
            self.tx_cpu += time.thread_time() - c0
            if closing:
                return

    def _send_pending(self) -> None:
        r = self.rings
        cap = r.tx_id.shape[0]
        todo = self._tx.take()
        if not todo:
            return
        frames = [(int(r.tx_id[n % cap]), int(r.tx_word[n % cap]).to_bytes(8, "little", signed=True),
                   float(r.tx_t[n % cap])) for n in todo]
        if self._tx.overrun(todo.start):                # overwritten while being copied: lost
            self._tx.skipped += len(frames)
        elif not self._up:
            self.dropped_while_down += len(frames)
        else:
            try:
                self._send_frames(frames)
                self.sent += len(frames)
            except Exception as exc:  # noqa: BLE001  (can.CanError, OSError, websocket errors...)
                self.send_errors += 1
                self._mark_down(exc)

    # -- reader / reconnect thread ---------------------------------------------------------------
    def _mark_down(self, exc: BaseException) -> None:
        with self._lock:
            self.last_error = f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:200]
            self._up = False

    def _read_loop(self) -> None:
        put = self._rx.put
        notify = self.notify
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
            put(msg.arbitration_id, msg.data, (FLAG_EXTENDED if msg.is_extended_id else 0)
                | (FLAG_REMOTE if msg.is_remote_frame else 0) | (FLAG_FD if msg.is_fd else 0))
            if notify is not None:
                notify()

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
                self._send_frames = frame_sender(bus)
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
                "reconnects": self.reconnects, "tx_dropped": self.tx_dropped, "rx_dropped": self.rx_dropped,
                "tx_cpu_s": self.tx_cpu,
                "last_error": self.last_error}

