"""`rtsim batch` end to end on configs/batch/smoke.toml (both cars and the motorcycle, 12 short runs):
a bad grid value and a fall are recorded rows and the batch goes on; a batch killed after some rows
resumes with only the missing runs; a Ray cluster started here with `ray start` on 127.0.0.1 (one node,
two worker slots; a worker process killed while it runs a task) gives the local pool's table row for
row (wall time and worker excluded), and every process of that cluster listens on loopback only. The
cluster is stopped by killing its own processes (found by its temp folder and port), not `ray stop`,
which would stop every Ray process of the user."""
from __future__ import annotations

import csv
import math
import os
import secrets
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
VOLATILE = ("wall_s", "step_s", "outside_s", "outside_pct", "between_s", "worker")
# token authentication on, the token in the environment of this cluster's processes only (nothing
# written to ~/.ray)
ENV = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "PYTHONPATH": str(ROOT), "RAY_AUTH_MODE": "token",
       "RAY_AUTH_TOKEN": secrets.token_hex(16)}
# `ray start` replaces a node address of 127.0.0.1 by the machine's routable one unless
# RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 (Ray's single-machine mode); its servers bind only the loopback
# address when the node's address is 127.0.0.1 and every interface otherwise (measured with Ray 2.60:
# with a second node on 127.0.0.2 the GCS and the raylets listened on "::"). That mode refuses a second
# node, so the cluster here is one head node with two worker slots.
NODE_IP = "127.0.0.1"
ENV["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"


def _batch(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "rtsim.cli", "batch", str(PLAN), *args], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def _rows(path: Path) -> list[dict]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _journal_ids(path: Path) -> list[str]:
    """The run ids of a journal (JSON lines after the header line), in the order they arrived; a last line
    cut off by a kill (no line break yet) left out."""
    import json

    return [json.loads(line)["run_id"] for line in path.read_text().split("\n")[1:-1]]


def _identity(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """The plan on the local pool, killed (SIGKILL to its process group) after 4 journalled rows, then
    resumed: (output folder, rows before the kill, the resumed run's output)."""
    out = tmp_path_factory.mktemp("batch_local")
    journal = out / "journal.jsonl"
    p = _batch("--out", str(out), "--no-report", start_new_session=True)
    deadline = time.monotonic() + 900          # an empty kernel cache on a loaded machine: minutes
    seen = 0
    while time.monotonic() < deadline and p.poll() is None:
        seen = len(_journal_ids(journal)) if journal.exists() else 0
        if seen >= 4:
            break
        time.sleep(0.02)
    assert p.poll() is None, "the batch ended before it could be interrupted:\n" + p.stdout.read()
    assert seen >= 4, f"only {seen} rows journalled in 900 s"
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    before = _journal_ids(journal)
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
    journal = _journal_ids(out / "journal.jsonl")
    assert len(journal) == 12 and len(set(journal)) == 12 and journal[:len(before)] == before


def _loopback(ip: str) -> bool:
    import ipaddress

    a = ipaddress.ip_address(ip)
    return (getattr(a, "ipv4_mapped", None) or a).is_loopback


def _ray_processes(temp_dir: str, port: int):
    """The processes of the cluster this test started: those naming its temp folder or its GCS port, and
    their children."""
    import psutil

    roots = []
    for p in psutil.process_iter(["cmdline"]):
        try:
            if any(temp_dir in a or a.endswith(f"{NODE_IP}:{port}") for a in (p.info["cmdline"] or ())):
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
        pytest.fail("ray is a test dependency (the rtsim[ray] extra that tools/setup installs) but its `ray` "
                    "command is not installed")
    import psutil
    from tests.service_harness import free_port

    temp_dir = tempfile.mkdtemp(prefix="rtray", dir="/tmp")       # short: Ray's socket paths must fit
    port = free_port()
    common = [f"--node-ip-address={NODE_IP}", "--num-cpus=2", f"--temp-dir={temp_dir}", "--disable-usage-stats"]
    try:
        # plain `ray` (the rtsim[ray] extra) starts no Ray Client server and refuses the option; where
        # the client's dependency (grpc) is installed, the head starts one: on a free port, not 10001
        import importlib.util
        client = [f"--ray-client-server-port={free_port()}"] if importlib.util.find_spec("grpc") else []
        for args in (["--head", f"--port={port}", "--include-dashboard=false", *client],):
            r = subprocess.run([ray_bin, "start", *args, *common], env=ENV, cwd=ROOT, capture_output=True, text=True,
                               timeout=120)
            assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
        out = tmp_path / "ray"
        p = _batch("--out", str(out), "--no-report", "--ray", f"{NODE_IP}:{port}")
        killed = None
        deadline = time.monotonic() + 300
        while killed is None and p.poll() is None and time.monotonic() < deadline:
            for proc in _ray_processes(temp_dir, port):
                try:
                    if proc.name().startswith("ray::run_one") or "ray::run_one" in " ".join(proc.cmdline()):
                        proc.kill()
                        killed = proc.pid
                        break
                except psutil.Error:
                    pass
            time.sleep(0.02)
        listening = []
        for proc in _ray_processes(temp_dir, port):
            try:
                listening += [(proc.name(), c.laddr) for c in proc.net_connections("inet") if c.status == "LISTEN"]
            except psutil.Error:
                pass
        text, _ = p.communicate(timeout=300)
        assert p.returncode == 1, text
        assert killed is not None, "no Ray worker was seen running a task to kill:\n" + text
        assert listening and all(_loopback(a.ip) for _, a in listening), listening
        rows = _rows(out / "results.csv")
        assert _identity(rows) == _identity(_rows(local[0] / "results.csv"))
        assert all(r["status"] != "error" for r in rows), [r["error"] for r in rows if r["status"] == "error"]
    finally:
        for proc in _ray_processes(temp_dir, port):          # this cluster's processes only (not `ray stop`)
            try:
                proc.kill()
            except psutil.Error:
                pass
        shutil.rmtree(temp_dir, ignore_errors=True)


def test_ray_auto_is_local_on_loopback_and_gives_the_same_table(local, tmp_path):
    """`--ray auto`: a Ray instance of the batch's own, every process listening on loopback only, the
    local pool's table, and no token or state left in ~/.ray."""
    import psutil

    out = tmp_path / "auto"
    home_ray = Path.home() / ".ray" / "auth_token"
    had_token = home_ray.exists()
    p = _batch("--out", str(out), "--no-report", "--ray", "auto")
    listening, seen = [], set()
    while p.poll() is None:
        try:
            procs = [psutil.Process(p.pid), *psutil.Process(p.pid).children(recursive=True)]
        except psutil.Error:
            break
        for proc in procs:
            try:
                for c in proc.net_connections("inet"):
                    if c.status == "LISTEN" and (proc.pid, c.laddr) not in seen:
                        seen.add((proc.pid, c.laddr))
                        listening.append((proc.name(), c.laddr))
            except psutil.Error:
                pass
        time.sleep(0.1)
    text, _ = p.communicate(timeout=300)
    assert p.returncode == 1, text
    assert listening and all(_loopback(a.ip) for _, a in listening), listening
    assert _identity(_rows(out / "results.csv")) == _identity(_rows(local[0] / "results.csv"))
    assert home_ray.exists() == had_token


def test_a_killed_pool_worker_loses_no_run(local, tmp_path):
    """A local pool worker killed mid-batch breaks the pool; the runs not yet back go to a fresh pool and
    the table is the same, no run lost."""
    import psutil

    out = tmp_path / "pool"
    journal = out / "journal.jsonl"
    p = _batch("--out", str(out), "--no-report")
    killed = None
    while killed is None and p.poll() is None:
        done = len(journal.read_text().splitlines()) - 1 if journal.exists() else 0
        if 1 <= done < 12:
            try:
                workers = [c for c in psutil.Process(p.pid).children(recursive=True)
                           if "spawn_main" in " ".join(c.cmdline())]
                if workers:
                    workers[0].kill()
                    killed = workers[0].pid
            except psutil.Error:
                pass
        time.sleep(0.01)
    text, _ = p.communicate(timeout=300)
    assert p.returncode == 1, text
    assert killed is not None, "the batch ended before a worker could be killed:\n" + text
    assert _identity(_rows(out / "results.csv")) == _identity(_rows(local[0] / "results.csv"))


def _plan_file(tmp_path, body: str) -> Path:
    plan = tmp_path / "plan.toml"
    plan.write_text(body)
    return plan


def _run_plan(plan: Path, *args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rtsim.cli", "batch", str(plan), *args], cwd=ROOT, env=ENV,
                          capture_output=True, text=True, timeout=600, **kw)


def _table(path: Path) -> list[list[str]]:
    """The CSV table's cells, the volatile columns left out (multi-line cells kept whole)."""
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    keep = [i for i, c in enumerate(rows[0]) if c not in VOLATILE]
    return [[r[i] for i in keep] for r in rows]


def test_a_resumed_batch_gives_the_table_of_an_uninterrupted_one_with_multi_line_errors(tmp_path):
    """Runs whose error text holds line breaks, a tab, quotes and non-ASCII characters (a vehicle kind
    that fails every run and draws nothing from its seed, tests/batch_failing_kind.py), two seeds per
    point: each point is simulated once and its other seed's row is a copy, said once at the start. A
    batch stopped after 2 simulations and resumed writes the report byte for byte and the results table
    cell for cell (wall time and worker aside) as the batch run straight through, each error text
    exactly as raised."""
    from tests.batch_failing_kind import MESSAGE

    (tmp_path / "failing.toml").write_text('assembly = "tests.batch_failing_kind"\nname = "failing"\n')
    scen = (ROOT / "configs" / "scenarios" / "step_steer_80kph.toml").as_posix()
    plan = _plan_file(tmp_path, f'name = "multiline"\nmetrics = ["peak_roll"]\nrepetitions = 2\n[[cases]]\n'
                      f'scenario = "{scen}"\nvehicle = "failing.toml"\n'
                      '[grid]\n"scenario.duration" = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]\n')
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    r = _run_plan(plan, "--workers", "1", "--out", str(straight))
    assert r.returncode == 1, r.stdout + r.stderr
    notes = [line for line in r.stderr.splitlines() if "seeds change nothing" in line]
    assert len(notes) == 1 and "6 of the 12 runs are simulated" in notes[0], r.stderr
    r = _run_plan(plan, "--workers", "1", "--out", str(resumed), "--limit", "2")
    assert r.returncode == 1 and "2 to run" in r.stderr, r.stdout + r.stderr
    r = _run_plan(plan, "--workers", "1", "--out", str(resumed))
    assert r.returncode == 1 and "4 already in" in r.stderr and "4 to run" in r.stderr, r.stdout + r.stderr
    assert (resumed / "report.html").read_bytes() == (straight / "report.html").read_bytes()
    table = _table(resumed / "results.csv")
    assert table == _table(straight / "results.csv") and len(table) == 13
    head = table[0]
    errors = [row[head.index("error")] for row in table[1:]]
    assert all(e.startswith(f"RuntimeError: {MESSAGE} (batch_failing_kind.py:") for e in errors), errors
    rows = [dict(zip(head, row)) for row in table[1:]]
    by_id = {row["run_id"]: row for row in rows}
    copies = [row for row in rows if row["copy_of"]]
    assert len(copies) == 6 and all(row["seed"] == "1" for row in copies)
    for row in copies:
        orig = by_id[row["copy_of"]]
        assert orig["seed"] == "0" and not orig["copy_of"]
        assert {k: v for k, v in row.items() if k not in ("run_id", "seed", "copy_of")} == \
            {k: v for k, v in orig.items() if k not in ("run_id", "seed", "copy_of")}


def test_a_sigkilled_batch_leaves_no_worker_or_resource_tracker_behind(tmp_path):
    """`rtsim batch` with 2 pool workers on slow runs, in a session of its own: once its first row is
    back, SIGKILL to the batch process alone (not its group). Every process it had started (the pool's
    workers and multiprocessing's resource tracker) ends by itself."""
    import psutil

    scen = (ROOT / "configs" / "scenarios" / "step_steer_80kph.toml").as_posix()
    veh = (ROOT / "configs" / "vehicles" / "xbw.toml").as_posix()
    plan = _plan_file(tmp_path, f'name = "slow"\nmetrics = ["peak_roll"]\n[[cases]]\nscenario = "{scen}"\n'
                      f'vehicle = "{veh}"\n[grid]\n"scenario.duration" = [60.0, 60.5, 61.0, 61.5, 62.0, 62.5]\n')
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "rtsim.cli", "batch", str(plan), "--workers", "2", "--out", str(out),
                          "--no-report"], cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    started: list = []
    try:
        deadline = time.monotonic() + 600
        journal = out / "journal.jsonl"
        while p.poll() is None and time.monotonic() < deadline:
            if journal.exists() and len(journal.read_text().split("\n")) >= 3:      # header + 1 row
                break
            time.sleep(0.05)
        assert p.poll() is None, "the batch ended before it could be killed"
        started = psutil.Process(p.pid).children(recursive=True)
        cmd = {c.pid: " ".join(c.cmdline()) for c in started}
        workers = [pid for pid, c in cmd.items() if "spawn_main" in c]
        trackers = [pid for pid, c in cmd.items() if "resource_tracker" in c]
        assert len(workers) == 2 and len(trackers) == 1, cmd
        os.kill(p.pid, signal.SIGKILL)
        p.wait()

        def alive() -> list:
            out = []
            for c in started:
                try:
                    if c.is_running() and c.status() != psutil.STATUS_ZOMBIE:
                        out.append(c)
                except psutil.NoSuchProcess:
                    pass
            return out
        deadline = time.monotonic() + 60
        while alive() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not alive(), [cmd[c.pid] for c in alive()]
    finally:
        for c in started:
            try:
                c.kill()
            except psutil.Error:
                pass
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except OSError:
            pass
        p.wait()
