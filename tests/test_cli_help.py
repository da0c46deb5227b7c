"""`rtsim --help` and every subcommand's help: each value a flag takes is named by what it is (FILE, DIR,
NAME, PORT, S, N, ...), never by a placeholder argparse derives from an internal destination name
(``--scenario OPT_SCENARIO``, ``--can-hub-port CAN_HUB_PORT``). Parses help strings only: no simulation."""
from __future__ import annotations

import argparse
import re

import pytest

from rtsim.cli import build_parser

#: placeholders that name the kind of value even when they equal the upper-cased option name
KIND_WORDS = {"PORT", "ENDPOINT", "ADDRESS", "HOST", "FILE", "DIR", "NAME", "ID", "CPU", "N", "S", "LIST"}
#: a placeholder made from an internal destination (the service's settings are stored as opt_<name>)
INTERNAL = re.compile(r"\bOPT_[A-Z_]+\b")


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("rtsim has no subcommands")


PARSER = build_parser()
COMMANDS = _subparsers(PARSER)


def _takes_value(action: argparse.Action) -> bool:
    return action.nargs != 0 and not isinstance(action, (argparse._HelpAction, argparse._VersionAction))


def test_every_command_is_listed():
    assert {"serve", "demo", "run", "describe", "resim", "validate", "view", "batch", "bench"} <= set(COMMANDS)


def test_top_level_help_has_no_internal_placeholder():
    text = PARSER.format_help()
    assert not INTERNAL.findall(text), INTERNAL.findall(text)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_has_no_internal_placeholder(name):
    text = COMMANDS[name].format_help()
    assert not INTERNAL.findall(text), f"rtsim {name} --help: {INTERNAL.findall(text)}"


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_value_is_named_by_its_kind(name):
    """Each option taking a value has choices or an explicit metavar, and that metavar is not just the
    option's (or its destination's) name upper-cased, unless that name is itself a kind (--port PORT)."""
    bad = []
    for action in COMMANDS[name]._actions:
        if not action.option_strings or not _takes_value(action):
            continue
        flag = max(action.option_strings, key=len)
        if action.choices is not None and action.metavar is None:
            continue
        if action.metavar is None:
            bad.append(f"{flag}: no metavar (argparse would show {action.dest.upper()})")
            continue
        derived = {action.dest.upper(), flag.lstrip("-").upper().replace("-", "_")}
        if action.metavar in derived and action.metavar not in KIND_WORDS:
            bad.append(f"{flag} {action.metavar}: the name, not the kind of value")
    assert not bad, f"rtsim {name}: " + "; ".join(bad)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_positionals_are_named_by_their_kind(name):
    bad = [a.dest for a in COMMANDS[name]._actions
           if not a.option_strings and _takes_value(a) and a.metavar is None and a.dest != "command"]
    assert not bad, f"rtsim {name}: positional arguments shown by their internal name: {bad}"


def test_the_rule_catches_a_derived_placeholder():
    """The checks above fail on the placeholders they are meant to catch."""
    p = argparse.ArgumentParser(prog="x")
    p.add_argument("--scenario", dest="opt_scenario")
    p.add_argument("--can-hub-port", type=int)
    assert INTERNAL.findall(p.format_help())
    flagged = [a for a in p._actions if a.option_strings and _takes_value(a) and a.metavar is None]
    assert len(flagged) == 2


#: the developer entry points docs/commands.md lists, each with its own parser
MODULES = ("drivers.ecu_demo", "drivers.eps_demo", "drivers.rider_assist_demo", "rtsim.validate.bench",
           "bridge.payloads", "bridge.foxglove_client")


def derived_placeholders(usage: str) -> list[str]:
    """`--flag VALUE` pairs of a usage text whose VALUE is just the flag's name upper-cased."""
    return [f"--{flag} {value}" for flag, value in re.findall(r"--([a-z][a-z0-9-]*) ([A-Z][A-Z0-9_]*)\b", usage)
            if value == flag.upper().replace("-", "_") and value not in KIND_WORDS]


def test_the_usage_rule_catches_a_derived_placeholder():
    assert derived_placeholders("[--can-channel CAN_CHANNEL] [--port PORT] [--dt S]") == ["--can-channel CAN_CHANNEL"]


@pytest.mark.parametrize("module", MODULES)
def test_module_entry_points_name_values_by_kind(module):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = proc.stdout
    assert not INTERNAL.findall(text) and not derived_placeholders(text), (module, derived_placeholders(text))
