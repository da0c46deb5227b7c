"""`rtsim faults`: the fault catalogue (``--list``, ``--json``), or check fault files (``FILE.toml ...``:
each ``[[faults]]`` entry against the catalogue's kinds, parameters and ranges; the targets are checked
against the vehicle when a session arms them)."""
from __future__ import annotations

import argparse
import json

from .catalog import KINDS, listing


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="*", metavar="FILE", help="fault files ([[faults]] tables) to check")
    p.add_argument("--list", action="store_true", help="list every fault kind, its target and its parameters")
    p.add_argument("--json", action="store_true", help="the catalogue (or the checked faults) as JSON")


def catalogue_json() -> list[dict]:
    return [{"kind": k.name, "target": k.target, "actuator": k.actuator, "description": k.description,
             "params": [{"name": p.name, "lo": p.lo, "hi": p.hi, "unit": p.unit, "meaning": p.meaning,
                         "default": None if p.default is None or p.default != p.default else p.default,
                         "integer": p.integer} for p in k.params]} for k in KINDS]


def main(args) -> int:
    from .spec import load_fault_file

    if args.files:
        out = {}
        for f in args.files:
            out[f] = [s.table() for s in load_fault_file(f)]       # ConfigError: one line, exit 2
        if args.json:
            print(json.dumps(out, indent=2))
        else:
            for f, specs in out.items():
                print(f"rtsim faults: {f}: {len(specs)} fault(s) valid: {', '.join(s['id'] for s in specs)}")
        return 0
    if args.json:
        print(json.dumps(catalogue_json(), indent=2))
    else:
        print(listing())
    return 0
