"""The control ops' argument rules (rtsim.service.control_args), without a service: every op refuses what it
does not declare, wrong types and non-finite numbers, with one line naming the op, the argument and the
reason; load_scenario reads only inside the scenario folders (no absolute path, no '..', no link out).
The same rules through Zenoh against a running service: tests/test_service_control.py."""
from __future__ import annotations

import math
import os

import pytest

from rtsim.service.control_args import (OP_ARGS, SHIPPED_SCENARIOS, ControlError, check_request, scenario_file,
                                        scenario_folders)
from bridge.zenoh_link import CONTROL_OPS


def _refused(op, args) -> str:
    with pytest.raises(ControlError) as e:
        check_request(op, args)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{op}: " if op in OP_ARGS else "unknown op"), msg
    return msg


def test_every_zenoh_op_has_a_declaration():
    assert set(CONTROL_OPS) == set(OP_ARGS)


@pytest.mark.parametrize("op,args,words", [
    ("step", {"steps": 5}, ["unknown argument 'steps'", "n"]),
    ("step", {"count": 7}, ["unknown argument 'count'"]),
    ("step", {"n": 5.0}, ["n = 5.0", "integer"]),
    ("step", {"n": "5"}, ["n = '5'"]),
    ("step", {"n": True}, ["n = True"]),
    ("step", {"n": 0}, ["n = 0", "out of range (allowed 1 <= n <= 1e+06)"]),
    ("pause", {"now": True}, ["unknown argument 'now'", "none"]),
    ("resume", {"x": 1}, ["unknown argument 'x'"]),
    ("reset", {"scenario": "hil_flat"}, ["unknown argument 'scenario'"]),
    ("load_scenario", {}, ["argument 'scenario' missing"]),
    ("load_scenario", {"scenario": 3}, ["scenario = 3"]),
    ("load_scenario", {"scenario": "hil_flat", "at": 2}, ["unknown argument 'at'"]),
    ("drive", {"throttle_angle_cmd": math.nan}, ["throttle_angle_cmd = nan is not a finite number"]),
    ("drive", {"brake_pressure_cmd": math.inf}, ["brake_pressure_cmd = inf is not a finite number"]),
    ("drive", {"steering_wheel_angle_cmd": -math.inf}, ["is not a finite number"]),
    ("drive", {"throttle": 0.5}, ["unknown argument 'throttle'", "throttle_angle_cmd"]),
    ("drive", {"throttle_angle_cmd": "0.5"}, ["throttle_angle_cmd = '0.5'"]),
    ("drive", {"takeover": 1}, ["takeover = 1"]),
    ("drive", {"seq": 1.5}, ["seq = 1.5"]),
    ("drive", {"_ws": 3}, ["unknown argument '_ws'"]),
    ("driver", {"steering_wheel_angle_cmd": math.nan}, ["not a finite number"]),
    ("driver", {"steering": 1.0}, ["unknown argument 'steering'"]),
])
def test_refusals_name_the_op_the_argument_and_the_reason(op, args, words):
    msg = _refused(op, args)
    for w in words:
        assert w in msg, msg


def test_more_than_one_error_is_still_one_line():
    msg = _refused("drive", {"throttle_angle_cmd": math.nan, "brake_pressure_cmd": "x"})
    assert "(and 1 more)" in msg


def test_unknown_ops_are_refused():
    for op in ("warp", "", None, 3, "_install"):
        assert "unknown op" in _refused(op, {})


def test_accepted_requests_keep_only_what_was_sent_and_explicit_nulls():
    assert check_request("step", {}) == {}
    assert check_request("step", {"n": 5}) == {"n": 5}
    assert check_request("pause", {}) == {}
    r = check_request("drive", {"throttle_angle_cmd": 0, "brake_pressure_cmd": None, "seq": 4, "takeover": False})
    assert r == {"throttle_angle_cmd": 0.0, "brake_pressure_cmd": None, "seq": 4, "takeover": False}
    assert check_request("driver", {"steering_wheel_angle_cmd": None}) == {"steering_wheel_angle_cmd": None}
    assert check_request("load_scenario", {"scenario": "hil_flat"}) == {"scenario": "hil_flat"}


def test_load_scenario_reads_only_inside_the_scenario_folders(tmp_path):
    mine = tmp_path / "mine"
    (mine / "sub").mkdir(parents=True)
    outside = tmp_path / "outside"
    outside.mkdir()
    text = (SHIPPED_SCENARIOS / "hil_flat.toml").read_text()
    (mine / "own.toml").write_text(text)
    (mine / "sub" / "deep.toml").write_text(text)
    (outside / "secret.toml").write_text(text)
    os.symlink(outside / "secret.toml", mine / "escape.toml")
    os.symlink(outside, mine / "linked_dir")
    folders = scenario_folders([mine])
    assert folders == [SHIPPED_SCENARIOS.resolve(), mine.resolve()]
    # inside: shipped names, the declared folder's names, a relative path below it
    assert scenario_file("hil_flat", folders) == (SHIPPED_SCENARIOS / "hil_flat.toml").resolve()
    assert scenario_file("own", folders) == (mine / "own.toml").resolve()
    assert scenario_file("sub/deep.toml", folders) == (mine / "sub" / "deep.toml").resolve()
    # outside: refused, each with its reason
    cases = {str(outside / "secret.toml"): "absolute path", "/etc/passwd": "absolute path",
             str(SHIPPED_SCENARIOS / "hil_flat.toml"): "absolute path", "~/x.toml": "absolute path",
             "../outside/secret.toml": "'..'", "sub/../../outside/secret": "'..'",
             "escape": "is a link to", "linked_dir/secret.toml": "is a link to",
             "no_such_scenario": "no scenario 'no_such_scenario'"}
    for name, reason in cases.items():
        with pytest.raises(ControlError) as e:
            scenario_file(name, folders)
        msg = str(e.value)
        assert reason in msg and msg.startswith("load_scenario: ") and "\n" not in msg, (name, msg)
    # without the folder declared, its scenarios are not reachable at all
    with pytest.raises(ControlError, match="no scenario 'own'"):
        scenario_file("own", scenario_folders())
