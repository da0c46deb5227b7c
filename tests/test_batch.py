"""`rtsim batch` end to end on configs/batch/smoke.toml (both cars and the motorcycle, 12 short runs):
a bad grid value and a fall are recorded rows and the batch goes on; a batch killed after some rows
resumes with only the missing runs; a Ray cluster started here on 127.0.0.1 (a head and a worker, one
of its worker processes killed mid-batch) gives the local pool's table row for row (wall time and
worker excluded), and every Ray process listens on loopback only."""
from __future__ import annotations

import csv
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLAN = ROOT / "configs" / "batch" / "smoke.toml"
VOLATILE = ("wall_s", "worker")
ENV = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "PYTHONPATH": str(ROOT)}


def _batch(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "rtsim.cli", "batch", str(PLAN), *args], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def _rows(path: Path) -> list[dict]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _identity(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """The plan on the local pool, killed (SIGKILL to its process group) after 4 journalled rows, then
    resumed: (output folder, rows before the kill, the resumed run's output)."""
    out = tmp_path_factory.mktemp("batch_local")
    journal = out / "journal.csv"
    p = _batch("--out", str(out), "--no-report", start_new_session=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and p.poll() is None:
        if journal.exists() and len(journal.read_text().splitlines()) >= 1 + 4:
            break
        time.sleep(0.02)
    assert p.poll() is None, "the batch ended before it could be interrupted:\n" + p.stdout.read()
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    before = [r["run_id"] for r in _rows(journal)]
    r = _batch("--out", str(out))
    text, _ = r.communicate(timeout=300)
    assert r.returncode == 1, text            # some runs fail or error by design
    return out, before, text


def test_errors_and_falls_are_rows_and_the_batch_goes_on(local):
    out, _, _ = local
    rows = _rows(out / "results.csv")
    assert len(rows) == 12 and len({r["run_id"] for r in rows}) == 12
    assert [r["run_id"] for r in rows] == sorted(r["run_id"] for r in rows)
    bad = [r for r in rows if r["scenario.duration"] == "-1.0"]
    assert len(bad) == 4 and all(r["status"] == "config_error" and r["verdict"] == "error" for r in bad)
    assert all("duration = -1.0: out of range" in r["error"] and "smoke" not in r["error"] for r in bad)
    fell = [r for r in rows if r["status"] == "fall"]
    assert len(fell) == 1 and fell[0]["scenario"] == "motorcycle_counter_steer" and fell[0]["verdict"] == "fail"
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == 7 and all(r["verdict"] == "pass" for r in ok)
    for r in ok + fell:      # the run ended where it should: its duration, or the fall
        assert float(r["simulated_s"]) == pytest.approx(float(r["scenario.duration"]), abs=1e-9) or r is fell[0]
        assert float(r["max_constraint_violation"]) < 1e-6
    # the cars' power audit: the integrator's energy error is small against the kinetic energy
    cars = [r for r in ok if r["vehicle"] in ("xbw", "eps_car")]
    assert len(cars) == 4 and all(float(r["energy_residual_max"]) < 50.0 for r in cars)
    assert all(math.isnan(float(r["energy_residual_max"])) for r in ok if r["vehicle"] == "")
    import pyarrow.parquet as pq
    table = pq.read_table(out / "results.parquet").to_pylist()
    assert [t["run_id"] for t in table] == [r["run_id"] for r in rows]
    html = (out / "report.html").read_text()
    assert "Failures and errors (5)" in html and "data:image/png;base64" in html


def test_resume_runs_only_what_was_missing(local):
    out, before, text = local
    assert 4 <= len(before) < 12
    assert f"{len(before)} already in" in text and f"{12 - len(before)} to run" in text
    journal = [r["run_id"] for r in _rows(out / "journal.csv")]
    assert len(journal) == 12 and len(set(journal)) == 12 and journal[:len(before)] == before


def _ray_processes(temp_dir: str):
    import psutil

    roots = []
    for p in psutil.process_iter(["cmdline"]):
        try:
            if any(temp_dir in a for a in (p.info["cmdline"] or ())):
                roots.append(p)
        except psutil.Error:
            pass
    procs = {p.pid: p for p in roots}
    for p in roots:
        try:
            procs.update({c.pid: c for c in p.children(recursive=True)})
        except psutil.Error:
            pass
    return list(procs.values())


def test_ray_cluster_gives_the_same_table_and_loses_no_run(local, tmp_path):
    ray_bin = shutil.which("ray", path=str(Path(sys.executable).parent))
    if ray_bin is None:
        pytest.fail("ray is a dependency (pyproject.toml) but its `ray` command is not installed")
    import psutil
    from tests.service_harness import free_port

    temp_dir = tempfile.mkdtemp(prefix="rtray", dir="/tmp")       # short: Ray's socket paths must fit
    port = free_port()
    common = ["--node-ip-address=127.0.0.1", "--num-cpus=1", f"--temp-dir={temp_dir}", "--disable-usage-stats"]
    try:
        subprocess.run([ray_bin, "start", "--head", f"--port={port}", "--include-dashboard=false", *common],
                       env=ENV, cwd=ROOT, check=True, capture_output=True, timeout=120)
        subprocess.run([ray_bin, "start", f"--address=127.0.0.1:{port}", *common], env=ENV, cwd=ROOT, check=True,
                       capture_output=True, timeout=120)
        out = tmp_path / "ray"
        p = _batch("--out", str(out), "--no-report", "--ray", f"127.0.0.1:{port}")
        killed = None
        deadline = time.monotonic() + 300
        while killed is None and p.poll() is None and time.monotonic() < deadline:
            for proc in _ray_processes(temp_dir):
                try:
                    if proc.name().startswith("ray::run_one") or "ray::run_one" in " ".join(proc.cmdline()):
                        proc.kill()
                        killed = proc.pid
                        break
                except psutil.Error:
                    pass
            time.sleep(0.02)
        listening = []
        for proc in _ray_processes(temp_dir):
            try:
                listening += [(proc.name(), c.laddr) for c in proc.net_connections("inet") if c.status == "LISTEN"]
            except psutil.Error:
                pass
        text, _ = p.communicate(timeout=300)
        assert p.returncode == 1, text
        assert killed is not None, "no Ray worker was seen running a task to kill:\n" + text
        assert listening and all(a.ip in ("127.0.0.1", "::1") for _, a in listening), listening
        rows = _rows(out / "results.csv")
        assert _identity(rows) == _identity(_rows(local[0] / "results.csv"))
        assert all(r["status"] != "error" for r in rows), [r["error"] for r in rows if r["status"] == "error"]
    finally:
        for proc in _ray_processes(temp_dir):          # this cluster's processes only (not `ray stop`)
            try:
                proc.kill()
            except psutil.Error:
                pass
        shutil.rmtree(temp_dir, ignore_errors=True)
