"""The compiled fault table of a session: ``FaultSpec``s checked against the served vehicle (its channel
dictionary, its DBC's frames, its actuators) and written as rows of ``rtsim.faults.kernels.FaultPlan``;
the Python face of the fault state (arming, clearing, the events, the status).

``FaultTargets`` is what the table needs to know of the vehicle and its interface; the service builds it
(rtsim.service.faults) from the vehicle sim, its codec and the loop's rates. An actuator fault is one or
two writes into arrays the vehicle exposes (``VehicleSim.fault_actuators``: actuator name -> writes); a
fault whose actuator the vehicle lacks is refused in one line.

Arming runs between two steps on the loop's thread: a row is written into the next free slot and counted
in ``plan.n`` last, so the compiled step never sees half a row.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rtsim.errors import ConfigError

from .catalog import (BY_CODE, BY_NAME, K_BABBLE, K_BUS_OFF, K_CORRUPT_COUNTER, K_CORRUPT_CRC, K_DELAY,
                      K_FRAME_DELAY, K_LOSS, K_OUT_OF_RANGE, MAX_DELAY)
from .kernels import (AM_COMMAND, CAPACITY, DIR_IN, DIR_NONE, DIR_OUT, EV_ONSET, FF_COND_VALUE, FF_P0, FI_AFTER,
                      FI_AFTER_DELAY, FI_AMODE, FI_ARR, FI_COND_CH, FI_COND_OP, FI_COND_SRC, FI_CMASK, FI_CRC0,
                      FI_CRC_POS, FI_CSTART, FI_DIR, FI_DURATION, FI_FRAME, FI_IDX, FI_KIND, FI_LAG, FI_M, FI_N,
                      FI_ONSET, FI_PAYLOAD, FI_PERIOD, FI_SEED, FI_TARGET, FI_TRIG, G_EV_HEAD, OP_ABS_GT,
                      OP_ABS_LT, OP_GT, OP_LT, PH_ACTIVE, PH_ENDED, RING, SI_END, SI_ONSET, SI_PHASE, SI_RNG,
                      SRC_SENSOR, SRC_STATE, TRIG_AFTER, TRIG_AT, TRIG_WHEN, fault_end, make_plan, make_state)
from .spec import FaultSpec


@dataclass(frozen=True)
class Write:
    """One write of an actuator fault: array ``arr`` (an index into what the vehicle's compiled
    ``vehicle_fault_arrays`` returns), element ``idx``, mode (kernels.AM_*), value (AM_VALUE; NaN: the
    fault's ``value`` parameter, or the element's value at the onset)."""
    arr: int
    idx: int
    mode: int
    value: float = math.nan


@dataclass(frozen=True)
class SentFrame:
    frame_id: int
    name: str
    index: int          # among the sensor frames, -1 for the status, diagnostics frames
    every: int          # period in steps


@dataclass(frozen=True)
class CommandFrame:
    frame_id: int
    name: str
    crc_pos: int        # byte of the CRC (-1: none)
    crc0: int
    cstart: int         # alive counter: first bit and mask (0: none)
    cmask: int


@dataclass
class FaultTargets:
    dt: float
    sensor_names: tuple[str, ...]
    state_names: tuple[str, ...]
    sensor_every: int
    state_every: int
    sent: dict[str, SentFrame]                      # the frames the simulator sends, by name
    received: dict[str, CommandFrame]               # the command frames it takes, by name
    frame_of: dict[str, int]                        # sensor channel -> index of the sensor frame carrying it
    ranges: dict[str, tuple[float, float]]          # sensor channel -> its DBC signal's (min, max)
    actuators: dict[str, dict[str, tuple[Write, ...]]]   # actuator name -> fault kind -> its writes
    families: dict[str, str] = field(default_factory=dict)   # actuator name -> family (catalog actuator)
    exempt: tuple[int, ...] = ()                    # ids no bus fault may take (lockstep request, ack)


@dataclass
class Armed:
    spec: FaultSpec
    rows: list[int]
    armed_step: int


class FaultTable:
    """A session's faults (module docstring): ``plan`` and ``state`` go into the compiled step."""

    def __init__(self, targets: FaultTargets):
        self.targets = targets
        self.plan = make_plan()
        self.state = make_state()
        self.armed: dict[str, Armed] = {}
        self._row_of: dict[int, str] = {}
        self._ev_seen = 0

    # ---- arming -----------------------------------------------------------------------------------------
    def arm(self, spec: FaultSpec, k: int, source: str = "fault", key: str = "") -> None:
        """Check ``spec`` against the vehicle and add it at step k (the loop's step count now); ConfigError
        (``source: key.field = value: reason``) if it does not fit."""
        where = f"{key}." if key else ""

        def err(name, value, reason):
            return ConfigError(f"{source}: {where}{name} = {value!r}: {reason}")
        if spec.id in self.armed:
            raise err("id", spec.id, "a fault of this id is armed already (clear_fault it first, or use another id)")
        rows = self._rows(spec, k, err)
        n = int(self.plan.n[0])
        if n + len(rows) > CAPACITY:
            raise err("id", spec.id, f"the session holds at most {CAPACITY} fault rows")
        fi, ff = self.plan.fi, self.plan.ff
        for j, (ri, rf) in enumerate(rows):
            if j > 0:                     # an actuator's further writes follow the first row's onset
                ri[FI_TRIG], ri[FI_AFTER], ri[FI_AFTER_DELAY] = TRIG_AFTER, n, 0
            fi[n + j] = ri
            ff[n + j] = rf
            self.state.si[n + j, SI_RNG] = (int(ri[FI_SEED]) * 0x2545F4914F6CDD1D) & 0x7FFFFFFFFFFFFFFF
            self._row_of[n + j] = spec.id
        self.armed[spec.id] = Armed(spec, list(range(n, n + len(rows))), k)
        self.plan.n[0] = n + len(rows)

    def _rows(self, spec: FaultSpec, k: int, err) -> list[tuple[np.ndarray, np.ndarray]]:
        tg = self.targets
        kind = BY_NAME[spec.kind]
        ri = np.zeros(len(self.plan.fi[0]), dtype=np.int64)
        rf = np.zeros(len(self.plan.ff[0]))
        ri[FI_KIND] = kind.code
        ri[FI_FRAME] = -1
        ri[FI_DIR] = DIR_NONE
        p = spec.params
        rf[FF_P0] = next(iter(p.values())) if p else 0.0
        steps = self._steps
        # trigger
        if spec.when is not None:
            c = spec.condition
            if c.channel in tg.sensor_names:
                ri[FI_COND_SRC], ri[FI_COND_CH] = SRC_SENSOR, tg.sensor_names.index(c.channel)
            elif c.channel in tg.state_names:
                ri[FI_COND_SRC], ri[FI_COND_CH] = SRC_STATE, tg.state_names.index(c.channel)
            else:
                raise err("when", spec.when, f"{c.channel!r} is neither a sensor nor a state channel of the vehicle")
            ri[FI_TRIG] = TRIG_WHEN
            ri[FI_COND_OP] = {(">", False): OP_GT, ("<", False): OP_LT, (">", True): OP_ABS_GT,
                              ("<", True): OP_ABS_LT}[(c.op, c.magnitude)]
            rf[FF_COND_VALUE] = c.value
        elif spec.after is not None:
            if spec.after not in self.armed:
                raise err("after", spec.after, f"no fault of that id is armed before this one "
                                               f"(armed: {', '.join(self.armed) or 'none'})")
            ri[FI_TRIG] = TRIG_AFTER
            ri[FI_AFTER] = self.armed[spec.after].rows[0]
            ri[FI_AFTER_DELAY] = steps(spec.after_delay, "after_delay", err)
        else:
            ri[FI_TRIG] = TRIG_AT
            ri[FI_ONSET] = max(k + 1, steps(spec.at, "at", err)) if spec.at is not None else k + 1
        ri[FI_DURATION] = steps(spec.duration, "duration", err) if spec.duration is not None else -1
        if spec.duration is not None and ri[FI_DURATION] < 1:
            raise err("duration", spec.duration, f"shorter than one step ({tg.dt:g} s)")
        ri[FI_SEED] = int(p.get("seed", 0))
        # target
        t = spec.target
        if kind.target == "sensor":
            if t not in tg.sensor_names:
                raise err("target", t, f"not a sensor channel of the vehicle (its channels: {', '.join(tg.sensor_names)})")
            ri[FI_TARGET] = tg.sensor_names.index(t)
            ri[FI_FRAME] = tg.frame_of[t]
            if kind.code == K_DELAY:
                period = tg.sensor_every * tg.dt
                n = p["delay"] / period
                if abs(n - round(n)) > 1e-6:
                    raise err("delay", p["delay"], f"not a whole number of the channel's sample periods ({period:g} s)")
                ri[FI_LAG] = int(round(n))
                if ri[FI_LAG] >= RING:
                    raise err("delay", p["delay"], f"more samples than the delay ring holds ({RING})")
            if kind.code == K_OUT_OF_RANGE:
                lo, hi = tg.ranges[t]
                if lo <= p["value"] <= hi:
                    raise err("value", p["value"], f"inside the DBC's range of {t} ({lo:g} .. {hi:g}); an "
                                                   f"out_of_range fault needs a value outside it")
        elif kind.target == "bus":
            if t != "bus":
                raise err("target", t, "a bus_off fault targets the bus: target = \"bus\"")
        elif kind.target == "frame":
            self._frame_target(kind.code, t, p, ri, err)
        else:
            if t not in tg.actuators:
                have = ", ".join(n for n, f in tg.families.items() if f == kind.actuator)
                raise err("target", t, f"this vehicle has no such actuator for a {kind.name} fault"
                                       + (f" (its {kind.actuator} actuators: {have})" if have else
                                          f" (it has no {kind.actuator} actuator)"))
            if tg.families.get(t) != kind.actuator:
                raise err("target", t, f"is a {tg.families.get(t)} actuator; a {kind.name} fault needs a "
                                       f"{kind.actuator} actuator")
            rows = []
            for w in tg.actuators[t][kind.name]:
                r = ri.copy()
                r[FI_ARR], r[FI_IDX], r[FI_AMODE] = w.arr, w.idx, w.mode
                f = rf.copy()
                f[FF_P0] = w.value if not math.isnan(w.value) else p.get("value", math.nan)
                rows.append((r, f))
            return rows
        return [(ri, rf)]

    def _frame_target(self, code: int, t, p: dict, ri: np.ndarray, err) -> None:
        tg = self.targets
        by_id = {f.frame_id: f for f in (*tg.sent.values(), *tg.received.values())}
        if code == K_BABBLE:
            if isinstance(t, str):
                if t not in tg.sent and t not in tg.received:
                    raise err("target", t, "not a frame of the DBC (give its name or any id as a number)")
                t = (tg.sent.get(t) or tg.received[t]).frame_id
            if not 0 <= t <= 0x7FF:
                raise err("target", t, "a standard CAN id: 0 .. 2047")
            ri[FI_TARGET] = t
            ri[FI_PERIOD] = self._steps(p["period"], "period", err)
            if ri[FI_PERIOD] < 1:
                raise err("period", p["period"], f"shorter than one step ({tg.dt:g} s)")
            w = int(p["payload"])
            ri[FI_PAYLOAD] = w - (1 << 64) if w >= 1 << 63 else w       # the same 64 bits as int64
            return
        frame = (tg.sent.get(t) or tg.received.get(t)) if isinstance(t, str) else by_id.get(t)
        if frame is None:
            names = ", ".join((*tg.sent, *tg.received))
            raise err("target", t, f"not a frame the simulator sends or takes (frames: {names})")
        if frame.frame_id in tg.exempt:
            raise err("target", t, "the lockstep step request and acknowledgement drive the simulation; no bus "
                                   "fault takes them")
        ri[FI_TARGET] = frame.frame_id
        if isinstance(frame, SentFrame):
            ri[FI_DIR] = DIR_OUT
            ri[FI_FRAME] = frame.index
            if code in (K_CORRUPT_CRC, K_CORRUPT_COUNTER):
                raise err("target", t, f"{frame.name} is sent by the simulator and carries no "
                                       f"{'CRC' if code == K_CORRUPT_CRC else 'alive counter'}; corrupt faults "
                                       f"take the ECU's command frames ({', '.join(tg.received)})")
        else:
            ri[FI_DIR] = DIR_IN
            ri[FI_CRC_POS], ri[FI_CRC0], ri[FI_CSTART], ri[FI_CMASK] = (frame.crc_pos, frame.crc0, frame.cstart,
                                                                          frame.cmask)
            if code == K_CORRUPT_CRC and frame.crc_pos < 0:
                raise err("target", t, f"{frame.name} has no CRC")
            if code == K_CORRUPT_COUNTER:
                if frame.cmask == 0:
                    raise err("target", t, f"{frame.name} has no alive counter")
                ri[FI_PAYLOAD] = int(p["add"])
        if code == K_LOSS:
            ri[FI_N], ri[FI_M] = int(p["n"]), int(p["m"])
            if ri[FI_N] > ri[FI_M]:
                raise err("n", p["n"], f"more than m = {int(p['m'])}")
        if code == K_FRAME_DELAY:
            ri[FI_LAG] = self._steps(p["delay"], "delay", err)
            if isinstance(frame, SentFrame) and ri[FI_LAG] > frame.every * (RING - 1):
                raise err("delay", p["delay"], f"more frames in flight than the delay ring holds ({RING})")

    def _steps(self, seconds: float, name: str, err) -> int:
        """Whole steps of ``seconds``; ConfigError if it is not a whole number of steps."""
        n = seconds / self.targets.dt
        if abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise err(name, seconds, f"not a whole number of steps ({self.targets.dt:g} s)")
        return int(round(n))

    # ---- clearing ---------------------------------------------------------------------------------------
    def clear(self, fault_id: str, k: int) -> dict:
        """End fault ``fault_id`` at step k (it acts no more from the next sample on); KeyError if none."""
        a = self.armed[fault_id]
        for r in a.rows:
            fault_end(self.plan, self.state, r, k)
        return self.describe(fault_id)

    # ---- what happened ---------------------------------------------------------------------------------
    def events(self) -> list[dict]:
        """The onsets and ends since the last call (one per fault: its first row's), oldest first."""
        head = int(self.state.g[G_EV_HEAD])
        out = []
        ev = self.state.ev
        lost = max(0, head - self._ev_seen - len(ev))
        for n in range(self._ev_seen + lost, head):
            row, what, step = (int(x) for x in ev[n % len(ev)])
            fid = self._row_of.get(row)
            if fid is None or self.armed[fid].rows[0] != row:
                continue
            spec = self.armed[fid].spec
            out.append({"time": step * self.targets.dt, "step": step, "id": fid, "kind": spec.kind,
                        "target": spec.target, "event": "onset" if what == EV_ONSET else "end"})
        self._ev_seen = head
        return out

    def describe(self, fault_id: str) -> dict:
        a = self.armed[fault_id]
        r = a.rows[0]
        si = self.state.si
        ph = int(si[r, SI_PHASE])
        onset, end = int(si[r, SI_ONSET]), int(si[r, SI_END])
        dt = self.targets.dt
        return {"id": fault_id, "kind": a.spec.kind, "target": a.spec.target,
                "state": "active" if ph == PH_ACTIVE else "ended" if ph == PH_ENDED else "armed",
                "onset_time": onset * dt if onset >= 0 else None,
                "end_time": end * dt if end >= 0 and ph == PH_ENDED else None}

    def status(self) -> list[dict]:
        return [self.describe(i) for i in self.armed]

    def specs(self) -> list[dict]:
        """Every armed spec as a table (what the recording keeps)."""
        return [a.spec.table() for a in self.armed.values()]

    @property
    def active(self) -> list[str]:
        return [i for i, a in self.armed.items() if self.state.si[a.rows[0], SI_PHASE] == PH_ACTIVE]


def kind_of(code: int) -> str:
    return BY_CODE[code].name
