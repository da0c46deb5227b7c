"""`rtsim resim FILE.mcap`: re-run the model from a recording's received CAN frames and report how far
the new run is from the recorded sensors and state.

The recording's metadata (written by `rtsim serve --record`) names the scenario, the vehicle, the
step, the mode and the watchdog's hold pressure. The received frames (``can/rx``) are fed to a fresh
``HilLoop`` exactly as the service took them: in lockstep mode in recorded order (the SIM_STEP_REQ
frames among them run the steps); in realtime/fast mode each frame at the step at which the service
processed it (its recorded simulation time), stepping in between, up to the last recorded sample. The
loop, the E2E checks, the watchdog and the compiled step are the service's own, so with an unchanged
model and configuration the sensors and state come out bit for bit identical. A changed model shows
as per-channel differences. The user command source's changes (``rtsim view`` driving: the ``user``
topic, each with the step the loop applied it at) are applied at the same steps, so a session someone
drove from the browser re-simulates too (``user=False``: without them, a what-if). The control requests
that changed the run (the ``control`` topic: lockstep ``step`` requests over Zenoh, the ``driver`` op's live
inputs, pause and resume) are repeated at their steps as well; a reset or a new scenario restarts
simulation time, and the re-run stops there.

Also accepts python-can logs (.asc, .blf, candump .log) of ECU command frames with ``--scenario``: the
model is driven by them and the run is reported without a comparison.

A damaged recording (chunks that do not check out, a file cut short, a writer killed before it closed the
file: bridge.mcap_recorder.RecordingInfo) is re-run from what could be read; the report's first line and its
``health``/``damage`` fields say what was lost and how the session ended (the rtsim.session_end record, or the
last recorded status of a file never closed). A recording with no readable chunk, or no sensor or state sample
to compare with, is an error (ConfigError: one line, exit 2).
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from bridge import payloads
from bridge.can_codec import Codec
from bridge.can_e2e import FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE
from rtsim.errors import ConfigError

from bridge.mcap_recorder import SESSION_END_METADATA
from rtsim.model_fault import TEST_FAULT_METADATA

from .loop import HilLoop
from .outbox import RingDrain
from .server import build_sim, resolve_scenario

ROOT = Path(__file__).resolve().parents[2]


class Collector:
    """Reads a re-run loop's rings after every compiled call: every sensor and state sample."""

    def __init__(self, loop: HilLoop):
        self.sensors: list[tuple[float, np.ndarray]] = []
        self.state: list[tuple[float, np.ndarray]] = []
        self._drain = RingDrain(loop.rings, loop.lp.sensor_ids, raw=self._raw)
        loop.on_chunk = self._drain.drain

    def _raw(self, key, t, values):
        (self.sensors if key == "sensors" else self.state).append((t, values))



def _flags(frame: dict) -> int:
    """The receive ring's format flags (bridge.can_e2e.FLAG_*) of a recorded ``can/rx`` frame."""
    return ((FLAG_EXTENDED if frame.get("extended") else 0) | (FLAG_REMOTE if frame.get("remote") else 0)
            | (FLAG_FD if frame.get("fd") else 0))

def _file_for(meta: dict, key: str, override: Path | None, tmp: Path) -> tuple[Path, str]:
    """The config file to use and a note: the override, the recorded path (recorded in another checkout:
    this one's file at the same place under configs/) if its text is unchanged, else the recorded text
    written next to nothing (a temporary file in the recorded folder when possible, so relative paths
    still resolve)."""
    if override is not None:
        return override, f"{key} {override} (given)"
    rec = meta.get(f"rtsim.{key}")
    if rec is None:
        raise ConfigError(f"the recording has no rtsim.{key} metadata (not written by rtsim serve?)")
    path = Path(rec["path"])
    if not path.exists() and "configs" in path.parts:     # recorded in another checkout: this one's file
        local = ROOT.joinpath(*path.parts[len(path.parts) - 1 - path.parts[::-1].index("configs"):])
        if local.parent.is_dir():
            path = local
    if path.exists() and path.read_text() == rec["toml"]:
        return path, f"{key} {path} (unchanged)"
    folder = path.parent if path.parent.exists() else tmp
    out = Path(tempfile.mkstemp(suffix=".toml", prefix=f".resim-{key}-", dir=folder)[1])
    out.write_text(rec["toml"])
    return out, f"{key} as recorded ({path} {'changed since' if path.exists() else 'missing'})"


class SessionEvents:
    """A recording's events repeated on a re-run loop at the steps the service took them at: the user command
    source's changes (``user`` topic; one logged at step k acts on steps k+1 on, as in the service) and the
    control ops that changed the run (``control`` topic: a lockstep ``step`` runs its steps, ``driver`` sets
    the in-loop driver's live inputs, pause and resume change nothing simulated time sees). A reset or a new
    scenario restarts simulation time: the re-run ends there (``ended_by``)."""

    def __init__(self, loop: HilLoop, user=(), control=()):
        """``user``, ``control``: the topics' messages in recorded order, merged by the service's event count
        (``order``). (Recordings made before the control topic have only ``user``, in order; their events
        after a restart of time, where the step count falls, are left out.)"""
        self.loop = loop
        self.ended_by = None
        for topic, msgs in (("user", user), ("control", control)):
            for n, m in enumerate(msgs):
                bad = payloads.validation_errors(topic, m.data)
                if bad:
                    raise ConfigError(f"re-simulation: {topic} event {n} of the recording is malformed: {bad[0]}")
        merged = [(m.data.get("order", n), "user", m.data) for n, m in enumerate(user)]
        merged += [(m.data["order"], m.data["op"], m.data) for m in control]
        merged.sort(key=lambda e: e[0])
        self.events = []
        for _, op, data in merged:
            step = int(data["step"])
            if self.events and step < self.events[-1][0]:
                break
            if op in ("reset", "load_scenario"):
                self.ended_by = f"{op} at t = {data['time']:.3f} s"
                break
            self.events.append((step, op, data))
        self.i = 0
        self.applied = {"user": 0, "control": 0}
        self.users = sum(1 for e in self.events if e[1] == "user")

    def _apply(self, op: str, data: dict) -> None:
        loop = self.loop
        if op == "user":
            loop.apply_user(data.get("channels") or {}, bool(data.get("takeover")))
            self.applied["user"] += 1
            return
        self.applied["control"] += 1
        if op == "step":                  # the steps, with what was logged on the way
            self.i += 1
            self.advance(int(data["args"].get("n", 1)))
            self.i -= 1
            return
        reply = loop.apply_control(op, dict(data.get("args") or {}))
        if not reply.get("ok"):
            raise ConfigError(f"re-simulation: the recorded {op} request at step {loop.k} was refused: "
                              f"{reply.get('error')}")

    def apply_due(self, frame_step: int | None = None) -> None:
        """Every event logged at the loop's current step or before; ``frame_step`` (lockstep: the recorded step
        of the next frame) also runs the ``step`` ops logged before it."""
        ev, loop = self.events, self.loop
        while self.i < len(ev):
            step, op, data = ev[self.i]
            if op == "step":
                if frame_step is None or step >= frame_step or step != loop.k:
                    break
            elif step > loop.k:
                break
            self._apply(op, data)
            self.i += 1

    def advance(self, n: int) -> None:
        """``n`` steps, the events applied at their steps on the way."""
        loop, target = self.loop, self.loop.k + int(n)
        while loop.k < target and loop.run_state == "running":
            self.apply_due()
            ev = self.events[self.i] if self.i < len(self.events) else None
            nxt = ev[0] if ev is not None and ev[1] != "step" else target
            k0 = loop.k
            loop.advance(min(target, nxt) - k0)
            if loop.k == k0:
                break
        self.apply_due()

    def finish(self) -> None:
        """The lockstep ``step`` ops logged after the last frame."""
        self.apply_due(frame_step=1 << 62)


def resim(path: str | Path, vehicle: Path | None = None, scenario: Path | None = None, user: bool = True) -> dict:
    """Re-run a recording; returns the comparison report (see the module docstring); ``user`` False leaves
    out the user command source's recorded changes."""
    from bridge.mcap_recorder import read_recording

    path = Path(path)
    messages, info = read_recording(path)
    meta = info.metadata
    damage = f"; {info.health_line()}" if info.damaged else ""
    if not info.usable:
        raise ConfigError(f"{path}: nothing to re-simulate: no chunk of the recording is readable{damage}")
    session = meta.get("rtsim.session")
    if session is None:
        raise ConfigError(f"{path}: no rtsim.session metadata; record with `rtsim serve --record`{damage}")
    for key, given in (("scenario", scenario), ("vehicle", vehicle)):
        if given is None and f"rtsim.{key}" not in meta:
            raise ConfigError(f"{path}: no rtsim.{key} metadata (not written by rtsim serve?){damage}")
    vid = session["vehicle_id"]
    if not (messages.get(f"rtsim/{vid}/sensors") or messages.get(f"rtsim/{vid}/state")):
        raise ConfigError(f"{path}: nothing to re-simulate: no sensor or state sample of vehicle {vid!r} in the "
                          f"recording to compare with{damage}")
    notes = []
    temps = []
    with tempfile.TemporaryDirectory() as tmp:
        spath, note = _file_for(meta, "scenario", scenario, Path(tmp))
        notes.append(note)
        vpath, note = _file_for(meta, "vehicle", vehicle, Path(tmp))
        notes.append(note)
        temps = [p for p in (spath, vpath) if p.name.startswith(".resim-")]
        try:
            sim, sc = build_sim(spath, vpath, float(session["dt"]), rider=session.get("rider", "on") == "on")
        finally:
            for p in temps:
                p.unlink(missing_ok=True)
    if info.channels is not None and info.channels != sim.vm.channels:
        diff = _channel_difference(info.channels, sim.vm.channels)
        notes.append(f"the recorded channels differ from the vehicle's: {diff}")
    mode = session["mode"]
    forced = session.get(TEST_FAULT_METADATA)         # rtsim.model_fault's test-only hook, as recorded
    specs = recorded_faults(meta, path)
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode=mode, state_rate=float(session.get("state_rate", 100.0)),
                   hold_pressure=float(session["hold_pressure"]), driver=sc.driver(),
                   test_fault_at=None if forced is None else float(forced), faults=specs,
                   fault_where=[(f"{path} (rtsim.faults)", f"faults[{n}]") for n in range(len(specs))])
    col = Collector(loop)
    rx = messages.get(f"rtsim/{vid}/can/rx", [])
    rec_sensors = messages.get(f"rtsim/{vid}/sensors", [])
    rec_state = messages.get(f"rtsim/{vid}/state", [])
    events = SessionEvents(loop, messages.get(f"rtsim/{vid}/user", []) if user else [],
                           messages.get(f"rtsim/{vid}/control", []))
    dt = sim.dt
    if events.ended_by is not None:
        notes.append(f"replayed up to the {events.ended_by} (simulation time restarts there)")
    rx, rec_sensors, rec_state = (_before_restart(x) for x in (rx, rec_sensors, rec_state))
    replayed = 0
    for m in rx:
        kf = int(round(m.data["time"] / dt))
        if mode != "lockstep":
            events.advance(kf - loop.k)
        events.apply_due(kf if mode == "lockstep" else None)
        loop.rx_writer.put(int(m.data["id"]), bytes.fromhex(m.data["data"]), _flags(m.data))
        loop.take_frames()
        replayed += 1
        if loop.run_state == "model_fault":
            break
    faults = _model_faults(messages.get(f"rtsim/{vid}/status", []), meta.get(SESSION_END_METADATA), loop)
    if mode == "lockstep":
        events.finish()
    elif rec_sensors or rec_state or faults["recorded_model_fault"] is not None:
        # up to the last sample recorded (a cut file may end on either), or the recorded failed step
        end = int(round(max(m[-1].data["time"] for m in (rec_sensors, rec_state) if m) / dt)) \
            if rec_sensors or rec_state else 0
        if faults["recorded_model_fault"] is not None:      # the sensors end before the failed step
            end = max(end, int(faults["recorded_model_fault"]["step"]))
        events.advance(end - loop.k)
    report = {"recording": str(path), "mode": mode, "dt": dt, "files": notes, "frames_replayed": replayed,
              "user_changes": events.users, "user_changes_applied": events.applied["user"],
              "control_ops": len(events.events) - events.users, "control_ops_applied": events.applied["control"],
              "ended_by": events.ended_by,
              "sim_time": loop.sim_time, "run_state": loop.run_state, "message": loop.message,
              "sensors": _compare(rec_sensors, col.sensors, sim.vm.channels.sensor_names),
              "state": _compare(rec_state, col.state, sim.vm.channels.state_names)}
    report["faults"] = _compare_faults(messages.get(f"rtsim/{vid}/faults", []), loop)
    report["identical"] = bool(report["sensors"]["identical"] and report["state"]["identical"]
                               and report["faults"]["identical"])
    report["health"] = info.health_line()
    report["damage"] = info.damage
    report.update(_model_faults(messages.get(f"rtsim/{vid}/status", []), meta.get(SESSION_END_METADATA), loop))
    return report


def recorded_faults(meta: dict, path) -> list:
    """The faults the session armed from its settings (the ``rtsim.faults`` metadata): re-armed as recorded.
    (Faults armed live are ``inject_fault`` requests on the control topic: repeated at their steps.)"""
    from rtsim.faults.spec import load_fault_specs

    rec = meta.get("rtsim.faults")
    if rec is None:
        return []
    try:
        tables = json.loads(rec["faults"])
    except (KeyError, ValueError) as exc:
        raise ConfigError(f"{path}: the rtsim.faults metadata is malformed: {exc}") from None
    return load_fault_specs(tables, f"{path} (rtsim.faults)")


def _compare_faults(recorded: list, loop) -> dict:
    """The recorded fault events (onsets, ends) against the rerun's, by (id, event, step)."""
    def key(e):
        return (e["id"], e["event"], int(e["step"]))
    rec = [key(m.data) for m in _before_restart(recorded)]
    got = [key(e) for topic, e in loop.event_log if topic == "faults"]
    upto = loop.k           # the rerun's last step: events after it were not re-run
    return {"recorded": len(rec), "rerun": len(got),
            "identical": [e for e in rec if e[2] <= upto] == [e for e in got if e[2] <= upto],
            "events": [{"id": i, "event": ev, "step": st} for i, ev, st in got[:50]]}


def _model_faults(status: list, end: dict | None, loop) -> dict:
    """The recorded model failure (the first status that carries one, else the session-end record) and the
    rerun's: ``recorded_model_fault``, ``model_fault`` (None for none) and ``model_fault_reproduced``
    (both failed at the same step with the same reason code; None when neither failed)."""
    rec = next((m.data["model_fault"] for m in status if m.data.get("model_fault")), None)
    if rec is None and end is not None and end.get("how") == "model_fault":
        rec = {"reason_code": int(end["reason_code"]), "reason": end.get("reason", ""),
               "message": end.get("message", ""), "step": int(end["step"]), "sim_time": float(end["sim_time"]),
               "coordinate": end.get("coordinate", "")}
    got = None if loop.model_fault is None else loop.model_fault.as_dict()
    same = None
    if rec is not None or got is not None:
        same = bool(rec is not None and got is not None and int(rec["step"]) == got["step"]
                    and int(rec["reason_code"]) == got["reason_code"])
    return {"recorded_model_fault": rec, "model_fault": got, "model_fault_reproduced": same}


def _fault_line(rep: dict) -> str | None:
    """The report's model-failure line (None when neither the recording nor the rerun failed)."""
    rec, got = rep.get("recorded_model_fault"), rep.get("model_fault")
    if rec is None and got is None:
        return None
    if rep.get("model_fault_reproduced"):
        return (f"  model fault reproduced: step {got['step']} (t = {got['sim_time']:.3f} s), {got['reason']} "
                f"(code {got['reason_code']}){' at ' + repr(got['coordinate']) if got['coordinate'] else ''}")
    recorded = "none" if rec is None else f"step {rec['step']}, {rec['reason']} (code {rec['reason_code']})"
    rerun = "none" if got is None else f"step {got['step']}, {got['reason']} (code {got['reason_code']})"
    return f"  model fault NOT reproduced: recorded {recorded}; rerun {rerun}"


def _before_restart(messages: list) -> list:
    """A topic's messages up to the first whose time falls (a reset or a new scenario restarted simulation
    time there)."""
    for n in range(1, len(messages)):
        if messages[n].data["time"] < messages[n - 1].data["time"]:
            return messages[:n]
    return messages


def _channel_difference(recorded, vehicle) -> str:
    """What differs between two channel dictionaries, per kind: names only in one, changed units."""
    out = []
    for kind in ("sensors", "commands", "state"):
        rec = {c.name: c.unit for c in getattr(recorded, kind)}
        now = {c.name: c.unit for c in getattr(vehicle, kind)}
        parts = [f"recorded only {', '.join(n for n in rec if n not in now)}" if set(rec) - set(now) else "",
                 f"vehicle only {', '.join(n for n in now if n not in rec)}" if set(now) - set(rec) else "",
                 ", ".join(f"{n} {rec[n]} -> {now[n]}" for n in rec if n in now and rec[n] != now[n])]
        if any(parts):
            out.append(f"{kind}: " + "; ".join(p for p in parts if p))
    return "; ".join(out) or "descriptions or order"


def replay_log(path: str | Path, scenario: Path | None = None, vehicle: Path | None = None,
               dt: float | None = None, models: dict | None = None) -> dict:
    """Drive the model with the ECU command frames of a python-can log (.asc, .blf, candump .log),
    each applied at its logged time (relative to the first frame), through the service's loop (E2E
    checks and watchdog included); returns a report of the run (no recorded state to compare).
    ``models``: a cache of built vehicle models (see ``build_sim``)."""
    from bridge.can_logs import read_frames

    frames = read_frames(path)
    sim, sc = build_sim(scenario, vehicle, dt, models)
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="fast", driver=sc.driver())
    col = Collector(loop)
    t_first = frames[0].time if frames else 0.0
    for f in frames:
        loop.advance(int(round((f.time - t_first) / sim.dt)) - loop.k)
        loop.rx_writer.put(f.can_id, bytes(f.data),
                           (FLAG_EXTENDED if f.is_extended else 0) | (FLAG_FD if f.is_fd else 0))
        loop.take_frames()
        if loop.run_state == "model_fault":
            break
    loop.advance(int(round(0.5 / sim.dt)))       # half a second after the last frame
    ch = sim.vm.channels
    xs = np.array([v for _, v in col.state]) if col.state else np.zeros((0, len(ch.state)))
    ix, iy, isp = (ch.index("state", n) for n in ("pos_x", "pos_y", "speed"))
    dist = float(np.sum(np.hypot(np.diff(xs[:, ix]), np.diff(xs[:, iy])))) if len(xs) > 1 else 0.0
    return {"log": str(path), "scenario": sc.name, "frames": len(frames), "accepted": loop.rx.accepted,
            "rejected": dict(loop.rx.counters), "sim_time": loop.sim_time, "run_state": loop.run_state,
            "message": loop.message, "distance": dist,
            "peak_speed": float(xs[:, isp].max()) if len(xs) else 0.0}


def _compare(recorded, rerun, names) -> dict:
    """Per-channel max |difference| over the samples present in both (matched by time)."""
    got = {round(t * 1e6): v for t, v in rerun}
    worst = {n: 0.0 for n in names}
    matched = missing = 0
    identical = True
    for m in recorded:
        t = m.data["time"]
        v = got.get(round(t * 1e6))
        if v is None:
            missing += 1
            continue
        matched += 1
        for i, n in enumerate(names):
            r = m.data.get(n)
            r = np.nan if r is None else float(r)
            if not (r == v[i] or (np.isnan(r) and np.isnan(v[i]))):
                identical = False
                worst[n] = max(worst[n], abs(r - v[i]) if np.isfinite(r - v[i]) else np.inf)
    return {"recorded": len(recorded), "rerun": len(rerun), "matched": matched, "missing": missing,
            "identical": identical and missing == 0 and matched > 0,
            "max_abs_diff": {n: d for n, d in worst.items() if d > 0}}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="FILE", help="an MCAP recording of `rtsim serve --record`, or a python-can log "
                                     "(.asc, .blf, candump .log) of ECU command frames")
    p.add_argument("--vehicle", metavar="FILE|NAME",
                   help="vehicle TOML to use instead of the recorded one (what-if runs)")
    p.add_argument("--scenario", metavar="FILE|NAME", help="scenario TOML or name to use instead of the recorded one")
    p.add_argument("--without-user", action="store_true",
                   help="leave out the recorded commands of the user (rtsim view): what the session would have been")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 unless the rerun is bit-identical and the recording intact (closed, nothing lost)")


def main(args) -> int:
    if Path(args.recording).suffix.lower() in (".asc", ".blf", ".log"):
        rep = replay_log(args.recording, resolve_scenario(args.scenario) if args.scenario else None,
                         Path(args.vehicle) if args.vehicle else None)
        if args.json:
            print(json.dumps(rep, indent=2))
        else:
            print(f"rtsim resim: {rep['log']}: {rep['frames']} frames, {rep['accepted']} commands accepted, "
                  f"rejected {({k: v for k, v in rep['rejected'].items() if v})}; {rep['sim_time']:.3f} s "
                  f"simulated on {rep['scenario']}: distance {rep['distance']:.1f} m, peak speed "
                  f"{rep['peak_speed'] * 3.6:.1f} km/h, {rep['run_state']}")
        return 0
    rep = resim(args.recording, Path(args.vehicle) if args.vehicle else None,
                resolve_scenario(args.scenario) if args.scenario else None, user=not args.without_user)
    if args.json:
        print(json.dumps(rep, indent=2, default=float))
    else:
        print(f"rtsim resim: {rep['recording']}: {rep['health']}")
        print(f"rtsim resim: {rep['recording']}: {rep['frames_replayed']} received frames, "
              f"{rep['user_changes_applied']} of {rep['user_changes']} user-command changes and "
              f"{rep['control_ops_applied']} of {rep['control_ops']} control requests replayed in "
              f"{rep['mode']} mode, {rep['sim_time']:.3f} s simulated ({'; '.join(rep['files'])})")
        f = rep["faults"]
        if f["recorded"] or f["rerun"]:
            print(f"  faults: {f['recorded']} recorded onsets/ends, {f['rerun']} in the rerun, "
                  f"{'the same steps' if f['identical'] else 'DIFFERENT'}")
        for part in ("sensors", "state"):
            c = rep[part]
            diff = ", ".join(f"{n} {d:.3g}" for n, d in sorted(c["max_abs_diff"].items(), key=lambda x: -x[1])[:6])
            print(f"  {part}: {c['matched']} of {c['recorded']} recorded samples matched, "
                  f"{'bit-identical' if c['identical'] else 'max |diff|: ' + (diff or 'none, but samples missing')}")
        if _fault_line(rep) is not None:
            print(_fault_line(rep))
        fault = rep.get("model_fault") if rep.get("model_fault_reproduced") else None
        print(f"rtsim resim: {'IDENTICAL' if rep['identical'] else 'DIFFERENT'}"
              + (" (over what the damaged recording holds)" if rep["damage"]["damaged"] else "")
              + (f", model fault reproduced at step {fault['step']} ({fault['reason']})" if fault else
                 ", model fault NOT reproduced" if rep.get("model_fault_reproduced") is False else ""))
    return 1 if args.strict and (not rep["identical"] or rep["damage"]["damaged"]) else 0
