"""A vehicle added in the tests only: the kart (tests/vehicles/kart.toml and its assembly,
tests/vehicles/kart_assembly.py: a chassis and four wheels bolted to it, no suspension) goes through the
commands that take a vehicle exactly as a shipped one does, with nothing in rtsim naming it:

- `rtsim describe`: the fields every vehicle reports; its degrees of freedom those of a chassis and four
  spinning wheels (plus the steering's rack and column), none for suspension travel;
- `rtsim run`: straight-line driving under a constant rear wheel torque, then a constant brake pressure, against
  a one-dimensional reference (m_eff dv/dt = drive - brake forces at the tyre's radius - rolling resistance
  - drag), and the stopping distance that reference gives;
- `rtsim serve` (CAN on the loopback hub, Zenoh on tcp/127.0.0.1 with scouting off, recorded to MCAP) with
  the test as the ECU on the bus and a Zenoh client, `rtsim view` of it in headless Chromium (the page
  draws frames while simulated time advances), then `rtsim resim` of the recording: identical;
- `rtsim batch`: a plan of two runs.

Waits are bounded by wall-clock limits (waits.py) and never asserted; every criterion is on simulated time
and recorded stamps.
"""
from __future__ import annotations

import csv
import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rtsim.cli import main
from rtsim.vehicle.registry import DESCRIBE_FIELDS, DESCRIBE_GEOMETRY, open_vehicle
from service_harness import ServiceProcess, can_segment, free_port, send_lockstep_cycle
from waits import EVENT

ROOT = Path(__file__).resolve().parents[1]
KART = ROOT / "tests" / "vehicles" / "kart.toml"
FLAT = ROOT / "configs" / "roads" / "flat.toml"
G = 9.81                 # m/s^2, the model's gravity (rtsim.vehicle.car.layout.G)
T_DRIVE = 20.0           # N m on each rear wheel while driving
P_BRAKE = 300.0          # kPa line pressure while braking (below the proportioning knee: rear = line)
T_SWITCH = 2.5           # s: drive torque off, brake on
THROTTLE = 0.15          # rad, the served kart's throttle command from the test's ECU


def _cli(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _scenario(folder: Path, name: str, torque: float, duration: float) -> Path:
    """Straight ahead from rest on the flat road: `torque` (N m) on each rear wheel until T_SWITCH, then
    no torque and P_BRAKE of line pressure."""
    text = f'''name = "{name}"
description = "kart: constant rear wheel torque from rest, then a constant brake pressure"
road = "{FLAT}"
duration = {duration}
dt = 0.001
output_rate = 500.0

[initial]
speed = 0.0
x = 0.0
y = 0.0
yaw = 0.0

[torque_mode.wheel_torque_rl]
type = "table"
time = [0.0, {T_SWITCH}, {T_SWITCH + 1e-4}]
value = [{torque}, {torque}, 0.0]
[torque_mode.wheel_torque_rr]
type = "table"
time = [0.0, {T_SWITCH}, {T_SWITCH + 1e-4}]
value = [{torque}, {torque}, 0.0]

[inputs.brake_pressure_cmd]
type = "table"
time = [0.0, {T_SWITCH}, {T_SWITCH + 1e-4}]
value = [0.0, 0.0, {P_BRAKE}]

[inputs.steering_wheel_angle_cmd]
type = "constant"
value = 0.0
'''
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


def _tir(path: Path, key: str) -> float:
    """A number of a .tir file, read independently of the model's loader."""
    m = re.search(rf"^\s*{key}\s*=\s*([-+0-9.eE]+)", path.read_text(), re.MULTILINE)
    assert m, key
    return float(m.group(1))


def test_describe_reports_the_fields_of_every_vehicle(capsys):
    code, out, err = _cli(capsys, "describe", "--vehicle", KART, "--json")
    assert code == 0, err
    kart = json.loads(out)
    code, out, err = _cli(capsys, "describe", "--vehicle", "xbw", "--json")
    assert code == 0, err
    car = json.loads(out)
    assert tuple(kart)[:len(DESCRIBE_FIELDS)] == tuple(car)[:len(DESCRIBE_FIELDS)] == DESCRIBE_FIELDS
    assert tuple(kart["geometry"])[:len(DESCRIBE_GEOMETRY)] == DESCRIBE_GEOMETRY
    assert tuple(kart["channels"]) == tuple(car["channels"])
    assert kart["kind"] == "kart" and kart["id"] == "kart"
    assert kart["mass"] == pytest.approx(130.0 + 4 * 5.0, rel=1e-12) == sum(kart["masses"].values())
    # a chassis (6) and four wheels spinning (4), the rack and the steering column (2): 12 degrees of
    # freedom; the car's suspension adds one travel per corner (16)
    assert kart["n_dof"] == kart["n_coordinates"] - kart["n_constraints"] == 12
    assert car["n_dof"] == kart["n_dof"] + 4
    geo = kart["geometry"]
    assert geo["wheelbase"] == pytest.approx(1.20, abs=1e-5)
    assert geo["track_front"] == pytest.approx(1.10, abs=1e-4) and geo["track_rear"] == pytest.approx(1.20, abs=1e-9)


def test_run_accelerates_and_stops_as_the_force_balance_says(tmp_path, capsys):
    """Straight line: the acceleration under a constant drive torque T on each rear wheel and the deceleration
    under a constant brake pressure p against m_eff a = sum(forces) with m_eff = m + sum(I_w) / r^2, the drive
    force 2 T / r, the brake torques n mu A R p of the kit's calipers (front and rear from the config), the
    tyres' rolling resistance (MF 5.2: My = Fz R0 (QSY1 + QSY3 |v| / LONGVL + QSY4 (v / LONGVL)^4)), drag
    rho CdA v^2 / 2; r the loaded radius R0 - Fz / kz. Measured above the tyre's low-speed blending speed
    (VXLOW), with the brake pressure settled; then the stopping distance from 1.5 m/s against v^2 / (2 a), and
    the chassis' pitch between the two phases against the tyres' deflection under the load transfer."""
    scen = _scenario(tmp_path, "kart_accel_brake", T_DRIVE, 4.5)
    out = tmp_path / "kart.csv"
    code, _, err = _cli(capsys, "run", "--vehicle", KART, "--scenario", scen, "--out", out)
    assert code == 0, err
    rows = list(csv.reader(out.open()))
    data = np.array(rows[1:], dtype=float)
    col = {name: data[:, i] for i, name in enumerate(rows[0])}
    t, v, x = col["time"], col["speed"], col["pos_x"]

    cfg = open_vehicle(KART).config
    tir = KART.parent / cfg.tyres.property_file
    r0, kz, vref = _tir(tir, "UNLOADED_RADIUS"), _tir(tir, "VERTICAL_STIFFNESS"), _tir(tir, "LONGVL")
    qsy1, qsy3, qsy4 = _tir(tir, "QSY1"), _tir(tir, "QSY3"), _tir(tir, "QSY4")
    m = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    inertia = 2 * cfg.front.wheel_spin_inertia_kgm2 + 2 * cfg.rear.wheel_spin_inertia_kgm2
    r = r0 - m * G / 4 / kz
    m_eff = m + inertia / r ** 2
    cda, rho = cfg.aero.drag_area_m2, cfg.aero.air_density_kg_m3

    def resist(speed):
        """Rolling resistance (all four tyres, at the ground) and drag, N."""
        s = speed / vref
        return m * G * r0 / r * (qsy1 + qsy3 * s + qsy4 * s ** 4) + 0.5 * rho * cda * speed ** 2

    def slope(sel):
        return np.polyfit(t[sel], v[sel], 1)[0], float(np.mean(v[sel]))

    drive = (t < T_SWITCH) & (v > 1.1) & (v < 1.7)
    assert drive.sum() > 100, "the kart never got into the measured speed band"
    a_drive, v_mean = slope(drive)
    a_ref = (2 * T_DRIVE / r - resist(v_mean)) / m_eff
    assert a_drive == pytest.approx(a_ref, rel=0.01), (a_drive, a_ref)

    b = cfg.brakes
    per_kpa = 1e3 * 2 * sum(p.pads * p.mu * p.piston_area * p.effective_radius for p in (b.front, b.rear))
    assert P_BRAKE < b.proportioning_knee
    braking = (t > T_SWITCH + 0.2) & (v > 1.1) & (v < 1.6)
    assert braking.sum() > 50
    a_brake, v_mean = slope(braking)
    a_ref = -(per_kpa * P_BRAKE / r + resist(v_mean)) / m_eff
    assert a_brake == pytest.approx(a_ref, rel=0.01), (a_brake, a_ref)

    # no suspension: the chassis pitches only on the tyres. Between the two phases the load moving between
    # the axles, m (a_drive - a_brake) h / L, changes the tyres' deflections by that over kz per axle
    # (pitch positive nose down, ISO 8855); a sprung car pitches some twenty times as far
    wf, wr = cfg.front.hardpoints.wheel_centre, cfg.rear.hardpoints.wheel_centre
    wheelbase = wf[0] - wr[0]
    h = (cfg.chassis.mass_kg * cfg.chassis.cg_m[2] + 2 * cfg.front.unsprung_mass_kg * wf[2]
         + 2 * cfg.rear.unsprung_mass_kg * wr[2]) / m
    pitch = col["pitch_angle"]
    d_pitch = float(np.mean(pitch[braking]) - np.mean(pitch[drive]))
    d_pitch_ref = m * (a_drive - a_brake) * h / (wheelbase ** 2 * kz)
    assert d_pitch == pytest.approx(d_pitch_ref, rel=0.1), (d_pitch, d_pitch_ref)

    # stopping distance from 1.5 m/s (the tyres' low-speed blending below VXLOW = 1 m/s left in: 2 %)
    k0 = np.flatnonzero((t > T_SWITCH) & (v <= 1.5))[0]
    stopped = np.flatnonzero((t > t[k0]) & (v < 0.01))
    assert stopped.size, "the kart did not stop"
    d = x[stopped[0]] - x[k0]
    d_ref = v[k0] ** 2 / (2 * -a_ref)
    assert d == pytest.approx(d_ref, rel=0.02), (d, d_ref)
    assert np.all(np.abs(col["pos_y"]) < 1e-3)                       # straight ahead
    assert float(np.max(np.abs(col["constraint_violation"]))) < 1e-6


def test_serve_over_can_and_zenoh_view_and_resim(tmp_path):
    """`rtsim serve` of the kart in lockstep, CAN on a loopback hub, Zenoh on tcp/127.0.0.1, recorded: the test
    as the lockstep ECU on the bus (throttle, brake and steering commands, then SIM_STEP_REQ, then its
    SIM_STEP_ACK) steps it in a thread; the sensor frames on the bus and the state samples over Zenoh show
    simulated time advancing and the kart moving off; the `rtsim view` page draws frames while simulated
    time advances; `rtsim resim` of the recording is identical."""
    import threading

    import can
    import playwright.sync_api as playwright_api

    from bridge.can_codec import Codec
    from bridge.mcap_recorder import read_recording
    from bridge.zenoh_link import ZenohClient
    from service_harness import Listener
    from viewer_harness import NO_CHROMIUM, ViewThread, chromium_path, launch, open_page, require_page_libraries
    from viewer_harness import sim_time, wait_sim

    require_page_libraries()
    if chromium_path() is None:
        pytest.skip(NO_CHROMIUM)
    model = open_vehicle(KART).model
    codec = Codec(model.dbc, model.channels)
    rec = tmp_path / "kart.mcap"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop, acks, failures = threading.Event(), [], []

    def ecu(bus):
        """10 steps per cycle, commands every cycle (every 10 ms of simulated time: none times out)."""
        ctr = [0, 0, 0, 0]
        try:
            while not stop.is_set():
                send_lockstep_cycle(bus, codec, ctr, (THROTTLE, 0.0, 0.0), 10)
                deadline = time.monotonic() + EVENT
                while True:
                    msg = bus.recv(1.0)
                    if msg is not None and msg.arbitration_id == codec.step_ack.frame_id:
                        t, c = codec.decode_step_ack(msg.data)
                        if c == ctr[3]:
                            acks.append(t)
                            break
                    if time.monotonic() > deadline:
                        raise AssertionError(f"no SIM_STEP_ACK within {EVENT:g} s")
                time.sleep(0.005)
        except Exception as exc:  # noqa: BLE001  (reported by the test's thread)
            failures.append(exc)

    with can_segment() as (iface, channel):
        svc = ServiceProcess(iface, channel, "--vehicle", str(KART), "--zenoh-listen", endpoint,
                             "--record", str(rec), "--mode", "lockstep")
        opened = []
        try:
            ecu_bus = can.Bus(interface=iface, channel=channel)
            opened.append(ecu_bus.shutdown)
            listener = Listener(can.Bus(interface=iface, channel=channel), [f.frame_id for f in codec.sensor_frames])
            opened += [listener.bus.shutdown, listener.close]
            client = ZenohClient("kart", connect=(endpoint,))
            opened.append(client.close)
            state: list[dict] = []
            client.subscribe("state", state.append)
            stepper = threading.Thread(target=ecu, args=(ecu_bus,), daemon=True)
            stepper.start()
            opened.append(lambda: (stop.set(), stepper.join(EVENT)))
            view = ViewThread("kart", [endpoint])
            opened.append(view.close)
            pw = playwright_api.sync_playwright().start()
            opened.append(pw.stop)
            browser = launch(pw)
            opened.append(browser.close)
            pg, logs = open_page(browser, view.url)
            t0, frames0 = sim_time(pg), pg.evaluate("rtsimView.frames")
            wait_sim(pg, t0 + 2.0)
            frames1 = pg.evaluate("rtsimView.frames")
            assert frames1 > frames0, f"no frame drawn over 2 s of simulated time ({frames0} -> {frames1})"
            assert not [m for m in logs if m[0] in ("error", "pageerror")], logs
            # over CAN: the sensor frames' simulated time stamps advance with the page's
            assert listener.sim_ms is not None and listener.sim_ms >= 1000 * (t0 + 2.0) - 10, listener.sim_ms
        finally:
            for close in reversed(opened):
                close()
            rc, _ = svc.stop()
            svc.close()
        assert not failures, failures
        assert rc == 0, svc.output
    # the ECU's SIM_STEP_ACKs: 10 steps of 1 ms each, none lost
    assert len(acks) > 200 and np.allclose(np.diff(acks), 0.010, atol=1e-9), acks[:5]
    # over Zenoh: state samples at advancing simulated times
    times = [s["time"] for s in state]
    assert len(times) > 100 and all(b > a for a, b in zip(times, times[1:])), times[:5]
    # the recording: the kart drove off under the ECU's throttle, with no command timed out
    msgs, _info = read_recording(rec)
    rec_state = [m.data for m in msgs["rtsim/kart/state"]]
    assert max(s["throttle_angle"] for s in rec_state) == pytest.approx(THROTTLE, abs=0.01)
    assert max(s["speed"] for s in rec_state) > 1.0, "the ECU's throttle never moved the kart"
    assert len(msgs["rtsim/kart/sensors"]) > 1000                    # 500 Hz of simulated time
    p = subprocess.run([sys.executable, "-m", "rtsim.cli", "resim", str(rec), "--json"], cwd=ROOT,
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    report = json.loads(p.stdout[:p.stdout.rindex("}") + 1])
    assert report["sensors"]["matched"] > 1000 and report["identical"], report


def test_batch_runs_a_plan_of_two_kart_runs(tmp_path):
    """Two runs of the kart, twice the drive torque in the second: both ok, the second one farther."""
    cases = []
    for k, torque in enumerate((T_DRIVE, 2 * T_DRIVE)):
        scen = _scenario(tmp_path, f"kart_{k}", torque, 3.0)
        cases.append(f'[[cases]]\nscenario = "{scen}"\nvehicle = "{KART}"\n')
    plan = tmp_path / "kart_plan.toml"
    plan.write_text('name = "kart"\ndescription = "two kart runs"\nmetrics = ["distance"]\n\n' + "\n".join(cases))
    p = subprocess.run([sys.executable, "-m", "rtsim.cli", "batch", str(plan), "--out", str(tmp_path / "out"),
                        "--workers", "1", "--no-report"], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    rows = list(csv.DictReader(next((tmp_path / "out").glob("*.csv")).open()))
    assert len(rows) == 2 and all(r["status"] == "ok" for r in rows), rows
    by_case = {Path(r["scenario"]).stem: float(r["distance"]) for r in rows}   # (rows come sorted by run id)
    d = [by_case["kart_0"], by_case["kart_1"]]
    assert 0 < d[0] < d[1], by_case
    assert not math.isnan(d[1])


def test_a_rigid_axle_is_a_locked_slider_without_spring(tmp_path):
    """The car assembly's rigid mount (what the kart's corners are) is checked on load, in one line naming the
    file, the key and the value: only a vertical slider can be locked, a rigid axle has no spring, a
    suspended one needs its spring."""
    import tomllib

    from rtsim.errors import ConfigError
    from rtsim.vehicle.car.config import load_vehicle

    src = ROOT / "configs" / "vehicles" / "xbw.toml"
    base = tomllib.loads(src.read_text())
    cases = [("front", {"rigid": True}, "front.rigid = True: a rigid mount is a locked vertical_slider"),
             ("rear", {"spring": None}, "rear.spring = None: a suspended axle needs its [spring]")]
    for axle, change, words in cases:
        data = json.loads(json.dumps(base))
        data[axle].update(change)
        if change.get("spring", 0) is None:
            del data[axle]["spring"]
        with pytest.raises(ConfigError) as err:
            load_vehicle(src, data)
        assert str(err.value).startswith(f"{src}: {words}") and "\n" not in str(err.value), str(err.value)


def test_an_assembly_file_that_is_missing_is_refused_in_one_line(tmp_path, capsys):
    """``assembly = "file.py"`` is read relative to the vehicle file; a missing one is one line naming it."""
    bad = tmp_path / "bad_kart.toml"
    bad.write_text(KART.read_text().replace('assembly = "kart_assembly.py"', 'assembly = "no_such_assembly.py"'))
    code, _, err = _cli(capsys, "describe", "--vehicle", bad)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "assembly = 'no_such_assembly.py'" in lines[0], err
    assert "cannot import it" in lines[0] and str(tmp_path / "no_such_assembly.py") in lines[0], err
