"""`rtsim serve`: the HIL service assembled from its parts, run until stopped.

Parts: the vehicle on the scenario's road (``VehicleSim``), the CAN port (python-can through
``bridge.can_bus.open_bus``: ``--can-interface/--can-channel``, else ``vcan0`` when the kernel has it,
else the embedded python-can-remote hub on 127.0.0.1, started here when none is running), the Zenoh
link (peer mode, scouting off, tcp/127.0.0.1 endpoints), the MCAP recorder, the publisher thread
(``Outbox``) and the loop (``HilLoop``) paced by ``rtsim.realtime.Pacer``.

Threads: the loop runs on the thread that calls ``run()`` (the main thread for the CLI, so SIGINT and
SIGTERM are handled there: they stop the pacer, which returns within one period); the CAN reader, the
publisher, the recorder's writer and Zenoh's own threads run beside it. Control requests from Zenoh
are built off the loop thread (a reset or a new scenario builds its VehicleSim there) and handed to the
loop through the inbox, so the loop only swaps a finished object in between two steps.
"""
from __future__ import annotations

import gc
import json
import queue
import signal
import sys
import threading
import time
from pathlib import Path

from bridge.can_bus import HUB_HOST, LoopbackHub, default_hub_port, socketcan_available
from bridge.can_codec import Codec
from rtsim.errors import ConfigError
from rtsim.model_fault import TEST_FAULT_METADATA
from rtsim.realtime.health import LoopHealth
from rtsim.realtime.pacer import Pacer

from rtsim.vehicle.registry import resolve_scenario, resolve_vehicle

from .config import DEFAULT_SCENARIO, ServeOptions
from .control_args import ControlError, check_request, scenario_file, scenario_folders
from .loop import HilLoop, Request

ROOT = Path(__file__).resolve().parents[2]


def default_scenario(vehicle: Path | None) -> Path:
    """The scenario served when none is given: the vehicle's own default (rtsim.vehicle.registry)."""
    if vehicle is None:
        return DEFAULT_SCENARIO
    from rtsim.vehicle.registry import open_vehicle
    return open_vehicle(vehicle).default_scenario


def build_sim(scenario: Path | None, vehicle: Path | None = None, dt: float | None = None,
              models: dict | None = None, rider: bool = True):
    """(vehicle sim, Scenario) at the scenario's start (None: the vehicle's default scenario), as the
    vehicle's kind builds it for the service (rtsim.vehicle.registry: a car's VehicleSim, a
    two-wheeler's TwoWheelerHil with the scenario's rider unless ``rider`` is False). ``models`` caches
    built vehicle models by resolved config path (a build solves the suspension linkages or settles the
    two-wheeler on its suspension: seconds)."""
    from drivers.scenario import load_scenario
    from rtsim.vehicle.registry import open_vehicle

    sc = load_scenario(scenario if scenario is not None else default_scenario(vehicle), check_files=True)
    opened = open_vehicle(vehicle if vehicle is not None else sc.vehicle_path)
    return opened.service_sim(sc, dt, models, rider), sc


def session_faults(o: ServeOptions, sc) -> tuple[list, list]:
    """The faults of a session (rtsim.faults.spec): the scenario's ``[[faults]]``, then those of each file of
    ``faults`` (the settings file's own first, then the ``--faults`` files); and where each was read (file,
    key) for the errors of arming them on the vehicle."""
    from rtsim.configfile import load_toml
    from rtsim.faults.spec import load_fault_specs

    specs, where = [], []
    for n, spec in enumerate(sc.spec.faults):
        specs.append(spec)
        where.append((str(sc.path), f"faults[{n}]"))
    for path in o.faults:
        for n, spec in enumerate(load_fault_specs(load_toml(path).get("faults", []), path)):
            specs.append(spec)
            where.append((str(path), f"faults[{n}]"))
    ids = [s.id for s in specs]
    dup = next((i for i in ids if ids.count(i) > 1), None)
    if dup is not None:
        raise ConfigError(f"faults: the id {dup!r} is given twice ({', '.join(w[0] for s, w in zip(specs, where) if s.id == dup)})")
    return specs, where


class Service:
    """The assembled service (see the module docstring). ``out`` prints the start-up lines. ``controller``
    (optional, for a program that embeds the service): a command source (rtsim.fmu.controller: a mapping
    or a controller written in Python) that stands in every session (resets too) where the scenario's
    controller FMU would (rtsim.service.controller)."""

    def __init__(self, opts: ServeOptions, out=print, controller=None):
        opts.check()
        self.opts = opts
        self.controller = controller
        self.out = out
        self.hub = None
        self.port = None
        self.zenoh = None
        self.recorder = None
        self.foxglove = None
        self.outbox = None
        self._closed = False
        self._stopping = threading.Event()
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    # -- assembly ------------------------------------------------------------------------------------
    def _build(self) -> None:
        o = self.opts
        self.scenario_path = resolve_scenario(o.scenario) if o.scenario is not None else default_scenario(o.vehicle)
        self.models: dict = {}
        from rtsim.model_fault import test_fault_time
        self.test_fault_at = test_fault_time()      # the test-only hook (rtsim.model_fault), from the environment
        self.sim, self.sc = build_sim(self.scenario_path, o.vehicle, o.dt, self.models, o.rider == "on")
        self.fault_specs, self.fault_where = session_faults(o, self.sc)
        self.model = self.sim.vm
        self.vehicle_id = o.vehicle_id or self.model.config.id
        ch = self.model.channels
        self.codec = Codec(o.dbc or self.model.dbc, ch)        # the served vehicle's interface
        self.inbox = queue.SimpleQueue()

        from .rings import make_rings
        self.rings = make_rings(len(ch.sensors), len(self.codec.sensor_frames), len(ch.state), len(ch.commands))
        self._open_can()
        if o.zenoh:
            from bridge.zenoh_link import ZenohLink
            self.zenoh = ZenohLink(self.vehicle_id, listen=tuple(o.zenoh_listen),
                                   connect=tuple(o.zenoh_connect), allow_remote=o.zenoh_allow_remote)
        self.health = LoopHealth(period=self.sim.dt)
        self.loop = HilLoop(self.sim, self.codec, self.rings, mode=o.mode, state_rate=o.state_rate,
                            hold_pressure=o.hold_pressure, inbox=self.inbox, health=self.health,
                            scenario_name=self.sc.name, driver=self._driver(self.sc), user_input=o.user_input,
                            test_fault_at=self.test_fault_at, faults=self.fault_specs, fault_where=self.fault_where,
                            user_hold=o.user_hold)
        self.loop.port = self.port
        self.loop.on_model_fault = self._on_model_fault
        if o.record is not None:         # (after the loop: a fault that does not fit the vehicle leaves no file)
            from bridge.mcap_recorder import Recorder
            self.recorder = Recorder(o.record, self.vehicle_id, metadata=self.session_metadata(),
                                     poll_interval=0.005, channels=ch)
        scene, road = self._foxglove()
        from .outbox import Outbox
        self.outbox = Outbox(self.rings, self.loop.lp.sensor_ids, zenoh=self.zenoh, recorder=self.recorder,
                             status_fn=self.loop.status, status_period=1.0 / o.status_rate, channels=ch,
                             frame_periods=[f.period for f in self.codec.sensor_frames],
                             scene=scene, road=road, foxglove=self.foxglove, event_log=self.loop.event_log)
        self.loop.outbox = self.outbox
        self.pacer = Pacer(self.loop.run_steps, self.sim.dt, "fast" if o.mode == "fast" else (
            "lockstep" if o.mode == "lockstep" else "realtime"), max_catch_up=o.max_catch_up,
            health=self.health, spin=o.spin, stop_event=self._stopping)
        if self.zenoh is not None:
            self.zenoh.serve(self.control, self.config)
        self._warm_up()

    def _driver(self, sc):
        """The scenario's driver for a session, with the service's ``controller`` if it was given one."""
        d = sc.driver()
        if self.controller is not None:
            d.controller = self.controller
        return d

    def _foxglove(self):
        """The 3D scene (bridge.scene) for the recording and the Foxglove server, and that server when
        asked for (``--foxglove-port``): (SceneBuilder, road scene bytes), or (None, None)."""
        o = self.opts
        if o.record is None and o.foxglove_port is None:
            return None, None
        from bridge.scene import scene_for

        scene, road = scene_for(self.sim, self.vehicle_id, (self.sc.spec.initial.x, self.sc.spec.initial.y))
        if o.foxglove_port is not None:
            from bridge.foxglove_live import FoxgloveLive
            self.foxglove = FoxgloveLive(self.vehicle_id, self.model.channels, o.foxglove_host, o.foxglove_port,
                                         o.foxglove_allow_remote)
        return scene, road

    def _warm_up(self) -> None:
        """Load every compiled kernel of the loop (numba loads a cached kernel at its first call:
        ~1 s for the vehicle step) on a throwaway copy, so the first paced step is not a stall."""
        sim, sc = build_sim(self.scenario_path, self.opts.vehicle, self.opts.dt, self.models)
        scratch = HilLoop(sim, self.codec, mode=self.opts.mode, state_rate=self.opts.state_rate,
                          driver=sc.driver())
        if scratch.mode == "lockstep":
            scratch.advance(scratch.status_every)                 # every branch of the step
            scratch.take_frames()
        else:
            scratch.run_steps(scratch.status_every)
        self.health.recent_percentiles()

    def _open_can(self) -> None:
        o = self.opts
        from .busport import BusPort

        iface, chan = o.can_interface, o.can_channel
        if iface is None:
            if socketcan_available(chan or "vcan0"):
                iface, chan = "socketcan", chan or "vcan0"
            else:
                port = o.can_hub_port or default_hub_port()
                if chan is None and o.start_hub and not _reachable(HUB_HOST, port):
                    self.hub = LoopbackHub(port)
                    self.out(f"rtsim serve: started the loopback CAN hub on {self.hub.channel} "
                             f"(python-can interface 'remote'; no SocketCAN in this kernel)")
                iface, chan = "remote", chan or f"{HUB_HOST}:{port}"
        self.can_interface, self.can_channel = iface, chan
        notify = (lambda: self.inbox.put(("can", None))) if o.mode == "lockstep" else None
        self.port = BusPort(self.rings, iface, chan, notify=notify)

    def session_metadata(self) -> dict[str, dict[str, str]]:
        """What `rtsim resim` needs to rebuild this session: the files as they were, the step, the
        mode and the watchdog's hold pressure (MCAP metadata records)."""
        from rtsim.vehicle.offline import default_vehicle_path

        vpath = resolve_vehicle(self.opts.vehicle) if self.opts.vehicle else (self.sc.vehicle_path or default_vehicle_path())
        return {
            "rtsim.session": {"mode": self.opts.mode, "dt": repr(self.sim.dt), "vehicle_id": self.vehicle_id,
                              "scenario": self.sc.name, "hold_pressure": repr(self.loop_hold_pressure()),
                              "state_rate": repr(self.opts.state_rate), "rider": self.opts.rider,
                              "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                              **({} if self.test_fault_at is None else
                                 {TEST_FAULT_METADATA: repr(self.test_fault_at)})},
            "rtsim.scenario": {"path": str(self.scenario_path.resolve()), "toml": self.scenario_path.read_text()},
            "rtsim.vehicle": {"path": str(vpath.resolve()), "toml": vpath.read_text()},
            "rtsim.dbc": {"path": str(self.codec.path.resolve()), "text": self.codec.path.read_text()},
            **({} if not self.fault_specs else
               {"rtsim.faults": {"faults": json.dumps([s.table() for s in self.fault_specs])}}),
        }

    def _on_model_fault(self, fault) -> None:
        """The loop entered the model-fault state (loop thread, once per failure): one console line; a
        status carrying the fault published at once, and the recording's chunk with it pushed to disk."""
        self.out(f"rtsim serve: {fault.line()}; SIM_STATUS goes on with fault_model = 1, the sensor frames "
                 f"stopped; send the reset control op to restart")
        if self.outbox is not None:
            self.outbox.status_now(flush_recording=True)

    def session_end(self) -> dict[str, str]:
        """How the session ended (the recording's ``rtsim.session_end`` metadata, string values): ``how``
        ("stopped", or "model_fault" when the model was in the fault state at the close, then the fault's
        fields: reason_code, reason, message, step, sim_time, coordinate) and ``end_sim_time`` (s)."""
        fault = self.loop.model_fault if hasattr(self, "loop") else None
        end = {"how": "model_fault" if fault is not None else "stopped",
               "end_sim_time": repr(self.loop.sim_time) if hasattr(self, "loop") else "0.0"}
        if fault is not None:
            end.update({k: str(v) if not isinstance(v, float) else repr(v) for k, v in fault.as_dict().items()})
        return end

    def loop_hold_pressure(self) -> float:
        from bridge.can_codec import DEFAULT_HOLD_PRESSURE

        return self.opts.hold_pressure if self.opts.hold_pressure is not None else DEFAULT_HOLD_PRESSURE

    # -- control (Zenoh threads) -----------------------------------------------------------------------
    def control(self, request: dict) -> dict:
        """Handle one control request (see ``HilLoop._control``); builds new simulations here, off the
        loop thread, and waits for the loop to take the request."""
        op = request.get("op")
        try:          # every argument as its op declares it (rtsim.service.control_args), before the loop
            args = check_request(op, {k: v for k, v in request.items() if k != "op"})
            if op == "load_scenario":
                path = scenario_file(args["scenario"], scenario_folders(self.opts.scenario_dirs))
        except ControlError as exc:
            return {"ok": False, "error": str(exc)}
        if op in ("reset", "load_scenario"):
            path = self.scenario_path if op == "reset" else path
            sim, sc = build_sim(path, self.opts.vehicle, self.opts.dt, self.models, self.opts.rider == "on")
            if op == "load_scenario":
                self.scenario_path, self.sc, self.model = path, sc, sim.vm
                if self.outbox is not None and self.outbox.scene is not None:     # its road (and vehicle) in 3D
                    from bridge.scene import scene_for
                    self.outbox.replace_scene(*scene_for(sim, self.vehicle_id, (sc.spec.initial.x, sc.spec.initial.y)))
            args = {"_sim": sim, "_name": sc.name, "_driver": self._driver(sc)}
            if op == "load_scenario":       # the new scenario's faults replace the old one's
                args["_faults"] = session_faults(self.opts, sc)
        req = Request(op, args)
        self.inbox.put(("ctl", req))
        timeout = 120.0 if op == "step" else 10.0
        if not req.done.wait(timeout):
            return {"ok": False, "error": f"{op}: the loop did not answer within {timeout:g} s"}
        return req.reply

    def config(self) -> dict:
        """The running configuration (Zenoh ``config`` query)."""
        o = self.opts.model_dump(mode="json")
        return {
            "vehicle_id": self.vehicle_id,
            "options": o,
            "scenario": {"name": self.sc.name, "path": str(self.scenario_path)},
            "vehicle": self.model.config.model_dump(mode="json"),
            "dt": self.sim.dt,
            "can": self.port.stats() if self.port is not None else None,
            "zenoh": {"endpoints": list(self.zenoh.endpoints)} if self.zenoh is not None else None,
            "dbc": str(self.codec.path),
            "channels": json.loads(self.codec.channels.to_json()),   # the served vehicle's interface
            # what a person may drive (rtsim.vehicle.kit.user_inputs): channels, ranges, full scales, the
            # bus command each competes with, the page's control groups and default plots
            "user_inputs": self.sim.user_inputs.as_json(),
        }

    # -- running ---------------------------------------------------------------------------------------
    def describe(self) -> list[str]:
        lines = [f"rtsim serve: vehicle {self.vehicle_id} ({self.model.config.name}), scenario "
                 f"{self.sc.name}, mode {self.opts.mode}, step {self.sim.dt * 1e3:g} ms",
                 f"  CAN:    {self.port.description} (DBC {self.codec.path.name}: sensors every "
                 f"{self.loop.sensor_every * self.sim.dt * 1e3:g} ms, status every "
                 f"{self.loop.status_every * self.sim.dt * 1e3:g} ms)"]
        if self.zenoh is not None:
            lines.append(f"  Zenoh:  {', '.join(self.zenoh.endpoints)} (peer, scouting off); keys "
                         f"rtsim/{self.vehicle_id}/{{sensors,state,status,commands,control,config}}")
        else:
            lines.append("  Zenoh:  off")
        if self.foxglove is not None:
            lines.append(f"  Foxglove: {self.foxglove.url} (open it in the Foxglove app: Open connection)")
        lines.append(f"  record: {self.recorder.path}" if self.recorder is not None else "  record: off")
        if self.fault_specs:
            lines.append(f"  faults: {len(self.fault_specs)} armed ({', '.join(s.id for s in self.fault_specs)}); "
                         f"live: control ops inject_fault, clear_fault")
        lines.append("  stop with Ctrl-C (SIGINT) or SIGTERM")
        return lines

    def run(self) -> dict:
        """Run until stopped (signal, ``stop()``, or ``duration``); returns the closing summary. The
        description, whose last line says the service is ready, is printed once the signals are handled
        and the heap is frozen: a SIGTERM sent on reading it stops the service cleanly."""
        restore = self._install_signals()
        # The cyclic garbage collector would run on whichever thread allocates, the loop included,
        # for milliseconds at a time. Move everything built so far out of its reach and switch the
        # automatic collection off; the publisher thread collects the young generation once a second.
        gc.collect()
        gc.freeze()
        gc.disable()
        for line in self.describe():
            self.out(line)
        unpin = self._pin_loop_thread()
        t0 = time.monotonic()
        try:
            if self.opts.mode == "lockstep":
                if self.opts.duration is not None:
                    threading.Timer(self.opts.duration, self.stop).start()
                self.loop.run_lockstep()
            else:
                self.pacer.run(duration=self.opts.duration)
        finally:
            unpin()
            gc.enable()
            restore()
            wall = time.monotonic() - t0
            summary = self.close()
            summary["wall_s"] = wall
        return summary

    def _pin_loop_thread(self):
        """``--loop-cpu N``: this thread (the loop's; the others were started before and keep their CPUs)
        on CPU N alone; ``--loop-priority P``: this thread under SCHED_FIFO at priority P. On Linux
        ``sched_setaffinity(0, ...)`` and ``sched_setscheduler(0, ...)`` act on the calling thread only.
        Returns what restores the previous settings."""
        import os

        cpu, prio = self.opts.loop_cpu, self.opts.loop_priority
        undo = []
        try:
            if cpu is not None:
                before = os.sched_getaffinity(0)
                os.sched_setaffinity(0, {cpu})
                undo.append(lambda: os.sched_setaffinity(0, before))
                self.out(f"rtsim serve: loop thread pinned to CPU {cpu}")
            if prio is not None:
                policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
                undo.append(lambda: os.sched_setscheduler(0, policy, param))
                self.out(f"rtsim serve: loop thread under SCHED_FIFO, priority {prio}")
        except OSError as exc:
            for u in reversed(undo):
                u()
            what = f"--loop-cpu {cpu}" if len(undo) == 0 and cpu is not None else f"--loop-priority {prio}"
            raise ConfigError(f"{what}: {exc.strerror or exc}") from exc

        def restore():
            for u in reversed(undo):
                u()
        return restore

    def stop(self) -> None:
        """Thread-safe: makes ``run()`` return within one period (and close everything)."""
        self._stopping.set()
        self.pacer.stop()
        self.loop.stop_event.set()

    def _install_signals(self):
        if threading.current_thread() is not threading.main_thread():
            return lambda: None
        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

        def handler(signum, frame):
            self.stop()
        for s in old:
            signal.signal(s, handler)

        def restore():
            for s, h in old.items():
                signal.signal(s, h)
        return restore

    def close(self) -> dict:
        """Stop every part, finalise the recording; idempotent. Returns a summary."""
        if self._closed:
            return {}
        self._closed = True
        summary = {}
        if hasattr(self, "loop"):
            summary = {"sim_time": self.loop.sim_time, "steps": self.loop.k, "health": self.health.summary(),
                       "run_state": self.loop.run_state, "message": self.loop.message,
                       "rejected": dict(self.loop.rx.counters), "accepted_frames": self.loop.rx.accepted,
                       "model_fault": None if self.loop.model_fault is None else self.loop.model_fault.as_dict()}
            if self.recorder is not None:
                self.recorder.session_end = self.session_end()
        for part in ("outbox", "foxglove", "zenoh", "recorder", "port", "hub"):
            obj = getattr(self, part)
            if obj is None:
                continue
            try:
                obj.close()
            except Exception as exc:  # noqa: BLE001  (report, keep closing the others)
                print(f"rtsim serve: closing {part}: {type(exc).__name__}: {exc}", file=sys.stderr)
        if self.port is not None:
            summary["can"] = self.port.stats()
        if self.foxglove is not None:
            summary["foxglove"] = {"url": self.foxglove.url, "published": self.foxglove.published,
                                   "errors": self.foxglove.errors}
        if self.outbox is not None and self.outbox.scene is not None:
            summary["scene_errors"] = self.outbox.scene_errors
        if self.recorder is not None:
            summary["recording"] = {"path": str(self.recorder.path), "written": self.recorder.written,
                                    "dropped": self.recorder.dropped, "chunks": self.recorder.chunks}
        return summary


def _reachable(host: str, port: int) -> bool:
    import socket

    try:
        socket.create_connection((host, port), timeout=0.5).close()
        return True
    except OSError:
        return False

