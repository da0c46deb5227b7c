"""The accelerometer frame of rtsim validate: the level-frame conversion against kinematics, and the
frame a set of runs declares (CSV comment, MCAP metadata, --accel-frame) with its mismatches as clear
errors; the structural report's lag sign.

Reference for the conversion: in a steady turn the centre of mass's acceleration in the yaw-aligned
horizontal frame is v_x r (v_y' = 0), whatever the body's roll; a body-fixed accelerometer on the rolled
body reads that rotated into its axes plus gravity's component: a_y cos(roll) + g sin(roll).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from drivers.base import NSTATE, DriverView
from rtsim.validate.data import DataError, accel_frame, load_run
from rtsim.validate.replay import GRAVITY, Replayer, level_frame

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"


def test_level_frame_of_a_tilted_car_at_rest():
    """At rest on a slope (roll and pitch, ISO 8855 signs) the body reads gravity in its axes; the level
    frame reads nothing."""
    roll, pitch = 0.08, -0.05
    # R = Rz Ry(pitch) Rx(roll); the body reads R^T (0, 0, g): g times R's third row
    f = GRAVITY * np.array([-math.sin(pitch), math.cos(pitch) * math.sin(roll), math.cos(pitch) * math.cos(roll)])
    assert f[1] > 0.0 and f[0] > 0.0        # right side down reads +y, nose up (pitch < 0) reads +x
    lx, ly, lz = level_frame(*(np.array([v]) for v in (*f, roll, pitch)))
    assert np.allclose([lx[0], ly[0], lz[0]], 0.0, atol=1e-12)


def test_level_frame_in_a_steady_turn_of_the_model():
    """rtsim's car in a steady left turn at 15 m/s (speed held by the rear torques): the level accel_y of
    its IMU equals v_x r, the body accel_y equals v_x r cos(roll) + g sin(roll) (the 6-7 % gain the planar
    peer does not have)."""
    from rtsim.vehicle.car.sim import VehicleSim
    from rtsim.vehicle.car.step import CMD_STEER, EX_TORQUE_LEFT, EX_TORQUE_RIGHT
    from rtsim.vehicle.offline import vehicle_state

    rp = Replayer(VEHICLE)
    sim = VehicleSim(rp.model, rp.road, 1e-3, speed=15.0)
    sim.set_torque_mode(True)
    names = rp.model.channels.sensor_names
    row, state = np.zeros(sim.nsensor), np.zeros(NSTATE)
    sim.io.commands[CMD_STEER] = 0.6
    for _ in range(500):                         # 5 s; a P controller on the speed every 10 ms
        vehicle_state(sim, state)
        tq = 40.0 + 300.0 * (15.0 - state[DriverView.SPEED])
        sim.io.extra[EX_TORQUE_LEFT] = sim.io.extra[EX_TORQUE_RIGHT] = tq
        sim.step(10)
    sim.physical_sensors(row)
    vehicle_state(sim, state)
    s = {n: row[i] for i, n in enumerate(names)}
    r, roll = s["gyro_z"], s["roll"]
    assert r > 0.1 and roll > 0.01                  # turning left, rolled right side down
    ay = state[DriverView.SPEED] * r
    _, ly, _ = level_frame(*(np.array([s[c]]) for c in ("accel_x", "accel_y", "accel_z", "roll", "pitch")))
    assert abs(ly[0] - ay) <= 0.01 * ay, (ly[0], ay)
    body = ay * math.cos(roll) + GRAVITY * math.sin(roll)
    assert abs(s["accel_y"] - body) <= 0.01 * ay, (s["accel_y"], body)
    assert s["accel_y"] > 1.04 * ly[0]             # the body frame's roll gain is real here


def _csv(path: Path, frame: str | None) -> Path:
    t = np.arange(20) * 0.01
    head = f"# logger: test\n# accel_frame: {frame}\n" if frame else ""
    path.write_text(head + "time,accel_y\n" + "".join(f"{x:.3f},{0.1 * x:.4f}\n" for x in t))
    return path


def test_declared_frame(tmp_path):
    level = [load_run(_csv(tmp_path / f"l{i}.csv", "level")) for i in range(2)]
    body = load_run(_csv(tmp_path / "b.csv", "body"))
    none = load_run(_csv(tmp_path / "n.csv", None))
    assert [r.accel_frame for r in level] == ["level", "level"] and none.accel_frame is None
    assert level[0].channels["accel_y"].size == 20             # the comment lines are not data
    assert accel_frame(level) == "level" and accel_frame(level, "level") == "level"
    assert accel_frame([none]) == "body" and accel_frame([none], "level") == "level"
    assert accel_frame([*level, none], "level") == "level"     # the undeclared run takes the asked frame
    with pytest.raises(DataError, match="different accelerometer frames.*body \\(b.csv\\).*level \\(l0.csv, l1.csv"):
        accel_frame([*level, body])
    with pytest.raises(DataError, match="declare accel_frame level .* but the body frame was asked"):
        accel_frame(level, "body")
    with pytest.raises(DataError, match="others none \\(n.csv\\)"):
        accel_frame([*level, none])
    with pytest.raises(DataError, match="'tilted' is not an accelerometer frame"):
        load_run(_csv(tmp_path / "x.csv", "tilted"))


def test_structural_lag_sign():
    """A model whose signal comes 20 ms after the car's is said to lag it (residual = model - car)."""
    from rtsim.validate.structural import describe_signature, signature
    t = np.arange(0.0, 10.0, 0.01)
    car = np.sin(2.0 * t)
    model = np.sin(2.0 * (t - 0.02))
    sig = signature(t, model, model - car)
    assert sig["kind"] == "lag" and sig["value"] == pytest.approx(0.02, rel=0.05)
    assert describe_signature(sig, "m/s^2").startswith("lag: the model lags the car's signal by 20 ms")


def test_cli_frame_mismatch_is_an_error(tmp_path, capsys):
    """`rtsim validate --accel-frame body` on runs that declare the level frame stops with the reason."""
    from rtsim.validate.cli import _standalone
    runs = [_csv(tmp_path / f"l{i}.csv", "level") for i in range(3)]
    rc = _standalone(["--vehicle", str(VEHICLE), "--runs", *map(str, runs), "--report", str(tmp_path / "r"),
                      "--accel-frame", "body", "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "declare accel_frame level (l0.csv, l1.csv, l2.csv) but the body frame was asked" in err


def test_mcap_metadata_declares_the_frame(tmp_path):
    """A recording's metadata record with the key accel_frame declares it, as a CSV comment does."""
    from bridge.mcap_recorder import Recorder, read_recording
    from bridge.payloads import encode_json
    with Recorder(tmp_path / "run.mcap", "xbw", metadata={"logger": {"accel_frame": "level"}}) as rec:
        for k in range(20):
            rec.record("sensors", k * 10_000_000, encode_json({"time": k * 0.01, "accel_y": 0.1 * k}))
    run = load_run(tmp_path / "run.mcap", read_mcap=read_recording)
    assert run.accel_frame == "level" and run.channels["accel_y"].size == 20
