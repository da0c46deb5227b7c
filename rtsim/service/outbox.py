"""Hand-off from the real-time thread to the observers (Zenoh publishers and the MCAP recorder).

The compiled step writes sensor samples (with the packed payloads of their CAN frames), state
samples, the frames it took or sent besides the sensor frames, and command events into the
preallocated rings of ``rtsim.service.rings``. A publisher thread reads them and turns them into the
JSON payloads of ``bridge.payloads``, handing each payload to Zenoh (congestion control DROP: never
blocks) and to the recorder (a bounded queue: never blocks). So a slow or absent subscriber, or a slow
disk, never delays the loop: when the publisher falls more than a ring's capacity behind, the oldest
items are skipped and counted in ``dropped``.

Each payload is encoded once and the same bytes go to every sink, so Zenoh, MCAP and Foxglove carry
identical messages. Log times in the recording are simulation times (ns).

With a scene (bridge.scene.SceneBuilder) the publisher also encodes, for every state sample (at most
``SCENE_RATE``), the vehicle's 3D scene and frame transform (Foxglove messages, topics ``scene`` and
``tf``) from the state and the sensor sample of the same time, for the recorder and the Foxglove server
(bridge.foxglove_live). The road's scene goes out at the start, again when simulation time restarts (a
reset, or a new scenario whose scene ``replace_scene`` gave) and when a Foxglove client subscribes to it.
A scene that fails to build is counted (``scene_errors``), never raised.

The events the loop thread logs into a deque with the step they acted at go to the recording only, so that
`rtsim resim` repeats them at the same steps: the user command source's changes (``rtsim view``'s ``drive``
op: values, takeover, release, lapse) on ``user``, the control ops that change the run (pause, resume,
lockstep ``step``, ``driver``, reset, load_scenario) on ``control``.
"""
from __future__ import annotations

import collections
import functools
import threading

from bridge import payloads
from rtsim.channels import CAR, ChannelDictionary

from .rings import CMD_ACCEPTED, H_CMD, H_LOG, H_SENSOR, H_STATE, LOG_RX, RingReader, Rings


#: Highest rate of the 3D scene messages, Hz (they follow the state samples; the state rate may be higher).
SCENE_RATE = 100.0


class RingDrain:
    """Reads the publisher's rings in order and calls ``emit(key, t, payload)`` per message: ``key``
    'sensors', 'state' or 'commands' with JSON bytes; 'can/rx' or 'can/tx' with (id, payload bytes), or
    (id, payload bytes, length, bridge.can_e2e.FLAG_* flags) for an extended-id, remote or CAN FD frame.
    ``raw`` (optional) receives each sensor and state sample as (key, t, values array) without JSON:
    re-simulation compares numbers."""

    def __init__(self, rings: Rings, frame_ids, emit=None, raw=None, frames: bool = True,
                 channels: ChannelDictionary = CAR, frame_periods=None):
        """A sensor frame is recorded as 'can/tx' at the samples the step sent it at (``Rings.sensor_sent``:
        its period came and no fault took it); ``frame_periods`` (per sensor frame, s) is kept for callers."""
        self.r = rings
        self.channels = channels
        self._encode_sensors = functools.partial(payloads.encode_sensors, names=channels.sensor_names)
        self._encode_state = functools.partial(payloads.encode_state, names=channels.state_names)
        self.emit = emit
        self.raw = raw
        self.frames = frames
        self.frame_ids = [int(f) for f in frame_ids]
        self.frame_periods = None if frame_periods is None else [float(p) for p in frame_periods]
        h = rings.heads
        self._sensors = RingReader(h, H_SENSOR, rings.sensor_t.shape[0])
        self._state = RingReader(h, H_STATE, rings.state_t.shape[0])
        self._log = RingReader(h, H_LOG, rings.log_t.shape[0])
        self._cmd = RingReader(h, H_CMD, rings.cmd_t.shape[0])

    @property
    def dropped(self) -> int:
        return sum(x.skipped for x in (self._sensors, self._state, self._log, self._cmd))

    def drain(self) -> int:
        """Everything written since the last call; returns the number of messages."""
        return self._log_frames() + self._commands() + self._sensor_samples() + self._state_samples()

    def _log_frames(self) -> int:
        r, emit = self.r, self.emit
        cap = r.log_t.shape[0]
        todo = self._log.take()
        if emit is None or not self.frames:
            return 0
        for n in todo:
            j = n % cap
            fid, size, direction, flags = (int(x) for x in r.log_meta[j])
            data = r.log_data[j, :min(size, r.log_data.shape[1])].tobytes()
            emit("can/rx" if direction == LOG_RX else "can/tx", float(r.log_t[j]),
                 (fid, data, size, flags) if flags else (fid, data))
        return len(todo)

    def _commands(self) -> int:
        r, emit = self.r, self.emit
        cap = r.cmd_t.shape[0]
        todo = self._cmd.take()
        if emit is None:
            return 0
        for n in todo:
            j = n % cap
            kind, arg = (int(x) for x in r.cmd_meta[j])
            t = float(r.cmd_t[j])
            if kind == CMD_ACCEPTED:
                body = {self.channels.command_names[arg]: float(r.cmd_v[j, arg]), "source": "can"}
            else:
                body = {**{nm: float(r.cmd_v[j, i]) for i, nm in enumerate(self.channels.command_names)},
                        "source": "safe" if arg else "can"}
            emit("commands", t, payloads.encode_json({"time": t, **body}))
        return len(todo)

    def _sensor_samples(self) -> int:
        r = self.r
        return self._samples(self._sensors, "sensors", r.sensor_t, r.sensor_v, self._encode_sensors,
                             r.sensor_words if self.frames else None)

    def _state_samples(self) -> int:
        r = self.r
        return self._samples(self._state, "state", r.state_t, r.state_v, self._encode_state)

    def _samples(self, reader, key, times, values, encode, words=None) -> int:
        """One sample ring: (t, values) to ``raw`` and as JSON to ``emit``; with ``words``, each
        sample's packed sensor frames as 'can/tx' records."""
        emit, raw = self.emit, self.raw
        cap = times.shape[0]
        todo = reader.take()
        for n in todo:
            j = n % cap
            t = float(times[j])
            if raw is not None:
                raw(key, t, values[j].copy())
            if emit is not None:
                emit(key, t, encode(t, values[j]))
                if words is not None:
                    row = words[j].tobytes()
                    sent = int(self.r.sensor_sent[j])
                    for k, fid in enumerate(self.frame_ids):
                        if (sent >> k) & 1:
                            emit("can/tx", t, (fid, row[8 * k:8 * k + 8]))
        return len(todo)


class Outbox:
    """The publisher thread: drains the rings every ``poll`` s into Zenoh and the recorder, and
    publishes the status (``status_fn()``) every ``status_period`` s."""

    def __init__(self, rings: Rings, frame_ids, zenoh=None, recorder=None, status_fn=None,
                 status_period: float = 0.1, poll: float = 0.005, channels: ChannelDictionary = CAR,
                 frame_periods=None, scene=None, road: bytes | None = None, foxglove=None, event_log=None):
        """``scene``: a bridge.scene.SceneBuilder (None: no scene topics); ``road``: the road's scene
        (bytes); ``foxglove``: a bridge.foxglove_live.FoxgloveLive server; ``event_log``: the loop's deque of
        (topic, event) (HilLoop.event_log), recorded on those topics."""
        self.event_log = event_log
        self.zenoh = zenoh
        self.recorder = recorder
        self.foxglove = foxglove
        self.scene = scene if (recorder is not None or foxglove is not None) else None
        self.road = road
        self.scene_errors = 0
        self.last_scene_error: str | None = None
        self._recent_sensors: collections.deque = collections.deque(maxlen=32)   # (t, values)
        self._last_t = 0.0
        self._scene_due = -1.0
        self._next_scene = None
        self.status_fn = status_fn
        self.status_period = float(status_period)
        self.poll = float(poll)
        self.published = 0
        self._rings = RingDrain(rings, frame_ids, emit=self._emit, frames=recorder is not None, channels=channels,
                                frame_periods=frame_periods, raw=self._sample if self.scene is not None else None)
        self._stop = threading.Event()
        self._status_due = 0.0
        self._flush_after_status = False
        self._thread = threading.Thread(target=self._run, name="rtsim-publisher", daemon=True)
        self._thread.start()

    @property
    def dropped(self) -> int:
        return self._rings.dropped

    def _emit(self, key: str, t: float, data) -> None:
        if key in ("sensors", "state", "status", "commands"):
            if self.zenoh is not None:
                self.zenoh.publish(key, data)
            if self.foxglove is not None:
                self.foxglove.publish(key, t, data)
        elif self.foxglove is not None and key in ("scene", "tf", "road"):
            self.foxglove.publish(key, t, data)
        if self.recorder is not None:
            self.recorder.record(key, int(round(t * 1e9)), data)
        self.published += 1

    def _sample(self, key: str, t: float, values) -> None:
        """A raw sensor or state sample (RingDrain ``raw``): the scene of each state sample, with the
        newest sensor sample not later than it (the same time: sensors every 2 ms, state every 10 ms)."""
        if key == "sensors":
            self._recent_sensors.append((t, values))
            return
        if t < self._last_t:                    # a reset: simulation time starts again
            self._scene_due = -1.0
            self._restart(t)
        self._last_t = t
        if t < self._scene_due - 1e-9:          # at most SCENE_RATE Hz, whatever the state rate
            return
        self._scene_due = t + 1.0 / SCENE_RATE
        sensors = None
        for ts, v in reversed(self._recent_sensors):
            if ts <= t + 1e-9:
                sensors = v
                break
        try:
            scene, tf = self.scene.vehicle(t, values, sensors)
        except Exception as exc:  # noqa: BLE001  (a bad sample must not stop the publisher)
            self.scene_errors += 1
            self.last_scene_error = f"at {t:.3f} s: {type(exc).__name__}: {exc}"
            return
        self._emit("tf", t, tf)
        self._emit("scene", t, scene)

    def replace_scene(self, scene, road: bytes) -> None:
        """A new scenario's scene and road (its vehicle may differ), taken when simulation time restarts
        (the loop installs the new scenario between two steps; the samples before it keep the old one)."""
        if self.scene is not None:
            self._next_scene = (scene, road)

    def _restart(self, t: float) -> None:
        """Simulation time restarted (reset or a new scenario): the new scene, and the road again at t."""
        nxt, self._next_scene = self._next_scene, None
        if nxt is not None:
            self.scene, self.road = nxt
        if self.road is not None:
            self._emit("road", t, self.road)

    def _send_road(self, start: bool = False) -> None:
        """The road's scene: at the start to every sink (log time 0), later to the Foxglove server when
        one of its clients subscribed to it (at the newest state time)."""
        fox = self.foxglove
        if self.road is None or self.scene is None:
            return
        if start:
            self._emit("road", 0.0, self.road)
        elif fox is not None and fox.road_wanted.is_set():
            fox.road_wanted.clear()
            fox.publish("road", self._last_t, self.road)

    def status_now(self, flush_recording: bool = False) -> None:
        """Publish a status at the publisher's next turn (any thread); ``flush_recording``: then push the
        recording's chunk in progress to disk (a model failure: kept even if the process is killed later)."""
        self._flush_after_status = self._flush_after_status or flush_recording
        self._status_due = 0.0

    def _maybe_status(self, now: float) -> None:
        if self.status_fn is None or now < self._status_due:
            return
        self._status_due = now + self.status_period
        flush, self._flush_after_status = self._flush_after_status, False
        self.flush()                          # what the loop logged before this status goes first
        status = self.status_fn()
        self._emit("status", float(status["time"]), payloads.encode_json(status))
        if flush and self.recorder is not None:
            self.recorder.flush_soon()

    def flush(self) -> None:
        """Publish everything pending now (publisher thread, or after it stopped)."""
        self._events()
        self._rings.drain()

    def _events(self) -> None:
        """The events the loop logged (recorded only: a re-simulation repeats them)."""
        log = self.event_log
        while log:
            topic, ev = log.popleft()
            if self.recorder is not None:
                self.recorder.record(topic, int(round(ev["time"] * 1e9)), payloads.encode_json(ev))
            self.published += 1

    def _run(self) -> None:
        import gc
        import time

        next_gc = 0.0
        self._send_road(start=True)
        while not self._stop.is_set():
            self._send_road()
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
        self._thread.join(10.0)
        if self._thread.is_alive():     # stuck in a sink: draining beside it would duplicate records
            return
        self.flush()
        if final_status and self.status_fn is not None:
            status = self.status_fn()
            self._emit("status", float(status["time"]), payloads.encode_json(status))
