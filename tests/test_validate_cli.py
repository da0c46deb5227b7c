"""`rtsim validate` end to end (rtsim/validate/cli.py, report.py, configwrite.py): runs with a hidden
accelerometer bias in, report.html with its plots, summary.json in the issue's schema, a new vehicle
config with the effect that the config loader accepts (the original untouched) and its diff; one run
compares without a band; a missing file is a one-line error; `--ray auto` (a Ray instance of its own on
127.0.0.1, in a child process) gives the same summary."""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from validate_fieldgen import write_runs

from rtsim.validate.cli import _standalone
from rtsim.validate.replay import Replayer
from rtsim.vehicle.car.config import load_vehicle

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli_runs")
    rp = Replayer(VEHICLE)
    return write_runs(folder, rp.model, rp.road, {"sensor_bias": [{"channel": "accel_x", "bias": 0.15}]}, n=7,
                      seed=7)


@pytest.fixture(scope="module")
def report(runs, tmp_path_factory):
    """(report folder, printed text) of `rtsim validate` on the runs, the vehicle file's digest before."""
    digest = hashlib.sha256(VEHICLE.read_bytes()).hexdigest()
    out = tmp_path_factory.mktemp("cli_report") / "report"
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert _standalone(["--vehicle", str(VEHICLE), "--runs", *map(str, runs), "--report", str(out)]) == 0
    return out, text.getvalue(), digest


def test_cli_writes_report_summary_and_new_config(report):
    out, text, digest = report
    assert hashlib.sha256(VEHICLE.read_bytes()).hexdigest() == digest          # original untouched
    summ = json.loads((out / "summary.json").read_text())
    assert set(summ) == {"effects", "before", "after", "iterations", "verdict", "runs", "channels", "nuisance",
                         "correlations", "confounded", "accel_frame"}
    assert len(summ["runs"]["used"]) == 7 and summ["runs"]["left_out"] == [] and summ["runs"]["min_runs"] == 3
    v = summ["verdict"]
    assert v["headline"].startswith("Found: sensor_bias on accel_x: bias = ") and not v["notice"]
    assert v["found"][0]["name"] == "sensor_bias" and v["found"][0]["values"][0]["unit"] == "m/s^2"
    assert v["text"].splitlines()[0] == v["headline"] and f"verdict: {v['headline']}" in text
    assert {c["channel"]: c["status"] for c in v["channels"]}["accel_x"] == "explained"
    assert summ["accel_frame"] == "body" and "accelerometer frame: body" in text     # rtsim's own runs: body
    eff = summ["effects"][0]
    assert eff["name"] == "sensor_bias" and eff["parameters"]["channel"] == "accel_x"
    assert abs(eff["parameters"]["bias"] - 0.15) < 0.015 and eff["uncertainty"]["bias"] > 0
    for part in ("before", "after"):
        for c in ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr", "accel_x"):
            m = summ[part][c]
            assert set(m) == {"rms", "max", "inside_band"} and 0.0 <= m["inside_band"] <= 1.0
    assert summ["after"]["accel_x"]["rms"] * 5 <= summ["before"]["accel_x"]["rms"]
    assert summ["iterations"][0]["winner"]["name"] == "sensor_bias"
    html = (out / "report.html").read_text()
    for img in ("inputs.png", "channel_accel_x.png", "channel_wheel_speed_fl.png"):
        assert f'src="{img}"' in html and (out / img).stat().st_size > 1000
    new = out / "xbw_validated.toml"
    cfg, _ = load_vehicle(new)
    assert cfg.effects["sensor_bias"][0]["channel"] == "accel_x"
    assert cfg.tyres.property_file.endswith("michelin_155_80_r13.tir")
    assert "+[[effects.sensor_bias]]" in text and "verdict:" in text


def _without_times(d):
    if isinstance(d, dict):
        return {k: _without_times(v) for k, v in d.items() if k != "seconds"}
    return [_without_times(v) for v in d] if isinstance(d, list) else d


def _numba_cache_files(root: Path) -> set[Path]:
    """numba's compiled-code files: beside the sources, or under NUMBA_CACHE_DIR when set."""
    import numba
    where = [root / d for d in ("rtsim", "bridge", "drivers")]
    if numba.config.CACHE_DIR:
        where.append(Path(numba.config.CACHE_DIR))
    return {p for d in where if d.is_dir() for p in d.rglob("*.nbc")}


def _function_of(path: Path) -> tuple[str, str]:
    """(folder, module.function-line.pyXY) of a numba cache file `module.function-line.pyXY.N.nbc`: the
    function it holds, whatever the variant index N."""
    return str(path.parent), path.name.rsplit(".", 2)[0]


def test_cli_on_ray_gives_the_same_summary(runs, report, tmp_path):
    """The re-simulations as Ray tasks (rtsim.batch.executors.ray_map: the iteration's context shipped once
    to each worker): the same summary as the forked workers' (every number; the iterations' durations
    aside), and no kernel compiled again in the Ray workers."""
    out = tmp_path / "ray"
    root = VEHICLE.parents[2]
    env = {**os.environ, "PYTHONPATH": str(root), "RAY_USAGE_STATS_ENABLED": "0"}
    compiled = _numba_cache_files(root)
    r = subprocess.run([sys.executable, "-m", "rtsim.cli", "validate", "--vehicle", str(VEHICLE), "--runs",
                        *map(str, runs), "--report", str(out), "--no-progress", "--ray", "auto"],
                       cwd=root, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    # the Ray workers load the kernels the run without Ray compiled (same types: writable arrays), none
    # compiled again (read-only arrays from Ray's object store would make every kernel a new variant)
    # a kernel compiled again is a new variant file (index .2, .3, ...) of a function the run without Ray
    # cached; files of functions it never used are other processes' (tests running beside this one)
    cached = {_function_of(p) for p in compiled}
    new = sorted(p.name for p in _numba_cache_files(root) - compiled if _function_of(p) in cached)
    assert not new, f"the Ray workers compiled kernel variants the run without Ray had not: {new[:8]}"
    ray_summary = json.loads((out / "summary.json").read_text())
    plain = json.loads((report[0] / "summary.json").read_text())
    assert ray_summary["effects"] and _without_times(ray_summary) == _without_times(plain)


def test_cli_one_run_compares_without_a_band(runs, tmp_path):
    out = tmp_path / "one"
    """Below the 3 runs the data checks ask for only with --min-runs, and the report says so at its top."""
    assert _standalone(["--vehicle", str(VEHICLE), "--runs", str(runs[0]), "--report", str(out),
                        "--no-progress", "--max-iterations", "1"]) == 2
    assert _standalone(["--vehicle", str(VEHICLE), "--runs", str(runs[0]), "--report", str(out),
                        "--no-progress", "--max-iterations", "1", "--min-runs", "1"]) == 0
    summ = json.loads((out / "summary.json").read_text())
    assert all(m["inside_band"] is None for m in summ["before"].values())
    assert summ["runs"]["min_runs"] == 1 and summ["verdict"]["notice"].startswith(
        "Fewer runs allowed than the 3 the data checks ask for (--min-runs 1): 1 run(s) used, no band")
    html = (out / "report.html").read_text()
    assert "no confidence interval" in html
    assert html.index("<h1>") < html.index("class=notice") < html.index("Terms.") < html.index("<h2>Verdict")


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    assert _standalone(["--vehicle", str(VEHICLE), "--runs", str(tmp_path / "nope.csv"), "--report",
                        str(tmp_path / "r"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rtsim validate: error:") and "nope.csv: no such file" in err and "\n" not in err


def test_cli_bad_vehicle_with_progress_is_one_line(tmp_path, capsys):
    """The progress display starts at its first stage: a vehicle file refused before it (here a chassis
    mass of -1 kg) is the only output, no line of the display before it."""
    bad = tmp_path / "bad.toml"
    bad.write_text(VEHICLE.read_text().replace("mass_kg = ", "mass_kg = -1.0 # ", 1))
    runs = tmp_path / "runs.csv"
    runs.write_text("t\n0.0\n")
    assert _standalone(["--vehicle", str(bad), "--runs", str(runs), "--report", str(tmp_path / "r")]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("rtsim validate: error:") and captured.err.count("\n") == 1
    assert "mass_kg" in captured.err and captured.out == ""
