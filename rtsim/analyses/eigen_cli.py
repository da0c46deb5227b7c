"""`rtsim eigen`: the stability of a two-wheeler in straight running against speed (rtsim.analyses.eigen,
rtsim.analyses.stability), as JSON and a root-locus figure."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rtsim.errors import RtsimError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", required=True, help="two-wheeler vehicle TOML (e.g. configs/vehicles/motorcycle.toml)")
    p.add_argument("--speeds", default="1:60:0.5", help="start:stop:step or a comma list, m/s (1:60:0.5)")
    p.add_argument("--out", metavar="JSON", help="write the modes and stability changes here (default: stdout)")
    p.add_argument("--plot", metavar="PNG", help="also write the root locus here")


def main(args) -> int:
    from rtsim.vehicle.motorcycle.config import load_motorcycle
    from rtsim.vehicle.motorcycle.build import build_motorcycle

    from .eigen import TwoWheelerLinearisation
    from .stability import as_dict, root_locus, speed_grid, sweep, write_json

    try:
        speeds = speed_grid(args.speeds)
    except ValueError as exc:
        raise RtsimError(str(exc)) from None
    cfg, base = load_motorcycle(args.vehicle)
    lin = TwoWheelerLinearisation(build_motorcycle(cfg, base))
    results, crossings = sweep(lin, speeds)
    data = as_dict(cfg.name, results, crossings)
    if args.out:
        write_json(args.out, data)
    else:
        json.dump(data, sys.stdout, indent=1)
        print()
    for c in crossings:
        print(f"{c.mode} becomes {c.becomes} at {c.speed:.6f} m/s", file=sys.stderr)
    if args.plot:
        root_locus(results, crossings, cfg.name, Path(args.plot))
    return 0
