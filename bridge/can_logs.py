"""CAN frame logs in and out: our MCAP recordings and python-can's log formats, as one frame list.

``read_frames(path, direction=None)`` returns a :class:`FrameLog` (a list of :class:`Frame`, sorted
by time, stable) from

* ``.mcap``  rtsim recordings (``bridge.mcap_recorder``): topics ``rtsim/<vid>/can/rx`` (frames the
  simulator received = ECU commands, direction ``"rx"``) and ``rtsim/<vid>/can/tx`` (frames the
  simulator sent = sensor and status frames, ``"tx"``); the frame time is the message's ``time``
  field (s). A recording cut short by SIGKILL is recovered as ``read_recording`` does (``note``).
* ``.asc`` (Vector ASCII), ``.blf`` (Vector binary), ``.log`` (``candump -L``), ``.csv``
  (python-can's CSV) through python-can's readers, also gzip-compressed (``.asc.gz`` ...). The
  direction is the *logger's* (Rx/Tx in ASC and BLF, the ``R``/``T`` suffix of candump lines);
  ``None`` where the format does not record it (CSV, candump lines without a suffix). A log taken
  on the simulator's side of the bus therefore means the same as a recording; one taken at the ECU
  has rx and tx swapped.

Times are in s relative to the first data frame of the file (all directions), so the rx and tx
frames of one file share a time base however they are filtered. Error frames and remote frames are
skipped and counted in ``FrameLog.skipped``. Every failure (missing file, unknown suffix, a line or
record python-can cannot parse, a file without any data frame) raises ``RtsimError`` in one line
naming the file, the line (text formats) or record (BLF, MCAP) and what is wrong.

``command_inputs(frames, codec=None)`` runs the ECU command frames through
``bridge.can_codec.CommandReceiver`` (CRC, alive counter, DLC and range checks exactly as the
service applies them) and returns the step-held command series with every rejection counted and
listed (:class:`CommandInputs`). ``write_frames(path, frames)`` writes ``.asc``, ``.blf``, ``.log``
or ``.csv`` with python-can's writers (for tests and conversions).
"""
from __future__ import annotations

import gzip
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, NamedTuple

import numpy as np

from rtsim.errors import RtsimError

LOG_SUFFIXES = (".asc", ".blf", ".log", ".csv")
SUFFIXES = (".mcap",) + LOG_SUFFIXES
DIRECTIONS = ("rx", "tx")


class Frame(NamedTuple):
    """One CAN data frame: ``time`` s (relative to the file's first frame), ``can_id`` the
    arbitration id, ``data`` the payload, ``direction`` ``"rx"``/``"tx"``/``None`` (see the module
    docstring), ``is_extended`` 29-bit id, ``is_fd`` CAN FD frame."""

    time: float
    can_id: int
    data: bytes
    direction: str | None = None
    is_extended: bool = False
    is_fd: bool = False


class FrameLog(list):
    """A list of :class:`Frame` plus where it came from: ``path``, ``format`` (the suffix),
    ``skipped`` (``{"error_frames": n, "remote_frames": n}``), ``total`` (data frames in the file
    before the direction filter), ``topics`` (MCAP: topics read), ``note`` (recovery notes; for a
    damaged MCAP its damage report) and ``recording`` (MCAP: the reader's RecordingInfo, else None)."""

    def __init__(self, frames=(), *, path: Path | None = None, format: str = "", skipped=None,
                 total: int = 0, topics=(), note: str = "", recording=None):
        super().__init__(frames)
        self.path = path
        self.format = format
        self.skipped = dict(skipped or {"error_frames": 0, "remote_frames": 0})
        self.total = total
        self.topics = tuple(topics)
        self.note = note
        self.recording = recording

    def span(self) -> float:
        """Time from the first to the last frame, s (0 for fewer than two frames)."""
        return self[-1].time - self[0].time if len(self) > 1 else 0.0

    def ids(self) -> list[int]:
        """The distinct arbitration ids, sorted."""
        return sorted({f.can_id for f in self})


def _suffix(path: Path) -> tuple[str, bool]:
    """(format suffix, gzip) of a file name such as ``x.asc`` or ``x.asc.gz``."""
    sfx = [s.lower() for s in path.suffixes]
    if sfx and sfx[-1] == ".gz":
        return (sfx[-2] if len(sfx) >= 2 else ""), True
    return (sfx[-1] if sfx else ""), False


def _check_direction(direction: str | None) -> str | None:
    if direction in (None, "all"):
        return None
    if direction not in DIRECTIONS:
        raise RtsimError(f"direction {direction!r}: expected 'rx', 'tx', 'all' or None")
    return direction


# --------------------------------------------------------------------------------------------------
# reading

def read_frames(path: str | Path, direction: str | None = None, *, vehicle: str | None = None) -> FrameLog:
    """All CAN data frames of ``path`` (``.mcap``, ``.asc``, ``.blf``, ``.log``, ``.csv``, or those
    gzip-compressed), sorted by time, times in s from the file's first data frame. ``direction``
    ``"rx"``/``"tx"`` keeps only those frames (frames of unknown direction are dropped then);
    ``None``/``"all"`` keeps all. ``vehicle`` picks the vehicle id of an MCAP recording holding
    several (required then). Raises RtsimError (see the module docstring)."""
    path = Path(path)
    direction = _check_direction(direction)
    kind, gz = _suffix(path)
    if kind not in SUFFIXES or (gz and kind == ".mcap"):
        raise RtsimError(f"{path}: unknown CAN log format {''.join(path.suffixes) or '(no suffix)'!r}; "
                         f"expected one of {', '.join(SUFFIXES)} (log formats also as .gz)")
    if not path.is_file():
        raise RtsimError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise RtsimError(f"{path}: empty file")
    recording = None
    if kind == ".mcap":
        raw, skipped, topics, recording = _read_mcap(path, vehicle)
        note = recording.health_line() if recording.damaged else recording.note
    else:
        raw, skipped, note = _read_log(path, kind, gz)
        topics = ()
    if not raw:
        what = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in skipped.items() if n)
        raise RtsimError(f"{path}: no CAN data frames in the file" + (f" ({what} skipped)" if what else "")
                         + (f"; {note}" if note else ""))
    raw.sort(key=lambda f: f.time)            # stable: file order among equal times
    t0 = raw[0].time
    frames = [f._replace(time=f.time - t0) for f in raw if direction is None or f.direction == direction]
    return FrameLog(frames, path=path, format=kind, skipped=skipped, total=len(raw), topics=topics,
                    note=note, recording=recording)


def _read_mcap(path: Path, vehicle: str | None):
    from bridge.mcap_recorder import read_recording

    messages, info = read_recording(path)      # ConfigError (an RtsimError) if not MCAP
    by_vid: dict[str, dict[str, list]] = {}
    for topic, msgs in messages.items():
        parts = topic.split("/")
        if len(parts) == 4 and parts[0] == "rtsim" and parts[2] == "can" and parts[3] in DIRECTIONS:
            by_vid.setdefault(parts[1], {})[parts[3]] = msgs
    if not by_vid:
        raise RtsimError(f"{path}: no CAN topics (rtsim/<vehicle>/can/rx|tx) in the recording; topics: "
                         f"{', '.join(sorted(messages)) or 'none'}"
                         + (f"; {info.health_line()}" if info.damaged else ""))
    if vehicle is None:
        if len(by_vid) > 1:
            raise RtsimError(f"{path}: CAN topics of several vehicles ({', '.join(sorted(by_vid))}); "
                             f"pick one with vehicle=")
        vehicle = next(iter(by_vid))
    elif vehicle not in by_vid:
        raise RtsimError(f"{path}: no CAN topics of vehicle {vehicle!r}; vehicles: {', '.join(sorted(by_vid))}")
    out: list[Frame] = []
    topics = []
    for d in DIRECTIONS:
        msgs = by_vid[vehicle].get(d)
        if msgs is None:
            continue
        topic = f"rtsim/{vehicle}/can/{d}"
        topics.append(topic)
        for k, m in enumerate(msgs):
            out.append(_mcap_frame(path, topic, k, m, d))
    return out, {"error_frames": 0, "remote_frames": 0}, tuple(topics), info


def _mcap_frame(path: Path, topic: str, k: int, m, direction: str) -> Frame:
    msg = m.data
    try:
        can_id = int(msg["id"])
        data = bytes.fromhex(msg["data"])
        t = float(msg["time"]) if msg.get("time") is not None else m.log_time_ns * 1e-9
        if "dlc" in msg and int(msg["dlc"]) != len(data):
            raise ValueError(f"dlc {msg['dlc']} but {len(data)} data bytes")
        if not (0 <= can_id < (1 << 29)) or not math.isfinite(t):
            raise ValueError(f"id {can_id} or time {t} out of range")
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise RtsimError(f"{path}: {topic} message {k}: not a CAN frame ({type(exc).__name__}: {exc})") from None
    return Frame(t, can_id, data, direction, bool(msg.get("extended")) or can_id > 0x7FF,
                 bool(msg.get("fd")) or len(data) > 8)


class _Lines:
    """A text file that counts the lines python-can's readers take from it (for error messages)."""

    def __init__(self, fh):
        self._fh = fh
        self.n = 0
        self.last = ""

    def __iter__(self):
        return self

    def __next__(self) -> str:
        line = next(self._fh)
        self.n += 1
        self.last = line
        return line

    def readline(self) -> str:
        line = self._fh.readline()
        if line:
            self.n += 1
            self.last = line
        return line

    def close(self) -> None:
        self._fh.close()

    @property
    def closed(self) -> bool:
        return self._fh.closed


def _reader(kind: str, fh):
    import can

    readers = {".asc": can.ASCReader, ".blf": can.BLFReader, ".log": can.CanutilsLogReader,
               ".csv": can.CSVReader}
    return readers[kind](fh)


def _read_log(path: Path, kind: str, gz: bool):
    try:
        import can  # noqa: F401
    except ImportError:
        raise RtsimError(f"{path}: reading CAN logs needs python-can (`pip install python-can`)") from None
    binary = kind == ".blf"
    try:
        raw = gzip.open(path, "rb") if gz else open(path, "rb")
    except OSError as exc:
        raise RtsimError(f"{path}: cannot open: {exc.strerror or exc}") from None
    lines = None
    fh = raw if binary else io.TextIOWrapper(raw, encoding="utf-8", errors="replace", newline=None)
    if not binary:
        fh = lines = _Lines(fh)
    skipped = {"error_frames": 0, "remote_frames": 0}
    out: list[Frame] = []
    note = ""
    try:
        try:
            reader = _reader(kind, fh)
        except Exception as exc:  # noqa: BLE001  (BLFParseError, struct.error, ...)
            raise RtsimError(f"{path}: not a {kind} file ({_why(exc)})") from None
        it = iter(reader)
        while True:
            try:
                msg = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001  (ValueError, BLFParseError, zlib.error, OSError ...)
                where = (f"line {lines.n}: {lines.last.strip()[:60]!r}" if lines is not None
                         else f"record after frame {len(out) + sum(skipped.values())}")
                raise RtsimError(f"{path}: {where}: cannot parse ({_why(exc)})") from None
            if msg.is_error_frame:
                skipped["error_frames"] += 1
                continue
            if msg.is_remote_frame:
                skipped["remote_frames"] += 1
                continue
            if msg.timestamp is None or not math.isfinite(msg.timestamp):
                where = f"line {lines.n}" if lines is not None else f"frame {len(out)}"
                raise RtsimError(f"{path}: {where}: frame without a valid time stamp ({msg.timestamp})")
            direction = "rx" if msg.is_rx else "tx"
            if lines is not None and kind in (".log", ".csv"):
                tail = lines.last.rstrip()[-2:].lower()
                if kind == ".csv" or tail not in (" r", " t"):
                    direction = None            # the format/line does not say
            out.append(Frame(float(msg.timestamp), int(msg.arbitration_id), bytes(msg.data), direction,
                             bool(msg.is_extended_id), bool(msg.is_fd) or len(msg.data) > 8))
        if binary:
            count = getattr(reader, "object_count", 0)
            if count and count > len(out) + sum(skipped.values()):
                note = (f"the BLF header announces {count} objects, {len(out) + sum(skipped.values())} "
                        f"CAN frames read (truncated file, or objects other than CAN frames)")
        if not out and lines is not None:
            note = f"{lines.n} lines read, none is a CAN data frame"
    finally:
        try:
            fh.close()
        except Exception:  # noqa: BLE001
            pass
    return out, skipped, note


def _why(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    name = type(exc).__name__
    if name == "error":                       # struct.error, zlib.error
        name = f"{type(exc).__module__}.error"
    return f"{name}: {text}" if text else name


# --------------------------------------------------------------------------------------------------
# writing

def write_frames(path: str | Path, frames: Iterable[Frame], start: float = 0.0) -> int:
    """Write ``frames`` to ``.asc``, ``.blf``, ``.log`` (candump -L) or ``.csv`` with python-can's
    writers; returns the number written. Frame times are written as ``start + time`` (s; ``start``
    = 0 keeps them relative, exact to the format's resolution: 1 us for ASC and candump; pass
    ``time.time()`` for real dates in the headers). Direction ``"tx"`` is written as Tx, ``"rx"``
    and ``None`` as Rx (the formats have no "unknown"; CSV has no direction at all)."""
    import can

    path = Path(path)
    kind, gz = _suffix(path)
    writers = {".asc": can.ASCWriter, ".blf": can.BLFWriter, ".log": can.CanutilsLogWriter,
               ".csv": can.CSVWriter}
    if kind not in writers or gz:
        raise RtsimError(f"{path}: cannot write {''.join(path.suffixes) or '(no suffix)'!r}; "
                         f"expected one of {', '.join(writers)}")
    n = 0
    try:
        writer = writers[kind](str(path))
    except OSError as exc:
        raise RtsimError(f"{path}: cannot write: {exc.strerror or exc}") from None
    try:
        for f in frames:
            writer.on_message_received(can.Message(
                timestamp=start + f.time, arbitration_id=f.can_id, data=f.data,
                is_extended_id=f.is_extended or f.can_id > 0x7FF, is_fd=f.is_fd,
                is_rx=f.direction != "tx", channel=0 if kind == ".asc" else None))
            n += 1
    finally:
        writer.stop()
    return n


# --------------------------------------------------------------------------------------------------
# command inputs

class Rejection(NamedTuple):
    time: float       # s
    can_id: int
    kind: str         # dlc, crc, counter, range


@dataclass
class CommandInputs:
    """The ECU's commands as the service would have taken them from a frame log.

    ``times``: s, one sample per command frame (accepted or not); ``values[name]`` (every name of
    ``rtsim.channels.COMMAND_NAMES``, in its SI unit): the latest accepted value at each sample,
    step-held, NaN before the command's first valid frame; ``accepted``: frames accepted;
    ``rejected``: every rejected frame (time, id, kind); ``counters``: the ``CommandReceiver``'s
    counters after the last frame; ``other_frames``: frames whose id is no command frame (not
    decoded)."""

    times: np.ndarray
    values: dict[str, np.ndarray]
    accepted: int
    rejected: list[Rejection] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)
    other_frames: int = 0

    def value_at(self, name: str, t: float) -> float:
        """Step-held value of command ``name`` at time ``t`` (s); NaN before its first valid frame."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return float(self.values[name][k]) if k >= 0 else math.nan

    def summary(self) -> str:
        bad = {k: self.counters.get(k, 0) for k in ("dlc", "crc", "counter", "range") if self.counters.get(k, 0)}
        rej = ", ".join(f"{k} {n}" for k, n in bad.items()) or "none"
        return (f"{len(self.times)} command frames: {self.accepted} accepted, {len(self.rejected)} rejected "
                f"({rej}); {self.other_frames} other frames ignored")


def command_inputs(frames: Iterable[Frame], codec=None, *, receiver=None) -> CommandInputs:
    """Decode the ECU command frames among ``frames`` (any direction; filter with
    ``read_frames(..., direction=)`` first when needed) through a fresh
    ``CommandReceiver(codec)`` (``codec``: a Codec, a DBC path or None for configs/can/xbw.dbc), or
    through ``receiver`` when given (custom clamp/timeouts). Rejected frames are counted by kind and
    listed, never used."""
    from bridge.can_codec import REJECT_KINDS, CommandReceiver

    rx = receiver if receiver is not None else CommandReceiver(codec)
    ids = {rx.codec.command_plan(n)[0].frame_id for n in rx.names}
    names = rx.names
    times: list[float] = []
    rows: list[tuple] = []
    rejected: list[Rejection] = []
    other = accepted = 0
    nan = math.nan
    for f in sorted(frames, key=lambda f: f.time):
        if f.can_id not in ids or f.is_extended:
            other += 1
            continue
        before = [rx.counters[k] for k in REJECT_KINDS]
        if rx.receive(f.can_id, f.data, f.time):
            accepted += 1
        else:
            kind = next((k for k, b in zip(REJECT_KINDS, before) if rx.counters[k] != b), "unknown")
            rejected.append(Rejection(f.time, f.can_id, kind))
        times.append(f.time)
        rows.append(tuple(nan if v is None else v for v in rx.value))
    arr = np.array(rows, dtype=float).reshape(len(rows), len(names))
    values = {n: arr[:, i].copy() for i, n in enumerate(names)}
    return CommandInputs(np.array(times, dtype=float), values, accepted, rejected, dict(rx.counters), other)
