"""The model-fault state (a vehicle model that fails): what an ECU on the bus, the Zenoh status, the recording,
`rtsim resim` and offline runs see, with the failure forced by rtsim.model_fault's test-only hook
(``RTSIM_TEST_MODEL_FAULT_AT``: the model's own failure path, a NaN velocity before the step ending at that
time, so the step fails with a non-finite generalized force on the first coordinate, chassis.x).

The bus is read by an independent python-can client on the loopback hub (or the bus of
RTSIM_CAN_INTERFACE); SIM_STATUS and SIM_DIAG are decoded with cantools from the DBC; the assertions are
on the simulation times the frames carry and on recorded stamps, never on wall-clock windows (those only
bound the waits, tests/waits.py).
"""
from __future__ import annotations

import csv
import json
import re
import signal
import subprocess
import sys
import time

import can
import cantools
import numpy as np
import pytest

from bridge.can_bus import open_bus
from bridge.can_codec import DEFAULT_DBC, Codec
from bridge.mcap_recorder import SESSION_END_METADATA, read_recording
from rtsim.model_fault import TEST_FAULT_ENV
from service_harness import ROOT, Listener, ServiceProcess, can_segment, send_lockstep_cycle
from waits import EVENT, PROCESS

realtime = pytest.mark.realtime_e2e
CODEC = Codec()
SENSOR_IDS = tuple(f.frame_id for f in CODEC.sensor_frames)
STATUS_ID = CODEC.status_frame.frame_id
DIAG_ID = CODEC.diag_frame.frame_id
NONFINITE_FORCE = 2          # rtsim.mbs.model.ERR_NONFINITE_FORCE, the DBC's model_fault_reason 2


@pytest.fixture
def segment():
    with can_segment() as seg:
        yield seg


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_file(str(DEFAULT_DBC))


def _status_frames(frames, db):
    """[(arrival index, sim_time ms, fault_model, model_fault_reason of the SIM_DIAG right after)]."""
    out = []
    diag = None
    for j in range(len(frames) - 1, -1, -1):         # each SIM_DIAG follows its SIM_STATUS in the same step
        _, fid, data = frames[j]
        if fid == DIAG_ID:
            diag = db.decode_message(fid, data, decode_choices=False)["model_fault_reason"]
        elif fid == STATUS_ID:
            st = db.decode_message(fid, data, decode_choices=False)
            out.append((j, int(round(st["sim_time"] * 1000)), int(st["fault_model"]), diag))
            diag = None
    return out[::-1]


def _send_command(bus, ctr: list) -> None:
    ctr[0] = (ctr[0] + 1) & 0xF
    fid, data = CODEC.encode_command("throttle_angle_cmd", 0.05, ctr[0])
    bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))


def _wait(cond, what: str, tick=None, timeout: float = PROCESS) -> None:
    deadline = time.monotonic() + timeout        # bounds the wait only
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        if tick is not None:
            tick()
        time.sleep(0.01)


@realtime
def test_model_fault_keeps_the_bus_contract_and_reset_recovers(segment, tmp_path, monkeypatch, db):
    """The bar: after a forced model failure at 1.0 s an independent CAN client sees SIM_STATUS every 100 ms of
    simulated time with fault_model = 1 and SIM_DIAG's reason, no sensor frame (the DBC's rule: they stop),
    the commands still counted; one console line; the Zenoh status and the recording carry the fault;
    `rtsim resim` reproduces it (same step, same reason); `reset` recovers."""
    from bridge.zenoh_link import ZenohClient
    from rtsim.service.resim import _fault_line, resim

    fault_at, fault_step = 1.0, 1000                     # the service's step: 1 ms
    monkeypatch.setenv(TEST_FAULT_ENV, repr(fault_at))
    iface, chan = segment
    rec = tmp_path / "fault.mcap"
    bus = open_bus(iface, chan)                         # listening before the service sends its first frame
    listener = Listener(bus, SENSOR_IDS)
    svc = client = None
    ctr = [0]
    status: list[dict] = []
    try:
        svc = ServiceProcess(iface, chan, "--zenoh-listen", "tcp/127.0.0.1:0", "--record", str(rec),
                             "--max-catch-up", "10000", "--json")
        endpoint = re.search(r"Zenoh:\s+(tcp/127\.0\.0\.1:\d+)", svc.output).group(1)
        client = ZenohClient("xbw", connect=(endpoint,))
        client.subscribe("status", status.append)
        ecu = lambda: _send_command(bus, ctr)            # noqa: E731  (a command every tick: counted throughout)
        _wait(lambda: any(s["run_state"] == "model_fault" and s["sim_time"] >= fault_at + 2.0 for s in status),
              "2 s of simulated time in the model-fault state", ecu)
        on_disk = read_recording(rec)[0].get("rtsim/xbw/status", [])   # the file is still open
        reply = client.control("reset", timeout=EVENT)
        assert reply["ok"], reply
        n_reset = len(listener.frames)
        _wait(lambda: any(i in SENSOR_IDS for _, i, _ in listener.frames[n_reset:])
              and any(s["run_state"] == "running" and s["sim_time"] >= 0.5 for s in status[-3:]),
              "sensor frames and a running status after the reset", ecu)
        rc, _ = svc.stop(signal.SIGTERM)
    finally:
        if client is not None:
            client.close()
        listener.close()
        bus.shutdown()
        if svc is not None:
            svc.close()
    assert rc == 0, svc.output
    frames = listener.frames
    st = _status_frames(frames, db)
    reset_at = next(n for n in range(1, len(st)) if st[n][1] < st[n - 1][1])   # simulation time restarts
    before, after = st[:reset_at], st[reset_at:]
    ms = np.array([s[1] for s in before])
    # SIM_STATUS every 100 ms of simulated time, before, at and after the failure, up to the reset
    assert np.all(np.diff(ms) == 100), sorted(set(np.diff(ms)))
    assert ms[0] < _ms(fault_at) and ms[-1] >= _ms(fault_at) + 2000
    for _, t, flag, reason in before:
        failed = t >= _ms(fault_at)                      # the status of the failed step's period on
        assert flag == int(failed) and reason == (NONFINITE_FORCE if failed else 0), (t, flag, reason)
    # the sensor rule: the last sensor sample is the last good step's (998 ms: every 2 ms); none after it
    first_fault = next(j for j, t, flag, _ in before if flag)
    sensor_before = [int.from_bytes(d[0:2], "little") for _, i, d in frames[:first_fault] if i in SENSOR_IDS]
    assert max(sensor_before) == fault_step - 2
    between = frames[first_fault:before[-1][0]]          # up to the last status before the reset
    assert not [i for _, i, _ in between if i in SENSOR_IDS]
    resumed = next(d for _, i, d in frames[first_fault:] if i in SENSOR_IDS)
    assert int.from_bytes(resumed[0:2], "little") == 2  # the first sensor frame after the failure: the reset's
    # after the reset: flags clear, sensor frames again from the new start
    assert all(flag == 0 and reason == 0 for _, _, flag, reason in after)
    sensor_after = [int.from_bytes(d[0:2], "little") for _, i, d in frames[after[0][0]:] if i in SENSOR_IDS]
    assert sensor_after and min(sensor_after) < 1000
    # one console line: time, step, reason, coordinate
    lines = [ln for ln in svc.lines if "model fault" in ln]
    assert len(lines) == 1, lines
    assert "t = 1.000 s (step 1000)" in lines[0] and "nonfinite_force" in lines[0] and "'chassis.x'" in lines[0]
    # the Zenoh status: run_state model_fault with the details; commands still counted in the fault state
    faulted = [s for s in status if s["run_state"] == "model_fault"]
    assert faulted and all(s["faults"]["model"] for s in faulted)
    mf = faulted[0]["model_fault"]
    assert (mf["reason_code"], mf["reason"], mf["step"], mf["coordinate"]) == (
        NONFINITE_FORCE, "nonfinite_force", fault_step, "chassis.x")
    assert mf["sim_time"] == pytest.approx(fault_at)
    assert faulted[-1]["accepted_frames"] > faulted[0]["accepted_frames"]
    # the recording: the fault's status was on disk while the service ran; the clean close says how it ended
    assert any(m.data.get("run_state") == "model_fault" for m in on_disk)
    messages, info = read_recording(rec)
    assert info.complete
    assert info.metadata[SESSION_END_METADATA]["how"] == "stopped"          # the reset recovered the model
    assert info.metadata["rtsim.session"]["test_model_fault_at"] == repr(fault_at)
    rep = resim(rec)
    print(f"\nresim: {_fault_line(rep)}; identical {rep['identical']}")
    assert rep["model_fault_reproduced"] is True
    assert rep["model_fault"]["step"] == fault_step and rep["model_fault"]["reason_code"] == NONFINITE_FORCE
    assert "model fault reproduced: step 1000" in _fault_line(rep)


def _ms(t: float) -> int:
    return int(round(t * 1000.0))


@pytest.mark.can_e2e
def test_lockstep_model_fault_acknowledges_steps_and_the_recording_says_how_it_ended(segment, tmp_path,
                                                                                        monkeypatch, db):
    """Lockstep: every SIM_STEP_REQ is still run and acknowledged after the failure, simulation time advancing
    by its steps (the vehicle frozen); SIM_STATUS every 100 ms with the flag; a clean stop in the fault
    state writes rtsim.session_end how = model_fault with the fault's fields; resim reports the failure."""
    fault_at = 0.5
    monkeypatch.setenv(TEST_FAULT_ENV, repr(fault_at))
    iface, chan = segment
    rec = tmp_path / "lockstep_fault.mcap"
    svc = ServiceProcess(iface, chan, "--no-zenoh", "--mode", "lockstep", "--record", str(rec))
    bus = open_bus(iface, chan)
    ctr = [0, 0, 0, 0]
    acks, frames = [], []
    try:
        for _ in range(100):                                     # 100 requests of 10 steps: 1.0 s
            send_lockstep_cycle(bus, CODEC, ctr, (0.05, 0.0, 0.0), 10)
            deadline = time.monotonic() + EVENT
            while True:
                msg = bus.recv(1.0)
                assert time.monotonic() < deadline, "no SIM_STEP_ACK"
                if msg is None:
                    continue
                frames.append((0.0, msg.arbitration_id, bytes(msg.data)))
                if msg.arbitration_id == CODEC.step_ack.frame_id:
                    t, c = CODEC.decode_step_ack(msg.data)
                    if c == ctr[3]:
                        acks.append(t)
                        break
        rc, _ = svc.stop(signal.SIGTERM)
    finally:
        bus.shutdown()
        svc.close()
    assert rc == 0, svc.output
    assert np.allclose(np.diff(acks), 0.010, atol=1e-6) and acks[-1] == pytest.approx(1.0)
    st = _status_frames(frames, db)
    assert [t for _, t, _, _ in st] == list(range(100, 1001, 100))
    assert [(flag, reason) for _, t, flag, reason in st] == [
        (int(t >= 500), NONFINITE_FORCE if t >= 500 else 0) for _, t, _, _ in st]
    sensor_ms = [int.from_bytes(d[0:2], "little") for _, i, d in frames if i in SENSOR_IDS]
    assert max(sensor_ms) == 498
    _, info = read_recording(rec)
    end = info.metadata[SESSION_END_METADATA]
    assert end["how"] == "model_fault"
    assert (end["reason_code"], end["reason"], end["step"], end["coordinate"]) == ("2", "nonfinite_force", "500",
                                                                                     "chassis.x")
    assert float(end["sim_time"]) == pytest.approx(fault_at)
    out = subprocess.run([sys.executable, "-m", "rtsim.cli", "resim", str(rec), "--json"], cwd=ROOT,
                         capture_output=True, text=True, timeout=PROCESS)
    assert out.returncode == 0, out.stderr
    rep = json.loads(out.stdout)
    assert rep["identical"], (rep["sensors"], rep["state"])
    assert rep["model_fault_reproduced"] is True and rep["run_state"] == "model_fault"
    assert rep["model_fault"]["step"] == 500 and rep["recorded_model_fault"]["step"] == 500


@pytest.mark.parametrize("scenario, coordinate", [("straight_line", "chassis.x"),        # the car
                                                  ("motorcycle_steady_turn", "p.x")])     # the two-wheeler's ride
def test_offline_run_writes_the_rows_up_to_the_failure_and_exits_non_zero(tmp_path, scenario, coordinate):
    """`rtsim run` with a forced failure at 0.5 s: the CSV holds every row up to it (rows at the scenario's
    output rate from 0 to the last good row), the failure's step, time, reason and coordinate beside it,
    one line on stderr, exit status 3."""
    out = tmp_path / "run.csv"
    proc = subprocess.run([sys.executable, "-m", "rtsim.cli", "run", "--scenario", f"configs/scenarios/{scenario}.toml",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=PROCESS,
                          env={**__import__("os").environ, TEST_FAULT_ENV: "0.5"})
    assert proc.returncode == 3, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()   # a cold kernel cache's progress lines aside
             and not ln.startswith(("rtsim run: compiling kernels", "rtsim run: kernels compiled"))]
    assert len(lines) == 1 and "model fault at t = 0.500 s (step 500)" in lines[0], proc.stderr
    with out.open() as fh:
        rows = list(csv.reader(fh))
    t = np.array([float(r[0]) for r in rows[1:]])
    dt_row = t[1] - t[0]
    assert t[0] == 0.0 and np.allclose(np.diff(t), dt_row)
    assert t[-1] < 0.5 <= t[-1] + dt_row + 1e-9          # every row before the failed step, none after
    fault = json.loads(out.with_suffix(".model_fault.json").read_text())
    assert (fault["step"], fault["reason_code"], fault["coordinate"]) == (500, NONFINITE_FORCE, coordinate)
    assert fault["sim_time"] == pytest.approx(0.5)
