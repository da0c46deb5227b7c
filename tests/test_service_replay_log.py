"""`rtsim resim LOG`: ECU command frames from python-can logs (.asc, .blf, candump .log) drive the model
through the service's loop, with the same E2E checks (a corrupted frame is counted, not used)."""
from __future__ import annotations

import can  # noqa: F401  (python-can reads the logs: a hard dependency, never skipped)
import pytest

from bridge.can_codec import Codec
from bridge.can_logs import Frame, write_frames
from rtsim.service.resim import replay_log


def _session(codec: Codec, seconds: float = 4.0) -> list[Frame]:
    """An ECU's command stream: brake held for 0.5 s, then a throttle press; one corrupted frame."""
    frames, ctr = [], [0, 0, 0]
    names = ("throttle_angle_cmd", "brake_pressure_cmd", "steering_wheel_angle_cmd")
    for k in range(int(seconds / 0.01)):
        t = k * 0.01
        values = (0.0, 2000.0, 0.0) if t < 0.5 else (0.25, 0.0, 0.0)
        for i, name in enumerate(names):
            ctr[i] = (ctr[i] + 1) & 0xF
            fid, data = codec.encode_command(name, values[i], ctr[i])
            if k == 200 and i == 0:
                data = data[:7] + bytes((data[7] ^ 0xFF,))        # bad CRC
            frames.append(Frame(t + 1e-4 * i, fid, data, "rx"))
    return frames


MODELS: dict = {}     # one vehicle build for the module


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])
def test_command_log_drives_the_model(tmp_path, suffix):
    codec = Codec()
    frames = _session(codec)
    path = tmp_path / f"ecu{suffix}"
    write_frames(path, frames)
    rep = replay_log(path, models=MODELS)
    assert rep["frames"] == len(frames)
    assert rep["accepted"] == len(frames) - 1 and rep["rejected"]["crc"] == 1
    assert rep["run_state"] == "running"
    # the throttle press moves the car from rest (the same log replays the same way every time)
    assert rep["peak_speed"] > 1.0 and rep["distance"] > 1.0
    assert replay_log(path, models=MODELS)["distance"] == rep["distance"]
