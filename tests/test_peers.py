"""tools/peers/mujoco_box_car.py, the peer of `rtsim bench --suite vehicle`: without MuJoCo (an optional
dependency, the `peers` extra) it says in one line how to install it; with MuJoCo it builds the 14-DOF box
car (6 + 4 slide + 4 hinge DOF) and keeps it on its wheels."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "tools" / "peers" / "mujoco_box_car.py"


def test_without_mujoco_it_says_how_to_install_it():
    code = ("import runpy, sys; sys.modules['mujoco'] = None; sys.argv = ['mujoco_box_car.py']; "
            f"runpy.run_path({str(SCRIPT)!r}, run_name='__main__')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 1 and "pip install 'rtsim[peers]'" in lines[0], r.stdout + r.stderr


@pytest.mark.skipif(importlib.util.find_spec("mujoco") is None,
                    reason="MuJoCo is an optional dependency (pip install 'rtsim[peers]')")
def test_box_car_has_14_dof_and_stays_on_its_wheels():
    r = subprocess.run([sys.executable, str(SCRIPT), "--steps", "300"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "nv = 14" in r.stdout and "us/step" in r.stdout
