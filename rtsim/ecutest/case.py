"""One test case run: the HIL service (rtsim.service.server.Service, in this process) on the case's vehicle,
scenario and faults, recorded to ``<out>/cases/<name>/session.mcap``, with the ECU under test on a CAN bus of
this worker's own (a python-can-remote hub on 127.0.0.1, port chosen by the system: no two workers or test
runs can share one); then the expectations judged on the recording (rtsim.ecutest.expect).

The ECU is a process started for the case (``[ecu] command``): it drives simulated time in lockstep (as the
shipped demo controllers do with ``--lockstep``) and the case ends when it exits, after ``--duration`` s of
simulated time; or an ECU already on a bus (``[ecu] channel``, realtime): the service then runs the case's
duration. Or no ECU at all: a controller FMU (``controller``, its mapping file; rtsim.fmu) is the command
source, through the service's own path for it (rtsim.service.controller), and the case is the lockstep clock:
it steps the service through the case's duration. A controller given beside an ECU drives what the ECU does
not command (the service's priority rules). ``timeout`` (wall s) only bounds a hung case. Every process
started here is stopped here."""
from __future__ import annotations

import hashlib
import json
import os
import sys
import threading
import time
from pathlib import Path

from rtsim.compile_status import worker_progress

from .catalog import Case, LoadedCatalogue, load_catalogue
from .expect import judge

ROOT = Path(__file__).resolve().parents[2]
#: the result table's columns (the journal's; rtsim.batch.results.Journal)
COLUMNS = ["run_id", "case", "name", "status", "message", "sim_end", "outcomes", "ecu", "wall_s", "worker"]
PLACEHOLDERS = ("{interface}", "{channel}", "{duration}", "{lockstep}")

_HUB = None        # this worker's loopback CAN hub (one per worker process, kept for its cases)


def worker_hub():
    """This process's loopback CAN hub (started at the first case; ends with the process)."""
    global _HUB
    if _HUB is None:
        from bridge.can_bus import LoopbackHub
        _HUB = LoopbackHub(0)
    return _HUB


def close_hub() -> None:
    global _HUB
    if _HUB is not None:
        _HUB.close()
        _HUB = None


def ecu_command(cat: LoadedCatalogue, case: Case, channel: str) -> list[str]:
    """The ECU's argv for a case: placeholders filled, else the bus, duration and lockstep flags appended
    (the shipped demo controllers' interface)."""
    e = cat.spec.ecu
    lockstep = cat.spec.mode == "lockstep"
    words = list(e.command) + list(e.args) + list(case.ecu_args)
    subst = {"{python}": sys.executable, "{interface}": "remote", "{channel}": channel,
             "{duration}": repr(cat.duration(case)), "{lockstep}": "--lockstep" if lockstep else ""}
    templated = any(p in w for w in words for p in PLACEHOLDERS)
    out = []
    for w in words:
        for k, v in subst.items():
            w = w.replace(k, v)
        if w:
            out.append(str(script_path(cat, w) or w))
    if not templated:
        out += ["--can-interface", "remote", "--can-channel", channel, "--duration", repr(cat.duration(case))]
        if lockstep:
            out.append("--lockstep")
    return out


def script_path(cat: LoadedCatalogue, word: str) -> Path | None:
    """A command word naming a script (``*.py``) as an absolute path: relative ones are relative to the
    catalogue's folder (None: not a script)."""
    if not word.endswith(".py"):
        return None
    p = Path(word)
    return p if p.is_absolute() else (cat.path.parent / p).resolve()


def case_id(cat: LoadedCatalogue, index: int) -> str:
    """A case's run id: a hash of everything its result depends on: the catalogue's settings and the case's
    table, the content of every config file it reads (scenario, vehicle and the files they name, as
    rtsim.batch.inputs finds them) and of every file the ECU command names (a script)."""
    from rtsim.batch.inputs import digest, run_inputs
    from rtsim.service.server import default_scenario

    case = cat.spec.cases[index]
    vehicle = cat.config(case, "vehicle")
    scenario = cat.config(case, "scenario") or default_scenario(vehicle)
    files = run_inputs(scenario, vehicle, {}).files
    spec = cat.spec.model_dump(mode="json", exclude={"cases"})
    ecu = cat.spec.ecu
    words = (list(ecu.command or []) + list(ecu.args) if ecu is not None else []) + list(case.ecu_args)
    scripts = {w: digest(script_path(cat, w)) for w in words if w.endswith(".py")}
    mapping = cat.controller(case)
    if mapping is not None:                 # the controller FMU: its mapping file and the FMU itself
        scripts.update({str(mapping.path): digest(mapping.path), str(mapping.fmu): digest(mapping.fmu)})
    blob = json.dumps({"catalogue": spec, "case": case.model_dump(mode="json"), "files": files,
                       "scripts": scripts}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _step_through(svc, duration: float) -> dict:
    """Run the lockstep service ``svc`` on a thread and step it through ``duration`` s of simulated time (1 s
    a request), then stop it: the clock of a case without an ECU. Its closing summary; a step refused (a
    model fault, the service stopped by the case's timeout) ends the stepping early."""
    summary: dict = {}
    th = threading.Thread(target=lambda: summary.update(svc.run() or {}), name="rtsim-test-service", daemon=True)
    th.start()
    n, chunk, done = int(round(duration / svc.sim.dt)), max(1, int(round(1.0 / svc.sim.dt))), 0
    try:
        while done < n and th.is_alive():
            k = min(chunk, n - done)
            if not svc.control({"op": "step", "n": k}).get("ok"):
                break
            done += k
    finally:
        svc.stop()
        th.join()
    summary.setdefault("sim_time", done * svc.sim.dt)
    return summary


def _faults_file(specs, path: Path) -> Path:
    """The case's faults as a ``[[faults]]`` TOML file (what the service arms; strings as JSON-escaped TOML
    basic strings, numbers with repr)."""
    lines = []
    for s in specs:
        lines.append("[[faults]]")
        for k, v in s.table().items():
            lines.append(f"{k} = {json.dumps(v) if isinstance(v, str) else str(v).lower() if isinstance(v, bool) else repr(v)}")
        lines.append("")
    path.write_text("\n".join(lines))
    return path


def run_case(catalogue: str, index: int, out: str, run_id: str) -> dict:
    """Run case ``index`` of the catalogue file; the result row (COLUMNS). Never raises for a failing
    ECU or case: the row's status is ``passed``, ``failed`` or ``error`` (the case could not be judged)."""
    t_wall = time.monotonic()
    cat = load_catalogue(catalogue)
    case = cat.spec.cases[index]
    cdir = Path(out) / "cases" / case.name
    cdir.mkdir(parents=True, exist_ok=True)
    row = {"run_id": run_id, "case": index, "name": case.name, "worker": os.getpid()}
    log = (cdir / "log.txt").open("w", encoding="utf-8")
    try:
        with worker_progress("test"):        # a first start compiles the service here: say so
            row.update(_run(cat, case, index, cdir, log))
    except Exception as exc:  # noqa: BLE001  (the row says what went wrong: one line)
        row.update(status="error", message=f"{type(exc).__name__}: {' '.join(str(exc).split())}")
    finally:
        log.close()
    row["wall_s"] = time.monotonic() - t_wall
    return row


def _say(log):
    lock = threading.Lock()

    def say(line: str) -> None:
        with lock:
            log.write(line + "\n")
            log.flush()
    return say


def _run(cat: LoadedCatalogue, case: Case, index: int, cdir: Path, log) -> dict:
    from rtsim.service.config import ServeOptions
    from rtsim.service.ecu_process import EcuProcess
    from rtsim.service.server import Service

    say = _say(log)
    record = cdir / "session.mcap"
    record.unlink(missing_ok=True)
    duration = cat.duration(case)
    external = cat.external
    channel = external or worker_hub().channel
    kw = {k: v for k in ("vehicle", "scenario") if (v := cat.config(case, k)) is not None}
    opts = ServeOptions(mode=cat.spec.mode, record=record, zenoh=False, can_interface="remote", can_channel=channel,
                        start_hub=False, faults=[_faults_file(cat.faults[index], cdir / "faults.toml")],
                        duration=duration if external else None, **kw)
    ecu = None
    ended = threading.Event()
    holder: dict = {}

    def on_exit(_e) -> None:
        ended.set()
        if "svc" in holder:
            holder["svc"].stop()
    try:
        svc = Service(opts, out=say, controller=cat.controller(case))   # its bus port listens from here: the
        holder["svc"] = svc                                               # ECU's first frames are kept
        clocked = cat.spec.ecu is None      # no ECU: this case steps the lockstep service itself
        if not external and not clocked:    # (started before, on this worker's running hub, its first step
            cmd = ecu_command(cat, case, channel)   # request could reach the bus before the service did)
            say("ecu: " + " ".join(cmd))
            ecu = EcuProcess(cmd, cwd=ROOT, on_exit=on_exit, echo=lambda line: say("ecu: " + line))
        timer = threading.Timer(cat.spec.timeout, svc.stop)
        timer.daemon = True
        timer.start()
        try:
            if ended.is_set():              # the ECU ended while the service was built
                svc.close()
                summary = {}
            elif clocked:
                summary = _step_through(svc, duration)
            else:
                summary = svc.run()
        finally:
            timer.cancel()
        timed_out = not external and ecu is not None and not ecu.ended
    finally:
        if ecu is not None and not ecu.ended:
            ecu.stop()
        if "svc" in holder:
            holder["svc"].close()          # (idempotent: closed by run() already when it ran)
    if clocked and summary.get("sim_time", 0.0) < duration - 0.5 * svc.sim.dt:
        return {"status": "error", "message": f"the case did not end within its timeout ({cat.spec.timeout:g} s "
                f"wall): stopped at t = {summary.get('sim_time', 0.0):.3f} s of {duration:g} s"}
    say(json.dumps({"service": {k: summary.get(k) for k in ("sim_time", "steps", "run_state", "accepted_frames")}}))
    ecu_info = {}
    if ecu is not None:
        ecu.wait(5.0)
        ecu_info = {"returncode": ecu.returncode, "result": ecu.result, "last": ecu.last_message()}
        if timed_out:
            return {"status": "error", "ecu": ecu_info, "message": f"the case did not end within its timeout "
                    f"({cat.spec.timeout:g} s wall); the ECU was stopped"}
        if ecu.returncode != 0:
            return {"status": "error", "ecu": ecu_info,
                    "message": "the ECU " + ecu.describe_end().removeprefix("the demo ECU ")}
    if not record.exists():
        return {"status": "error", "ecu": ecu_info, "message": "the service wrote no recording"}
    from .signals import read_signals

    sig = read_signals(record)
    ids = {s.id for s in cat.faults[index]}
    outcomes = []
    for e in case.expect:
        try:
            outcomes.append(judge(e, sig, sig.end, ids))
        except KeyError as exc:
            from .expect import Outcome
            outcomes.append(Outcome(e.label(), e.signal, False, f"{e.label()}: {exc.args[0]}", e.after, None,
                                    (float("nan"), float("nan"))))
    from .report import plot_case

    plot_case(sig, case, outcomes, cdir / "plot.png")
    failed = [o for o in outcomes if not o.passed]
    return {"status": "failed" if failed else "passed", "message": " | ".join(o.message for o in failed),
            "sim_end": sig.end, "outcomes": [o.as_dict() for o in outcomes], "ecu": ecu_info}
