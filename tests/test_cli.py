"""`rtsim bench`, run as a user would: the installed console script in a subprocess."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import references as R
import rtsim.cli  # noqa: F401  (the module under test: an ImportError fails, never skips)

_SCRIPT = Path(sys.executable).with_name("rtsim")
COMMAND = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "rtsim.cli"]
TIMEOUT = 300  # s: a cold numba cache compiles the kernels first

REQUIRED_KEYS = {
    "problem", "dt", "t_end", "steps", "wall_s", "us_per_step", "max_position_constraint_violation",
    "max_velocity_constraint_violation", "energy_drift", "final",
}


def rtsim(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(COMMAND + list(args), capture_output=True, text=True, timeout=TIMEOUT)


@pytest.fixture(scope="module")
def pendulum_json():
    proc = rtsim("bench", "--problem", "pendulum", "--t-end", "1", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    return json.loads(proc.stdout)


def test_bench_json_schema(pendulum_json):
    assert isinstance(pendulum_json, list) and len(pendulum_json) == 1
    r = pendulum_json[0]
    assert REQUIRED_KEYS <= set(r), REQUIRED_KEYS - set(r)
    assert r["problem"] == "pendulum"
    assert r["dt"] == pytest.approx(1e-3)           # the problem's default step
    assert r["t_end"] == pytest.approx(1.0)
    assert r["steps"] == 1000 and isinstance(r["steps"], int)
    assert r["wall_s"] > 0 and math.isfinite(r["wall_s"])
    assert r["us_per_step"] == pytest.approx(r["wall_s"] / r["steps"] * 1e6, rel=1e-6)


def test_bench_json_physics(pendulum_json):
    r = pendulum_json[0]
    ref = R.pendulum_reference([1.0], with_energy=True)
    assert set(r["final"]) == {"x_P1", "y_P1"}
    assert abs(r["final"]["x_P1"] - ref["x_P1"][0]) <= 1e-3
    assert abs(r["final"]["y_P1"] - ref["y_P1"][0]) <= 1e-3
    assert 0.0 <= r["max_position_constraint_violation"] <= 1e-8
    assert 0.0 <= r["max_velocity_constraint_violation"] <= 1e-6
    # conservative: drift is reported; trapezoidal bound 5 (w h)^2 m g L with w = sqrt(2 g / L)
    # (see tests/test_benchmarks.py::test_energy_conserved)
    assert r["energy_drift"] is not None
    assert 0.0 <= r["energy_drift"] <= 5.0 * (2 * 9.81 * 1e-6) * 9.81


def test_bench_options_dt_and_t_end():
    proc = rtsim("bench", "--problem", "fourbar", "--dt", "0.002", "--t-end", "0.5", "--json")
    assert proc.returncode == 0, proc.stderr
    (r,) = json.loads(proc.stdout)
    assert r["problem"] == "fourbar"
    assert r["dt"] == pytest.approx(2e-3)
    assert r["steps"] == 250 and r["t_end"] == pytest.approx(0.5)
    ref = R.fourbar_reference(1, [0.5])
    assert np.hypot(r["final"]["x_B0"] - ref["x_B0"][0], r["final"]["y_B0"] - ref["y_B0"][0]) <= 1e-3


def _assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    assert proc.stdout.strip() == ""


def test_bench_unknown_problem_fails_cleanly():
    proc = rtsim("bench", "--problem", "nosuch")
    _assert_one_line_error(proc, "nosuch")


@pytest.mark.parametrize("flag", ["--dt", "--t-end"])
def test_bench_rejects_non_positive_times(flag):
    proc = rtsim("bench", "--problem", "pendulum", flag, "-1")
    _assert_one_line_error(proc, flag)
