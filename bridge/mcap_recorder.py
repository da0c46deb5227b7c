"""Live session recorder of the HIL service: MCAP written off the real-time thread.

The real-time loop calls :meth:`Recorder.record` (``topic_key, log_time_ns, payload``), which only
appends a tuple to a bounded queue and never blocks: when the queue is full the message is dropped
and counted (:attr:`Recorder.dropped`). A writer thread serialises the payloads (JSON) and writes
them into zstd-compressed chunks.

Topics (``topic_key`` → MCAP topic), each registered on first use with a JSON-schema channel that
Foxglove opens without plug-ins (message encoding ``json``, schema encoding ``jsonschema``; the schemas
are bridge.payloads.SCHEMAS, names and units from the channel dictionary, rtsim.channels):

* ``sensors``  → ``rtsim/<vehicle_id>/sensors``  every sensor channel + ``time`` (s)
* ``state``    → ``rtsim/<vehicle_id>/state``    every state channel + ``time`` (s)
* ``status``   → ``rtsim/<vehicle_id>/status``   service status (mode, loop health, faults, ...)
* ``commands`` → ``rtsim/<vehicle_id>/commands`` the actuator commands applied + their ``source``
* ``can/rx``, ``can/tx`` → ``rtsim/<vehicle_id>/can/rx|tx`` raw frames as
  ``{"id": int, "dlc": int, "data": "hex", "time": s}``, plus ``"extended"``, ``"remote"``, ``"fd"``:
  true for a received frame of that format (absent otherwise)
* ``scene``, ``tf``, ``road`` → ``rtsim/<vehicle_id>/scene|tf|road`` the 3D scene (bridge.scene):
  protobuf messages (``foxglove.SceneUpdate``, ``foxglove.FrameTransforms``) with the foxglove SDK's own
  schemas (schema encoding ``protobuf``: a FileDescriptorSet), given as encoded bytes, so Foxglove's 3D
  panel shows the vehicle on any recording

Payloads: a dict (``time`` is added from ``log_time_ns`` when missing), or ``bytes`` holding an
already-encoded JSON message. On the CAN topics a frame may also be given as ``(can_id, data)`` or
``(can_id, data, dlc)`` with ``data`` bytes, or as a dict whose ``data`` is bytes. The payload is
serialised later on the writer thread: do not mutate a dict after handing it to ``record``.

Chunking / flush policy: a chunk is closed and pushed to the operating system (``Writer.flush`` +
file flush, so it survives a SIGKILL of the process; no fsync) when its messages reach
``chunk_size`` bytes (default 256 KiB) or when its first message is ``flush_interval`` seconds old
(default 1 s, wall clock), whichever comes first. A killed recorder therefore loses at most the
chunk in progress (≤ ``chunk_size`` bytes, ≤ about ``flush_interval`` s) plus what was still queued.
:func:`read_recording` recovers every complete chunk of such a file.
"""
from __future__ import annotations

import collections
import json
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NamedTuple

from mcap.writer import CompressionType, Writer

from bridge.mcap_scan import MCAP_MAGIC, scan, string
from bridge.payloads import TOPIC_KEYS, encode_json, schemas_for
from rtsim.channels import CAR, ChannelDictionary
from rtsim.errors import ConfigError
#: The MCAP metadata record holding the recorded vehicle's channel dictionary (``{"json": ...}``,
#: rtsim.channels.ChannelDictionary.to_json), so a replay knows the channels it holds.
CHANNELS_METADATA = "rtsim.channels"

CAN_KEYS = frozenset(("can/rx", "can/tx"))
#: The 3D scene's topic keys (bridge.scene.SCENE_KEYS; not imported here, so that a recorder without a
#: scene does not load the foxglove SDK).
SCENE_KEYS = ("scene", "tf", "road")
#: The MCAP metadata record a clean close writes when the service set ``Recorder.session_end``, last: ``how``
#: ("stopped", "model_fault") and, for a fault, ``reason_code``, ``reason``, ``message``, ``step``,
#: ``sim_time``, ``coordinate``, plus ``end_sim_time`` (string values).
SESSION_END_METADATA = "rtsim.session_end"
_FLUSH = object()          # queue item: push the chunk in progress to disk now (``flush_soon``)

def _can_frame(payload, t_s: float) -> dict:
    if isinstance(payload, dict):
        data = payload.get("data", b"")
        hexdata = data.hex() if isinstance(data, (bytes, bytearray, memoryview)) else str(data)
        dlc = payload.get("dlc", len(hexdata) // 2)
        return {"id": int(payload["id"]), "dlc": int(dlc), "data": hexdata,
                "time": float(payload.get("time", t_s))}
    can_id, data, *rest = payload
    data = bytes(data)
    frame = {"id": int(can_id), "dlc": int(rest[0]) if rest else len(data), "data": data.hex(), "time": t_s}
    flags = int(rest[1]) if len(rest) > 1 else 0      # bridge.can_e2e.FLAG_*: only set ones are written
    for bit, name in ((1, "extended"), (2, "remote"), (4, "fd")):
        if flags & bit:
            frame[name] = True
    return frame


class Recorder:
    """Records a live session to an MCAP file from a writer thread (see the module docstring).

    ``on_chunk(chunks, messages)`` (optional) is called on the writer thread after each chunk has
    been pushed to the operating system, with the number of chunks and of messages written so far.
    """

    def __init__(self, path: str | Path, vehicle_id: str, chunk_size: int = 256 * 1024,
                 flush_interval: float = 1.0, queue_size: int = 100_000,
                 on_chunk: Callable[[int, int], Any] | None = None, poll_interval: float = 0.002,
                 metadata: dict[str, dict[str, str]] | None = None, channels: ChannelDictionary = CAR):
        if chunk_size <= 0 or flush_interval <= 0 or queue_size <= 0:
            raise ValueError("chunk_size, flush_interval and queue_size must be positive")
        self.path = Path(path)
        self.vehicle_id = vehicle_id
        self.chunk_size = int(chunk_size)
        self.flush_interval = float(flush_interval)
        self.queue_size = int(queue_size)
        self.on_chunk = on_chunk
        self._poll = poll_interval
        self._queue: collections.deque = collections.deque()
        self.dropped = 0        # messages refused by record() (queue full, or recorder closed)
        self.written = 0        # messages handed to the MCAP writer
        self.chunks = 0         # chunks pushed to the OS
        self.errors = 0         # payloads that could not be serialised (skipped)
        self.last_error: str | None = None
        self.error: BaseException | None = None   # fatal writer-thread error (I/O), re-raised by close()
        self.session_end: dict[str, str] | None = None   # written at a clean close (SESSION_END_METADATA)
        self._closing = False
        self._closed = False
        self._close_lock = threading.Lock()
        self._running = threading.Event()
        self._running.set()
        self._fh = open(self.path, "wb")
        self._writer = Writer(self._fh, chunk_size=self.chunk_size * 4 + (1 << 20),
                              compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="rtsim")
        metadata = {CHANNELS_METADATA: {"json": channels.to_json()}, **(metadata or {})}
        for name, values in metadata.items():             # the vehicle's channels, session facts: before
            self._writer.add_metadata(name, {str(k): str(v) for k, v in values.items()})   # any chunk
        self._fh.flush()         # header and metadata are on disk even if the process dies before a chunk
        self._schema_defs = schemas_for(channels)       # the recorded vehicle's channels
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._chunk_bytes = 0
        self._chunk_started: float | None = None
        self._thread = threading.Thread(target=self._run, name=f"mcap-recorder-{vehicle_id}",
                                        daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------- real-time side
    def record(self, topic_key: str, log_time_ns: int, payload) -> bool:
        """Queue one message; never blocks. Returns False (and counts it in ``dropped``) when the
        queue is full or the recorder is closed. Raises ValueError for an unknown topic key."""
        if topic_key not in self._schema_defs and topic_key not in SCENE_KEYS:
            raise ValueError(f"unknown topic key {topic_key!r}; allowed: {', '.join(TOPIC_KEYS + SCENE_KEYS)}")
        q = self._queue
        if self._closing or len(q) >= self.queue_size:
            self.dropped += 1
            return False
        q.append((topic_key, log_time_ns, payload))
        return True

    def flush_soon(self) -> None:
        """Push the chunk in progress to disk once the messages queued so far are written (any thread)."""
        self._queue.append((_FLUSH, 0, None))

    @property
    def queued(self) -> int:
        return len(self._queue)

    def topic(self, topic_key: str) -> str:
        return f"rtsim/{self.vehicle_id}/{topic_key}"

    # ---------------------------------------------------------------- diagnostics / tests
    def pause(self) -> None:
        """Suspend the writer thread (messages keep queueing, then dropping). For tests."""
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    # ---------------------------------------------------------------- writer thread
    def _channel(self, key: str) -> int:
        cid = self._channels.get(key)
        if cid is None and key in SCENE_KEYS:
            from bridge.scene import topic_schemas     # the foxglove SDK: loaded when a scene is recorded
            name, encoding, data = topic_schemas()[key]
            sid = self._schema_ids.get(name)
            if sid is None:
                sid = self._schema_ids[name] = self._writer.register_schema(name=name, encoding=encoding, data=data)
            cid = self._channels[key] = self._writer.register_channel(topic=self.topic(key), message_encoding=encoding,
                                                                       schema_id=sid)
            self._seq[key] = 0
        if cid is None:
            name, schema = self._schema_defs[key]
            sid = self._schema_ids.get(name)
            if sid is None:
                sid = self._writer.register_schema(name=name, encoding="jsonschema",
                                                   data=json.dumps(schema).encode())
                self._schema_ids[name] = sid
            cid = self._writer.register_channel(topic=self.topic(key), message_encoding="json",
                                                schema_id=sid)
            self._channels[key] = cid
            self._seq[key] = 0
        return cid

    def _serialise(self, key: str, t_ns: int, payload) -> bytes:
        if key in CAN_KEYS and not isinstance(payload, (bytes, bytearray)):
            return encode_json(_can_frame(payload, t_ns * 1e-9))
        if isinstance(payload, (bytes, bytearray, memoryview)):
            return bytes(payload)
        if "time" not in payload:
            payload = {"time": t_ns * 1e-9, **payload}
        return encode_json(payload)

    def _write(self, item) -> None:
        key, t_ns, payload = item
        try:
            data = self._serialise(key, t_ns, payload)
        except Exception as e:  # a bad payload must not stop the recording
            self.errors += 1
            self.last_error = f"{key} at {t_ns} ns: {type(e).__name__}: {e}"
            return
        cid = self._channel(key)
        seq = self._seq[key]
        self._seq[key] = seq + 1
        self._writer.add_message(channel_id=cid, log_time=int(t_ns), publish_time=int(t_ns),
                                 sequence=seq & 0xFFFFFFFF, data=data)
        self.written += 1
        if self._chunk_started is None:
            self._chunk_started = time.monotonic()
        self._chunk_bytes += len(data) + 31

    def _maybe_flush(self, force: bool = False) -> None:
        if self._chunk_started is None:
            return
        if (force or self._chunk_bytes >= self.chunk_size
                or time.monotonic() - self._chunk_started >= self.flush_interval):
            self._writer.flush()       # closes the chunk, writes it and flushes the file object
            self._fh.flush()
            self._chunk_bytes = 0
            self._chunk_started = None
            self.chunks += 1
            if self.on_chunk is not None:
                try:
                    self.on_chunk(self.chunks, self.written)
                except Exception as e:
                    self.last_error = f"on_chunk: {type(e).__name__}: {e}"

    def _run(self) -> None:
        q = self._queue
        try:
            while True:
                if not self._running.is_set() and not self._closing:
                    self._running.wait(0.05)
                    continue
                try:
                    item = q.popleft()
                except IndexError:
                    if self._closing:
                        break
                    self._maybe_flush()
                    time.sleep(self._poll)
                    continue
                if item[0] is _FLUSH:
                    self._maybe_flush(force=True)
                    continue
                self._write(item)
                self._maybe_flush()
            self._maybe_flush(force=True)   # the last chunk, counted and reported like the others
            if self.session_end is not None:
                self._writer.add_metadata(SESSION_END_METADATA, {str(k): str(v) for k, v in self.session_end.items()})
            self._writer.finish()
        except BaseException as e:  # I/O failure: stop; close() re-raises
            self.error = e
            self._closing = True
        finally:
            try:
                self._fh.close()
            except OSError as e:
                self.error = self.error or e

    # ---------------------------------------------------------------- closing
    def close(self) -> None:
        """Drain the queue, finish the file (summary with every channel) and close it. Idempotent."""
        with self._close_lock:
            if self._closed:
                return
            self._closing = True
            self._running.set()
            self._thread.join()
            self._closed = True
        if self.error is not None:
            raise OSError(f"MCAP recorder {self.path}: writer failed: {self.error}") from self.error

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -------------------------------------------------------------------- reading
# (the walk over a file's records, damaged or not, is bridge.mcap_scan; what it could not read is reported by
# RecordingInfo.damage and .health_line)

_FAULT_KEYS = ("reason_code", "reason", "message", "step", "sim_time", "coordinate")


class RecordedMessage(NamedTuple):
    log_time_ns: int
    sequence: int
    data: Any          # the decoded JSON message (dict), or raw bytes for non-JSON channels


@dataclass
class RecordingInfo:
    path: Path
    complete: bool                 # footer and summary present: the writer closed the file
    messages: int                  # messages read (recovered, for a damaged file)
    chunks: int                    # complete chunks read
    topics: dict[str, int] = field(default_factory=dict)   # messages per topic
    truncated_bytes: int = 0       # trailing bytes of an incomplete record that were discarded (a cut)
    note: str = ""                 # what the reader could not read, in words
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)   # MCAP metadata records by name
    channels: ChannelDictionary | None = None   # the recorded vehicle's channels (None: not recorded)
    cut: bool = False              # the file ends inside a record: truncated mid-file
    chunks_skipped: int = 0        # chunks that did not check out (bad CRC, compression or records)
    messages_lost: int | None = 0  # messages in what could not be read (None: unknown, nothing to estimate from)
    messages_lost_exact: bool = True   # False: messages_lost is an estimate (messages per byte of the chunks read)
    bytes_discarded: int = 0       # bytes not read: skipped chunks, broken framing, the cut-off end
    last_status: dict | None = None    # the last status message recorded (rtsim/<vehicle>/status), decoded

    def __post_init__(self):
        """The channel dictionary's record becomes ``channels``; ``metadata`` keeps the session's."""
        record = self.metadata.pop(CHANNELS_METADATA, None)
        if record is not None and self.channels is None:
            try:
                self.channels = ChannelDictionary.from_json(record.get("json", ""))
            except ValueError as exc:
                self.note = "; ".join(filter(None, (self.note, f"unreadable {CHANNELS_METADATA}: {exc}")))

    @property
    def damaged(self) -> bool:
        """Anything of the file could not be read, or the file was not closed by its writer."""
        return bool(not self.complete or self.cut or self.chunks_skipped or self.bytes_discarded
                    or self.messages_lost)

    @property
    def usable(self) -> bool:
        """At least one chunk (or message) could be read."""
        return self.chunks > 0 or self.messages > 0

    @property
    def session_end(self) -> dict:
        """How the recorded session ended: ``how`` from the rtsim.session_end record ("stopped",
        "model_fault", with the fault's fields); without it "closed, end not recorded" (a file closed by an
        rtsim that did not write it) or "not closed (killed or crashed)" with the last recorded status's
        ``run_state`` and ``model_fault``."""
        end = self.metadata.get(SESSION_END_METADATA)
        if end is not None:
            out = {"how": end.get("how", "unknown"), "recorded": True}
            fault = {k: end[k] for k in _FAULT_KEYS if k in end}
            if fault:
                out["model_fault"] = fault
            return out
        out = {"how": "closed, end not recorded" if self.complete else "not closed (killed or crashed)",
               "recorded": False}
        if not self.complete and self.last_status is not None:
            out["last_run_state"] = self.last_status.get("run_state")
            if self.last_status.get("model_fault"):
                out["model_fault"] = self.last_status["model_fault"]
        return out

    @property
    def damage(self) -> dict:
        """What a command reports of the file (``--json``): closed, cut, chunks read and skipped, messages
        lost (exact or an estimate), bytes discarded, how the session ended, and the reader's notes."""
        return {"damaged": self.damaged, "closed": self.complete, "cut": self.cut, "chunks_read": self.chunks,
                "chunks_skipped": self.chunks_skipped, "messages_read": self.messages,
                "messages_lost": self.messages_lost, "messages_lost_exact": self.messages_lost_exact,
                "bytes_discarded": self.bytes_discarded, "session_end": self.session_end, "notes": self.note}

    def health_line(self) -> str:
        """The damage report in one line (the first line a command prints about the file)."""
        parts = []
        if self.chunks_skipped:
            parts.append(f"{self.chunks_skipped} unreadable chunk{'s' * (self.chunks_skipped != 1)} skipped")
        lost = self.messages_lost
        if lost is None:
            parts.append("an unknown number of messages lost")
        elif lost:
            parts.append(f"{'' if self.messages_lost_exact else 'about '}{lost} messages lost")
        if self.bytes_discarded:
            parts.append(f"{self.bytes_discarded} bytes discarded")
        if self.cut:
            parts.append(f"cut off mid-record ({self.truncated_bytes} bytes of the last record)")
        if not self.complete:
            parts.append("not closed (no summary: the writer was killed, crashed or is still writing)")
        end = self.session_end
        how = end["how"].replace("_", " ")
        if not end["recorded"] and end.get("last_run_state"):
            how += f", last status {end['last_run_state']}"
        fault = end.get("model_fault")
        if fault:
            how += ": " + _fault_text(fault)
        lost_any = self.chunks_skipped or lost is None or lost or self.bytes_discarded or self.cut
        head = (("DAMAGED recording: " if lost_any else "UNCLOSED recording: ") + ", ".join(parts) if parts
                else "recording intact, closed")
        return (f"{head}; {self.chunks} chunks, {self.messages} messages read; session ended: {how}")


def _fault_text(fault: dict) -> str:
    """A model fault's fields in words: "non_finite_force (code 3): <message> at step 2525, t = 2.525 s,
    coordinate rack" (the fields present)."""
    reason, code = fault.get("reason"), fault.get("reason_code")
    head = " ".join(filter(None, (str(reason) if reason not in (None, "") else "",
                                  f"(code {code})" if code not in (None, "") else "")))
    where = ", ".join(filter(None, (f"step {fault['step']}" if fault.get("step") not in (None, "") else "",
                                    f"t = {fault['sim_time']} s" if fault.get("sim_time") not in (None, "") else "",
                                    f"coordinate {fault['coordinate']}" if fault.get("coordinate") else "")))
    text = ": ".join(filter(None, (head, str(fault.get("message") or ""))))
    return " at ".join(filter(None, (text or "model fault", where)))


def _decode(encoding: str, data: bytes):
    if encoding == "json":
        return json.loads(bytes(data))
    return bytes(data)


_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_MESSAGE = struct.Struct("<HIQ")          # channel id, sequence, log time (publish time follows)
_RECORD = struct.Struct("<BQ")
_OP_CHANNEL, _OP_MESSAGE = 0x04, 0x05


def _is_status(topic: str) -> bool:
    return topic.startswith("rtsim/") and topic.endswith("/status") and topic.count("/") == 2


class _Topics:
    """A scan's consumer (bridge.mcap_scan): channels, metadata and the messages of the channels ``want``
    selects, kept per chunk all or nothing; ``decode`` True decodes them (RecordedMessage), False keeps
    their bytes and log times. The last status message of any vehicle is kept in every case."""

    def __init__(self, want, decode: bool):
        self.want, self.decode = want, decode
        self.channels: dict[int, tuple[str, str]] = {}       # id -> (topic, message encoding)
        self.wanted: dict[int, tuple[list, list]] = {}
        self.counts: dict[str, int] = {}
        self.meta: dict[str, dict[str, str]] = {}
        self.status: tuple[int, bytes] | None = None         # (log time, bytes) of the last status message
        self._status_ids: set[int] = set()

    def channel(self, buf, body: int) -> None:
        cid = _U16.unpack_from(buf, body)[0]
        topic, p = string(buf, body + 4)
        encoding, _ = string(buf, p)
        if cid in self.channels:
            return
        self.channels[cid] = (topic, encoding)
        self.counts.setdefault(topic, 0)
        if self.want(topic):
            self.wanted[cid] = ([], [])
        if _is_status(topic):
            self._status_ids.add(cid)

    def metadata(self, name: str, values: dict) -> None:
        self.meta[name] = values

    def _records(self, rec, start: int, end: int) -> tuple[int, int]:
        """Take the records of [start, end) of ``rec`` (a chunk's, or one record of the file) all or nothing:
        ValueError (or struct.error) for records that do not parse or a message that does not decode, and
        then nothing of them is kept. Returns (messages kept, orphans: messages on an unknown channel)."""
        kept = orphans = 0
        pos = start
        per_cid: dict[int, int] = {}
        rows: list = []
        status = None
        channels, wanted, status_ids, decode = self.channels, self.wanted, self._status_ids, self.decode
        unpack_rec, unpack_msg = _RECORD.unpack_from, _MESSAGE.unpack_from
        while pos + 9 <= end:
            op, length = unpack_rec(rec, pos)
            body = pos + 9
            pos = body + length
            if pos > end:
                raise ValueError("record runs past its chunk")
            if op == _OP_MESSAGE:
                cid, seq, t = unpack_msg(rec, body)
                if cid not in channels:
                    orphans += 1
                    continue
                kept += 1
                per_cid[cid] = per_cid.get(cid, 0) + 1
                w = wanted.get(cid)
                if w is not None:
                    data = rec[body + 22:pos]
                    rows.append((w, t, RecordedMessage(t, seq, _decode(channels[cid][1], data)) if decode
                                 else bytes(data)))
                if cid in status_ids:
                    status = (t, bytes(rec[body + 22:pos]))
            elif op == _OP_CHANNEL:
                self.channel(rec, body)
        if pos != end:
            raise ValueError("chunk ends inside a record")
        for cid, n in per_cid.items():
            self.counts[channels[cid][0]] += n
        for w, t, v in rows:
            w[0].append(t)
            w[1].append(v)
        if status is not None:
            self.status = status
        return kept, orphans

    def chunk(self, data: bytes) -> tuple[int, int]:
        return self._records(memoryview(data), 0, len(data))

    def message(self, buf, pos: int, end: int) -> None:
        self._records(buf, pos, end)

    def info(self, path: Path, sc) -> RecordingInfo:
        lost, exact = sc.messages_lost
        status = None
        if self.status is not None:
            try:
                status = json.loads(self.status[1])
            except ValueError:
                status = None
        return RecordingInfo(path, sc.closed, sc.messages, sc.chunks, dict(self.counts),
                             truncated_bytes=sc.trailing_bytes, note=_notes(sc.notes), metadata=self.meta,
                             cut=sc.cut, chunks_skipped=sc.chunks_skipped, messages_lost=lost,
                             messages_lost_exact=exact, bytes_discarded=sc.bytes_discarded,
                             last_status=status if isinstance(status, dict) else None)


def _notes(notes: list[str], most: int = 6) -> str:
    """The reader's notes in one string, the first ``most`` of them and how many more."""
    text = "; ".join(notes[:most])
    return text + (f"; and {len(notes) - most} more" if len(notes) > most else "")


def _file_bytes(path: Path) -> bytes:
    """The file's bytes once its magic is checked; ConfigError when it cannot be read or is not MCAP."""
    try:
        buf = path.read_bytes()
    except OSError as e:
        raise ConfigError(f"{path}: cannot open recording: {e.strerror or e}") from e
    if not buf:
        raise ConfigError(f"{path}: empty file (not an MCAP recording)")
    if not MCAP_MAGIC.startswith(buf[:len(MCAP_MAGIC)]):
        raise ConfigError(f"{path}: not an MCAP file (magic {buf[:8]!r}, expected {MCAP_MAGIC!r})")
    return buf


def read_recording(path: str | Path):
    """Read a recording: ``(messages, info)`` with ``messages[topic]`` the list of
    :class:`RecordedMessage` in file (recording) order and ``info`` a :class:`RecordingInfo`.

    Any file that starts with the MCAP magic is read as far as it can be (bridge.mcap_scan): a file whose
    writer was killed (no summary, last chunk cut), cut short, or with damaged chunks gives every chunk that
    checks out (whole, CRC-verified), and ``info`` says what was lost (``damage``, ``health_line``); it
    never raises for damage. Raises ConfigError when the file cannot be read, is empty or is not MCAP."""
    path = Path(path)
    buf = _file_bytes(path)
    if len(buf) < len(MCAP_MAGIC):
        return {}, RecordingInfo(path, False, 0, 0, truncated_bytes=len(buf), note="truncated magic", cut=True,
                                 bytes_discarded=len(buf), messages_lost=None, messages_lost_exact=False)
    reader = _Topics(lambda _t: True, decode=True)
    sc = scan(buf, reader)
    out = {reader.channels[cid][0]: w[1] for cid, w in reader.wanted.items()}
    return out, reader.info(path, sc)


# -------------------------------------------------------------------- reading a few topics fast


class TopicData(NamedTuple):
    log_time_ns: Any        # numpy int64 array, one per message, in file order
    data: list              # the messages' bytes as recorded (JSON text for the service's JSON topics)


def read_topics(path: str | Path, topics) -> tuple[dict[str, TopicData], RecordingInfo]:
    """The messages of a few ``topics`` of a recording (names, or a function of a name saying whether it is
    wanted), undecoded: ``{topic: TopicData}`` and the recording's :class:`RecordingInfo` (metadata, channel
    dictionary and damage report included).

    What `read_recording` gives for those topics, much faster on a session's recording (a 45 MB file with
    every CAN frame, three topics of it: 8.3-8.8 s -> 0.35 s here): nothing is decoded (a page that parses
    JSON itself gets the bytes as recorded). A damaged file gives what `read_recording` gives (the same walk,
    bridge.mcap_scan). Raises ConfigError when the file cannot be read, is empty or is not MCAP."""
    import numpy as np

    path = Path(path)
    buf = _file_bytes(path)
    want = topics if callable(topics) else set(topics).__contains__
    reader = _Topics(want, decode=False)
    if len(buf) < len(MCAP_MAGIC):
        return {}, RecordingInfo(path, False, 0, 0, truncated_bytes=len(buf), note="truncated magic", cut=True,
                                 bytes_discarded=len(buf), messages_lost=None, messages_lost_exact=False)
    sc = scan(buf, reader)
    out = {reader.channels[cid][0]: TopicData(np.array(w[0], dtype=np.int64), w[1])
           for cid, w in reader.wanted.items()}
    return out, reader.info(path, sc)
