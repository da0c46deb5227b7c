"""CAN codec of a simulated vehicle, derived from its DBC (the X-by-wire car's: ``configs/can/xbw.dbc``).

The DBC is the single source of truth: it is loaded with cantools once, and everything the codec
needs (frame ids, DLCs, cycle times, signal positions, scales, ranges, which raw values wrap, the
E2E data IDs, the status enum) is read from it and precomputed into small tuples, so that the
per-frame hot path is plain integer arithmetic on one 64-bit little-endian word (all signals are
Intel byte order, whose start bit is the LSB position in that word).

Sensor frames (``Codec.encode_sensors``): every sensor channel of the vehicle's channel dictionary
(``Codec(dbc_path, channels)``; default the rear-drive car's, rtsim.channels.CAR) in exactly one
SIM frame, each frame with a ``sim_time_ms`` stamp (ms, modulo 65536). Values outside a signal's
[minimum, maximum] are sent saturated at the limit (as a real sensor saturates; NaN is replaced by
0.0 and then clamped into the range, infinities saturate); signals
with the DBC attribute ``SigWrap = 1`` (the cumulative wheel angles, time stamps, rolling counters)
wrap modulo 2**length instead.

Command frames (``CommandReceiver``), end-to-end checks in this order, each failure counted once:

1. unknown arbitration id: ignored, counted in ``counters["unknown_id"]`` (not a command error);
2. DLC different from the DBC length: ``"dlc"``;
3. CRC-8 SAE J1850 (poly 0x1D, init 0xFF, final xor 0xFF) over the frame's E2EDataID byte followed
   by every byte except the CRC byte (bytes 0-6) != byte 7: ``"crc"``;
4. the alive counter (4 bit), as the receiver of AUTOSAR E2E profiles 1 and 2 checks it. With d =
   (counter - reference counter) mod 16, d == 1 or d == 2 is in sequence (at most one frame lost,
   ``max_counter_step``). A repeated counter (d == 0) is never taken, whatever the time since the last
   good frame: ``"counter"`` and ``"counter_repeated"`` (a frozen sender sending the same frame forever
   gets nothing after its first frame). A jump (d > 2) is ``"counter"`` and ``"counter_jump"``. A jump,
   and the first frame after a time-out (no value taken for more than the time-out, whatever its
   counter), set the reference counter and start a re-synchronisation: the next ``E2ESyncCounter``
   frames in sequence (a DBC attribute per command frame) are checked but not taken, counted as
   ``"sync"``, and the frame after them is taken (a repeat within them restarts the count, a jump or a
   gap longer than the time-out restarts the re-synchronisation). So after a time-out the sender's
   first frame and the next E2ESyncCounter ones in sequence are not taken. The session's first frame
   (and, until a value has been taken, any frame that does not repeat the counter) is taken at once;
5. value outside the DBC [minimum, maximum]: ``"range"`` (the frame is authentic, so its counter is
   still taken as the reference). Signals named in ``clamp`` (empty by default) are clamped to the
   range and accepted instead, counted in ``counters["clamped"]``.

Before these, the frame's format: a frame with a command's (or SIM_STEP_REQ's) id that is not a classic
data frame with a standard id (extended id, remote frame, CAN FD) is never applied, counted as
``"format"``. A standard-id data frame with one of the simulator's own ids (``Codec.own_frame_ids``)
that it did not send is counted as ``"foreign_frames"`` (a second simulator on the bus) by the service's
step (``rtsim.service.kernel``).

``receive`` never raises, whatever the id, length or bytes. The watchdog ``check_timeouts(t)`` flags
a command whose last valid frame is older than its timeout (3 DBC cycle times by default; before
the first frame, counted from ``t0``): with frames taken at t_last and a 30 ms time-out, the value
at t_last + 30 ms is still the command's, from the first step after it the safe value applies. It
returns the values to apply: the latest valid value, or
when timed out (or never received) the safe value: throttle 0, brake ``hold_pressure``, steering
held at its last valid value (0 if none). Flags clear on the next valid frame.

Run ``python -m bridge.can_codec`` for per-frame encode/decode times.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable, Mapping, NamedTuple, Sequence

import numpy as np

from rtsim.channels import CAR, ChannelDictionary
from rtsim.configfile import note_read
from rtsim.errors import ConfigError

from . import can_e2e as e2e

DEFAULT_DBC = Path(__file__).resolve().parent.parent / "configs" / "can" / "xbw.dbc"

TIME_SIGNAL = "sim_time_ms"
STATUS_FRAME = "SIM_STATUS"
DIAG_FRAME = "SIM_DIAG"               # diagnostics, sent right after SIM_STATUS: model fault reason, E2E counters
STEP_REQUEST_FRAME = "SIM_STEP_REQ"   # lockstep: ECU asks for n steps (event frame, E2E protected)
STEP_ACK_FRAME = "SIM_STEP_ACK"       # lockstep: SIM answers with the time reached (event frame)
EVENT_FRAMES = frozenset((STEP_REQUEST_FRAME, STEP_ACK_FRAME))
#: the status frame's fault flags (the by-wire cars'; Codec.faults): each command's watchdog, the bus, the
#: vehicle model (failed and frozen), a second simulator on the bus (frames with this simulator's ids)
FAULTS = ("throttle_timeout", "brake_timeout", "steer_timeout", "bus_error", "model", "second_sim")
SIM_FAULTS = ("bus_error", "model", "second_sim")   # after the commands' time-out flags, in every DBC
REJECT_KINDS = ("dlc", "crc", "counter", "range")
#: the SIM_DIAG signals, in the order the compiled step hands them to ``pack_frames`` (after the status values)
DIAG_SOURCES = ("model_fault_reason", "rejected_repeated", "rejected_jump", "rejected_sync", "rejected_format",
                "foreign_frames", "accepted_frames")
#: What the watchdog applies when a command times out.
SAFE_POLICY = {
    "throttle_angle_cmd": "zero",
    "brake_pressure_cmd": "hold_pressure",
    "steering_wheel_angle_cmd": "hold_last",
}
#: The values of the SIM_STATUS signals, in the order the compiled step hands them to ``pack_frames``.
STATUS_SOURCES = ("mode", "sim_time", "loop_overruns", *(f"fault_{f}" for f in FAULTS),
                  *(f"rejected_{k}" for k in REJECT_KINDS))
DEFAULT_HOLD_PRESSURE = 3000.0  # kPa, brake line pressure held when BRAKE_CMD times out
TIMEOUT_PERIODS = 3


# --------------------------------------------------------------------------------------------------
# CRC-8 SAE J1850: poly 0x1D, init 0xFF, no reflection, final xor 0xFF (check("123456789") = 0x4B)

def _make_table(poly: int = 0x1D) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


CRC8_TABLE = _make_table()


def crc8_j1850(data: bytes | bytearray | Iterable[int], init: int = 0xFF) -> int:
    """CRC-8 SAE J1850 of ``data`` (final xor 0xFF applied)."""
    crc = init
    table = CRC8_TABLE
    for b in data:
        crc = table[crc ^ b]
    return crc ^ 0xFF


# --------------------------------------------------------------------------------------------------
# Precomputed layouts

class _Sig(NamedTuple):
    name: str
    start: int
    length: int
    mask: int
    signed: bool
    factor: float
    offset: float
    minimum: float
    maximum: float
    raw_min: int
    raw_max: int
    wrap: bool
    unit: str


class FrameInfo(NamedTuple):
    frame_id: int
    name: str
    length: int
    period: float  # s, from GenMsgCycleTime
    sender: str
    signals: tuple[_Sig, ...]


def _attr(obj, name, default=0):
    dbc = getattr(obj, "dbc", None)
    if dbc is None or name not in dbc.attributes:
        return default
    return dbc.attributes[name].value


def _sig_layout(msg, s, where) -> _Sig:
    if s.byte_order != "little_endian":
        raise ConfigError(f"{where}: signal {msg.name}.{s.name} is not Intel byte order; only Intel is supported")
    if s.is_float or s.is_multiplexer or s.multiplexer_ids:
        raise ConfigError(f"{where}: signal {msg.name}.{s.name}: float or multiplexed signals are not supported")
    if s.start + s.length > 8 * msg.length:
        raise ConfigError(f"{where}: signal {msg.name}.{s.name} ends at bit {s.start + s.length}, beyond DLC {msg.length}")
    factor, offset = float(s.scale), float(s.offset)
    lo_bits = -(1 << (s.length - 1)) if s.is_signed else 0
    hi_bits = (1 << (s.length - 1)) - 1 if s.is_signed else (1 << s.length) - 1
    lo = float(s.minimum) if s.minimum is not None else lo_bits * factor + offset
    hi = float(s.maximum) if s.maximum is not None else hi_bits * factor + offset
    raw_min = max(lo_bits, math.ceil((lo - offset) / factor - 1e-6))
    raw_max = min(hi_bits, math.floor((hi - offset) / factor + 1e-6))
    if raw_min > raw_max:
        raise ConfigError(f"{where}: signal {msg.name}.{s.name}: range [{lo}, {hi}] does not fit {s.length} bits")
    return _Sig(s.name, s.start, s.length, (1 << s.length) - 1, bool(s.is_signed), factor, offset, lo, hi,
                raw_min, raw_max, bool(_attr(s, "SigWrap", 0)), s.unit or "")


def _frame_info(msg, where) -> FrameInfo:
    if msg.is_extended_frame or getattr(msg, "is_fd", False) or msg.length != 8:
        raise ConfigError(f"{where}: frame {msg.name} must be a classic standard-id 8-byte frame")
    if not msg.cycle_time and msg.name not in EVENT_FRAMES:
        raise ConfigError(f"{where}: frame {msg.name} has no GenMsgCycleTime")
    sigs = tuple(_sig_layout(msg, s, where) for s in msg.signals)
    return FrameInfo(msg.frame_id, msg.name, msg.length, (msg.cycle_time or 0) / 1000.0,
                     (msg.senders or [""])[0], sigs)


def _encode_raw(sig: _Sig, value: float) -> int:
    """Physical value to raw bits (saturated, or wrapped for SigWrap signals). Never raises."""
    if sig.wrap:
        if value != value or value in (math.inf, -math.inf):
            value = 0.0
        return round((value - sig.offset) / sig.factor) & sig.mask
    if not (sig.minimum <= value <= sig.maximum):
        value = 0.0 if value != value else (sig.minimum if value < sig.minimum else sig.maximum)
        value = min(max(value, sig.minimum), sig.maximum)
    raw = round((value - sig.offset) / sig.factor)
    raw = sig.raw_min if raw < sig.raw_min else (sig.raw_max if raw > sig.raw_max else raw)
    return raw & sig.mask


class Codec:
    """Everything derived from the DBC, plus the encoders of the SIM frames and of command frames."""

    def __init__(self, dbc_path: str | Path = DEFAULT_DBC, channels: ChannelDictionary = CAR):
        """The codec of a vehicle's DBC, checked against the vehicle's channel dictionary: every sensor
        channel is a signal of one sensor frame, in the dictionary's unit; every command has its frame."""
        import cantools  # imported here: rtsim itself never needs it

        where = str(dbc_path)
        self.channels = channels
        sensor_names, command_names = channels.sensor_names, channels.command_names
        note_read(dbc_path)
        try:
            self.db = cantools.database.load_file(str(dbc_path), strict=True)
        except Exception as exc:  # noqa: BLE001  (cantools raises many types)
            raise ConfigError(f"{where}: cannot load DBC: {exc}") from exc
        self.path = Path(dbc_path)
        self.frames: dict[str, FrameInfo] = {m.name: _frame_info(m, where) for m in self.db.messages}

        # sensor frames: SIM frames carrying the time stamp
        self.sensor_frames = tuple(f for f in self.frames.values()
                                   if f.sender == "SIM" and any(s.name == TIME_SIGNAL for s in f.signals))
        index = {n: i for i, n in enumerate(sensor_names)}
        units = {c.name: c.unit for c in channels.sensors}
        seen: dict[str, str] = {}
        plans = []
        for f in self.sensor_frames:
            tsig = next(s for s in f.signals if s.name == TIME_SIGNAL)
            items = []
            for s in f.signals:
                if s.name == TIME_SIGNAL:
                    continue
                if s.name not in index:
                    raise ConfigError(f"{where}: {f.name}.{s.name} is not a sensor channel of the vehicle "
                                      f"(its channels: {', '.join(sensor_names)})")
                if (s.unit or "") != units[s.name]:
                    raise ConfigError(f"{where}: {f.name}.{s.name} is in {s.unit!r}, the vehicle's channel in "
                                      f"{units[s.name]!r}")
                if s.name in seen:
                    raise ConfigError(f"{where}: sensor {s.name} is in both {seen[s.name]} and {f.name}")
                seen[s.name] = f.name
                items.append((index[s.name], s))
            plans.append((f.frame_id, tsig.start, tsig.mask, tuple(items)))
        missing = [n for n in sensor_names if n not in seen]
        if missing:
            raise ConfigError(f"{where}: sensor channels missing from the sensor frames: {', '.join(missing)}")
        self._sensor_plans = tuple(plans)
        self.sensor_frame_of = seen

        # status frame
        if STATUS_FRAME not in self.frames:
            raise ConfigError(f"{where}: no {STATUS_FRAME} frame")
        self.status_frame = self.frames[STATUS_FRAME]
        mode_sig = self.db.get_message_by_name(STATUS_FRAME).get_signal_by_name("mode")
        self.modes = {str(v): int(k) for k, v in (mode_sig.choices or {}).items()}

        # command frames: ECU frames with an E2EDataID; the value signal is the one named in COMMAND_NAMES
        self.command_frames: dict[str, FrameInfo] = {}
        self._cmd_plans: dict[str, tuple] = {}
        #: per command, the frames in sequence to pass before values are taken again after a time-out or a
        #: counter jump (the DBC attribute E2ESyncCounter of its frame)
        self.sync_counter: dict[str, int] = {}
        for msg in self.db.messages:
            if "ECU" not in (msg.senders or []) or msg.name in EVENT_FRAMES:
                continue
            f = self.frames[msg.name]
            data_id = _attr(msg, "E2EDataID", None)
            sync = _attr(msg, "E2ESyncCounter", None)
            vals = [s for s in f.signals if s.name in command_names]
            ctr = [s for s in f.signals if s.name.endswith("_counter")]
            crc = [s for s in f.signals if s.name.endswith("_crc")]
            if data_id is None or sync is None or len(vals) != 1 or len(ctr) != 1 or len(crc) != 1:
                raise ConfigError(f"{where}: command frame {f.name} needs E2EDataID, E2ESyncCounter, one "
                                  f"command signal, one *_counter and one *_crc signal")
            if crc[0].start != 8 * (f.length - 1) or crc[0].length != 8:
                raise ConfigError(f"{where}: {f.name}: the CRC must be the last byte")
            cmd_unit = next(c.unit for c in channels.commands if c.name == vals[0].name)
            if (vals[0].unit or "") != cmd_unit:
                raise ConfigError(f"{where}: {f.name}.{vals[0].name} is in {vals[0].unit!r}, the vehicle's "
                                  f"command in {cmd_unit!r}")
            prefix = ctr[0].name[: -len("_counter")]
            self.command_frames[vals[0].name] = f
            self._cmd_plans[vals[0].name] = (f, vals[0], ctr[0], crc[0], int(data_id), prefix)
            self.sync_counter[vals[0].name] = int(sync)
        if set(self.command_frames) != set(command_names):
            raise ConfigError(f"{where}: command frames carry {sorted(self.command_frames)}, "
                              f"expected {list(command_names)}")
        self._cmd_by_frame_name = {p[0].name: n for n, p in self._cmd_plans.items()}
        #: the status frame's fault flags: each command's watchdog (in the commands' order), the bus
        self.faults = (*(f"{self._cmd_plans[n][5]}_timeout" for n in command_names), *SIM_FAULTS)
        #: the SIM_STATUS values in the order the compiled step hands them to ``pack_frames``
        self.status_sources = ("mode", "sim_time", "loop_overruns", *(f"fault_{f}" for f in self.faults),
                               *(f"rejected_{k}" for k in REJECT_KINDS))
        status_names = {s_.name for s_ in self.status_frame.signals}
        missing = [n for n in self.status_sources if n not in status_names]
        if missing:
            raise ConfigError(f"{where}: {STATUS_FRAME} lacks the signals {', '.join(missing)}")
        if DIAG_FRAME not in self.frames:
            raise ConfigError(f"{where}: no {DIAG_FRAME} frame")
        self.diag_frame = self.frames[DIAG_FRAME]
        missing = [n for n in DIAG_SOURCES if n not in {s_.name for s_ in self.diag_frame.signals}]
        if missing:
            raise ConfigError(f"{where}: {DIAG_FRAME} lacks the signals {', '.join(missing)}")
        if self.diag_frame.period != self.status_frame.period:
            raise ConfigError(f"{where}: {DIAG_FRAME} must have the cycle time of {STATUS_FRAME}")
        reason_sig = self.db.get_message_by_name(DIAG_FRAME).get_signal_by_name("model_fault_reason")
        #: model failure status code -> its name (the DBC's VAL_ table of model_fault_reason)
        self.model_fault_reasons = {int(k): str(v) for k, v in (reason_sig.choices or {}).items()}

        # lockstep request/acknowledgement
        for name in EVENT_FRAMES:
            if name not in self.frames:
                raise ConfigError(f"{where}: no {name} frame")
        req = self.frames[STEP_REQUEST_FRAME]
        by = {s_.name: s_ for s_ in req.signals}
        self.step_request = req
        self._step_req_plan = (req, by["lockstep_steps"], by["lockstep_counter"], by["lockstep_crc"],
                               int(_attr(self.db.get_message_by_name(STEP_REQUEST_FRAME), "E2EDataID", 0)))
        ack = self.frames[STEP_ACK_FRAME]
        by = {s_.name: s_ for s_ in ack.signals}
        self.step_ack = ack
        self._step_ack_plan = (ack, by["lockstep_sim_time"], by["lockstep_ack_counter"])
        #: every id this simulator sends (sensor frames, status, diagnostics, lockstep acknowledgement): one of
        #: them received from the bus was sent by someone else (a second simulator: SIM_STATUS.fault_second_sim)
        self.own_frame_ids = tuple(sorted({f.frame_id for f in self.sensor_frames} | {
            self.status_frame.frame_id, self.diag_frame.frame_id, ack.frame_id}))

    # -- sensors ------------------------------------------------------------------------------------
    def encode_sensors(self, values: Mapping[str, float] | Sequence[float], sim_time: float
                       ) -> list[tuple[int, bytes]]:
        """All sensor frames for one sample. ``values``: a mapping by channel name or a sequence in
        the order of the dictionary's sensor channels (``channels.sensor_names``); ``sim_time`` in s
        (sent as ms modulo 65536)."""
        if isinstance(values, Mapping):
            values = [values[n] for n in self.channels.sensor_names]
        t_raw = int(round(sim_time * 1000.0))
        out = []
        for frame_id, tstart, tmask, items in self._sensor_plans:
            word = (t_raw & tmask) << tstart
            for i, s in items:
                v = float(values[i])
                if s.wrap or not (s.minimum <= v <= s.maximum):
                    raw = _encode_raw(s, v)
                else:
                    raw = round((v - s.offset) / s.factor)
                    raw = (s.raw_min if raw < s.raw_min else (s.raw_max if raw > s.raw_max else raw)) & s.mask
                word |= raw << s.start
            out.append((frame_id, word.to_bytes(8, "little")))
        return out

    # -- status -------------------------------------------------------------------------------------
    def encode_status(self, mode: str | int, sim_time: float, loop_overruns: int = 0,
                      faults: Iterable[str] | Mapping[str, bool] = (),
                      rejected: Mapping[str, int] | None = None) -> tuple[int, bytes]:
        """The SIM_STATUS frame. ``mode``: "realtime", "lockstep", "fast" (or its number);
        ``faults``: names from ``self.faults`` that are set (or a mapping name -> bool); ``rejected``:
        counts by kind ``dlc, crc, counter, range`` (e.g. ``CommandReceiver.counters``), sent modulo 64."""
        if isinstance(mode, str):
            if mode not in self.modes:
                raise ValueError(f"mode {mode!r}: expected one of {sorted(self.modes)}")
            mode = self.modes[mode]
        if isinstance(faults, Mapping):
            faults = [k for k, v in faults.items() if v]
        faults = set(faults)
        unknown = faults - set(self.faults)
        if unknown:
            raise ValueError(f"unknown fault flags {sorted(unknown)}; expected {self.faults}")
        rejected = rejected or {}
        vals = {"mode": mode, "sim_time": sim_time, "loop_overruns": loop_overruns}
        for f in self.faults:
            vals[f"fault_{f}"] = 1 if f in faults else 0
        for k in REJECT_KINDS:
            vals[f"rejected_{k}"] = rejected.get(k, 0)
        word = 0
        for s in self.status_frame.signals:
            word |= _encode_raw(s, float(vals.get(s.name, 0))) << s.start
        return self.status_frame.frame_id, word.to_bytes(8, "little")

    def encode_diag(self, model_fault_reason: int = 0, counts: Mapping[str, int] | None = None) -> tuple[int, bytes]:
        """The SIM_DIAG frame: the model's failure status code (0: none) and ``counts`` by DIAG_SOURCES
        name without the ``rejected_`` prefix (``repeated``, ``jump``, ``sync``, ``format``,
        ``foreign_frames``, ``accepted_frames``), each sent modulo 2**length."""
        counts = counts or {}
        vals = {"model_fault_reason": model_fault_reason}
        for name in DIAG_SOURCES[1:]:
            vals[name] = counts.get(name.removeprefix("rejected_"), 0)
        word = 0
        for s in self.diag_frame.signals:
            word |= _encode_raw(s, float(vals.get(s.name, 0))) << s.start
        return self.diag_frame.frame_id, word.to_bytes(8, "little")

    # -- commands -----------------------------------------------------------------------------------
    def _cmd_name(self, name: str) -> str:
        if name in self._cmd_plans:
            return name
        if name in self._cmd_by_frame_name:
            return self._cmd_by_frame_name[name]
        raise KeyError(f"unknown command {name!r}; expected one of {list(self._cmd_plans)}")

    def encode_command(self, name: str, value: float, counter: int) -> tuple[int, bytes]:
        """A command frame with counter and CRC filled in. ``name``: the command signal
        (``throttle_angle_cmd``...) or the frame name (``THROTTLE_CMD``). The value is NOT clamped to
        the DBC range (so tests can build authentic out-of-range frames); it must fit the bits."""
        f, vs, cs, crcs, data_id, _ = self._cmd_plans[self._cmd_name(name)]
        raw = round((value - vs.offset) / vs.factor)
        lo = -(1 << (vs.length - 1)) if vs.signed else 0
        hi = (1 << (vs.length - 1)) - 1 if vs.signed else vs.mask
        if not lo <= raw <= hi:
            raise ValueError(f"{vs.name} = {value} does not fit {vs.length} bits")
        word = ((raw & vs.mask) << vs.start) | ((counter & cs.mask) << cs.start)
        body = word.to_bytes(f.length, "little")[: f.length - 1]
        crc = crc8_j1850(bytes((data_id,)) + body)
        return f.frame_id, body + bytes((crc,))

    # -- lockstep -----------------------------------------------------------------------------------
    def encode_step_request(self, steps: int, counter: int) -> tuple[int, bytes]:
        """SIM_STEP_REQ asking for ``steps`` (1..65535) fixed steps, counter and CRC filled in."""
        f, vs, cs, _, data_id = self._step_req_plan
        if not vs.raw_min <= int(steps) <= vs.raw_max:
            raise ValueError(f"lockstep_steps = {steps}: expected {vs.raw_min}..{vs.raw_max}")
        word = (int(steps) << vs.start) | ((counter & cs.mask) << cs.start)
        body = word.to_bytes(f.length, "little")[: f.length - 1]
        return f.frame_id, body + bytes((crc8_j1850(bytes((data_id,)) + body),))

    def decode_step_request(self, data: bytes) -> tuple[int, int] | None:
        """(steps, counter) of an authentic SIM_STEP_REQ payload; None if the DLC, CRC or the step
        count is wrong. Never raises."""
        f, vs, cs, _, data_id = self._step_req_plan
        try:
            if len(data) != f.length or crc8_j1850(bytes((data_id,)) + bytes(data[:-1])) != data[-1]:
                return None
            word = int.from_bytes(data, "little")
        except Exception:  # noqa: BLE001
            return None
        steps = (word >> vs.start) & vs.mask
        if not vs.raw_min <= steps <= vs.raw_max:
            return None
        return steps, (word >> cs.start) & cs.mask

    def encode_step_ack(self, sim_time: float, counter: int) -> tuple[int, bytes]:
        """SIM_STEP_ACK: the simulation time reached (s, 1 us resolution) and the request's counter."""
        f, ts, cs = self._step_ack_plan
        word = (_encode_raw(ts, sim_time) << ts.start) | ((counter & cs.mask) << cs.start)
        return f.frame_id, word.to_bytes(f.length, "little")

    def decode_step_ack(self, data: bytes) -> tuple[float, int]:
        """(sim_time s, counter) of a SIM_STEP_ACK payload."""
        f, ts, cs = self._step_ack_plan
        word = int.from_bytes(bytes(data), "little")
        return ((word >> ts.start) & ts.mask) * ts.factor + ts.offset, (word >> cs.start) & cs.mask

    def sensor_layout(self) -> dict[str, np.ndarray]:
        """The sensor frames as flat arrays for the compiled packer (``bridge.can_e2e.pack_frames``):
        per frame its id and time-stamp position; per signal its frame, channel index and scaling."""
        frames, sigs = [], []
        for k, (frame_id, tstart, tmask, items) in enumerate(self._sensor_plans):
            frames.append((frame_id, tstart, tmask))
            sigs += [(k, i, s_) for i, s_ in items]
        return _layout(frames, sigs)

    def frame_layout(self, name: str, sources: Sequence[str]) -> dict[str, np.ndarray]:
        """One SIM frame (``SIM_STATUS``, ``SIM_STEP_ACK``) as arrays for ``pack_frames``: signal
        ``sources[j]`` takes ``values[j]``; a signal not named in ``sources`` takes
        ``values[len(sources)]`` (keep it 0). No time stamp."""
        f = self.frames[name]
        index = {n: j for j, n in enumerate(sources)}
        return _layout([(f.frame_id, 0, 0)], [(0, index.get(s_.name, len(sources)), s_) for s_ in f.signals])

    def status_layout(self) -> dict[str, np.ndarray]:
        """SIM_STATUS (frame 0) and SIM_DIAG (frame 1) as arrays for ``pack_frames``, from one value
        array: ``status_sources`` then ``DIAG_SOURCES``, then a last value that stays 0 (signals
        named in neither)."""
        sources = (*self.status_sources, *DIAG_SOURCES)
        index = {n: j for j, n in enumerate(sources)}
        sigs = [(0, index.get(s_.name, len(sources)), s_) for s_ in self.status_frame.signals]
        sigs += [(1, index.get(s_.name, len(sources)), s_) for s_ in self.diag_frame.signals]
        return _layout([(self.status_frame.frame_id, 0, 0), (self.diag_frame.frame_id, 0, 0)], sigs)

    def command_plan(self, name: str):
        """(FrameInfo, value signal, counter signal, crc signal, data id, fault prefix) of a command."""
        return self._cmd_plans[self._cmd_name(name)]


def _layout(frames, sigs) -> dict[str, np.ndarray]:
    """Arrays of ``pack_frames`` from (frame id, time start, time mask) per frame and (frame index,
    value index, signal) per signal."""
    fr = np.array(frames, dtype=np.int64).reshape(-1, 3)
    return {"frame_id": fr[:, 0].copy(), "time_start": fr[:, 1].copy(), "time_mask": fr[:, 2].copy(),
            "sig_int": np.array([(k, i, s_.start, s_.mask, s_.raw_min, s_.raw_max) for k, i, s_ in sigs],
                                dtype=np.int64).reshape(-1, 6),
            "sig_float": np.array([(s_.factor, s_.offset, s_.minimum, s_.maximum, 1.0 if s_.wrap else 0.0)
                                   for _, _, s_ in sigs], dtype=np.float64).reshape(-1, 5)}


_NOT_REJECTIONS = ("accepted", "lockstep_rejected", "lockstep_ignored", "lockstep_repeated")


class CommandReceiver:
    """Decodes ECU command frames with end-to-end checks and a watchdog (see the module docstring).

    The checks run in compiled code (``bridge.can_e2e``) over the arrays ``plan`` and ``state``: the
    service's real-time step calls the same kernels on the same arrays inside its own compiled call."""

    def __init__(self, codec: Codec | str | Path | None = None, *, clamp: Iterable[str] = (),
                 hold_pressure: float = DEFAULT_HOLD_PRESSURE, timeouts: Mapping[str, float] | None = None,
                 max_counter_step: int = 2, t0: float = 0.0, slots: Mapping[str, int] | None = None,
                 invalid_slots: Mapping[str, int] | None = None):
        """``slots``: where each command's value goes in the array ``apply_timeouts`` fills (default:
        its position among the commands); ``invalid_slots``: for the commands named, where 1.0 goes
        while the command has no valid value (the vehicle's own layout, e.g. the EPS's safe state)."""
        if not isinstance(codec, Codec):
            codec = Codec(codec if codec is not None else DEFAULT_DBC)
        self.codec = codec
        self.clamp = frozenset(clamp)
        bad = self.clamp - set(codec.channels.command_names)
        if bad:
            raise ValueError(f"clamp: unknown command signals {sorted(bad)}")
        self.hold_pressure = float(hold_pressure)
        self.max_counter_step = int(max_counter_step)
        self.names = codec.channels.command_names
        timeouts = dict(timeouts or {})
        n = len(self.names)
        ip = np.zeros((n, e2e.NRP), dtype=np.int64)
        fp = np.zeros((n, e2e.NRF))
        self.timeout = {}
        self._fault_name = {}
        for i, name in enumerate(self.names):
            f, vs, cs, crcs, data_id, prefix = codec.command_plan(name)
            self.timeout[name] = float(timeouts.get(name, TIMEOUT_PERIODS * f.period))
            self._fault_name[name] = f"{prefix}_timeout"
            ip[i] = (f.frame_id, f.length, crcs.start // 8, CRC8_TABLE[0xFF ^ data_id], vs.start, vs.mask,
                     (1 << (vs.length - 1)) if vs.signed else 0, 1 << vs.length, vs.raw_min, vs.raw_max,
                     name in self.clamp, cs.start, cs.mask, e2e.POLICIES[SAFE_POLICY.get(name, "zero")],
                     self.max_counter_step, i if slots is None else slots[name],
                     (invalid_slots or {}).get(name, -1), codec.sync_counter[name])
            fp[i] = (vs.factor, vs.offset, vs.minimum, vs.maximum, self.timeout[name])
        req, steps, ctr, _, data_id = codec._step_req_plan
        step = np.array((req.frame_id, req.length, CRC8_TABLE[0xFF ^ data_id], steps.start, steps.mask,
                         steps.raw_min, steps.raw_max, ctr.start, ctr.mask), dtype=np.int64)
        self.plan = e2e.RxPlan(ip, fp, np.array(CRC8_TABLE, dtype=np.int64), step)
        self.state = e2e.make_state(n, self.hold_pressure)
        self.state.g[e2e.G_T0] = float(t0)
        self._buf = np.zeros(64, dtype=np.uint8)
        self._out = np.zeros(max(n, int(ip[:, e2e.RP_SLOT].max(initial=-1)) + 1,
                                 int(ip[:, e2e.RP_INVALID_SLOT].max(initial=-1)) + 1))
        self.fault_names = tuple(self._fault_name[nm] for nm in self.names)   # per command, its fault flag

    def reset(self, t0: float = 0.0) -> None:
        """Forget every command (a new session starting at ``t0``); counters are kept."""
        e2e.rx_reset(self.state, float(t0))

    def command_index(self, arbitration_id: int) -> int:
        """Index in COMMAND_NAMES of a command frame id (-1 for other ids)."""
        return int(e2e.rx_find(self.plan, int(arbitration_id)))

    # -- one frame --------------------------------------------------------------------------------
    def receive(self, arbitration_id: int, data: bytes, t: float, *, is_extended_id: bool = False,
                is_remote_frame: bool = False, is_fd: bool = False) -> bool:
        """Check and take one frame (its python-can flags as keywords); True if accepted. Never raises
        (``data`` that is not bytes-like is counted as a wrong DLC)."""
        i = self.command_index(arbitration_id)
        if i < 0:
            self.state.counts[e2e.C_UNKNOWN] += 1
            return False
        if is_extended_id or is_remote_frame or is_fd:
            self.state.counts[e2e.C_FORMAT] += 1
            return False
        try:
            if isinstance(data, (int, str)):
                raise TypeError("not bytes-like")
            raw = bytes(data)
        except Exception:  # noqa: BLE001  (data not bytes-like: count it as a bad frame)
            self.state.counts[e2e.C_DLC] += 1
            return False
        buf = self._buf
        m = min(len(raw), buf.shape[0])
        if m:
            buf[:m] = np.frombuffer(raw, dtype=np.uint8, count=m)
        return bool(e2e.rx_command(self.plan, self.state, i, buf, len(raw), float(t)))

    # -- watchdog -----------------------------------------------------------------------------------
    def check_timeouts(self, t: float) -> dict[str, float]:
        """Update the timeout flags at time ``t`` and return the command values to apply."""
        self.apply_timeouts(t, self._out)
        return {name: float(self._out[self.plan.ip[i, e2e.RP_SLOT]]) for i, name in enumerate(self.names)}

    def apply_timeouts(self, t: float, out) -> int:
        """As ``check_timeouts`` but writes the values into ``out`` at the commands' slots (a float
        array such as the vehicle's command array); returns a bit mask of timed-out commands (bit i:
        the i-th command)."""
        return int(e2e.rx_watchdog(self.plan, self.state, float(t), out))

    # -- reading --------------------------------------------------------------------------------------
    @property
    def counters(self) -> dict[str, int]:
        """Outcomes by kind but the accepted frames (``unknown_id``, ``dlc``, ``crc``, ``counter``,
        ``range``, ``counter_repeated``, ``counter_jump``, ``clamped``, ``sync``, ``format``,
        ``foreign_frames``); a snapshot."""
        return {k: int(v) for k, v in zip(e2e.COUNTER_NAMES, self.state.counts)
                if k not in _NOT_REJECTIONS}

    @property
    def accepted(self) -> int:
        return int(self.state.counts[e2e.C_ACCEPTED])

    @property
    def timed_out(self) -> list[bool]:
        return [bool(v) for v in self.state.iv[:, e2e.IV_TIMED_OUT]]

    @property
    def value(self) -> list[float | None]:
        """Latest valid value of each command, COMMAND_NAMES order (None before the first one)."""
        st = self.state
        return [float(st.fv[i, e2e.FV_VALUE]) if st.iv[i, e2e.IV_HAS_VALUE] else None for i in range(len(self.names))]

    @property
    def faults(self) -> dict[str, bool]:
        """Timeout flags by fault name (``throttle_timeout``...), as of the last ``check_timeouts``
        (a valid frame clears its flag at once)."""
        return {self._fault_name[n]: to for n, to in zip(self.names, self.timed_out)}

    @property
    def latest(self) -> dict[str, float | None]:
        """Latest valid value of each command (None before the first one)."""
        return dict(zip(self.names, self.value))


# --------------------------------------------------------------------------------------------------

def _benchmark(n: int = 20000) -> None:  # pragma: no cover - manual measurement
    import random
    import timeit

    codec = Codec()
    rx = CommandReceiver(codec)
    rng = random.Random(1)
    vals = [0.1 * rng.uniform(-1, 1) for _ in codec.channels.sensors]
    nf = len(codec.sensor_frames)
    t = min(timeit.repeat(lambda: codec.encode_sensors(vals, 1.234), number=n, repeat=5)) / n
    print(f"encode_sensors, all {nf} frames: {t * 1e6:.2f} us ({t * 1e6 / nf:.2f} us per frame)")
    msgs = {m.frame_id: m for m in codec.db.messages}
    frames = codec.encode_sensors(vals, 1.234)
    t = min(timeit.repeat(lambda: [msgs[i].encode(msgs[i].decode(d)) for i, d in frames],
                          number=n // 20, repeat=3)) / (n // 20)
    print(f"  for comparison cantools decode+encode of the {nf} frames: {t * 1e6:.1f} us")
    t = min(timeit.repeat(lambda: codec.encode_status("realtime", 12.3, 1, ("bus_error",), rx.counters),
                          number=n, repeat=5)) / n
    print(f"encode_status: {t * 1e6:.2f} us")
    frames = [codec.encode_command("throttle_angle_cmd", 0.5, c) for c in range(16)]
    state = {"k": 0, "t": 0.0}

    def rx_one():
        k = state["k"]
        fid, data = frames[k & 15]
        state["k"] = k + 1
        state["t"] += 0.01
        rx.receive(fid, data, state["t"])
    t = min(timeit.repeat(rx_one, number=n, repeat=5)) / n
    print(f"CommandReceiver.receive (valid frame, incl. harness ~0.1 us): {t * 1e6:.2f} us  accepted={rx.accepted}")
    bad = (0x080, bytes(8))
    t = min(timeit.repeat(lambda: rx.receive(*bad, 0.0), number=n, repeat=5)) / n
    print(f"CommandReceiver.receive (bad CRC): {t * 1e6:.2f} us")
    t = min(timeit.repeat(lambda: rx.receive(0x123, bad[1], 0.0), number=n, repeat=5)) / n
    print(f"CommandReceiver.receive (unknown id): {t * 1e6:.2f} us")
    t = min(timeit.repeat(lambda: codec.encode_command("steering_wheel_angle_cmd", 1.0, 3), number=n, repeat=5)) / n
    print(f"encode_command: {t * 1e6:.2f} us")
    t = min(timeit.repeat(lambda: rx.check_timeouts(1.0), number=n, repeat=5)) / n
    print(f"check_timeouts: {t * 1e6:.2f} us")


if __name__ == "__main__":  # pragma: no cover
    _benchmark()
