"""Every command that takes a vehicle runs on every shipped vehicle file (configs/vehicles/*.toml) or
refuses in one line saying why (rtsim.vehicle.registry). The commands run in this process through
``rtsim.cli.main`` (the compiled kernels load once), on short copies of the shipped scenarios.

`serve` is exercised through its compiled loop (``build_sim`` + ``HilLoop`` in fast mode, as the service
steps it, without the network); `demo`, `view`, `resim` and `validate` need processes, a browser or field
runs and are covered by their own tests (test_demo_supervision, test_viewer*, test_service_user_resim,
test_resim_recorded_before, test_validate_*)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from rtsim.cli import main
from rtsim.vehicle.registry import DESCRIBE_FIELDS, DESCRIBE_GEOMETRY, open_vehicle

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = sorted((ROOT / "configs" / "vehicles").glob("*.toml"))
NAMES = [p.stem for p in VEHICLES]
T_END = 0.3          # s simulated per run: enough for a few output rows, cheap


def _short(name: str, tmp: Path) -> Path:
    """A copy of the shipped scenario `name` lasting T_END, its relative paths made absolute."""
    text = (ROOT / "configs" / "scenarios" / f"{name}.toml").read_text()
    text = re.sub(r"(?m)^duration = .*$", f"duration = {T_END}", text)
    text = text.replace('"../', f'"{ROOT / "configs"}/')
    out = tmp / f"{name}.toml"
    out.write_text(text)
    return out


#: a scenario of each kind, and one of the other kind (which the vehicle must refuse in one line)
OWN = {"car": "step_steer_80kph", "two_wheeler": "motorcycle_steady_turn"}


def _cli(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _one_line_refusal(code: int, err: str, *words: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("rtsim: error: "), (code, err)
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("name", NAMES)
def test_describe_reports_the_same_fields_for_every_vehicle(name, capsys):
    code, out, err = _cli(capsys, "describe", "--vehicle", name, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert tuple(info)[:len(DESCRIBE_FIELDS)] == DESCRIBE_FIELDS
    assert isinstance(info["n_dof"], int) and info["n_dof"] >= 1
    assert info["n_dof"] == info["n_coordinates"] - info["n_constraints"]
    # the total mass is the sum of the bodies' (the car: chassis plus its four unsprung corners)
    assert info["mass"] == pytest.approx(sum(info["masses"].values()), rel=1e-12)
    geo = info["geometry"]
    assert set(DESCRIBE_GEOMETRY) <= set(geo)
    assert geo["wheelbase"] > 0 and 0 < geo["cg_to_front_axle"] < geo["wheelbase"] and geo["cg_height"] > 0
    ch = info["channels"]
    assert set(ch) == {"sensors", "commands", "state"} and ch["sensors"] and ch["state"]


def test_describe_fields_are_equal_across_vehicles(capsys):
    keys = []
    for name in NAMES:
        code, out, err = _cli(capsys, "describe", "--vehicle", name, "--json")
        assert code == 0, err
        info = json.loads(out)
        keys.append((tuple(info)[:len(DESCRIBE_FIELDS)], tuple(info["geometry"])[:len(DESCRIBE_GEOMETRY)],
                     tuple(info["channels"])))
    assert len(set(keys)) == 1, keys


@pytest.mark.parametrize("name", NAMES)
def test_run_energy_feel_eigen_statics_on_every_vehicle(name, tmp_path, capsys):
    vehicle = open_vehicle(name)
    kind = vehicle.kind.name
    own = _short(OWN[kind], tmp_path)
    other = _short(OWN["two_wheeler" if kind == "car" else "car"], tmp_path)
    out = tmp_path / f"{name}.csv"

    code, stdout, err = _cli(capsys, "run", "--vehicle", name, "--scenario", own, "--out", out)
    assert code == 0, err
    assert f"-> {out}; status ok" in stdout
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data["time"][-1] == pytest.approx(T_END, abs=1e-9) and np.isfinite(data["speed"]).all()

    code, _, err = _cli(capsys, "run", "--vehicle", name, "--scenario", other, "--out", tmp_path / "x.csv")
    _one_line_refusal(code, err, f"cannot drive {name}.toml")

    # energy: the power audit where the run carries it (the cars'), else one line saying it has none
    code, stdout, err = _cli(capsys, "energy", out)
    if "work_tyres" in data.dtype.names:
        assert code == 0 and "balance" in stdout, err
    else:
        _one_line_refusal(code, err, "no power audit")

    # feel: a car with electric power steering; any other vehicle's run refused in one line
    code, stdout, err = _cli(capsys, "feel", out, "--json")
    if getattr(vehicle.config, "eps", None) is not None:
        assert code == 0, err
        assert json.loads(stdout)
    else:
        _one_line_refusal(code, err, "electric power steering")

    # eigen and statics: the two-wheelers; the cars refused in one line
    for cmd, extra in (("statics", ()), ("eigen", ("--speeds", "5"))):
        code, stdout, err = _cli(capsys, cmd, "--vehicle", name, *extra)
        if "statics" in vehicle.kind.not_for or cmd in vehicle.kind.not_for:
            _one_line_refusal(code, err, f"rtsim {cmd} does not apply to {name}.toml")
        else:
            assert code == 0, err
            assert json.loads(stdout[:stdout.rindex("}") + 1])


@pytest.mark.parametrize("name", NAMES)
def test_the_service_loop_steps_every_vehicle(name):
    """`serve`'s compiled loop on every vehicle at its default scenario: 200 steps, finite sensors."""
    from bridge.can_codec import Codec
    from rtsim.service.loop import HilLoop
    from rtsim.service.resim import Collector
    from rtsim.service.server import build_sim

    sim, sc = build_sim(None, ROOT / "configs" / "vehicles" / f"{name}.toml")
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="fast")
    col = Collector(loop)
    loop.advance(200)
    assert col.sensors and np.isfinite(col.sensors[-1][1]).all()
    assert col.sensors[-1][0] == pytest.approx(0.2, abs=2e-3)      # simulated time, s


def test_batch_runs_every_vehicle(tmp_path):
    """One batch plan, one case per shipped vehicle (by name) on its kind's short scenario: every row ok."""
    import csv
    import subprocess
    import sys

    cases = []
    for name in NAMES:
        scen = _short(OWN[open_vehicle(name).kind.name], tmp_path)
        cases.append(f'[[cases]]\nscenario = "{scen}"\nvehicle = "{name}"\n')
    plan = tmp_path / "every.toml"
    plan.write_text('name = "every"\ndescription = "every vehicle"\nmetrics = ["distance"]\n\n' + "\n".join(cases))
    p = subprocess.run([sys.executable, "-m", "rtsim.cli", "batch", str(plan), "--out", str(tmp_path / "out"),
                        "--workers", "1", "--no-report"], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    table = next((tmp_path / "out").glob("*.csv"))
    rows = list(csv.DictReader(table.open()))
    assert len(rows) == len(NAMES) and all(r["status"] == "ok" for r in rows), rows
    assert all(float(r["distance"]) > 0 for r in rows)


def test_version_and_help_name_their_values(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and re.fullmatch(r"rtsim \d+\.\d+\.\d+\n", capsys.readouterr().out)
    with pytest.raises(SystemExit):
        main(["serve", "--help"])
    text = capsys.readouterr().out
    assert "--scenario FILE|NAME" in text and "OPT_" not in text


def test_run_takes_a_scenario_name(tmp_path, capsys, monkeypatch):
    """A scenario's name (configs/scenarios/<name>.toml) is accepted where its file is."""
    from rtsim.vehicle import registry

    short = _short("step_steer_80kph", tmp_path)
    monkeypatch.setattr(registry, "SCENARIOS", tmp_path)        # the short copy stands in for the shipped one
    code, stdout, err = _cli(capsys, "run", "--scenario", "step_steer_80kph", "--out", tmp_path / "s.csv")
    assert code == 0, err
    assert short.exists() and "step_steer_80kph" in stdout


def test_an_unknown_kind_is_refused_in_one_line(tmp_path, capsys):
    bad = tmp_path / "tricycle.toml"
    bad.write_text('name = "x"\nid = "x"\nkind = "tricycle"\n')
    code, _, err = _cli(capsys, "describe", "--vehicle", bad)
    _one_line_refusal(code, err, "kind = 'tricycle'", "unknown vehicle kind")


@pytest.mark.parametrize("name", NAMES)
def test_every_vehicle_declares_its_user_inputs(name):
    """What `rtsim view` may drive (the vehicle's UserInputs): each channel's value at a full control
    within its range, each channel in exactly one of the page's groups, and the command it competes with
    one of the vehicle's own bus commands (its channel dictionary) or, where its DBC does not carry it
    (the EPS car's throttle, brake and steering), an input of the scenario's in-loop driver."""
    from drivers.base import INPUT_NAMES

    vehicle = open_vehicle(name)
    inputs = vehicle.user_inputs
    commands = set(vehicle.describe()["channels"]["commands"])
    assert len(set(inputs.names)) == len(inputs.names) >= 3
    grouped = [n for g in inputs.groups for n in g.channels]
    assert sorted(grouped) == sorted(inputs.names)
    for ch in inputs.channels:
        assert ch.lo <= ch.sign * ch.full_scale <= ch.hi and ch.lo < ch.hi and ch.full_scale > 0, ch
        assert ch.bus in commands or (inputs.in_loop == "scenario" and ch.bus in INPUT_NAMES), (ch, sorted(commands))
    # the bus takes over a channel it replaces unless the user took over; one it adds to stays the user's
    ch = inputs.channels[0]
    assert inputs.who(ch, user_set=True, takeover=False, valid=True, in_loop=True) == "ecu"
    assert inputs.who(ch, user_set=True, takeover=True, valid=True, in_loop=True) == "user"
    assert inputs.who(ch, user_set=False, takeover=False, valid=False, in_loop=False) == inputs.idle


def test_a_user_input_declaration_is_checked():
    """A vehicle's user-input declaration is refused when a channel's full value lies outside its range,
    when a channel sits in no group or in two, or when a group's release rule is unknown."""
    from rtsim.vehicle.kit.user_inputs import ControlGroup, UserChannel, UserInputs

    ok = UserChannel("u", 0.0, 1.0, "1", "a throttle", 0.5, bus="u", control="throttle")
    with pytest.raises(ValueError, match="within 0 .. 1"):
        UserChannel("u", 0.0, 1.0, "1", "a throttle", 0.5, bus="u", control="throttle", sign=-1.0)
    with pytest.raises(ValueError, match="control 'pedal'"):
        UserChannel("u", 0.0, 1.0, "1", "a throttle", 0.5, bus="u", control="pedal")
    with pytest.raises(ValueError, match="release 'keep'"):
        ControlGroup("g", "keep", ("u",))
    with pytest.raises(ValueError, match="exactly one group"):
        UserInputs((ok,), (), writes="command", in_loop="scenario", idle="safe")
    with pytest.raises(ValueError, match="exactly one group"):
        UserInputs((ok,), (ControlGroup("a", "hold", ("u",)), ControlGroup("b", "hold", ("u",))),
                   writes="command", in_loop="scenario", idle="safe")
    assert UserInputs((ok,), (ControlGroup("a", "hold", ("u",)),), writes="command", in_loop="scenario",
                      idle="safe").full_scales() == {"u": 0.5}


def test_a_vehicle_file_may_name_its_own_assembly(tmp_path, capsys, monkeypatch):
    """``assembly = "package.module"``: the registry takes that module's KIND, unchanged itself; a module
    that cannot be imported, or defines no KIND, is refused in one line."""
    (tmp_path / "sled_assembly.py").write_text('''
from rtsim.vehicle.registry import VehicleKind


class SledKind(VehicleKind):
    """A one-body sled: enough of a kind for `describe`."""
    name = "sled"
    not_for = {"run": "a sled has no scenario runner"}

    def load(self, data, path):
        return data, path.parent

    def build(self, opened):
        return opened.config["mass_kg"]

    def describe(self, opened):
        m = opened.model
        return {"name": opened.config["name"], "id": "sled", "kind": self.name, "file": str(opened.path),
                "n_coordinates": 7, "n_constraints": 1, "n_dof": 6, "mass": m, "masses": {"body": m},
                "geometry": {"wheelbase": 1.0, "track_front": 0.5, "track_rear": 0.5, "cg_height": 0.2,
                             "cg_to_front_axle": 0.5, "wheel_centres": []},
                "channels": {"sensors": ["speed"], "commands": [], "state": ["speed"]}}


KIND = SledKind()
''')
    monkeypatch.syspath_prepend(str(tmp_path))
    sled = tmp_path / "sled.toml"
    sled.write_text('name = "Sled"\nassembly = "sled_assembly"\nmass_kg = 42.0\n')
    code, out, err = _cli(capsys, "describe", "--vehicle", sled, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert tuple(info)[:len(DESCRIBE_FIELDS)] == DESCRIBE_FIELDS and info["kind"] == "sled" and info["mass"] == 42.0
    code, _, err = _cli(capsys, "run", "--vehicle", sled, "--scenario", _short("step_steer_80kph", tmp_path),
                        "--out", tmp_path / "x.csv")
    _one_line_refusal(code, err, "rtsim run does not apply to sled.toml", "no scenario runner")
    sled.write_text('name = "Sled"\nassembly = "no_such_assembly"\n')
    code, _, err = _cli(capsys, "describe", "--vehicle", sled)
    _one_line_refusal(code, err, "assembly = 'no_such_assembly'", "cannot import")
    (tmp_path / "kindless_assembly.py").write_text("X = 1\n")
    sled.write_text('name = "Sled"\nassembly = "kindless_assembly"\n')
    code, _, err = _cli(capsys, "describe", "--vehicle", sled)
    _one_line_refusal(code, err, "defines no KIND")


@pytest.mark.parametrize("name", NAMES)
def test_every_vehicle_demo_has_its_ecus_closing_report(name):
    """`rtsim demo` closes with the report of the ECU the vehicle's demo runs (rtsim.service.demo.REPORTS,
    keyed by the ECU, not by the kind of vehicle)."""
    from rtsim.service.demo import REPORTS

    assert open_vehicle(ROOT / "configs" / "vehicles" / f"{name}.toml").demo.ecu in REPORTS
