"""ECU test catalogues without a bus: the catalogue's validation (one-line errors naming file, key, value and
what is allowed) and the judging of each expectation kind on signals built by hand, where the right verdict,
time and value are known exactly."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.ecutest.catalog import load_catalogue
from rtsim.ecutest.expect import judge
from rtsim.ecutest.signals import Signals
from rtsim.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
HEAD = """name = "c"
duration = 2.0
[ecu]
command = ["{python}", "-m", "drivers.ecu_demo"]
[[cases]]
name = "a"
"""


def _load(tmp_path, text):
    p = tmp_path / "cat.toml"
    p.write_text(text)
    return load_catalogue(p)


def test_shipped_catalogues_load():
    for name in ("demo_ecu", "demo_eps"):
        cat = load_catalogue(ROOT / "configs" / "tests" / f"{name}.toml")
        assert cat.spec.mode == "lockstep" and len(cat.spec.cases) >= 2


@pytest.mark.parametrize("body, key, words", [
    ('[[cases.expect]]\nkind = "reaction"\nsignal = "state.speed"\ncondition = "> 1"\nwithin = -0.1\n',
     "cases[0].expect[0].within", ["-0.1", "out of range", "3600"]),
    ('[[cases.expect]]\nkind = "bounds"\nsignal = "state.speed"\n', "cases[0].expect[0].max", ["min, max"]),
    ('[[cases.expect]]\nkind = "reached"\nsignal = "state.speed"\ncondition = "above 3"\n',
     "cases[0].expect[0].condition", ["'above 3'", "OP VALUE"]),
    ('[[cases.expect]]\nkind = "reached"\nsignal = "state.speed"\ncondition = "> 3"\nafter = "fault:nope"\n',
     "cases[0].expect[0].after", ["names no fault"]),
    ('[[cases.expect]]\nkind = "wobbly"\nsignal = "state.speed"\n', "cases[0].expect[0]", ["wobbly"]),
    ('[[cases.faults]]\nid = "f"\nkind = "loss"\ntarget = "BRAKE_CMD"\nprobability = 2.0\n'
     '[[cases.expect]]\nkind = "reached"\nsignal = "state.speed"\ncondition = "> 3"\n',
     "cases[0].faults[0].probability", ["2.0", "out of range"]),
])
def test_bad_catalogue_is_one_line_naming_file_key_value(tmp_path, body, key, words):
    with pytest.raises(ConfigError) as exc:
        _load(tmp_path, HEAD + body)
    text = str(exc.value)
    assert "\n" not in text and text.startswith(str(tmp_path / "cat.toml")) and key in text, text
    for w in words:
        assert w in text, text


def _signals():
    """A ramp 0..2 s (1 m/s^2) sampled every 2 ms; a fault from 0.5 s to 1.5 s; a command that steps from 0
    to 3000 at 0.522 s (22 ms after the onset)."""
    t = np.round(np.arange(0, 1001) * 0.002, 9)
    sig = Signals()
    sig.series["state.speed"] = (t, t.copy())
    sig.series["commands.brake"] = (t, np.where(t >= 0.522 - 1e-9, 3000.0, 0.0))
    sig.fault_events = [(0.5, "f", "onset"), (1.5, "f", "end")]
    sig.series["fault.f"] = (np.array([0.0, 0.5, 1.5]), np.array([0.0, 1.0, 0.0]))
    sig.end = 2.0
    return sig


def _expect(tmp_path, table: str):
    cat = _load(tmp_path, HEAD + '[[cases.faults]]\nid = "f"\nkind = "loss"\ntarget = "BRAKE_CMD"\nn = 1\nm = 1\n'
                'at = 0.5\n[[cases.expect]]\n' + table)
    return cat.spec.cases[0].expect[0]


def test_reaction_time_and_its_failure_message(tmp_path):
    sig = _signals()
    e = _expect(tmp_path, 'kind = "reaction"\nsignal = "commands.brake"\nafter = "fault:f"\ncondition = ">= 3000"\n'
                'within = 0.031\n')
    o = judge(e, sig, sig.end)
    assert o.passed and o.event_time == 0.5 and o.time == pytest.approx(0.522)
    e = _expect(tmp_path, 'name = "fast brake"\nkind = "reaction"\nsignal = "commands.brake"\nafter = "fault:f"\n'
                'condition = ">= 3000"\nwithin = 0.02\n')
    o = judge(e, sig, sig.end)
    assert not o.passed and o.message.startswith("fast brake: ") and "never >= 3000" in o.message
    assert "t = 0.52 s" in o.message and o.value == 0.0          # the last sample of the window, 0 there


def test_bounds_names_first_violation_time_and_value(tmp_path):
    sig = _signals()
    e = _expect(tmp_path, 'kind = "bounds"\nsignal = "state.speed"\nmax = 1.2\nafter = "fault:f"\n')
    o = judge(e, sig, sig.end)
    assert not o.passed and o.time == pytest.approx(1.202) and o.value == pytest.approx(1.202)
    assert "state.speed = 1.202 at t = 1.202 s" in o.message and "worst 2 at t = 2 s" in o.message
    e = _expect(tmp_path, 'kind = "bounds"\nsignal = "state.speed"\nmin = 0.5\nmax = 1.2\nafter = "fault:f"\n'
                'end = 0.7\n')
    assert judge(e, sig, sig.end).passed


def test_monotonic_and_reached_and_condition_events(tmp_path):
    sig = _signals()
    e = _expect(tmp_path, 'kind = "monotonic"\nsignal = "state.speed"\ndirection = "increasing"\n')
    assert judge(e, sig, sig.end).passed
    e = _expect(tmp_path, 'kind = "monotonic"\nsignal = "state.speed"\ndirection = "decreasing"\n')
    o = judge(e, sig, sig.end)
    assert not o.passed and o.time == pytest.approx(0.002)
    e = _expect(tmp_path, 'kind = "reached"\nsignal = "fault.f"\ncondition = "== 0"\nafter = "fault_end:f"\n')
    o = judge(e, sig, sig.end)
    assert o.passed and o.time == 1.5
    e = _expect(tmp_path, 'kind = "reached"\nsignal = "commands.brake"\ncondition = "> 0"\n'
                'after = "state.speed > 0.4"\nend = 0.05\n')
    o = judge(e, sig, sig.end)
    assert not o.passed and o.event_time == pytest.approx(0.402)
    e = _expect(tmp_path, 'kind = "reached"\nsignal = "state.speed"\ncondition = "> 1"\nafter = "state.speed > 5"\n')
    o = judge(e, sig, sig.end)
    assert not o.passed and "never happened" in o.message


def test_cli_refuses_a_bad_catalogue_in_one_line(tmp_path, capsys):
    from rtsim.cli import main

    p = tmp_path / "bad.toml"
    p.write_text(HEAD + '[[cases.expect]]\nkind = "monotonic"\nsignal = "state.speed"\ndirection = "up"\n')
    assert main(["test", str(p), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cases[0].expect[0].direction" in err and "'up'" in err, err
    assert not (tmp_path / "out").exists()
