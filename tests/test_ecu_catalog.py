"""`rtsim test` end to end: the shipped demo catalogues run against the demo ECU and the demo EPS controller
over the CAN hub in lockstep; their JUnit XML read back with junitparser; the HTML report with its plots; a
resumed run taking every row from the journal; and an ECU no catalogue was written for (tests/ecu_small.py,
with a deliberate bug in one fault reaction) caught by exactly the case aimed at that bug.

One pool of two worker processes (each with its own CAN hub and service) serves every catalogue here, so the
kernels load once; the pool and everything it started are stopped at the end and checked gone. Every
assertion is on simulated time and recorded stamps."""
from __future__ import annotations

import os
from pathlib import Path

import junitparser          # a dependency of rtsim (it writes the JUnit XML): missing is a failure
import psutil               # the test extra: finds the processes a run leaves
import pytest

from rtsim.ecutest.cli import make_pool, run_catalogue, stop_pool
from rtsim.ecutest.report import write_html, write_junit

ROOT = Path(__file__).resolve().parent.parent
HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def pool():
    me = psutil.Process(os.getpid())
    before = {p.pid for p in me.children(recursive=True)}
    p = make_pool(2)
    try:
        yield p
    finally:
        # what the pool started (its workers and their CAN hubs), taken before stopping it: a hub whose
        # worker ended is no longer this process's descendant. multiprocessing's resource tracker serves
        # this whole Python process (it ends with it), not the run.
        started = [c for c in me.children(recursive=True)
                   if c.pid not in before and "multiprocessing.resource_tracker" not in _cmdline(c)]
        stop_pool(p)
        left = started + [c for c in me.children(recursive=True) if c.pid not in before and c not in started
                          and "multiprocessing.resource_tracker" not in _cmdline(c)]
        gone, alive = psutil.wait_procs(left, timeout=20)
        alive = [c for c in alive if _running(c)]          # a zombie has ended (its parent reaps it)
        names = [_cmdline(c) for c in alive]
        for c in alive:
            c.kill()
        assert not alive, f"processes left behind: {names}"


def _cmdline(proc) -> str:
    try:
        return " ".join(proc.cmdline())
    except psutil.Error:
        return str(proc.pid)


def _running(proc) -> bool:
    try:
        return proc.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _run(name_or_path, out, pool):
    path = name_or_path if isinstance(name_or_path, Path) else ROOT / "configs" / "tests" / f"{name_or_path}.toml"
    cat, rows = run_catalogue(path, out, workers=2, pool=pool, say=lambda line: None)
    write_junit(cat.spec.name, rows, out / "junit.xml")
    write_html(cat, rows, out, out / "report.html")
    return cat, rows


def _junit(path):
    xml = junitparser.JUnitXml.fromfile(str(path))
    cases = [c for s in xml for c in s]
    return {c.name: c for c in cases}


def _outcome(row, label):
    return next(o for o in row["outcomes"] if o["label"] == label)


def test_demo_ecu_catalogue(pool, tmp_path):
    out = tmp_path / "demo"
    cat, rows = _run("demo_ecu", out, pool)
    assert [r["status"] for r in rows].count("error") == 0, [r["message"] for r in rows]
    cases = _junit(out / "junit.xml")
    assert set(cases) == {c.name for c in cat.spec.cases}
    failed = {n for n, c in cases.items() if not c.is_passed}
    assert failed == {"front_wheel_sensor_stuck"}                   # the demo ECU's weakness, and only it
    (res,) = cases["front_wheel_sensor_stuck"].result
    assert isinstance(res, junitparser.Failure)
    msg = res.message
    assert msg.startswith("speed stays within 10 % of the 12.5 m/s target: state.speed = ")
    assert " at t = " in msg and "outside [-inf, 13.75]" in msg and "worst " in msg
    by = {r["name"]: r for r in rows}
    # the failing value is the recorded one, past the bound, after the fault's onset at 2 s
    o = _outcome(by["front_wheel_sensor_stuck"], "speed stays within 10 % of the 12.5 m/s target")
    assert o["value"] > 13.75 and o["time"] > 2.0
    # the bench's safe state: the hold pressure exactly within the watchdog's 3 periods (30 ms + 1 step),
    # counted from the recorded fault onset (at the step of 2.0 s)
    o = _outcome(by["brake_pressure_timeout"], "hold pressure applied within 31 ms")
    assert o["event_time"] == pytest.approx(2.0, abs=1e-9) and 2.0 < o["time"] <= 2.031 + 1e-9
    # every case ran its simulated duration
    for r in rows:
        assert r["sim_end"] >= cat.duration(cat.spec.cases[r["case"]]) - 0.002
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len(rows)
    for r in rows:
        assert (out / "cases" / r["name"] / "plot.png").stat().st_size > 1000
    # resumed: every row from the journal, none run again, the same table
    cat2, rows2 = run_catalogue(ROOT / "configs" / "tests" / "demo_ecu.toml", out, workers=2, pool=pool,
                                say=lambda line: None)
    assert rows2 == rows


def test_demo_eps_catalogue(pool, tmp_path):
    out = tmp_path / "eps"
    cat, rows = _run("demo_eps", out, pool)
    cases = _junit(out / "junit.xml")
    assert len(cases) == 2 and all(c.is_passed for c in cases.values()), [r["message"] for r in rows]
    by = {r["name"]: r for r in rows}
    o = _outcome(by["eps_command_loss"], "power stage off within 5 ms")
    # the watchdog: the last frame taken at the step before the onset, the stage off after 3 periods
    assert o["event_time"] == pytest.approx(1.2, abs=1e-9) and o["time"] - o["event_time"] <= 0.005 + 1e-9


def test_unseen_ecu_caught_by_exactly_its_case(pool, tmp_path):
    out = tmp_path / "small"
    cat, rows = _run(HERE / "ecu_small_catalog.toml", out, pool)
    cases = _junit(out / "junit.xml")
    assert len(cases) == 5
    assert {n for n, c in cases.items() if not c.is_passed} == {"front_right_sensor_stuck"}, \
        [r["message"] for r in rows]
    (res,) = cases["front_right_sensor_stuck"].result
    assert "ecu.BRAKE_CMD.brake_pressure_cmd never >= 4000" in res.message and "after fault:fr at 1.5 s" in res.message
    # its mirror image, the front-left sensor, is caught: the ECU's safe state within 0.1 s of the onset
    o = next(o for o in {r["name"]: r for r in rows}["front_left_sensor_stuck"]["outcomes"]
             if o["signal"] == "ecu.BRAKE_CMD.brake_pressure_cmd")
    assert o["passed"] and 1.5 < o["time"] <= 1.6 + 1e-9
