"""How a four-wheel car is drawn (rtsim.vehicle.kit.drawing), from its config: the wheel centres from the
hardpoints relative to the centre of mass (the reference point of its state pose, Euler z-y-x angles),
the tyre's unloaded radius and vertical stiffness from its .tir file (a loaded wheel stands on the road),
the front wheels steered by their ``steer_angle_*`` channels; the body as one box spanning the
wheelbase plus overhangs (the Foxglove scene), and for the viewer's page a lower body and a cabin."""
from __future__ import annotations

from pathlib import Path

from rtsim.channels import WHEELS

from ..kit.drawing import Drawing, DrawnWheel

CABIN_COLOUR = "#36414d"


def car_drawing(cfg, base: str | Path) -> Drawing:
    """The car of config ``cfg`` (rtsim.vehicle.car.config.VehicleConfig) whose files are relative to
    ``base``."""
    from ..kit.tyre.tir import P_UNLOADED_RADIUS, P_VERTICAL_STIFFNESS, load_tir

    tp = load_tir(Path(base) / cfg.tyres.property_file).params
    radius, kz = float(tp[P_UNLOADED_RADIUS]), float(tp[P_VERTICAL_STIFFNESS])
    cg = [float(v) for v in cfg.chassis.cg_m]
    rel = []
    for axle in (cfg.front, cfg.rear):
        wc = [float(v) for v in axle.hardpoints.wheel_centre]
        for side in (1.0, -1.0):
            rel.append((wc[0] - cg[0], side * wc[1] - cg[1], wc[2] - cg[2]))
    xs = [r[0] for r in rel]
    ys = [r[1] for r in rel]
    front, rear = max(xs), min(xs)
    width_t = max(0.12, 0.55 * radius)
    wheels = tuple(DrawnWheel(w, rel[i], radius, width_t, f"wheel_angle_{w}", f"wheel_speed_{w}",
                              f"steer_angle_{w}" if i < 2 else None, f"tyre_fz_{w}", kz)
                   for i, w in enumerate(WHEELS))
    # the page's body: a lower body from 0.65 m behind the rear wheels to 0.75 m ahead of the front ones,
    # and a cabin over its rear half; the driver's eyes behind the cabin's front, above the hood
    x_front, x_rear = front + 0.75, rear - 0.65
    length, width = x_front - x_rear, max(ys) - min(ys) + 0.15
    z_floor = rel[0][2] - 0.05
    cabin = (x_rear + length * 0.42, 0.0, z_floor + 0.5 + 0.05 + 0.225)
    pieces = ({"shape": "box", "at": [0.5 * (x_front + x_rear), 0.0, z_floor + 0.25 + 0.05],
               "size": [length, width, 0.5], "colour": "paint", "carrier": "body"},
              {"shape": "box", "at": list(cabin), "size": [length * 0.5, width * 0.86, 0.45], "colour": CABIN_COLOUR,
               "carrier": "body", "in_cockpit": False})
    return Drawing("zyx", (0.5 * (front + rear) + 0.1, 0.0, min(r[2] for r in rel) + 0.35),
                   (front - rear + 2.0 * radius + 0.5, max(ys) - min(ys) + 0.05, 0.55), wheels, pieces=pieces,
                   eye=(cabin[0] + length * 0.25 - 0.3, rel[0][1] * 0.45, z_floor + 1.1), chase=(8.5, 3.0))
