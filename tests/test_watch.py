"""`rtsim watch` (rtsim.watch): message rates, the rendered snapshot, and `--once` against a test
publisher over tcp/127.0.0.1 (all topics heard -> 0; silent topics named -> 1), in-process and as a
separate process. Rates are checked on a fake clock; `--timeout` only bounds how long `--once` waits
for the topics (tests/waits.py), it is generous because the machine may be loaded."""
from __future__ import annotations

import argparse
import io
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from bridge.payloads import FAULTS, REJECTIONS, encode_json, encode_sensors, encode_state
from bridge.zenoh_link import ZenohLink
from rtsim import watch
from rtsim.channels import SENSOR_NAMES, STATE_NAMES
from rtsim.errors import RtsimError
from waits import EVENT, PROCESS

ROOT = Path(__file__).resolve().parent.parent
VID = "xbw"


def status(t):
    return {"time": t, "vehicle_id": VID, "mode": "lockstep", "run_state": "paused", "sim_time": t,
            "steps": 4321, "overruns": 17, "skipped_steps": 2, "catch_up_steps": 9, "stalls": 1,
            "lateness_p50": 2e-6, "lateness_p99": 4.5e-4, "lateness_max": 0.0213, "cpu_p50": 3.1e-5,
            "cpu_p99": 6.2e-5, "cpu_max": 1.9e-4, "steal": None,
            "faults": {**dict.fromkeys(FAULTS, False), "steer_timeout": True},
            "rejected": {**dict.fromkeys(REJECTIONS, 0), "crc": 77}, "accepted_frames": 12345,
            "bus_errors": 3, "recorder": None, "zenoh_dropped": 0, "scenario": "step_steer_80kph",
            "message": "paused by request"}


SENSORS = np.arange(len(SENSOR_NAMES)) + 0.125          # accel_x = 0.125, ...
STATE = np.arange(len(STATE_NAMES)) * 10.0 + 0.5        # pos_x = 0.5, ..., speed = 120.5


class Publisher:
    """Publishes the given kinds at about 200 Hz from a thread until stopped."""

    def __init__(self, link, kinds=watch.TOPICS):
        self.link, self.kinds = link, kinds
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        i = 0
        while not self.stop.is_set():
            t = 0.002 * i
            msgs = {"sensors": lambda: encode_sensors(t, SENSORS),
                    "state": lambda: encode_state(t, STATE),
                    "status": lambda: encode_json(status(t)),
                    "commands": lambda: encode_json({"time": t, "steering_wheel_angle_cmd": -0.375,
                                                     "source": "safe"})}
            for k in self.kinds:
                self.link.publish(k, msgs[k]())
            i += 1
            self.stop.wait(0.005)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(10)


@pytest.fixture
def link():
    lk = ZenohLink(VID, listen=("tcp/127.0.0.1:0",))
    try:
        yield lk
    finally:
        lk.close()


def parse(argv):
    p = argparse.ArgumentParser()
    watch.add_arguments(p)
    return p.parse_args(argv)


def test_rates_and_silence_with_a_fake_clock():
    now = [100.0]
    m = watch.Monitor(clock=lambda: now[0])
    cb = m.callback("sensors")
    assert m.silent() == list(watch.TOPICS)
    for i in range(301):                        # 100 Hz for 3 s
        now[0] = 100.0 + i * 0.01
        cb({"time": i * 0.01})
    snap = m.snapshot()
    assert snap["sensors"]["rate"] == pytest.approx(100.0, rel=0.01)
    assert snap["sensors"]["count"] == 301 and snap["sensors"]["msg"] == {"time": 3.0}
    assert snap["state"]["rate"] == 0.0 and snap["state"]["msg"] is None
    assert m.silent() == ["state", "status", "commands"]
    now[0] += 0.5                               # early in a stream: rate since the first message
    m.callback("status")({})
    now[0] += 0.1
    m.callback("status")({})
    assert m.snapshot()["status"]["rate"] == pytest.approx(10.0)
    now[0] += 5.0                               # the publisher stopped: the rate decays to zero
    assert m.snapshot()["sensors"]["rate"] == 0.0
    assert m.snapshot()["sensors"]["age"] == pytest.approx(5.6)


def test_render_shows_every_section():
    m = watch.Monitor()
    m.callback("sensors")({"time": 1.0, **dict(zip(SENSOR_NAMES, SENSORS.tolist()))})
    m.callback("state")({"time": 1.0, **dict(zip(STATE_NAMES, STATE.tolist()))})
    m.callback("status")(status(1.0))
    buf = io.StringIO()
    Console(file=buf, width=120).print(watch.render(m.snapshot(), VID, "tcp/127.0.0.1:1"))
    out = buf.getvalue()
    for text in ("Sensors", "Vehicle state", "Actuators", "Loop health", "Faults / CAN", "Topics",
                 "lockstep", "paused", "step_steer_80kph", "paused by request",
                 "0.450 ms", "21.300 ms", "62.000 us", "FAULT", "silent"):
        assert text in out, text
    speed = STATE[STATE_NAMES.index("speed")]
    assert f"{speed:.5g}" in out and "m/s^2" in out


def test_once_against_a_publisher(link, capsys):
    with Publisher(link):
        rc = watch.main(parse(["--connect", link.endpoints[0], "--vehicle-id", VID, "--once",
                               "--timeout", str(EVENT)]))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "silent" not in out
    for name, v in (("accel_x", 0.125), ("brake_pressure", 12.125)):
        assert any(name in ln and f"{v:.5g}" in ln for ln in out.splitlines()), name
    assert "-0.375" in out and "safe" in out            # commands applied and their source
    assert "crc" in out and "77" in out and "12345" in out and "FAULT" in out


def test_once_names_silent_topics(link, capsys):
    # --once waits the whole --timeout for the silent topics: long enough for the sensors to be heard
    # on a loaded machine, short enough not to slow the suite
    with Publisher(link, kinds=("sensors",)):
        rc = watch.main(parse(["--connect", link.endpoints[0], "--once", "--timeout", "10"]))
    out = capsys.readouterr().out
    assert rc == 1
    assert "silent topics (no message within 10 s from" in out
    assert " ".join(out.split()).endswith("): state, status, commands")     # the sensors were heard


def test_live_view_for_a_duration(link, capsys):
    with Publisher(link):
        rc = watch.main(parse(["--connect", link.endpoints[0], "--duration", "0.6"]))
    assert rc == 0
    assert "Sensors" in capsys.readouterr().out


def test_bad_arguments():
    with pytest.raises(RtsimError, match="allow_remote"):
        watch.main(parse(["--connect", "tcp/0.0.0.0:7447", "--once"]))
    with pytest.raises(RtsimError, match="--timeout must be a positive number"):
        watch.main(parse(["--once", "--timeout", "0"]))


WATCH_CHILD = """
import argparse, sys
sys.path.insert(0, sys.argv[1])
from rtsim import watch
p = argparse.ArgumentParser(); watch.add_arguments(p)
sys.exit(watch.main(p.parse_args(sys.argv[2:])))
"""


def test_once_in_a_separate_process(link):
    with Publisher(link):
        proc = subprocess.run([sys.executable, "-c", WATCH_CHILD, str(ROOT), "--connect",
                               link.endpoints[0], "--once", "--timeout", str(EVENT)],
                              capture_output=True, text=True, timeout=PROCESS)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "step_steer_80kph" in proc.stdout and "\x1b[" not in proc.stdout   # plain text, no ANSI
