"""The batch plan's checks (one line naming the file, key, value and what is allowed), its expansion
(grid x seeded random sample x repetitions; ids stable and distinct) and the metrics against analytic
references on synthetic runs."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rtsim.batch.expand import expand
from rtsim.configfile import set_dotted as set_path
from rtsim.batch.metrics import compute
from rtsim.batch.plan import load_plan
from rtsim.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SCEN = (ROOT / "configs" / "scenarios" / "step_steer_80kph.toml").as_posix()


def _plan(tmp_path, body: str) -> Path:
    """A plan with one case; `body`'s top-level keys (before its first table) go before the case."""
    top, sep, tables = body.partition("[")
    p = tmp_path / "plan.toml"
    p.write_text(f'name = "t"\nmetrics = ["peak_roll"]\n{top}[[cases]]\nscenario = "{SCEN}"\n' + sep + tables)
    return p


@pytest.mark.parametrize("body, expected", [
    ('[grid]\n"chassis.mass_kg" = [1.0]\n', "grid = 'chassis.mass_kg': keys must be dotted paths starting with vehicle. or scenario."),
    ('[[criteria]]\nmetric = "speediness"\nmax = 1.0\n', "criteria[0].metric = 'speediness': unknown metric"),
    ('repetitions = 0\n', "repetitions = 0: out of range (allowed 1 <= repetitions <= 10000)"),
    ('[random]\nsamples = 3\n[random.params]\n"vehicle.a" = { uniform = [2.0, 1.0] }\n',
     'random.params."vehicle.a".uniform = [2.0, 1.0]: must be [lo, hi], finite, lo <= hi'),
])
def test_plan_errors_name_file_key_value_and_range(tmp_path, body, expected):
    p = _plan(tmp_path, body)
    with pytest.raises(ConfigError) as exc:
        load_plan(p)
    assert str(exc.value).startswith(f"{p}: ") and expected in str(exc.value)


def test_missing_case_file_is_named(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text('name = "t"\nmetrics = ["peak_roll"]\n[[cases]]\nscenario = "nope.toml"\n')
    with pytest.raises(ConfigError, match=r"cases\[0\]\.scenario = 'nope.toml': file not found"):
        load_plan(p)


def test_expansion_grid_times_sample_times_repetitions(tmp_path):
    p = _plan(tmp_path, 'repetitions = 2\nseed = 5\n[grid]\n"vehicle.chassis.mass_kg" = [700.0, 800.0, 900.0]\n'
              '[random]\nsamples = 4\n[random.params]\n"vehicle.tyres.scale" = { uniform = [0.9, 1.1] }\n')
    plan, base = load_plan(p)
    specs = expand(plan, base)
    assert len(specs) == 3 * 4 * 2 and len({s["run_id"] for s in specs}) == len(specs)
    assert [s["seed"] for s in specs[:2]] == [0, 1]
    scales = [s["params"]["vehicle.tyres.scale"] for s in specs]
    assert all(0.9 <= x <= 1.1 for x in scales) and len(set(scales)) == 4
    again = expand(*load_plan(p))
    assert [s["run_id"] for s in again] == [s["run_id"] for s in specs]        # same plan, same ids and points


def test_set_path_creates_tables_and_refuses_to_descend_into_a_value():
    d = {"a": {"b": 1}}
    set_path(d, "a.c.d", 2.0)
    assert d == {"a": {"b": 1, "c": {"d": 2.0}}}
    with pytest.raises(KeyError, match="a.b = 1 is not a table"):
        set_path(d, "a.b.x", 0)


def test_metrics_against_analytic_runs():
    # a straight stop at constant deceleration a from v0, brakes on at t = 1 s: distance v0^2 / (2 a)
    # (the row spacing shortens the stop by less than v0 dt); a steady circle: a_y = u r, no overshoot
    v0, a, dt = 20.0, 8.0, 1e-3
    t = np.arange(0.0, 5.0, dt)
    v = np.where(t < 1.0, v0, np.maximum(v0 - a * (t - 1.0), 0.0))
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    p = np.where(t < 1.0, 0.0, 4000.0)
    r = np.full_like(t, 0.2)
    cols = ("time", "speed", "pos_x", "pos_y", "brake_pressure", "yaw_rate")
    m = compute(["stopping_distance", "peak_lateral_acceleration", "yaw_rate_overshoot", "path_error_rms"], cols,
                np.column_stack([t, v, x, np.zeros_like(t), p, r]))
    stop = v0 ** 2 / (2 * a)
    assert stop - v0 * 1e-2 < m["stopping_distance"] <= stop + 1e-9
    assert m["peak_lateral_acceleration"] == pytest.approx(v0 * 0.2)
    assert m["yaw_rate_overshoot"] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(m["path_error_rms"])          # the run has no path_offset channel


# ---- run ids hash every file a run reads ----------------------------------------------------------
def _configs(tmp_path) -> Path:
    """A copy of the shipped configs (vehicles, tyres, roads, scenarios, can) to edit."""
    import shutil

    dst = tmp_path / "configs"
    for sub in ("vehicles", "tyres", "roads", "scenarios", "can"):
        shutil.copytree(ROOT / "configs" / sub, dst / sub)
    (dst / "batch").mkdir()
    return dst


def _ids(plan: Path) -> list[str]:
    return [s["run_id"] for s in expand(*load_plan(plan))]


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="latin-1")
    assert text.count(old) >= 1, (path, old)
    path.write_text(text.replace(old, new, 1), encoding="latin-1")


def test_editing_a_nested_file_gives_new_run_ids_and_an_unrelated_file_does_not(tmp_path):
    """A case with its own vehicle file, and one whose vehicle is the one its scenario names; a mesh road
    (its survey CSV read through the road file). Every nested file is in the ids; other files are not."""
    cfg = _configs(tmp_path)
    plan = cfg / "batch" / "p.toml"
    plan.write_text('name = "t"\nmetrics = ["peak_roll"]\nrepetitions = 2\n'
                    '[[cases]]\nscenario = "../scenarios/step_steer_80kph.toml"\nvehicle = "../vehicles/xbw.toml"\n'
                    '[[cases]]\nscenario = "../scenarios/on_centre_weave_100kph.toml"\n'
                    '[[cases]]\nscenario = "../scenarios/straight_line.toml"\nvehicle = "../vehicles/xbw.toml"\n'
                    '[grid]\n"scenario.duration" = [0.5, 1.0]\n')
    base = _ids(plan)
    assert len(base) == 12 and len(set(base)) == 12
    specs = expand(*load_plan(plan))
    read = {Path(f).relative_to(cfg).as_posix() for s in specs for f in s["inputs"]}
    assert {"tyres/michelin_155_80_r13.tir", "tyres/midsize_205_60_r15.tir", "vehicles/eps_car.toml",
            "roads/flat.toml", "roads/campus.toml", "roads/campus_survey.csv"} <= read

    # unrelated files: another vehicle, a DBC no batch run reads, another scenario, the plan folder
    _edit(cfg / "vehicles" / "motorcycle.toml", "[sensors]", "# edited\n[sensors]")
    _edit(cfg / "can" / "xbw.dbc", "VERSION", 'CM_ "edited";\nVERSION')
    _edit(cfg / "scenarios" / "steady_circle.toml", "road", "# edited\nroad")
    (cfg / "batch" / "notes.txt").write_text("unrelated")
    assert _ids(plan) == base

    def changed(before: list[str], after: list[str]) -> list[int]:
        return [i for i, (a, b) in enumerate(zip(before, after)) if a != b]

    # the xbw's tyre file (read through the vehicle file): the cases on the xbw change, the EPS car's do not
    _edit(cfg / "tyres" / "michelin_155_80_r13.tir", "= 2800 ", "= 2900 ")
    after_tyre = _ids(plan)
    assert changed(base, after_tyre) == [0, 1, 2, 3, 8, 9, 10, 11]
    # the vehicle file the second case's scenario names, and the tyre file that vehicle names
    _edit(cfg / "vehicles" / "eps_car.toml", "[sensors]", "# edited\n[sensors]")
    after_veh = _ids(plan)
    assert changed(after_tyre, after_veh) == [4, 5, 6, 7]
    _edit(cfg / "tyres" / "midsize_205_60_r15.tir", "= 4000 ", "= 4100 ")
    after_tyre2 = _ids(plan)
    assert changed(after_veh, after_tyre2) == [4, 5, 6, 7]
    # the survey CSV of the mesh road the third case's scenario names
    _edit(cfg / "roads" / "campus_survey.csv", "\n", "\n# edited\n")
    assert changed(after_tyre2, _ids(plan)) == [8, 9, 10, 11]
    # the same bytes again: the same ids (content, not modification time)
    _edit(cfg / "roads" / "campus_survey.csv", "\n# edited\n", "\n")
    assert _ids(plan) == after_tyre2


def test_a_run_reads_no_file_outside_its_id(tmp_path):
    """What the loaders record while a real (short) run runs, model build included, is within the files
    its id hashes: the resolved set is the one the run uses, for a car and a two-wheeler."""
    from rtsim.batch.run import run_one
    from rtsim.configfile import recording_reads

    plan = ROOT / "configs" / "batch" / "smoke.toml"
    specs = expand(*load_plan(plan))
    job = {"metrics": ["peak_roll"], "param_keys": [], "per_run": "none", "criteria": []}
    for case in (0, 2):
        spec = next(s for s in specs if s["case"] == case and s["params"]["scenario.duration"] == 0.5)
        spec = {**spec, "overrides": {**spec["overrides"], "scenario.duration": 0.05}}
        with recording_reads() as seen:
            row = run_one(spec, job)
        assert row["status"] == "ok", row["error"]
        assert seen and {str(p) for p in seen} <= set(spec["inputs"]), sorted(seen)
