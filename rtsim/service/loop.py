"""The HIL service's fixed-step loop: commands in, one model step, sensor frames out.

One step (``step_once``), all on the real-time thread, nothing allocated by the model side:

1. in realtime/fast mode, take every frame the CAN reader queued (commands through the E2E checks of
   ``CommandReceiver``; a lockstep request outside lockstep mode is counted and ignored) and every
   control request (Zenoh);
2. the watchdog (``CommandReceiver.apply_timeouts``) writes the command values, or the safe values of
   timed-out commands, straight into the vehicle's command array;
3. one compiled vehicle step (``VehicleSim.step``);
4. at the sensor period of the DBC (2 ms): true sensor values (plus the vehicle config's sensor model,
   if any), packed into all sensor frames by one compiled call and sent from reusable messages; the
   sample goes to the outbox ring (Zenoh ``sensors``, MCAP ``sensors`` and ``can/tx``);
5. at the state period (100 Hz default): the observer state (compiled) into the outbox ring;
6. at the status frame's DBC period (100 ms): the SIM_STATUS frame.

Times: everything the model and the watchdog see is simulation time ``t = steps * dt``; the pacer
keeps it on the wall clock in realtime mode. Lockstep mode runs ``run_lockstep``: the thread waits on
the inbox and processes CAN frames and control requests strictly in arrival order, so commands sent
before a SIM_STEP_REQ apply to its steps; the run is deterministic (replayable bit for bit).

Failures: a model failure (SimulationError) stops stepping (``run_state = "stopped"``, the error in
``message``), the service keeps answering and publishing status until a ``reset`` or
``load_scenario``. Bus errors are counted by the BusPort and flagged in the status frame.
"""
from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field

import numpy as np

from bridge.can_codec import FAULTS, Codec, CommandReceiver
from bridge.can_pack import SensorPacker
from rtsim.channels import COMMAND_NAMES
from rtsim.errors import RtsimError, SimulationError
from rtsim.realtime.health import LoopHealth
from rtsim.vehicle.sensors import NSENSOR, SM_DELAY_STEPS, seed_sensor_noise, sensor_model, sensor_params
from rtsim.mbs.model import OK
from rtsim.vehicle.state import NSTATE_OUT

from .kernel import service_step

RUN_STATES = ("running", "paused", "stopped")


@dataclass
class Request:
    """A control request crossing from a Zenoh thread to the loop thread; ``done`` is set when the
    loop has handled it, with ``reply`` (a dict) filled in."""
    op: str
    args: dict
    done: threading.Event = field(default_factory=threading.Event)
    reply: dict | None = None


class HilLoop:
    def __init__(self, sim, codec: Codec, port=None, outbox=None, *, mode: str = "realtime",
                 state_rate: float = 100.0, hold_pressure: float | None = None, inbox=None,
                 health: LoopHealth | None = None, scenario_name: str | None = None, sim_factory=None):
        self.codec = codec
        self.port = port
        self.outbox = outbox
        self.mode = mode
        self.inbox = inbox if inbox is not None else queue.SimpleQueue()
        self.health = health if health is not None else LoopHealth()
        self.scenario_name = scenario_name
        self.sim_factory = sim_factory            # (scenario path | None) -> (VehicleSim, name); for reset
        kw = {} if hold_pressure is None else {"hold_pressure": hold_pressure}
        self.rx = CommandReceiver(codec, **kw)
        self.packer = SensorPacker(codec)
        self.sensor_msgs = self.packer.make_messages() if port is not None else None
        self._step_req_id = codec.step_request.frame_id
        self._step_req_counter: int | None = None
        self.lockstep_rejected = 0
        self.lockstep_ignored = 0
        self.run_state = "running"
        self.message = ""
        self.stop_event = threading.Event()
        self._install(sim, state_rate)

    # -- set-up ------------------------------------------------------------------------------------
    def _install(self, sim, state_rate: float | None = None) -> None:
        """Take a (new) VehicleSim: step counters, sensor model, rates."""
        self.sim = sim
        self.dt = sim.dt
        self.k = 0
        sensor_period = min(f.period for f in self.codec.sensor_frames)
        status_period = self.codec.status_frame.period
        self.sensor_every = self._every(sensor_period, "sensor period")
        self.status_every = self._every(status_period, "status period")
        if state_rate is not None:
            self.state_every = max(1, int(round(1.0 / (state_rate * self.dt))))
        self.true = np.zeros(NSENSOR)
        self.values = np.zeros(NSENSOR)
        self.state = np.zeros(NSTATE_OUT)
        self.sm = sensor_params(sim.vm.config.sensors.channels, self.sensor_every * self.dt)
        self.sm_on = bool(np.any(self.sm))
        self.sm_buf = np.zeros((NSENSOR, int(self.sm[:, SM_DELAY_STEPS].max()) + 1))
        self.sm_head = 0
        if self.sm_on:
            seed_sensor_noise(0)          # reproducible noise: a session replays bit for bit
        self.rx.reset(0.0)                    # a new session: no command received yet
        self._mask = -1
        self._bus_errors_at_status = 0

    def _every(self, period: float, what: str) -> int:
        n = period / self.dt
        if n < 1 - 1e-9 or abs(n - round(n)) > 1e-6:
            raise RtsimError(f"step {self.dt:g} s does not divide the {what} {period:g} s of the DBC; "
                             f"use a step such as 0.001 or 0.0005 s")
        return int(round(n))

    @property
    def sim_time(self) -> float:
        return self.k * self.dt

    # -- one step ------------------------------------------------------------------------------------
    def step_once(self) -> None:
        """One fixed step (see the module docstring). In realtime/fast mode it first drains the inbox."""
        if self.mode != "lockstep":
            self.drain_inbox()
        if self.run_state != "running":
            return
        t = self.k * self.dt
        mask = self.rx.apply_timeouts(t, self.sim.io.commands)
        if mask != self._mask:
            self._mask = mask
            if self.outbox is not None:
                self.outbox.push_event("commands", t, self._commands_payload(
                    "safe" if mask else "can"))
        k = self.k + 1
        t1 = k * self.dt
        want_sensors = k % self.sensor_every == 0
        want_state = k % self.state_every == 0
        sim, p = self.sim, self.packer
        status = service_step(sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states,
                              sim.io, self.dt, want_sensors, not self.sm_on, self.true, t1, p.time_start,
                              p.time_mask, p.sig_int, p.sig_float, p.words, want_state, self.state)
        if status != OK:
            try:
                sim.sim._raise(status, k)
            except SimulationError as exc:
                self.run_state = "stopped"
                self.message = f"model stopped at t = {t:.3f} s: {exc}"
            return
        self.k = k
        if want_sensors:
            self._sensors(t1)
        if want_state and self.outbox is not None:
            self.outbox.push_state(t1, self.state)
        if k % self.status_every == 0:
            self.send_status(t1)

    def run_steps(self, n: int) -> None:
        for _ in range(int(n)):
            self.step_once()

    def _sensors(self, t: float) -> None:
        """Send and hand over the sample whose true values ``service_step`` computed (and packed,
        unless the vehicle config has a sensor model, applied here first)."""
        if self.sm_on:
            self.sm_head = sensor_model(self.sm, self.sm_buf, self.sm_head, self.true, self.values)
            vals = self.values
            self.packer.pack(vals, t)
        else:
            vals = self.true
        if self.port is not None:
            self.packer.refresh_messages(t)
            self.port.send_batch(self.sensor_msgs)
        if self.outbox is not None:
            self.outbox.push_sensor(t, vals, self.packer.words)

    def send_status(self, t: float) -> None:
        faults = self.faults()
        self._bus_errors_at_status = self.port.errors if self.port is not None else 0
        fid, data = self.codec.encode_status(self.mode, t, self.health.overruns, faults, self.rx.counters)
        self._send_event_frame(t, fid, data)

    def _send_event_frame(self, t: float, fid: int, data: bytes) -> None:
        if self.port is not None:
            import can

            self.port.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False, timestamp=t))
        if self.outbox is not None:
            self.outbox.push_event("can/tx", t, (fid, data))

    def faults(self) -> dict[str, bool]:
        f = {name: False for name in FAULTS}
        f.update(self.rx.faults)
        if self.port is not None:
            f["bus_error"] = (not self.port.up) or self.port.errors > self._bus_errors_at_status
        return f

    def _commands_payload(self, source: str) -> dict:
        cmds = self.sim.io.commands
        return {**{n: float(cmds[i]) for i, n in enumerate(COMMAND_NAMES)}, "source": source}

    # -- inbox ---------------------------------------------------------------------------------------
    def drain_inbox(self) -> None:
        inbox = self.inbox
        while not inbox.empty():
            self.handle(inbox.get_nowait())

    def handle(self, item) -> None:
        kind, obj = item
        if kind == "can":
            self.on_frame(obj)
        else:
            self.on_request(obj)

    def on_frame(self, msg) -> None:
        t = self.k * self.dt
        data = msg.data
        if self.outbox is not None:
            self.outbox.push_event("can/rx", t, (msg.arbitration_id, bytes(data)))
        if msg.arbitration_id == self._step_req_id:
            self.on_step_request(data)
            return
        if self.rx.receive(msg.arbitration_id, data, t) and self.outbox is not None:
            i = self.rx.command_index(msg.arbitration_id)
            self.outbox.push_event("commands", t, {COMMAND_NAMES[i]: self.rx.value[i], "source": "can"})

    def on_step_request(self, data) -> None:
        dec = self.codec.decode_step_request(data)
        if dec is None or (self._step_req_counter is not None and dec[1] == self._step_req_counter):
            self.lockstep_rejected += 1          # bad DLC/CRC/count, or a repeated request
            return
        steps, counter = dec
        self._step_req_counter = counter
        if self.mode != "lockstep":
            self.lockstep_ignored += 1
            return
        self.run_steps(steps)
        fid, ack = self.codec.encode_step_ack(self.sim_time, counter)
        self._send_event_frame(self.sim_time, fid, ack)

    # -- control requests (from Zenoh) --------------------------------------------------------------
    def on_request(self, req: Request) -> None:
        try:
            req.reply = self._control(req.op, req.args)
        except Exception as exc:  # noqa: BLE001  (a bad request must never stop the loop)
            req.reply = {"ok": False, "error": f"{req.op}: {exc}"}
        req.done.set()

    def _control(self, op: str, args: dict) -> dict:
        if op == "pause":
            if self.run_state == "running":
                self.run_state = "paused"
            return {"ok": True, "run_state": self.run_state, "sim_time": self.sim_time}
        if op == "resume":
            if self.run_state == "paused":
                self.run_state = "running"
            elif self.run_state == "stopped":
                return {"ok": False, "error": f"resume: the model stopped ({self.message}); send reset"}
            return {"ok": True, "run_state": self.run_state, "sim_time": self.sim_time}
        if op == "step":
            if self.mode != "lockstep":
                return {"ok": False, "error": f"step: only in lockstep mode (the service runs in {self.mode})"}
            n = int(args.get("n", 1))
            if not 1 <= n <= 1_000_000:
                return {"ok": False, "error": f"step: n = {n} outside 1..1000000"}
            if self.run_state != "running":
                return {"ok": False, "error": f"step: the simulation is {self.run_state}"}
            self.run_steps(n)
            return {"ok": True, "sim_time": self.sim_time, "steps": self.k}
        if op in ("reset", "load_scenario", "_install"):
            sim, name = args["_sim"], args.get("_name")
            self._install(sim)
            self.scenario_name = name or self.scenario_name
            self.run_state = "running"
            self.message = f"{op}: {self.scenario_name} at t = 0"
            return {"ok": True, "scenario": self.scenario_name, "sim_time": 0.0}
        return {"ok": False, "error": f"unknown op {op!r}; ops: reset, pause, resume, load_scenario, step"}

    # -- lockstep ------------------------------------------------------------------------------------
    def run_lockstep(self) -> None:
        """Lockstep mode: process inbox items in arrival order until ``stop_event``."""
        inbox = self.inbox
        while not self.stop_event.is_set():
            try:
                item = inbox.get(timeout=0.05)
            except queue.Empty:
                continue
            self.handle(item)

    # -- status ----------------------------------------------------------------------------------------
    def status(self) -> dict:
        """The status payload (bridge.payloads ``status``); called from the publisher thread."""
        h = self.health
        rec = getattr(self.outbox, "recorder", None) if self.outbox is not None else None
        zen = getattr(self.outbox, "zenoh", None) if self.outbox is not None else None
        pct = h.recent_percentiles()
        return {
            "time": self.sim_time,
            "vehicle_id": self.sim.vm.config.id,
            "mode": self.mode,
            "run_state": self.run_state,
            "sim_time": self.sim_time,
            "steps": self.k,
            "overruns": h.overruns,
            "skipped_steps": h.skipped_steps,
            "catch_up_steps": h.catch_up_steps,
            "stalls": h.stalls,
            "lateness_p50": pct["lateness_p50"],
            "lateness_p99": pct["lateness_p99"],
            "lateness_max": h.max_lateness if h.samples else None,
            "cpu_p50": pct["cpu_p50"],
            "cpu_p99": pct["cpu_p99"],
            "cpu_max": h.max_cpu if h.samples else None,
            "steal": h.steal_seconds(),
            "faults": self.faults(),
            "rejected": {k: self.rx.counters[k] for k in ("dlc", "crc", "counter", "range", "unknown_id")},
            "accepted_frames": self.rx.accepted,
            "bus_errors": self.port.errors if self.port is not None else 0,
            "recorder": None if rec is None else {"path": str(rec.path), "written": rec.written,
                                                  "dropped": rec.dropped, "chunks": rec.chunks},
            "zenoh_dropped": getattr(zen, "dropped", 0) if zen is not None else 0,
            "scenario": self.scenario_name,
            "message": self.message,
        }

