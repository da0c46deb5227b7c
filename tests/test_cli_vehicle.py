"""The vehicle commands as a user runs them: describe, run, and their one-line errors."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

RTSIM = [sys.executable, "-m", "rtsim.cli"]
ROOT = Path(__file__).resolve().parents[1]
KEYS = ("n_coordinates", "n_dof", "mass", "wheelbase", "track_front", "track_rear", "cg_height",
        "cg_to_front_axle", "wheel_radius", "wheel_inertia", "cornering_stiffness_front",
        "cornering_stiffness_rear", "slip_stiffness", "rolling_resistance_coefficient", "drag_area",
        "brake_gain_front", "brake_gain_rear", "steering_ratio")


def _run(*args, timeout=300):
    return subprocess.run([*RTSIM, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def test_describe_json_has_the_key_parameters_consistent_with_the_file():
    import tomllib
    p = _run("describe", "--json")
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    for k in KEYS:
        assert k in info and np.isfinite(info[k])
    cfg = tomllib.loads((ROOT / "configs/vehicles/xbw.toml").read_text())
    mass = cfg["chassis"]["mass_kg"] + 2 * cfg["front"]["unsprung_mass_kg"] + 2 * cfg["rear"]["unsprung_mass_kg"]
    # 6 body + 4 travels + 4 spins + the steering's column and rack (coordinates of the model since the
    # steering moved into the multibody step; before, the rack was guided and the count was 14)
    assert info["mass"] == mass and info["n_dof"] == 16
    front = cfg["front"]["hardpoints"]["wheel_centre"]
    rear = cfg["rear"]["hardpoints"]["wheel_centre"]
    assert abs(info["wheelbase"] - (front[0] - rear[0])) < 1e-3
    assert abs(info["track_front"] - 2 * front[1]) < 1e-3
    b = cfg["brakes"]["front"]
    assert abs(info["brake_gain_front"] - b["pads"] * b["mu"] * b["piston_area"] * b["effective_radius"] * 1000) < 1e-9


def test_run_writes_csv_and_reports(tmp_path):
    out = tmp_path / "ss.csv"
    p = _run("run", "--scenario", "configs/scenarios/step_steer_80kph.toml", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "step_steer_80kph" in p.stdout and str(out) in p.stdout
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert abs(data["time"][-1] - 6.0) < 1e-9 and abs(data["speed"][0] - 22.22) < 0.05


def test_bad_inputs_fail_with_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((ROOT / "configs/vehicles/xbw.toml").read_text().replace("mass_kg = 730.0", "mass_kg = -1.0"))
    for args in (("run", "--vehicle", str(bad), "--scenario", "configs/scenarios/step_steer_80kph.toml",
                  "--out", str(tmp_path / "x.csv")),
                 ("run", "--scenario", "configs/scenarios/nosuch.toml", "--out", str(tmp_path / "x.csv")),
                 ("run", "--scenario", "configs/scenarios/step_steer_80kph.toml", "--out", str(tmp_path / "x.txt")),
                 ("describe", "--vehicle", str(bad))):
        p = _run(*args)
        assert p.returncode == 2, (args, p.stdout, p.stderr)
        lines = [l for l in p.stderr.splitlines() if l.strip()]
        assert len(lines) == 1 and lines[0].startswith("rtsim: error:") and "Traceback" not in p.stderr
