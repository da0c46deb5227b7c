"""Fault specs and the catalogue (rtsim.faults): every bad value is one line naming the file, the key, the
value and the allowed range; triggers parse; the catalogue lists every kind (rtsim faults --list)."""
from __future__ import annotations

import pytest

from rtsim.configfile import validate
from rtsim.errors import ConfigError
from rtsim.faults.catalog import KINDS, listing
from rtsim.faults.spec import FaultSpec, load_fault_file, parse_condition


def _spec(**kw):
    return validate(FaultSpec, kw, "x.toml", prefix="faults[0]")


def test_a_valid_spec_fills_its_defaults_and_round_trips():
    s = _spec(id="l", kind="loss", target="BRAKE_CMD", probability=0.25, at=1.5)
    assert s.params == {"probability": 0.25, "n": 0, "m": 1, "seed": 1}
    assert _spec(**s.table()) == s


@pytest.mark.parametrize("kw, key, text", [
    (dict(kind="loss", target="X", probability=1.5), "faults[0].probability = 1.5", "0 <= probability <= 1"),
    (dict(kind="gain", target="accel_x"), "faults[0].gain = None", "missing"),
    (dict(kind="offset", target="accel_x", offset=1.0, gian=2), "faults[0].gian = 2", "unknown key"),
    (dict(kind="stuk", target="accel_x"), "faults[0].kind = 'stuk'", "not a fault kind"),
    (dict(kind="loss", target="X", n=1.5), "faults[0].n = 1.5", "whole number"),
    (dict(kind="offset", target="accel_x", offset=1.0, at=1.0, when="speed > 3"), "faults[0].when", "one trigger"),
    (dict(kind="offset", target="accel_x", offset=1.0, when="speed >> 3"), "faults[0].when", "not a condition"),
    (dict(kind="offset", target="accel_x", offset=1.0, duration=-1.0), "faults[0].duration = -1.0", "out of range"),
    (dict(kind="offset", target="accel_x", offset=1.0, after_delay=1.0), "faults[0].after_delay", "only with after"),
])
def test_bad_values_name_file_key_value_and_rule(kw, key, text):
    with pytest.raises(ConfigError) as e:
        _spec(id="f", **kw)
    msg = str(e.value)
    assert msg.startswith("x.toml: ") and key in msg and text in msg and "\n" not in msg, msg


def test_conditions_parse_channel_operator_and_magnitude():
    c = parse_condition("abs(accel_y) > 4")
    assert (c.channel, c.op, c.value, c.magnitude) == ("accel_y", ">", 4.0, True)
    c = parse_condition(" speed<20.5 ")
    assert (c.channel, c.op, c.value, c.magnitude) == ("speed", "<", 20.5, False)
    for bad in ("abs(speed > 3", "speed = 3", "speed > nan", "> 3"):
        with pytest.raises(ValueError):
            parse_condition(bad)


def test_fault_file_ids_are_unique_and_other_sections_refused(tmp_path):
    f = tmp_path / "f.toml"
    f.write_text('[[faults]]\nid = "a"\nkind = "bus_off"\ntarget = "bus"\nat = 1.0\n'
                 '[[faults]]\nid = "a"\nkind = "dropout"\ntarget = "accel_x"\n')
    with pytest.raises(ConfigError, match=r"f.toml: faults\[1\].id = 'a': used by faults\[0\]"):
        load_fault_file(f)
    f.write_text('[simulation]\ndt = 0.001\n')
    with pytest.raises(ConfigError, match="unknown key"):
        load_fault_file(f)


def test_babble_payload_takes_all_64_bits():
    s = _spec(id="b", kind="babble", target=0x7FF, period=0.01, payload=0xFFFFFFFFFFFFFFFF)
    assert s.params["payload"] == 0xFFFFFFFFFFFFFFFF and isinstance(s.params["payload"], int)


def test_the_listing_names_every_kind_and_parameter():
    text = listing()
    for k in KINDS:
        assert f"  {k.name}: " in text
        for p in k.params:
            assert f"      {p.name}: " in text
    assert len({k.code for k in KINDS}) == len(KINDS)


def test_cli_lists_and_checks(tmp_path, capsys):
    from rtsim.cli import main
    assert main(["faults", "--list"]) == 0
    assert "bus_off" in capsys.readouterr().out
    f = tmp_path / "f.toml"
    f.write_text('[[faults]]\nid = "a"\nkind = "drift"\ntarget = "accel_x"\nrate = 1e12\n')
    assert main(["faults", str(f)]) == 2
    err = capsys.readouterr().err
    assert "faults[0].rate = 1e+12: out of range" in err or "faults[0].rate = 1000000000000.0" in err, err


def test_scenario_and_service_settings_take_faults_sections(tmp_path):
    from drivers.scenario import load_scenario
    from rtsim.service.config import load_service_config

    shipped = (__import__("pathlib").Path(__file__).resolve().parents[1] / "configs" / "scenarios" / "hil_flat.toml")
    text = shipped.read_text().replace('road = "../roads/flat.toml"', f'road = "{shipped.parent.parent}/roads/flat.toml"')
    sc = tmp_path / "sc.toml"
    sc.write_text(text + '\n[[faults]]\nid = "a"\nkind = "offset"\ntarget = "accel_x"\noffset = 1.0\nat = 0.5\n')
    assert [f.id for f in load_scenario(sc).spec.faults] == ["a"]
    sc.write_text(text + '\n[[faults]]\nid = "a"\nkind = "offset"\ntarget = "accel_x"\noffset = "x"\n')
    with pytest.raises(ConfigError, match=r"sc.toml: faults\[0\].offset = 'x': must be a number"):
        load_scenario(sc)
    svc = tmp_path / "service.toml"
    svc.write_text('[simulation]\nmode = "lockstep"\n[[faults]]\nid = "b"\nkind = "bus_off"\ntarget = "bus"\n'
                   'at = 1.0\nduration = 0.0\n')
    with pytest.raises(ConfigError, match=r"service.toml: faults\[0\].duration = 0.0: out of range"):
        load_service_config(svc)
    svc.write_text('[simulation]\nmode = "lockstep"\n[[faults]]\nid = "b"\nkind = "bus_off"\ntarget = "bus"\n')
    assert load_service_config(svc)["faults"] == [svc]


def test_an_offline_run_refuses_a_scenario_with_faults_in_one_line(tmp_path, capsys):
    """`rtsim run` injects no faults: a scenario that arms some is refused (exit 2, one line naming the
    scenario and its faults and the commands that inject them), never run silently without them."""
    from pathlib import Path

    from rtsim.cli import main
    shipped = Path(__file__).resolve().parents[1] / "configs" / "scenarios" / "step_steer_80kph.toml"
    text = shipped.read_text().replace('road = "../roads/flat.toml"',
                                       f'road = "{(shipped.parent / "../roads/flat.toml").resolve()}"')
    sc = tmp_path / "step_with_fault.toml"
    sc.write_text(text + '\n[[faults]]\nid = "gyro_stuck"\nkind = "stuck_value"\ntarget = "gyro_z"\n'
                  'value = 0.0\nat = 2.0\n')
    assert main(["run", "--scenario", str(sc), "--out", str(tmp_path / "out.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "gyro_stuck" in err[0] and "rtsim serve" in err[0] and "--no-faults" in err[0]
    assert not (tmp_path / "out.csv").exists()
