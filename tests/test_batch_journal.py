"""The batch's bookkeeping without simulations: the journal gives back any text and number it was given
(a resumed batch's tables are byte for byte those of an uninterrupted one), the ETA counts completed run
times only, seeds that draw nothing are simulated once, and a missing Ray is one line saying how to
install it."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from rtsim.batch.cli import columns, copy_row, same_runs, seed_note
from rtsim.batch.progress import eta_seconds
from rtsim.batch.report import write_report
from rtsim.batch.results import Journal, sorted_rows, write_tables

ROOT = Path(__file__).resolve().parents[1]
TEXTS = ["line one\nline two", "tab\there", "quotes: 'single', \"double\", \\backslash\\, a comma,",
         "ünïcödé ✓ 漢字 \U0001F600", "crlf\r\nand a lone cr\r", "", "a lone surrogate \udcff from a file name",
         "  leading and trailing spaces  ", "NaN", "null", "{\"json\": [1]}", "\x00\x1f control"]
PLAN = SimpleNamespace(name="journal", description="the journal's round trip", metrics=["peak_roll", "distance"],
                       repetitions=1)


def _rows() -> list[dict]:
    vals = [math.nan, math.inf, -math.inf, -0.0, 0.1 + 0.2, 1e-310, 5e-324, 1.7976931348623157e308, 3.0, -2.5]
    rows = []
    for i, text in enumerate(TEXTS):
        rows.append({"run_id": f"{i:016x}", "case": i % 3, "scenario": "step_steer_80kph", "vehicle": "xbw",
                     "seed": i, "vehicle.chassis.mass_kg": vals[i % len(vals)],
                     "scenario.rider.p_roll": [1.0, {"a": text}] if i % 4 == 0 else 200.0 + i,
                     "status": "error" if text else "ok", "verdict": "error" if text else "pass",
                     "failed": text[::-1], "error": text, "simulated_s": vals[(i + 3) % len(vals)],
                     "peak_roll": vals[(i + 5) % len(vals)], "distance": None, "wall_s": 0.25 * i,
                     "worker": f"host:{1000 + i}", "copy_of": ""})
    return rows


def _tables(rows: list[dict], cols: list[str], out: Path) -> tuple[bytes, bytes]:
    out.mkdir()
    write_tables(rows, cols, out)
    write_report(rows, PLAN, ["vehicle.chassis.mass_kg", "scenario.rider.p_roll"], out / "report.html")
    return (out / "results.csv").read_bytes(), (out / "report.html").read_bytes()


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")     # the report's axes at 1.8e308
def test_a_resumed_journal_gives_byte_identical_tables(tmp_path):
    """Rows journalled, the journal cut off mid-row (a kill), read back and completed: the CSV table and
    the HTML report are byte for byte those of the rows written straight through, and each text (line
    breaks, tabs, quotes, unicode, a lone surrogate) and number (NaN, infinities, -0.0, subnormals) is
    the one computed."""
    cols = columns(PLAN, ["vehicle.chassis.mass_kg", "scenario.rider.p_roll"])
    rows = _rows()
    straight = Journal(tmp_path / "straight.jsonl", cols)
    for r in rows:
        straight.append(r)
    straight.close()
    ids = [r["run_id"] for r in rows]

    path = tmp_path / "resumed.jsonl"
    first = Journal(path, cols)
    for r in rows[:7]:
        first.append(r)
    first.close()
    with path.open("ab") as fh:                    # the kill came while the 8th row was being written
        fh.write(json.dumps(rows[7])[:25].encode())
    resumed = Journal(path, cols)
    assert sorted(resumed.rows) == ids[:7]           # the cut row dropped: its run is done again
    for r in rows[7:]:
        resumed.append(r)
    resumed.close()
    again = Journal(path, cols)                      # and read back once more, as a later resume would
    again.close()
    for r in rows:
        back = again.rows[r["run_id"]]
        assert back["error"] == r["error"] and back["failed"] == r["failed"]
        for c in ("vehicle.chassis.mass_kg", "simulated_s", "peak_roll"):
            assert repr(back[c]) == repr(r[c])      # bit for bit, NaN and the sign of zero included
    a = _tables(sorted_rows(straight.rows, ids), cols, tmp_path / "a")
    b = _tables(sorted_rows(again.rows, ids), cols, tmp_path / "b")
    assert a[0] == b[0] and a[1] == b[1]
    import csv
    import io
    table = list(csv.reader(io.StringIO(a[0].decode("utf-8"), newline="")))
    assert [r[cols.index("error")] for r in table[1:]] == [t.replace("\udcff", "\\udcff") for t in TEXTS]


def test_a_journal_of_another_plan_is_refused(tmp_path):
    from rtsim.errors import ConfigError

    j = Journal(tmp_path / "j.jsonl", ["run_id", "a"])
    j.close()
    with pytest.raises(ConfigError, match="columns differ"):
        Journal(tmp_path / "j.jsonl", ["run_id", "b"])


def test_eta_counts_completed_run_times_not_start_up():
    # two local workers, warmed before their first run: runs of 2 s each, 10 to go -> 5 rounds of 2 s
    done = [("h:1", 2.0), ("h:2", 2.0), ("h:1", 2.0)]
    assert eta_seconds(done, remaining=10, workers=2) == pytest.approx(10.0)
    # the case: 1 run done after a long start-up; the run took 3 s, 7 runs left on 1 worker
    assert eta_seconds([("h:1", 3.0)], remaining=7, workers=1) == pytest.approx(21.0)
    # Ray's workers compile in their first run (100 s): left out once a later run of that worker is back
    ray = [("a:1", 100.0), ("b:2", 101.0), ("a:1", 1.0), ("a:1", 3.0), ("b:2", 2.0)]
    assert eta_seconds(ray, remaining=4, workers=2, skip_first=True) == pytest.approx(2.0 * 2)
    assert eta_seconds(ray[:2], remaining=4, workers=2, skip_first=True) is None      # nothing counts yet
    # a run lost with its worker has no time; fewer runs left than workers: one round
    assert eta_seconds([("h:1", math.nan), ("h:2", 4.0)], remaining=1, workers=4) == pytest.approx(4.0)
    assert eta_seconds(done, remaining=0, workers=2) == 0.0


def _spec(rid, case, seed, random, over=None):
    return {"run_id": rid, "case": case, "seed": seed, "overrides": over or {"scenario.duration": 1.0},
            "random": random}


def test_runs_that_differ_only_by_a_seed_they_do_not_draw_are_simulated_once(tmp_path):
    specs = [_spec("a0", 0, 0, []), _spec("a1", 0, 1, []),                    # nothing random: one run
             _spec("b0", 0, 0, [], {"scenario.duration": 2.0}), _spec("b1", 0, 1, [], {"scenario.duration": 2.0}),
             _spec("c0", 1, 0, ["sensor noise on yaw_rate"]), _spec("c1", 1, 1, ["sensor noise on yaw_rate"]),
             _spec("d0", 2, 0, None), _spec("d1", 2, 1, None)]                # not known: the seed may matter
    rep = same_runs(specs)
    assert rep == {"a0": "a0", "a1": "a0", "b0": "b0", "b1": "b0", "c0": "c0", "c1": "c1", "d0": "d0", "d1": "d1"}
    plan = SimpleNamespace(name="p", repetitions=2)
    note = seed_note(plan, specs, rep)
    assert note.count("\n") == 0 and "seeds change nothing" in note and "6 of the 8 runs are simulated" in note
    every = [s for s in specs if s["random"] == []]
    assert "no run has anything random" in seed_note(plan, every, same_runs(every))
    assert seed_note(SimpleNamespace(name="p", repetitions=1), specs[:1], same_runs(specs[:1])) is None
    row = {"run_id": "a0", "seed": 0, "status": "ok", "peak_roll": 0.1, "wall_s": 3.0, "worker": "h:1", "copy_of": ""}
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "a0.csv").write_text("time\n0\n")
    copy = copy_row(row, specs[1], {"per_run": "csv", "out_dir": str(tmp_path)})
    assert math.isnan(copy.pop("outside_pct"))           # no wall time of its own: no share
    assert copy == {**row, "run_id": "a1", "seed": 1, "wall_s": 0.0, "step_s": 0.0, "outside_s": 0.0,
                    "between_s": 0.0, "worker": "", "copy_of": "a0"}
    assert (tmp_path / "runs" / "a1.csv").read_text() == "time\n0\n"


def test_the_shipped_sweep_has_no_random_element_and_a_noisy_car_has():
    """The shipped 200-run sweep: neither car has sensor noise, so its 100 seed pairs are one run each;
    with noise on a channel the car's runs draw from their seed."""
    from rtsim.batch.expand import expand
    from rtsim.batch.plan import load_plan
    from rtsim.vehicle.registry import open_vehicle

    specs = expand(*load_plan(ROOT / "configs" / "batch" / "step_steer_sweep.toml"))
    assert len(specs) == 200 and all(s["random"] == [] for s in specs)
    assert len(set(same_runs(specs).values())) == 100
    from rtsim.configfile import overrides
    xbw = (ROOT / "configs" / "vehicles" / "xbw.toml").resolve()
    with overrides({xbw: {"sensors.channels.gyro_z.noise_std": 0.01}}):
        noisy = open_vehicle(xbw)
    assert noisy.kind.random_elements(noisy, None) == ["sensor noise on gyro_z"]


@pytest.mark.parametrize("argv", [["batch", "configs/batch/smoke.toml", "--ray", "auto"]])
def test_a_missing_ray_is_one_line_saying_how_to_install_it(argv, tmp_path):
    """Ray is an optional extra: without it (its import made to fail), `rtsim batch --ray` exits with one
    line naming the extra, before anything runs."""
    code = ("import sys; sys.modules['ray'] = None\n"
            "from rtsim.cli import main\n"
            f"sys.exit(main({argv + ['--out', str(tmp_path / 'out')]!r}))\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines == ["rtsim: error: Ray is not installed; it is an optional extra of rtsim: pip install 'rtsim[ray]'"]
    assert not (tmp_path / "out").exists()
