"""`rtsim eigen`: the stability of a two-wheeler in straight running against speed (rtsim.analyses.eigen,
rtsim.analyses.stability), as JSON and a root-locus figure."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rtsim.errors import RtsimError


def _two_wheeler(path, command: str):
    """The opened vehicle (rtsim.vehicle.registry); one line of refusal where ``command`` does not apply."""
    from rtsim.vehicle.registry import open_vehicle

    vehicle = open_vehicle(path)
    vehicle.refuse(command)
    return vehicle


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", required=True, metavar="FILE|NAME",
                   help="two-wheeler vehicle TOML (e.g. configs/vehicles/motorcycle.toml)")
    p.add_argument("--speeds", default="1:60:0.5", metavar="START:STOP:STEP",
                   help="start:stop:step or a comma list, m/s (1:60:0.5)")
    p.add_argument("--out", metavar="JSON", help="write the modes and stability changes here (default: stdout)")
    p.add_argument("--plot", metavar="PNG", help="also write the root locus here")


def main(args) -> int:
    from .eigen import TwoWheelerLinearisation
    from .stability import as_dict, root_locus, speed_grid, sweep, write_json

    try:
        speeds = speed_grid(args.speeds)
    except ValueError as exc:
        raise RtsimError(str(exc)) from None
    vehicle = _two_wheeler(args.vehicle, "eigen")
    cfg = vehicle.config
    lin = TwoWheelerLinearisation(vehicle.model)
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


def add_statics_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", required=True, metavar="FILE|NAME", help="two-wheeler vehicle TOML")
    p.add_argument("--out", metavar="JSON", help="write the result here (default: stdout)")


def statics_main(args) -> int:
    """The two-wheeler at rest with the rider on: wheel loads, suspension sag, the frame's attitude."""
    import numpy as np

    from rtsim.vehicle.motorcycle.sim import static_pose

    vehicle = _two_wheeler(args.vehicle, "statics")
    cfg, mm = vehicle.config, vehicle.model
    q, loads = static_pose(mm)
    q0 = mm.coordinates(np.zeros(11))
    des = mm.design
    fork = float(mm.group(q, "ZETA")[0])
    up = lambda x: float((mm.group(x, "W_R") - mm.group(x, "P")) @ mm.group(x, "H_AX"))   # noqa: E731
    x_axis = np.cos(cfg.caster_rad) * mm.group(q, "E1") - np.sin(cfg.caster_rad) * mm.group(q, "H_AX")
    carried = loads.sum() > 0.0       # 0: the wheels roll on constraints (no tyre model), whose loads are not kept
    data = {"vehicle": cfg.name,
            "wheel_loads_n": {"front": float(loads[0]), "rear": float(loads[1])} if carried else None,
            "front_share": float(loads[0] / loads.sum()) if carried else None,
            **({} if carried else {"note": "no tyre loads: the wheels touch the ground through rolling constraints"}),
            "fork_compression_m": fork,
            "fork_compression_from_design_m": fork - des.zeta0,
            "rear_axle_rise_from_design_m": up(q) - up(q0),
            "pivot_height_change_m": float(mm.group(q, "P")[2] - mm.group(q0, "P")[2]),
            "pitch_rad": float(-np.arcsin(x_axis[2])),
            "axes": "ISO 8855; pitch positive nose down"}
    text = json.dumps(data, indent=1)
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text)
    return 0
