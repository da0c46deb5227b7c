"""`rtsim serve --config`: the documented file loads to the embedded defaults, flags override it, and
bad values are rejected naming file, key, value and range."""
from __future__ import annotations

from pathlib import Path

import pytest

from rtsim.cli import build_parser
from rtsim.errors import ConfigError
from rtsim.service.cli import options
from rtsim.service.server import ServeOptions

ROOT = Path(__file__).resolve().parent.parent


def _opts(*argv):
    return options(build_parser().parse_args(["serve", *argv]))


def test_documented_config_is_the_embedded_default():
    a, b = _opts("--config", str(ROOT / "configs" / "service.toml")), ServeOptions()
    assert a.scenario is None and b.scenario is None
    for f in ("rider", "mode", "dt", "can_interface", "can_channel", "start_hub", "zenoh", "zenoh_listen",
              "zenoh_connect", "state_rate", "status_rate", "max_catch_up", "record"):
        assert getattr(a, f) == getattr(b, f), f
    assert a.hold_pressure == 3000.0


def test_flags_override_the_file(tmp_path):
    cfg = tmp_path / "svc.toml"
    cfg.write_text('[simulation]\nmode = "lockstep"\n[can]\ninterface = "virtual"\nchannel = "x"\n'
                   '[record]\npath = "out.mcap"\n')
    o = _opts("--config", str(cfg), "--can-channel", "y", "--no-zenoh")
    assert (o.mode, o.can_interface, o.can_channel, o.zenoh) == ("lockstep", "virtual", "y", False)
    assert o.record == tmp_path / "out.mcap"              # relative to the file


@pytest.mark.parametrize("text, key", [
    ("[zenoh]\nstatus_rate = 50\n", "zenoh.status_rate"),
    ("[simulation]\nmode = \"turbo\"\n", "simulation.mode"),
    ("[can]\nbitrate = 500000\n", "can.bitrate"),
    ("[simulation]\nhold_pressure = -1\n", "simulation.hold_pressure"),
])
def test_bad_values_name_file_key_and_range(tmp_path, text, key):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    with pytest.raises(ConfigError) as e:
        _opts("--config", str(cfg))
    assert str(cfg) in str(e.value) and key in str(e.value)


def test_every_setting_is_declared_once_and_documented():
    """The file's keys and the flags come from the one declaration (rtsim.service.config); the shipped
    file documents each key (set, or commented out with its default)."""
    import argparse

    from rtsim.service.config import ServeOptions, add_arguments
    text = (ROOT / "configs" / "service.toml").read_text()
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    dests = {a.dest for a in parser._actions}
    for name, f in ServeOptions.model_fields.items():
        key = (f.json_schema_extra or {}).get("key")
        if key:
            sec, k = key.split(".")
            assert f"[{sec}]" in text and (f"\n{k} = " in text or f"\n# {k} = " in text), key
        assert f"opt_{name}" in dests, name
