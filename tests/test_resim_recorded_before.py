"""`rtsim resim` of a session recorded before the steering moved inside the multibody step (a 1.5 s
lockstep session of the demo ECU's lane change, recorded by the previous release and stored compressed):
it replays every recorded frame and reports where the model now differs, without failing. (A session
recorded now resimulates bit-identically: tests/test_service_e2e.py.)"""
from __future__ import annotations

import gzip
import shutil
from pathlib import Path

from rtsim.service.resim import resim

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "pre_kit_lockstep.mcap.gz"


def test_a_recording_from_before_the_kit_reports_its_differences(tmp_path):
    rec = tmp_path / "pre_kit_lockstep.mcap"
    with gzip.open(DATA, "rb") as src, rec.open("wb") as dst:
        shutil.copyfileobj(src, dst)
    # the recording names the previous release's files by absolute path; on another machine they are
    # gone, and its relative road and tyre paths cannot resolve from a temporary copy: re-simulate it
    # with today's files of the same names (the scenario and the vehicle are unchanged but for the
    # steering model, whose change is what the report must show)
    rep = resim(rec, vehicle=ROOT / "configs" / "vehicles" / "xbw.toml",
                scenario=ROOT / "configs" / "scenarios" / "hil_flat.toml")
    # every recorded sample was re-simulated and compared
    assert rep["sensors"]["missing"] == 0 and rep["sensors"]["matched"] >= 700
    assert rep["state"]["missing"] == 0 and rep["state"]["matched"] >= 140
    # ... and the steering shows the change of model (the rack is no longer guided one step late)
    assert not rep["identical"]
    assert rep["sensors"]["max_abs_diff"].get("steering_torque", 0.0) > 0.0
