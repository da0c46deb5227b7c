"""Judging a case's expectations (rtsim.ecutest.catalog) on its recorded signals (rtsim.ecutest.signals).

Every judgement is on recorded simulation stamps. The event an expectation starts from (``after``) is found
in the recording: ``start`` is t = 0, ``fault:ID`` the fault's recorded onset, ``fault_end:ID`` its recorded
end, a condition the first sample meeting it. An event that never happened fails the expectation (saying
so). A failure's message names the expectation, the simulated time and the observed value."""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .catalog import parse_condition
from .signals import Signals

OPS = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le, "==": operator.eq}
EPS = 1e-9          # s: slack on window edges (stamps are multiples of the step)


@dataclass
class Outcome:
    """One expectation judged: ``passed``; ``message`` (why it failed, or what was measured); the event's
    time (s, None when it never happened), the window judged (s), and the time and value that decided."""
    label: str
    signal: str
    passed: bool
    message: str
    event: str
    event_time: Optional[float]
    window: tuple[float, float]
    time: Optional[float] = None
    value: Optional[float] = None

    def as_dict(self) -> dict:
        return dict(self.__dict__, window=list(self.window))


def _fmt(v: float) -> str:
    return f"{v:.6g}"


def event_time(ev: str, sig: Signals) -> Optional[float]:
    """The simulated time (s) of the event ``ev``, None when the recording never shows it."""
    if ev == "start":
        return 0.0
    head, _, rest = ev.partition(":")
    if head in ("fault", "fault_end") and rest and " " not in ev:
        want = "onset" if head == "fault" else "end"
        return next((t for t, fid, e in sig.fault_events if fid == rest and e == want), None)
    name, op, value, mag = parse_condition(ev, signal=True)
    t, v = sig.get(name)
    hit = np.flatnonzero(OPS[op](np.abs(v) if mag else v, value))
    return float(t[hit[0]]) if len(hit) else None


def _window(t0: float, start: float, end: Optional[float], case_end: float) -> tuple[float, float]:
    return t0 + start, (t0 + end if end is not None else case_end)


def _select(t: np.ndarray, v: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    m = (t >= lo - EPS) & (t <= hi + EPS)
    return t[m], v[m]


def judge(e, sig: Signals, case_end: float, fault_ids=()) -> Outcome:
    """The expectation ``e`` on the signals ``sig`` of a case that ran to ``case_end`` s."""
    label = e.label()
    t0 = event_time(e.after, sig)
    if t0 is None:
        return Outcome(label, e.signal, False, f"{label}: the event {e.after!r} never happened (recording up to "
                       f"t = {_fmt(case_end)} s)", e.after, None, (math.nan, math.nan))
    if e.signal.startswith("fault.") and e.signal not in sig.series and e.signal[6:] in fault_ids:
        t, v = np.array([0.0]), np.array([0.0])          # declared, never triggered: inactive throughout
    else:
        t, v = sig.get(e.signal)
    if e.kind == "bounds":
        lo, hi = _window(t0, e.start, e.end, case_end)
        tw, vw = _select(t, v, lo, hi)
        where = f"from {_fmt(lo)} to {_fmt(hi)} s (after {e.after} at {_fmt(t0)} s)"
        allowed = f"[{'-inf' if e.min is None else _fmt(e.min)}, {'inf' if e.max is None else _fmt(e.max)}]"
        if not len(tw):
            return Outcome(label, e.signal, False, f"{label}: no sample of {e.signal} {where}", e.after, t0, (lo, hi))
        bad = np.flatnonzero(((vw < e.min) if e.min is not None else False) |
                             ((vw > e.max) if e.max is not None else False) | ~np.isfinite(vw))
        if len(bad):
            i = bad[0]
            dev = np.maximum((e.min - vw) if e.min is not None else -np.inf, (vw - e.max) if e.max is not None else -np.inf)
            k = int(np.nanargmax(np.where(np.isfinite(vw), dev, np.inf)))
            worst = f"; worst {_fmt(vw[k])} at t = {_fmt(tw[k])} s" if k != i else ""
            return Outcome(label, e.signal, False, f"{label}: {e.signal} = {_fmt(vw[i])} at t = {_fmt(tw[i])} s, "
                           f"outside {allowed} {where}{worst}", e.after, t0, (lo, hi), float(tw[i]), float(vw[i]))
        i = int(np.argmax(np.abs(vw)))
        return Outcome(label, e.signal, True, f"{e.signal} within {allowed} {where} ({len(tw)} samples)",
                       e.after, t0, (lo, hi), float(tw[i]), float(vw[i]))
    if e.kind in ("reaction", "reached"):
        _, op, value, _ = parse_condition(e.condition, signal=False)
        if e.kind == "reaction":
            lo, hi = t0, t0 + e.within
        else:
            lo, hi = _window(t0, e.start, e.end, case_end)
        tw, vw = _select(t, v, lo, hi)
        ok = OPS[op](vw, value)
        where = f"within {_fmt(lo)} .. {_fmt(hi)} s (after {e.after} at {_fmt(t0)} s)"
        if not ok.any():
            if not len(tw):
                return Outcome(label, e.signal, False, f"{label}: no sample of {e.signal} {where}", e.after, t0,
                               (lo, hi))
            i = int(np.argmin(np.abs(vw - value)))       # the closest the signal came
            return Outcome(label, e.signal, False, f"{label}: {e.signal} never {e.condition.strip()} {where}; "
                           f"closest {_fmt(vw[i])} at t = {_fmt(tw[i])} s, last {_fmt(vw[-1])} at t = "
                           f"{_fmt(tw[-1])} s", e.after, t0, (lo, hi), float(tw[i]), float(vw[i]))
        i = int(np.flatnonzero(ok)[0])
        reach = float(tw[i])
        if e.kind == "reaction" and e.hold > 0:
            th, vh = _select(t, v, reach, reach + e.hold)
            lost = np.flatnonzero(~OPS[op](vh, value))
            if len(lost):
                j = lost[0]
                return Outcome(label, e.signal, False, f"{label}: {e.signal} {e.condition.strip()} at t = "
                               f"{_fmt(reach)} s but not held for {_fmt(e.hold)} s: {_fmt(vh[j])} at t = "
                               f"{_fmt(th[j])} s", e.after, t0, (lo, reach + e.hold), float(th[j]), float(vh[j]))
        return Outcome(label, e.signal, True, f"{e.signal} {e.condition.strip()} at t = {_fmt(reach)} s, "
                       f"{_fmt((reach - t0) * 1e3)} ms after {e.after}", e.after, t0, (lo, hi), reach, float(vw[i]))
    # monotonic
    lo, hi = _window(t0, e.start, e.end, case_end)
    tw, vw = _select(t, v, lo, hi)
    where = f"from {_fmt(lo)} to {_fmt(hi)} s (after {e.after} at {_fmt(t0)} s)"
    if len(tw) < 2:
        return Outcome(label, e.signal, False, f"{label}: fewer than 2 samples of {e.signal} {where}", e.after, t0,
                       (lo, hi))
    step = np.diff(vw) if e.direction == "increasing" else -np.diff(vw)
    bad = np.flatnonzero(step < -e.tolerance)
    if len(bad):
        i = bad[0] + 1
        return Outcome(label, e.signal, False, f"{label}: {e.signal} not {e.direction} {where}: {_fmt(vw[i - 1])} "
                       f"at t = {_fmt(tw[i - 1])} s, then {_fmt(vw[i])} at t = {_fmt(tw[i])} s", e.after, t0,
                       (lo, hi), float(tw[i]), float(vw[i]))
    return Outcome(label, e.signal, True, f"{e.signal} {e.direction} {where} ({_fmt(vw[0])} -> {_fmt(vw[-1])})",
                   e.after, t0, (lo, hi), float(tw[-1]), float(vw[-1]))
