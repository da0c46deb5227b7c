"""Hand-off from the real-time thread to the observers (Zenoh publishers and the MCAP recorder).

The real-time thread only copies numbers into preallocated rings (sensor samples with the packed
payloads of their CAN frames, state samples) or appends low-rate events (received frames, commands,
event frames) to a deque. A publisher thread turns them into the JSON payloads of ``bridge.payloads``
and hands each payload to Zenoh (congestion control DROP: never blocks) and to the recorder (a bounded
queue: never blocks). So a slow or absent subscriber, or a slow disk, never delays the loop: when the
publisher falls more than a ring's capacity behind, the oldest samples are skipped and counted in
``dropped``.

Each payload is encoded once and the same bytes go to both sinks, so Zenoh and MCAP carry identical
messages. Log times in the recording are simulation times (ns).
"""
from __future__ import annotations

import collections
import threading

import numpy as np

from bridge import payloads


class Outbox:
    def __init__(self, nsensor: int, nstate: int, frame_ids, zenoh=None, recorder=None, status_fn=None,
                 status_period: float = 0.1, capacity: int = 8192, poll: float = 0.005):
        self.zenoh = zenoh
        self.recorder = recorder
        self.status_fn = status_fn
        self.status_period = float(status_period)
        self.capacity = int(capacity)
        self.poll = float(poll)
        self.frame_ids = [int(f) for f in frame_ids]
        cap = self.capacity
        self.sensor_t = np.zeros(cap)
        self.sensor_v = np.zeros((cap, nsensor))
        self.sensor_words = np.zeros((cap, len(self.frame_ids)), dtype=np.int64)
        self.state_t = np.zeros(cap)
        self.state_v = np.zeros((cap, nstate))
        self.sensor_head = 0          # samples written (real-time thread)
        self.state_head = 0
        self._sensor_tail = 0         # samples published (publisher thread)
        self._state_tail = 0
        self.events: collections.deque = collections.deque()
        self.max_events = 100_000
        self.dropped = 0
        self.published = 0
        self._stop = threading.Event()
        self._status_due = 0.0
        self._thread = threading.Thread(target=self._run, name="rtsim-publisher", daemon=True)
        self._thread.start()

    # -- real-time side (copies only) ------------------------------------------------------------
    def push_sensor(self, t: float, values: np.ndarray, words: np.ndarray) -> None:
        j = self.sensor_head % self.capacity
        self.sensor_t[j] = t
        self.sensor_v[j] = values
        self.sensor_words[j] = words
        self.sensor_head += 1

    def push_state(self, t: float, values: np.ndarray) -> None:
        j = self.state_head % self.capacity
        self.state_t[j] = t
        self.state_v[j] = values
        self.state_head += 1

    def push_event(self, key: str, t: float, payload) -> None:
        """A low-rate message: ``key`` 'can/rx' or 'can/tx' with payload (id, bytes), or 'commands'
        with a dict. Dropped and counted beyond ``max_events`` waiting."""
        if len(self.events) >= self.max_events:
            self.dropped += 1
            return
        self.events.append((key, t, payload))

    # -- publisher thread ------------------------------------------------------------------------
    def _emit(self, key: str, t: float, data: bytes) -> None:
        if self.zenoh is not None and key in ("sensors", "state", "status", "commands"):
            self.zenoh.publish(key, data)
        if self.recorder is not None:
            self.recorder.record(key, int(round(t * 1e9)), data)
        self.published += 1

    def _record_frame(self, key: str, t: float, can_id: int, data: bytes) -> None:
        if self.recorder is not None:
            self.recorder.record(key, int(round(t * 1e9)), (can_id, data))

    def _pending(self, head: int, tail: int) -> int:
        """Where to resume reading a ring: the oldest sample still in it (skipped ones counted)."""
        if head - tail > self.capacity:
            self.dropped += head - tail - self.capacity
            return head - self.capacity
        return tail

    def _drain_sensors(self) -> None:
        head, cap = self.sensor_head, self.capacity
        tail = self._pending(head, self._sensor_tail)
        for n in range(tail, head):
            j = n % cap
            t = float(self.sensor_t[j])
            self._emit("sensors", t, payloads.encode_sensors(t, self.sensor_v[j]))
            if self.recorder is not None:
                raw = self.sensor_words[j].tobytes()
                for k, fid in enumerate(self.frame_ids):
                    self._record_frame("can/tx", t, fid, raw[8 * k:8 * k + 8])
        self._sensor_tail = head

    def _drain_state(self) -> None:
        head, cap = self.state_head, self.capacity
        for n in range(self._pending(head, self._state_tail), head):
            j = n % cap
            t = float(self.state_t[j])
            self._emit("state", t, payloads.encode_state(t, self.state_v[j]))
        self._state_tail = head

    def _drain_events(self) -> None:
        ev = self.events
        while ev:
            key, t, payload = ev.popleft()
            if key in ("can/rx", "can/tx"):
                self._record_frame(key, t, payload[0], payload[1])
            else:
                self._emit(key, t, payloads.encode_json({"time": t, **payload}))

    def _maybe_status(self, now: float) -> None:
        if self.status_fn is None or now < self._status_due:
            return
        self._status_due = now + self.status_period
        status = self.status_fn()
        self._emit("status", float(status["time"]), payloads.encode_json(status))

    def flush(self) -> None:
        """Publish everything pending now (publisher thread, or after it stopped)."""
        self._drain_events()
        self._drain_sensors()
        self._drain_state()

    def _run(self) -> None:
        import gc
        import time

        next_gc = 0.0
        while not self._stop.is_set():
            self.flush()
            now = time.monotonic()
            self._maybe_status(now)
            if now >= next_gc:          # the service switches automatic collection off (server.py)
                next_gc = now + 1.0
                gc.collect(0)
            self._stop.wait(self.poll)

    def close(self, final_status: bool = True) -> None:
        """Stop the publisher thread after publishing what is pending (and a last status)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(2.0)
        self.flush()
        if final_status and self.status_fn is not None:
            status = self.status_fn()
            self._emit("status", float(status["time"]), payloads.encode_json(status))
