"""The HIL service's fixed-step loop: commands in, one model step, sensor frames out.

Each step is one compiled call (``rtsim.service.kernel.loop_run``) over preallocated arrays: it takes
the frames the CAN reader thread put in the receive ring (E2E checks, counters, watchdog), steps the
vehicle, packs the sensor and status frames into the transmit ring and the samples into the
publisher's rings (``rtsim.service.rings``). The Python here only moves between threads: control
requests from Zenoh (a queue, looked at once per step), waking the CAN writer, the inputs of the
status frame (loop overruns, bus errors; every status period) and model failures.

Times: everything the model and the watchdog see is simulation time ``t = k * dt``; the pacer keeps
it on the wall clock in realtime mode. Lockstep mode runs ``run_lockstep``: the thread waits for
frames or control requests and takes them in order; a SIM_STEP_REQ runs its steps and is acknowledged,
commands received before it apply to its steps; the run is deterministic (replayable bit for bit).

Failures: a model failure (a failed vehicle step) puts the loop in the model-fault state
(``run_state = "model_fault"``, ``model_fault`` the rtsim.model_fault.ModelFault: reason, step, time,
coordinate; ``message`` its line): the vehicle stays frozen at its last good step, simulation time and
the pace go on, the E2E receiver and the watchdog keep judging frames, SIM_STATUS (``fault_model``) and
SIM_DIAG (``model_fault_reason``) keep their period, the sensor frames stop (the DBCs' rule), and a
lockstep SIM_STEP_REQ is still run (time advances by its steps) and acknowledged, until a ``reset`` or
``load_scenario``. ``on_model_fault`` (optional) is called once with the ModelFault, on the loop thread.
Bus errors are counted by the BusPort and flagged in the status frame.

Faults (rtsim.faults): the session's (``faults``: armed at every start, a reset too) and those armed live
(control ops ``inject_fault``, ``clear_fault``) live in ``fault_table``; their onsets and ends go to the
recording on the ``faults`` topic, their states to the status (``injected_faults``).
"""
from __future__ import annotations

import collections
import queue
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from bridge.can_codec import DIAG_SOURCES, Codec, CommandReceiver
from bridge.can_e2e import (C_STEP_IGNORED, C_STEP_REJECTED, C_STEP_REPEATED, G_FOREIGN_T, IV_HAS_VALUE,
                            IV_TIMED_OUT, SECOND_SIM_HOLD, TIME_EPS)
from bridge.payloads import CONTROL_OPS
from drivers.base import INPUT_NAMES, INPUT_UNITS, LIMITS, NINPUT, NSTATE
from drivers.driver import Driver
from rtsim.boundcall import bind
from rtsim.errors import ConfigError, RtsimError
from rtsim.faults.kernels import G_EV_HEAD
from rtsim.faults.spec import FaultSpec
from rtsim.faults.table import FaultTable
from rtsim.mbs.model import OK
from rtsim.model_fault import ModelFault, describe, force_failure, test_fault_step
from rtsim.realtime.health import LoopHealth

from .kernel import (LI_BUS_ERROR, LI_K, LI_MASK, LI_MODEL_FAULT, LI_OVERRUNS, LI_PENDING_ACK, LI_PENDING_COUNTER,
                     LI_PENDING_STEPS, LI_STEP_COUNTER, NLI, NO_STEP_COUNTER, NPI, NST_AFTER_FAULTS, PI_ACK_ID,
                     PI_DIAG_ID, PI_DRIVER, PI_LOCKSTEP, PI_MODE_CODE, PI_SENSOR_EVERY, PI_STATE_EVERY,
                     PI_STATUS_EVERY, PI_STATUS_ID, PI_STEP_REQ_ID, ST_BUS_ERROR, ST_FAULT0, ST_RANGE, LoopParams,
                     LoopState, loop_run)
from .faults import fault_targets
from .rings import Rings, RxWriter, make_rings
from .user_input import NUSR, NWORK, USER_HOLD, check_value

RUN_STATES = ("running", "paused", "model_fault")
STEPPING = ("running", "model_fault")     # the states whose steps advance simulation time
CYCLE_WINDOW = 65536   # steps of compiled-call durations kept (as LoopHealth's window)
CHUNK = 256            # steps per compiled call when many run back to back (lockstep, re-simulation)
EVENT_LOG = 4096       # recorded events waiting for the publisher (it takes them every few ms)
#: the control ops that change what the simulation does (bridge.payloads.CONTROL_OPS) are recorded on the
#: ``control`` topic with the step they acted at, so that `rtsim resim` repeats them; ``drive`` has ``user``


MODEL_FAULT_TX = "SimModelFaultTx"      # the DBC's message attribute: what a frame does in the model-fault state


def check_model_fault_rule(codec: Codec) -> None:
    """The DBC must declare (attribute SimModelFaultTx, ENUM "stop","continue") what this loop does with
    the frames it sends while the model has failed: every sensor frame "stop", SIM_STATUS, its diagnostics
    and the lockstep acknowledgement "continue"; a DBC that declares otherwise is refused (one line)."""
    dbc = codec.db.dbc
    defn = dbc.attribute_definitions.get(MODEL_FAULT_TX) if dbc is not None else None
    if defn is None:
        raise RtsimError(f"{codec.path}: no {MODEL_FAULT_TX} message attribute (ENUM \"stop\",\"continue\"): the "
                         f"DBC must declare what its frames do while the model has failed")

    def rule(name: str) -> str:
        attr = codec.db.get_message_by_name(name).dbc.attributes.get(MODEL_FAULT_TX)
        v = attr.value if attr is not None else defn.default_value
        return defn.choices[v] if isinstance(v, int) and defn.choices else str(v)
    want = {f.name: "stop" for f in codec.sensor_frames}
    for f in (codec.status_frame, getattr(codec, "diag_frame", None), codec.step_ack):
        if f is not None:
            want[f.name] = "continue"
    wrong = [f"{n} {rule(n)!r}" for n, w in want.items() if rule(n) != w]
    if wrong:
        raise RtsimError(f"{codec.path}: {MODEL_FAULT_TX}: {', '.join(wrong)}; this simulator stops every sensor "
                         f"frame and continues SIM_STATUS, SIM_DIAG and SIM_STEP_ACK while the model has failed")


@dataclass
class Request:
    """A control request crossing from a Zenoh thread to the loop thread; ``done`` is set when the
    loop has handled it, with ``reply`` (a dict) filled in."""
    op: str
    args: dict
    done: threading.Event = field(default_factory=threading.Event)
    reply: dict | None = None


class HilLoop:
    """The loop of one service (see the module docstring). ``rings`` are shared with the CAN port and
    the publisher (made here if not given); ``on_chunk`` (optional) is called after every compiled call
    (re-simulation reads the rings there). ``driver`` (the scenario's, ``Scenario.driver()``) drives, in
    the loop, the driver's commands the DBC does not carry (the EPS car: its controller under test
    commands the motor; the steering-wheel angle, throttle and brake come from the scenario)."""

    def __init__(self, sim, codec: Codec, rings: Rings | None = None, *, mode: str = "realtime",
                 state_rate: float = 100.0, hold_pressure: float | None = None, inbox=None,
                 health: LoopHealth | None = None, scenario_name: str | None = None, on_chunk=None,
                 driver: Driver | None = None, user_input: bool = True, test_fault_at: float | None = None,
                 faults=(), fault_where=None, user_hold: float = USER_HOLD):
        self.codec = codec
        self.user_hold = user_hold       # s of wall time a user's command is held without a new request
        #: the session's faults (rtsim.faults.FaultSpec), armed at every start of the session (a reset too);
        #: ``fault_where``: per fault (file, key) where it was read (errors name them)
        self.fault_specs: list[FaultSpec] = list(faults)
        self.fault_where = list(fault_where) if fault_where is not None else [
            ("faults", f"faults[{n}]") for n in range(len(self.fault_specs))]
        self.fault_table: FaultTable | None = None
        self.port = None                 # set by the service: bus state for the status, writer wake-up
        self.outbox = None               # set by the service: recorder/Zenoh figures for the status
        self.mode = mode
        self.inbox = inbox if inbox is not None else queue.SimpleQueue()
        self.health = health if health is not None else LoopHealth()
        self.scenario_name = scenario_name
        self.on_chunk = on_chunk
        self.user_input = user_input       # the ``drive`` op (rtsim.service.user_input) accepted
        self._usr_deadline = None          # user_clock time the user's commands lapse at
        self.user_clock = time.monotonic   # the wall clock (s) a user command's hold runs on; a test may set its own
        self._usr_seq = None
        self._usr_requests = 0
        self._usr_lapses = 0               # hand-backs because the user's requests stopped coming
        # (topic, event) for the recording and re-simulation, each with the step it acted at: every change
        # of the user source (values, takeover; topic ``user``) and every control op of CONTROL_OPS
        # (topic ``control``; bridge.payloads has both schemas); the publisher thread takes them
        self.event_log: collections.deque = collections.deque()
        self.event_log_dropped = 0
        self.events_logged = 0
        self._usr_last = None
        ch = codec.channels               # the served vehicle's interface: ring widths, payload names
        if (len(ch.sensors), len(ch.state)) != (sim.nsensor, sim.nstate):
            raise RtsimError(f"{codec.path}: the vehicle declares {len(ch.sensors)} sensor and "
                             f"{len(ch.state)} state channels; its loop produces {sim.nsensor} and {sim.nstate}")
        self.rings = rings if rings is not None else make_rings(
            len(ch.sensors), len(codec.sensor_frames), len(ch.state), len(ch.commands))
        kw = {} if hold_pressure is None else {"hold_pressure": hold_pressure}
        self.rx = CommandReceiver(codec, slots=sim.command_slots, invalid_slots=sim.invalid_slots, **kw)   # the step's E2E state
        self.rx_writer = RxWriter(self.rings)            # for feeding frames by hand (re-simulation)
        self.state_rate = state_rate
        self.run_state = "running"
        self.message = ""
        self.model_fault: ModelFault | None = None
        # held while a reset or new scenario replaces the session and while the status is read, so a
        # status never pairs the old run state with the new session's fault flags
        self._session_lock = threading.RLock()
        self.on_model_fault = None        # called once per failure with the ModelFault (loop thread)
        self.test_fault_at = test_fault_at       # rtsim.model_fault's test-only hook: s, once per loop
        self._forced_step = None
        self.stop_event = threading.Event()
        self.li = np.zeros(NLI, dtype=np.int64)
        self.li[LI_STEP_COUNTER] = NO_STEP_COUNTER
        self.cycles = np.zeros(CYCLE_WINDOW, dtype=np.int64)
        check_model_fault_rule(codec)
        self._install(sim, driver)

    # -- set-up ------------------------------------------------------------------------------------
    def _install(self, sim, driver: Driver | None = None) -> None:
        """Take a (new) vehicle sim (a car's VehicleSim, a two-wheeler's TwoWheelerHil) and its scenario's
        driver: step counters, sensor model, rates; the E2E counters carry on. A car whose DBC carries the
        EPS motor command gets its EPS in external mode (the stage on at the controller's first valid
        command). A two-wheeler's in-loop driver is its rider (if it has one)."""
        self.sim = sim
        names = self.codec.channels.command_names
        self.external_eps = any(n in sim.eps_commands for n in names)   # the DBC carries the EPS's command
        if self.external_eps:
            sim.external_eps(True)
        # the scenario's driver drives the vehicle's driver inputs its DBC does not carry (a two-wheeler has
        # none of them: its in-loop source is its rider, sim.rider_on)
        driven = [i for i, n in enumerate(INPUT_NAMES) if n in sim.command_slots and n not in names]
        self.driver = driver if driver is not None and driven else Driver()
        self.driver.reset()
        drv_slot = np.full(NINPUT, -1, dtype=np.int64)
        if driver is not None:
            for i in driven:
                drv_slot[i] = sim.command_slots[INPUT_NAMES[i]]
        self.dt = sim.dt
        self.k = 0
        c = self.codec
        self.sensor_every = self._every(min(f.period for f in c.sensor_frames), "sensor period")
        self.frame_every = np.array([self._every(f.period, f"{f.name} period") for f in c.sensor_frames],
                                    dtype=np.int64)
        if np.any(self.frame_every % self.sensor_every):
            raise RtsimError(f"{c.path}: every sensor frame's period must be a multiple of the fastest one's")
        self.status_every = self._every(c.status_frame.period, "status period")
        self.state_every = max(1, int(round(1.0 / (self.state_rate * self.dt))))
        sim.seed_sensor_noise(0)          # reproducible sensor noise: a session replays bit for bit
        lay = c.sensor_layout()
        status = c.status_layout()                    # SIM_STATUS and SIM_DIAG
        ack = c.frame_layout(c.step_ack.name, ("lockstep_sim_time", "lockstep_ack_counter"))
        ints = np.zeros(NPI, dtype=np.int64)
        ints[PI_SENSOR_EVERY], ints[PI_STATE_EVERY], ints[PI_STATUS_EVERY] = \
            self.sensor_every, self.state_every, self.status_every
        ints[PI_LOCKSTEP] = self.mode == "lockstep"
        ints[PI_MODE_CODE] = c.modes[self.mode]
        ints[PI_STEP_REQ_ID], ints[PI_STATUS_ID], ints[PI_ACK_ID], ints[PI_DIAG_ID] = \
            c.step_request.frame_id, c.status_frame.frame_id, c.step_ack.frame_id, c.diag_frame.frame_id
        ints[PI_DRIVER] = bool(np.any(drv_slot >= 0)) or sim.rider_on
        usr_slot, usr_rx = self._user_slots(sim)
        faults = self.rx.fault_names
        sources = c.status_sources
        assert sources[ST_FAULT0 + len(faults) + ST_BUS_ERROR] == "fault_bus_error"
        assert sources[ST_FAULT0 + len(faults) + ST_RANGE] == "rejected_range"
        assert len(sources) + len(DIAG_SOURCES) == ST_FAULT0 + len(faults) + NST_AFTER_FAULTS
        self.fault_table = table = FaultTable(fault_targets(sim, c, self))
        for spec, (source, key) in zip(self.fault_specs, self.fault_where):
            table.arm(spec, 0, source, key)
        self._fault_ev_seen = 0
        self._controller(sim, driver)
        self.lp = LoopParams(self.rx.plan, ints, np.array([self.dt]), lay["frame_id"], lay["time_start"],
                             lay["time_mask"], lay["sig_int"], lay["sig_float"], status["sig_int"],
                             status["sig_float"], ack["sig_int"], ack["sig_float"], np.zeros(2, dtype=np.int64),
                             np.array([sources.index(f"fault_{f}") for f in faults], dtype=np.int64),
                             self.frame_every, self.driver.packed, self.driver.speed, self.driver.path,
                             self.driver.flags, drv_slot, usr_slot, usr_rx, table.plan)
        self.ls = LoopState(self.rx.state, self.li, np.zeros(sim.nsensor), np.zeros(sim.nstate),
                            np.zeros(len(sources) + len(DIAG_SOURCES) + 1), np.zeros(3),
                            np.zeros(len(lay["frame_id"]), dtype=np.int64), np.zeros(2, dtype=np.int64),
                            self.cycles, np.zeros(NSTATE), np.zeros(NINPUT), np.full(NINPUT, np.nan),
                            np.full(NUSR, np.nan), np.zeros(1, dtype=np.int64), np.zeros(NWORK), table.state)
        self._usr_deadline = None
        self._usr_last = None
        li = self.li
        li[LI_K] = 0
        li[LI_MASK] = -1
        li[LI_PENDING_STEPS] = li[LI_PENDING_ACK] = 0
        li[LI_MODEL_FAULT] = 0
        self.model_fault = None
        if self.test_fault_at is not None:
            self._forced_step = test_fault_step(self.test_fault_at, self.dt)
            self.test_fault_at = None         # once: a reset after the forced failure runs clean
        self.rx.reset(0.0)                    # a new session: no command received yet
        self._bus_errors_at_status = self.port.errors if self.port is not None else 0
        # one compiled call per step, its fixed arguments (model, state, loop arrays) bound once: passed
        # as one address table instead of unboxing ~120 arrays at every call (rtsim.boundcall)
        self._loop_run = bind(loop_run, sim.served(), self.lp, self.ls, self.rings, n_free=3)

    def _controller(self, sim, driver) -> None:
        """The scenario's controller FMU (its Driver's ``controller`` mapping), a fresh instance at every
        start (rtsim.service.controller)."""
        old = getattr(self, "ctl", None)
        if old is not None:
            old.close()
        mapping = getattr(driver, "controller", None)
        self.ctl = None
        if mapping is not None:
            from .controller import LoopController
            self.ctl = LoopController(sim, mapping, sim.dt, self.sensor_every, self.state_every)

    def _communicate(self) -> None:
        """The controller's step at step k (see rtsim.service.controller), logged as a user change."""
        self.ctl.communicate(self.k, self.sim_time, self.ls.values, self.ls.state, self.ls.usr)
        self._user_changed("controller")

    def _user_slots(self, sim) -> tuple[np.ndarray, np.ndarray]:
        """Per user channel (rtsim.service.user_input): the command slot it writes (a car's) or the
        invalid-flag slot of the bus command it overrides on a takeover (a two-wheeler's), and the index of
        that bus command among the DBC's commands (-1: not on the bus)."""
        names = self.codec.channels.command_names
        slot = np.full(NUSR, -1, dtype=np.int64)
        rx = np.full(NUSR, -1, dtype=np.int64)
        inputs = sim.user_inputs
        for u, ch in enumerate(inputs.channels):
            slot[u] = inputs.slot(ch, sim.command_slots, sim.invalid_slots, names)
            if ch.bus in names:
                rx[u] = names.index(ch.bus)
        return slot, rx

    def _every(self, period: float, what: str) -> int:
        n = period / self.dt
        if n < 1 - 1e-9 or abs(n - round(n)) > 1e-6:
            raise RtsimError(f"step {self.dt:g} s does not divide the {what} {period:g} s of the DBC; "
                             f"use a step such as 0.001 or 0.0005 s")
        return int(round(n))

    @property
    def sim_time(self) -> float:
        return self.k * self.dt

    @property
    def state(self) -> np.ndarray:
        """The last observer state sample (the vehicle's state channels' order)."""
        return self.ls.state

    def compiled_seconds(self, cycles_per_second: float) -> np.ndarray:
        """Duration (s) of the compiled call of each of the last steps (up to CYCLE_WINDOW), oldest
        first: the part of the loop thread's time spent in compiled code."""
        n = min(self.k, CYCLE_WINDOW)
        idx = (np.arange(self.k - n, self.k) + 1) % CYCLE_WINDOW
        return self.cycles[idx] / cycles_per_second

    @property
    def lockstep_rejected(self) -> int:
        return int(self.rx.state.counts[C_STEP_REJECTED])

    @property
    def lockstep_ignored(self) -> int:
        return int(self.rx.state.counts[C_STEP_IGNORED])

    @property
    def lockstep_repeated(self) -> int:
        """Retransmitted SIM_STEP_REQs (the counter of the request already run): acknowledged again."""
        return int(self.rx.state.counts[C_STEP_REPEATED])

    # -- compiled calls --------------------------------------------------------------------------------
    def _call(self, frames: bool, nsteps: int, ack_counter: int = -1) -> bool:
        """One compiled call; False on a model failure (the loop then in the model-fault state)."""
        if nsteps and self._forced_step == self.k + 1 and self.run_state == "running":
            self._forced_step = None
            force_failure(self.sim)           # the test-only hook (rtsim.model_fault)
        status = self._loop_run(frames, nsteps, ack_counter)
        self.k = int(self.li[LI_K])
        if self.fault_table.state.g[G_EV_HEAD] != self._fault_ev_seen:
            self._fault_events()
        if self.on_chunk is not None:
            self.on_chunk()
        if status != OK:
            self._model_failed(int(status))
            return False
        return True

    def _fault_events(self) -> None:
        """The fault onsets and ends of the last compiled call, for the recording (topic ``faults``)."""
        self._fault_ev_seen = int(self.fault_table.state.g[G_EV_HEAD])
        for ev in self.fault_table.events():
            self._log_event("faults", ev)

    def _model_failed(self, status: int) -> None:
        """The step numbered ``k`` (the kernel ran its period in the fault state) returned ``status``."""
        names = self.codec.model_fault_reasons if hasattr(self.codec, "model_fault_reasons") else {}
        fault = describe(self.sim, status, self.k, names)
        self.model_fault = fault
        self.run_state = "model_fault"
        self.message = fault.line()
        if self.on_model_fault is not None:
            try:
                self.on_model_fault(fault)
            except Exception as exc:  # noqa: BLE001  (reporting must never stop the loop)
                self.message += f" (reporting it failed: {type(exc).__name__}: {exc})"

    def step_once(self) -> None:
        """One paced step (realtime and fast modes): control requests, received frames, one step."""
        if not self.inbox.empty():
            self.drain_inbox()
        k = self.k + 1
        if self.run_state not in STEPPING:
            self._call(True, 0)              # frames are still checked and counted
            return
        if k % self.status_every == 0:
            self._status_inputs()
        if self.ctl is not None and self.k % self.ctl.every == 0:
            self._communicate()
        self._call(True, 1)
        if self.port is not None and (k % self.sensor_every == 0 or k % self.status_every == 0):
            self.port.wake()

    def run_steps(self, n: int) -> None:
        """``n`` paced steps (what the pacer calls)."""
        for _ in range(int(n)):
            self.step_once()

    def advance(self, n: int) -> None:
        """``n`` steps back to back without taking frames (lockstep requests, the ``step`` control,
        re-simulation), in compiled chunks; a paused loop does not step, one in the model-fault state
        steps in it (time advances, the vehicle stays frozen)."""
        n = int(n)
        while n > 0 and self.run_state in STEPPING:
            c = min(n, CHUNK)
            k0 = self.k
            if self.ctl is not None:        # a chunk ends where the controller's next step begins
                if k0 % self.ctl.every == 0:
                    self._communicate()
                c = min(c, self.ctl.every - k0 % self.ctl.every)
            f = self._forced_step
            if f is not None and k0 + 1 < f <= k0 + c:
                c = f - 1 - k0                # the test-only hook acts before the call whose first step is f
            if (k0 // self.status_every) != ((k0 + c) // self.status_every):
                self._status_inputs()
            self._call(False, c)
            if self.k == k0:
                break
            n -= self.k - k0
            if self.port is not None:
                self.port.wake()

    def take_frames(self) -> None:
        """Take every frame received so far, now (time ``k * dt``); in lockstep mode each SIM_STEP_REQ
        among them runs its steps and is acknowledged before the frames after it are taken."""
        li = self.li
        while True:
            self._call(True, 0)
            if li[LI_PENDING_ACK] == 0:
                return
            steps = int(li[LI_PENDING_STEPS])
            li[LI_PENDING_STEPS] = li[LI_PENDING_ACK] = 0
            if steps:
                self.advance(steps)
            self._call(False, 0, int(li[LI_PENDING_COUNTER]))
            if self.port is not None:
                self.port.wake()

    def _status_inputs(self) -> None:
        """What the SIM_STATUS frame needs from outside the step: loop overruns, the bus state."""
        self.li[LI_OVERRUNS] = self.health.overruns
        self.li[LI_BUS_ERROR] = self._bus_error()
        if self._usr_deadline is not None and self.user_clock() > self._usr_deadline:
            self._user_release()
            self._usr_lapses += 1
            self._user_changed("lapse")
        self._bus_errors_at_status = self.port.errors if self.port is not None else 0

    def _bus_error(self) -> bool:
        return self.port is not None and ((not self.port.up) or self.port.errors > self._bus_errors_at_status)

    def faults(self) -> dict[str, bool]:
        f = {name: False for name in self.codec.faults}
        f.update(self.rx.faults)
        f["bus_error"] = self._bus_error()
        f["model"] = bool(self.li[LI_MODEL_FAULT])
        f["second_sim"] = bool(self.sim_time - self.rx.state.g[G_FOREIGN_T] <= SECOND_SIM_HOLD + TIME_EPS)
        if self.external_eps:
            f["eps_safe_state"] = self.sim.eps_fault      # latched: assist off until a reset
        return f

    # -- inbox ---------------------------------------------------------------------------------------
    def drain_inbox(self) -> None:
        inbox = self.inbox
        while not inbox.empty():
            self.handle(inbox.get_nowait())

    def handle(self, item) -> None:
        """An inbox item: ``("can", None)`` (frames arrived: lockstep wake-up) or ``("ctl", Request)``.
        Frames received before a request are taken before it."""
        kind, obj = item
        if self.mode == "lockstep":
            self.take_frames()
        if kind == "ctl":
            self.on_request(obj)

    # -- control requests (from Zenoh) --------------------------------------------------------------
    def on_request(self, req: Request) -> None:
        try:
            req.reply = self.apply_control(req.op, req.args)
        except Exception as exc:  # noqa: BLE001  (a bad request must never stop the loop)
            req.reply = {"ok": False, "error": f"{req.op}: {exc}"}
        req.done.set()

    def apply_control(self, op: str, args: dict) -> dict:
        """A control request's reply; an accepted op of CONTROL_OPS is logged for the recording with the
        step it acted at (before a ``step`` runs, before a reset restarts time)."""
        k, t = self.k, self.sim_time
        reply = self._control(op, args)
        if op in CONTROL_OPS and reply.get("ok"):
            public = {a: v for a, v in args.items() if not a.startswith("_")}
            if op in ("reset", "load_scenario"):
                public["scenario"] = reply.get("scenario")
            self._log_event("control", {"time": t, "step": k, "op": op, "args": public})
        return reply

    def _log_event(self, topic: str, event: dict) -> None:
        """Queue an event for the recording, numbered (``order``) across both topics."""
        event["order"] = self.events_logged
        self.events_logged += 1
        if len(self.event_log) >= EVENT_LOG:
            self.event_log_dropped += 1
            return
        self.event_log.append((topic, event))

    def _control(self, op: str, args: dict) -> dict:
        if op == "pause":
            if self.run_state == "running":
                self.run_state = "paused"
            return {"ok": True, "run_state": self.run_state, "sim_time": self.sim_time}
        if op == "resume":
            if self.run_state == "paused":
                self.run_state = "running"
            elif self.run_state == "model_fault":
                return {"ok": False, "error": f"resume: {self.message}; send reset"}
            return {"ok": True, "run_state": self.run_state, "sim_time": self.sim_time}
        if op == "step":
            if self.mode != "lockstep":
                return {"ok": False, "error": f"step: only in lockstep mode (the service runs in {self.mode})"}
            n = int(args.get("n", 1))
            if not 1 <= n <= 1_000_000:
                return {"ok": False, "error": f"step: n = {n} outside 1..1000000"}
            if self.run_state not in STEPPING:
                return {"ok": False, "error": f"step: the simulation is {self.run_state}"}
            self.advance(n)
            return {"ok": True, "sim_time": self.sim_time, "steps": self.k}
        if op in ("reset", "load_scenario", "_install"):
            sim, name = args["_sim"], args.get("_name")
            if "_faults" in args:               # a new scenario's session faults (server.session_faults)
                self.fault_specs, self.fault_where = (list(x) for x in args["_faults"])
            with self._session_lock:
                self._install(sim, args.get("_driver"))
                self.scenario_name = name or self.scenario_name
                self.run_state = "running"
                self.message = f"{op}: {self.scenario_name} at t = 0"
            return {"ok": True, "scenario": self.scenario_name, "sim_time": 0.0}
        if op == "inject_fault":
            return self._inject_fault(args)
        if op == "clear_fault":
            return self._clear_fault(args)
        if op == "driver":
            return self._live_driver(args)
        if op == "drive":
            return self._drive(args)
        return {"ok": False, "error": f"unknown op {op!r}; ops: reset, pause, resume, load_scenario, step, driver, "
                                     f"drive, inject_fault, clear_fault"}

    # -- faults (rtsim.faults) -----------------------------------------------------------------------
    def _inject_fault(self, args: dict) -> dict:
        """The ``inject_fault`` op: a fault spec (``[[faults]]`` keys), armed now (step k): with no trigger it
        starts at step k + 1, with ``at`` at the step of that time (the next step if it has passed)."""
        from rtsim.configfile import validate
        try:
            spec = validate(FaultSpec, dict(args), "inject_fault")
            self.fault_table.arm(spec, self.k, "inject_fault")
        except ConfigError as exc:
            return {"ok": False, "error": str(exc)}
        return {"ok": True, "sim_time": self.sim_time, "fault": self.fault_table.describe(spec.id)}

    def _clear_fault(self, args: dict) -> dict:
        """The ``clear_fault`` op: ``{"id": ...}`` ends that fault at the current step."""
        fid = args.get("id")
        if fid not in self.fault_table.armed:
            return {"ok": False, "error": f"clear_fault: no fault {fid!r} (armed: "
                                          f"{', '.join(self.fault_table.armed) or 'none'})"}
        desc = self.fault_table.clear(fid, self.k)
        self._fault_events()
        return {"ok": True, "sim_time": self.sim_time, "fault": desc}

    def faults_status(self) -> dict:
        """The faults armed in the session (status ``injected_faults``): each one's state and times, and the
        frames the faults took."""
        from rtsim.faults.kernels import G_LOST_IN, G_LOST_OUT
        g = self.fault_table.state.g
        return {"faults": self.fault_table.status(), "lost_out": int(g[G_LOST_OUT]), "lost_in": int(g[G_LOST_IN])}

    # -- the user's command source (rtsim.service.user_input) ---------------------------------------
    def _drive(self, args: dict) -> dict:
        """The ``drive`` op: ``{channel: value | null, ..., "takeover": bool, "release": bool, "seq": n}``.
        Values are checked first (one bad value rejects the whole request); the reply says when they were
        applied (``sim_time``, ``wall_time``: the service's clock) and who drives each channel now."""
        if not self.user_input:
            return {"ok": False, "error": "drive: this service does not accept user commands (--no-user-input)"}
        inputs = self.sim.user_inputs
        new = {}
        takeover = args.get("takeover")
        if takeover is not None and not isinstance(takeover, bool):
            return {"ok": False, "error": f"drive: takeover = {takeover!r} must be true or false"}
        chans = list(inputs.names)
        for name, value in args.items():
            if name in ("takeover", "release", "seq"):
                continue
            if value is None:
                if name not in chans:
                    return {"ok": False, "error": f"drive: {name!r} is not a user channel (those are: "
                                                  f"{', '.join(chans)})"}
                new[chans.index(name)] = np.nan
                continue
            try:
                v = check_value(inputs, name, value)
            except ValueError as exc:
                return {"ok": False, "error": f"drive: {exc}"}
            new[chans.index(name)] = v
        if args.get("release"):
            self._user_release()
        else:
            usr = self.ls.usr
            for u, v in new.items():
                usr[u] = v
            if takeover is not None:
                self.ls.usr_mode[0] = int(takeover)
            self._usr_deadline = self.user_clock() + self.user_hold if not np.all(np.isnan(usr)) else None
        self._usr_requests += 1
        self._usr_seq = args.get("seq") if isinstance(args.get("seq"), int) else self._usr_seq
        self._user_changed("release" if args.get("release") else "drive")
        return {"ok": True, "seq": self._usr_seq, "sim_time": self.sim_time, "wall_time": time.time(),
                "drivers": self.drivers(), "user": self.user_status()}

    def _user_changed(self, cause: str) -> None:
        """Log the user source's values and takeover if they changed: they act from step ``k + 1`` on
        (the loop thread only appends to a deque; the publisher encodes and records it)."""
        usr = self.ls.usr
        now = (tuple(None if np.isnan(v) else float(v) for v in usr), bool(self.ls.usr_mode[0]))
        if now == self._usr_last:
            return
        self._usr_last = now
        names = self.sim.user_inputs.names
        self._log_event("user", {"time": self.sim_time, "step": self.k, "cause": cause,
                                 "channels": {n: now[0][u] for u, n in enumerate(names)},
                                 "takeover": now[1], "seq": self._usr_seq})

    def apply_user(self, channels: dict, takeover: bool) -> None:
        """Set the user source as a recorded change says (re-simulation; see ``_user_changed``): every
        user channel's value (None or absent: not driven) and the takeover."""
        usr = self.ls.usr
        for u, n in enumerate(self.sim.user_inputs.names):
            v = channels.get(n)
            usr[u] = np.nan if v is None else float(v)
        self.ls.usr_mode[0] = int(bool(takeover))

    def _user_release(self) -> None:
        self.ls.usr[:] = np.nan
        self.ls.usr_mode[0] = 0
        self._usr_deadline = None

    def user_status(self) -> dict:
        """The user source: the channels it drives now (SI values), whether it took over, the last request's
        sequence number, how many requests came and how many times the channels lapsed for want of one."""
        usr = self.ls.usr
        return {"channels": {n: float(usr[u]) for u, n in enumerate(self.sim.user_inputs.names)
                             if not np.isnan(usr[u])},
                "takeover": bool(self.ls.usr_mode[0]), "seq": self._usr_seq, "requests": self._usr_requests,
                "lapses": self._usr_lapses, "accepted": self.user_input}

    def drivers(self) -> dict[str, str]:
        """Who drives each of the vehicle's driving inputs now: "user" (rtsim view), "ecu" (a valid bus
        command), "scenario" (a car's in-loop driver), "rider" (a two-wheeler's), "safe" (the watchdog's
        safe value) or "none" (nobody: zero)."""
        inputs = self.sim.user_inputs
        names = self.codec.channels.command_names
        iv = self.rx.state.iv
        usr, takeover = self.ls.usr, bool(self.ls.usr_mode[0])
        out = {}
        for u, ch in enumerate(inputs.channels):
            bus = ch.bus
            valid = bus in names and bool(iv[names.index(bus), IV_HAS_VALUE]) and not iv[names.index(bus), IV_TIMED_OUT]
            in_loop = (u < len(self.lp.drv_slot) and int(self.lp.drv_slot[u]) >= 0) or bool(self.sim.rider_on)
            out[ch.name] = inputs.who(ch, not np.isnan(usr[u]), takeover, valid, in_loop)
        return out

    def _live_driver(self, args: dict) -> dict:
        """Live driver inputs (a person at a steering wheel, a joystick bridge): ``{channel: value}`` for
        the channels the in-loop driver drives, in SI units within drivers.base.LIMITS, held until the
        next request; ``{channel: null}`` hands the channel back to the scenario."""
        driven = [INPUT_NAMES[i] for i in np.flatnonzero(self.lp.drv_slot >= 0)]
        if not driven:
            return {"ok": False, "error": "driver: the CAN commands drive this vehicle; there is no in-loop driver"}
        live = self.ls.drv_live
        new = {}
        for name, value in args.items():
            if name not in driven:
                return {"ok": False, "error": f"driver: {name!r} is not driven in the loop (those are: "
                                              f"{', '.join(driven)})"}
            if value is not None:
                lo, hi = LIMITS[name]
                try:
                    v = float(value)
                except (TypeError, ValueError):
                    return {"ok": False, "error": f"driver: {name} = {value!r} is not a number"}
                if not lo <= v <= hi:
                    return {"ok": False, "error": f"driver: {name} = {v}: outside {lo} .. {hi} {INPUT_UNITS[name]}"}
                value = v
            new[INPUT_NAMES.index(name)] = np.nan if value is None else value
        for i, v in new.items():
            live[i] = v
        return {"ok": True, "live": {INPUT_NAMES[i]: float(live[i]) for i in range(NINPUT) if not np.isnan(live[i])},
                "sim_time": self.sim_time}

    # -- lockstep ------------------------------------------------------------------------------------
    def run_lockstep(self) -> None:
        """Lockstep mode: take frames and requests as they arrive until ``stop_event``."""
        inbox = self.inbox
        while not self.stop_event.is_set():
            try:
                item = inbox.get(timeout=0.05)
            except queue.Empty:
                continue
            self.handle(item)

    # -- status ----------------------------------------------------------------------------------------
    def status(self) -> dict:
        """The status payload (bridge.payloads ``status``); called from the publisher thread. Read under
        the session lock: its run state, fault flags and times are those of one session."""
        with self._session_lock:
            return self._status()

    def _status(self) -> dict:
        h = self.health
        rec = getattr(self.outbox, "recorder", None) if self.outbox is not None else None
        zen = getattr(self.outbox, "zenoh", None) if self.outbox is not None else None
        pct = h.recent_percentiles()
        counters = self.rx.counters
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
            "rejected": {**{k: counters[k] for k in ("dlc", "crc", "counter", "range", "unknown_id", "sync",
                                                     "format")},
                         "repeated": counters["counter_repeated"], "jump": counters["counter_jump"]},
            "foreign_frames": counters["foreign_frames"],
            "accepted_frames": self.rx.accepted,
            "bus_errors": self.port.errors if self.port is not None else 0,
            "recorder": None if rec is None else {"path": str(rec.path), "written": rec.written,
                                                  "dropped": rec.dropped + self.event_log_dropped,
                                                  "chunks": rec.chunks},
            "zenoh_dropped": getattr(zen, "dropped", 0) if zen is not None else 0,
            "scenario": self.scenario_name,
            "message": self.message,
            "model_fault": None if self.model_fault is None else self.model_fault.as_dict(),
            "wall_time": time.time(),
            "drivers": self.drivers(),
            "user": self.user_status(),
            "injected_faults": self.faults_status(),
        }

