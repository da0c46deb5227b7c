"""The preallocated rings between the service's threads and its compiled step.

Every ring is a set of numpy arrays with one writer and one reader; ``heads`` holds each ring's count of
items written (and, for the received frames, the count read), so a reader takes items ``tail .. head-1``
at slots ``n % capacity``. All of them are written and read with the GIL held (the compiled step does
not release it), so an item is complete before its head moves. A reader that falls more than a ring's
capacity behind skips the oldest items and counts them (``Rings.catch_up``); nothing ever blocks the
real-time thread.

Writers and readers:

* ``rx_*``: CAN frames received (id, length, flags ``bridge.can_e2e.FLAG_*``: extended id, remote, CAN FD;
  up to 64 payload bytes); the CAN reader thread writes, the
  step reads (``H_RX_TAIL``). A full ring drops new frames (counted in ``H_RX_DROPPED``).
* ``tx_*``: frames to send (id, 8-byte payload as a little-endian word, time stamp s); the step writes,
  the CAN writer thread reads.
* ``sensor_*``: sensor samples (time s, values in the vehicle's sensor channels' order, the packed sensor frames,
  which of them were sent);
  ``state_*``: observer state samples; the step writes, the publisher (Zenoh, MCAP) reads.
* ``log_*``: every frame the step took (direction RX) or sent besides the sensor frames (status, lockstep
  acknowledgement; direction TX), for the MCAP ``can/rx`` / ``can/tx`` topics.
* ``cmd_*``: command events for the ``commands`` topic: a command accepted (kind CMD_ACCEPTED, arg its
  index) or the watchdog's time-out mask changed (kind CMD_MASK, arg the mask; all values).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

# heads
(H_RX, H_RX_TAIL, H_RX_DROPPED, H_TX, H_SENSOR, H_STATE, H_LOG, H_CMD) = range(8)
NHEADS = 8
RX_DATA = 64                  # bytes kept per received frame (CAN FD at most)
LOG_RX, LOG_TX = 0, 1         # log_meta[:, 2]: direction
CMD_ACCEPTED, CMD_MASK = 0, 1  # cmd_meta[:, 0]: kind


class Rings(NamedTuple):
    heads: np.ndarray        # (NHEADS,) int64
    rx_meta: np.ndarray      # (cap, 3) int64: id, length (bytes), flags (bridge.can_e2e.FLAG_*)
    rx_data: np.ndarray      # (cap, RX_DATA) uint8
    tx_id: np.ndarray        # (cap,) int64
    tx_word: np.ndarray      # (cap,) int64, payload bytes 0-7 little-endian
    tx_t: np.ndarray         # (cap,) float64, s
    sensor_t: np.ndarray     # (cap,) float64, s
    sensor_v: np.ndarray     # (cap, nsensor) float64
    sensor_words: np.ndarray  # (cap, nframes) int64
    sensor_sent: np.ndarray  # (cap,) int64: bit f set when sensor frame f was sent at the sample (its period
                             # came and no fault took it: rtsim.faults)
    state_t: np.ndarray      # (cap,) float64, s
    state_v: np.ndarray      # (cap, nstate) float64
    log_t: np.ndarray        # (cap,) float64, s
    log_meta: np.ndarray     # (cap, 4) int64: id, length, direction, flags (bridge.can_e2e.FLAG_*)
    log_data: np.ndarray     # (cap, RX_DATA) uint8
    cmd_t: np.ndarray        # (cap,) float64, s
    cmd_meta: np.ndarray     # (cap, 2) int64: kind, arg
    cmd_v: np.ndarray        # (cap, ncmd) float64


def make_rings(nsensor: int, nframes: int, nstate: int, ncmd: int, *, rx: int = 16384, tx: int = 16384,
               samples: int = 8192, log: int = 32768, cmd: int = 4096) -> Rings:
    """Rings of the given capacities (items); the defaults hold seconds of traffic at 1 kHz (the receive
    ring: about 2 s of a classic CAN bus at 1 Mbit/s saturated with 8-byte frames, 8 000 frames/s)."""
    z = np.zeros
    return Rings(z(NHEADS, dtype=np.int64), z((rx, 3), dtype=np.int64), z((rx, RX_DATA), dtype=np.uint8),
                 z(tx, dtype=np.int64), z(tx, dtype=np.int64), z(tx),
                 z(samples), z((samples, nsensor)), z((samples, nframes), dtype=np.int64),
                 z(samples, dtype=np.int64),
                 z(samples), z((samples, nstate)),
                 z(log), z((log, 4), dtype=np.int64), z((log, RX_DATA), dtype=np.uint8),
                 z(cmd), z((cmd, 2), dtype=np.int64), z((cmd, ncmd)))


class RxWriter:
    """The CAN reader thread's end of the received-frame ring."""

    def __init__(self, rings: Rings):
        self.r = rings

    def put(self, can_id: int, data, flags: int = 0) -> bool:
        """Queue one received frame (``flags``: bridge.can_e2e.FLAG_* of an extended-id, remote or CAN FD
        frame, 0 for a classic standard-id data frame); False (counted) when the ring is full."""
        r = self.r
        heads = r.heads
        n = int(heads[H_RX])
        cap = r.rx_meta.shape[0]
        if n - int(heads[H_RX_TAIL]) >= cap:
            heads[H_RX_DROPPED] += 1
            return False
        j = n % cap
        size = len(data)
        m = min(size, RX_DATA)
        r.rx_meta[j, 0] = can_id
        r.rx_meta[j, 1] = size
        r.rx_meta[j, 2] = flags
        if m:
            r.rx_data[j, :m] = np.frombuffer(bytes(data[:m]), dtype=np.uint8)
        heads[H_RX] = n + 1
        return True

    @property
    def pending(self) -> int:
        return int(self.r.heads[H_RX] - self.r.heads[H_RX_TAIL])


class RingReader:
    """One reader's position in one ring: ``take()`` returns the range of item numbers to read now
    (slots ``n % capacity``); items overwritten before they were read are skipped and counted."""

    def __init__(self, heads: np.ndarray, head: int, capacity: int):
        self.heads = heads
        self.head = head
        self.capacity = capacity
        self.tail = int(heads[head])
        self.skipped = 0

    def take(self) -> range:
        head = int(self.heads[self.head])
        tail = self.tail
        if head - tail > self.capacity:
            self.skipped += head - tail - self.capacity
            tail = head - self.capacity
        self.tail = head
        return range(tail, head)

    def overrun(self, n: int) -> bool:
        """True if item n has been overwritten meanwhile (read it again or drop it)."""
        return int(self.heads[self.head]) - n > self.capacity
