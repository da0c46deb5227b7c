"""What the page draws, described once from the service's configuration: the vehicle's shape (wheel
centres, radii, tyre stiffness, body size: from its config file as the service reports it), the road
(plane, grade, or the survey mesh with its per-triangle friction), and the vehicle's controls and default
plots as the vehicle describes them (rtsim.vehicle.kit.user_inputs). All in SI units and ISO 8855 axes
(x forward, y left, z up), as the state channels.

Buildings: simple blocks from an optional file beside a survey (``<survey stem>_buildings.csv``).

The vehicle: a car's state pose is that of its centre of mass (``pos_*``, ``roll/pitch/yaw_angle``);
the wheel centres are given relative to it. A two-wheeler's pose is that of its rear frame at the
swingarm pivot; its points are given relative to the pivot in the frame's (x, z) plane.
"""
from __future__ import annotations

import math
import re
from pathlib import Path



def _tir_value(path: Path, key: str, default: float) -> float:
    """A number of a .tir tyre property file (KEY = value $ comment), or the default."""
    try:
        m = re.search(rf"^\s*{key}\s*=\s*([-+0-9.eE]+)", path.read_text(errors="replace"), re.MULTILINE)
    except OSError:
        return default
    return float(m.group(1)) if m else default


def car_shape(vehicle: dict, vehicle_path: Path | None) -> dict:
    """Wheel centres relative to the centre of mass (m), radius and vertical stiffness of the tyre, a body
    box around the wheels, from the car's config (as dumped by the service's ``config`` query)."""
    cg = vehicle["chassis"]["cg_m"]
    wheels = {}
    for axle, corners in (("front", ("fl", "fr")), ("rear", ("rl", "rr"))):
        wc = vehicle[axle]["hardpoints"]["wheel_centre"]
        for c, side in zip(corners, (1.0, -1.0)):
            wheels[c] = [wc[0] - cg[0], side * wc[1] - cg[1], wc[2] - cg[2]]
    radius, kz = 0.29, 2.0e5
    tir = (vehicle.get("tyres") or {}).get("property_file")
    if tir and vehicle_path is not None:
        p = (vehicle_path.parent / tir).resolve()
        radius = _tir_value(p, "UNLOADED_RADIUS", radius)
        kz = _tir_value(p, "VERTICAL_STIFFNESS", kz)
    xs = [w[0] for w in wheels.values()]
    track = max(w[1] for w in wheels.values()) - min(w[1] for w in wheels.values())
    return {"kind": "car", "wheels": wheels, "wheel_radius": radius, "wheel_width": 0.16, "tyre_kz": kz,
            "body": {"x_front": max(xs) + 0.75, "x_rear": min(xs) - 0.65, "width": track + 0.15,
                     "z_floor": wheels["fl"][2] - 0.05, "z_roof": wheels["fl"][2] + 1.15}}


def two_wheeler_shape(vehicle: dict) -> dict:
    """Points of a two-wheeler relative to its swingarm pivot in the rear frame's (x, z) plane (m): the
    rear wheel centre on the swingarm, the front wheel centre, the steering axis (a point and its
    direction), radii; from its config's geometry."""
    g = vehicle["geometry"]
    px, pz = g["swingarm_pivot_m"]
    rr, rf = vehicle["rear_wheel"]["radius_m"], vehicle["front_wheel"]["radius_m"]
    wb, trail, caster = g["wheelbase_m"], g["trail_m"], math.radians(g["caster_deg"])
    ground = wb + trail                      # the steering axis meets the ground here (x)
    axis = [-math.sin(caster), 0.0, math.cos(caster)]
    head = [ground + axis[0] * 1.0 - px, 0.0, axis[2] * 1.0 - pz]
    return {"kind": "two_wheeler", "rear_wheel": [-px, 0.0, rr - pz], "front_wheel": [wb - px, 0.0, rf - pz],
            "rear_radius": rr, "front_radius": rf, "steer_axis": axis, "steer_head": head,
            "rider": ([vehicle["rider"]["cg_m"][0] - px, 0.0, vehicle["rider"]["cg_m"][1] - pz]
                      if vehicle.get("rider") else None),          # (the benchmark bicycle has none)
            "cg": [vehicle["rear_frame"]["cg_m"][0] - px, 0.0, vehicle["rear_frame"]["cg_m"][1] - pz]}


BUILDING_COLUMNS = ("x", "y", "length", "width", "height", "yaw_deg")


def read_buildings(path: Path, vertices) -> list[dict]:
    """Building blocks beside a survey (``<survey stem>_buildings.csv``: x, y, length, width, height, yaw_deg
    per row, ``#`` comments): each with its base height, the survey's nearest vertex height (m). Raises
    ValueError naming the file, the line and the value."""
    import numpy as np

    out, header = [], None
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            if tuple(cells) != BUILDING_COLUMNS:
                raise ValueError(f"{path}:{n}: header {line!r}, expected {','.join(BUILDING_COLUMNS)}")
            header = cells
            continue
        try:
            vals = [float(c) for c in cells]
        except ValueError:
            raise ValueError(f"{path}:{n}: {line!r} is not {len(BUILDING_COLUMNS)} numbers") from None
        if len(vals) != len(BUILDING_COLUMNS) or not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{path}:{n}: {line!r}: expected {len(BUILDING_COLUMNS)} finite numbers")
        b = dict(zip(BUILDING_COLUMNS, vals))
        if min(b["length"], b["width"], b["height"]) <= 0 or max(b["length"], b["width"], b["height"]) > 1000:
            raise ValueError(f"{path}:{n}: length, width and height must be in (0, 1000] m")
        v = np.asarray(vertices).reshape(-1, 3)
        b["z"] = float(v[np.argmin((v[:, 0] - b["x"]) ** 2 + (v[:, 1] - b["y"]) ** 2), 2])
        out.append(b)
    return out


def road_description(road_path: Path | None) -> dict:
    """The road as the page draws it: {"type": "flat", "height"}, {"type": "grade", "grade", "heading",
    "origin"}, or {"type": "mesh", "vertices", "triangles", "mu"} (the survey's mesh as the service builds
    it); a road file that cannot be read gives a flat road at 0 with the reason in "note"."""
    if road_path is None:
        return {"type": "flat", "height": 0.0, "mu": 1.0, "note": "road unknown: drawn flat at z = 0"}
    from rtsim.road.config import FlatRoadConfig, GradeRoadConfig, read_road_config
    from rtsim.road.survey import read_survey, survey_to_mesh
    from rtsim.errors import RtsimError

    try:
        cfg = read_road_config(road_path)
        if isinstance(cfg, FlatRoadConfig):
            return {"type": "flat", "height": cfg.height, "mu": cfg.mu}
        if isinstance(cfg, GradeRoadConfig):
            return {"type": "grade", "grade": cfg.grade, "heading": math.radians(cfg.heading_deg),
                    "origin": list(cfg.origin), "mu": cfg.mu}
        survey = road_path.parent / cfg.survey
        mesh = survey_to_mesh(read_survey(survey), cfg.grid_spacing, cfg.alpha_radius, cfg.mu, cfg.rolling_resistance)
        out = {"type": "mesh", "vertices": [round(float(v), 4) for v in mesh.vertices.ravel()],
               "triangles": [int(i) for i in mesh.triangles.ravel()],
               "mu": [round(float(v), 4) for v in mesh.tri_mu], "source": road_path.name, "buildings": []}
        blocks = survey.with_name(survey.stem + "_buildings.csv")
        if blocks.is_file():
            try:
                out["buildings"] = read_buildings(blocks, mesh.vertices)
            except (OSError, ValueError) as exc:
                out["note"] = f"buildings not drawn: {exc}"
        return out
    except (RtsimError, OSError, ValueError) as exc:
        return {"type": "flat", "height": 0.0, "mu": 1.0, "note": f"road {road_path}: {exc}; drawn flat at z = 0"}


def describe(config: dict) -> dict:
    """The page's scene description from the service's ``config`` reply."""
    vehicle = config["vehicle"]
    kind = "two_wheeler" if vehicle.get("kind") == "two_wheeler" else "car"
    road_path = vehicle_path = None
    scen = (config.get("scenario") or {}).get("path")
    if scen:
        try:
            from drivers.scenario import load_scenario

            sc = load_scenario(scen)
            road_path = sc.road_path
            vehicle_path = sc.vehicle_path
        except Exception:            # noqa: BLE001  (another machine's path: draw a plane)
            road_path = None
    opt = (config.get("options") or {}).get("vehicle")
    if opt:
        from rtsim.service.server import resolve_vehicle
        try:
            vehicle_path = resolve_vehicle(opt)
        except Exception:            # noqa: BLE001
            pass
    if vehicle_path is None and kind == "car":
        from rtsim.vehicle.offline import default_vehicle_path
        vehicle_path = default_vehicle_path()
    shape = car_shape(vehicle, vehicle_path) if kind == "car" else two_wheeler_shape(vehicle)
    return {
        "vehicle_id": config.get("vehicle_id"), "name": vehicle.get("name"), "kind": kind, "dt": config.get("dt"),
        "mode": (config.get("options") or {}).get("mode"),
        "scenario": (config.get("scenario") or {}).get("name"),
        "shape": shape, "road": road_description(road_path),
        "channels": config.get("channels"),
        # what the vehicle says a person may drive (rtsim.vehicle.kit.user_inputs), as the page's control
        # groups, and its default plots; a service (or a recording) without it: nothing to drive with
        "controls": page_controls(config.get("user_inputs") or {}),
        "plots": (config.get("user_inputs") or {}).get("plots") or [],
    }


def page_controls(user_inputs: dict) -> list[dict]:
    """The page's control groups from the service's ``user_inputs`` (rtsim.vehicle.kit.user_inputs):
    ``[{"name", "release", "channels": [{"channel", "control", "full_scale", "sign"}, ...]}, ...]``."""
    chans = user_inputs.get("channels") or {}
    return [{"name": g["name"], "release": g["release"],
             "channels": [{"channel": n, "control": chans[n]["control"], "full_scale": chans[n]["full_scale"],
                           "sign": chans[n]["sign"]} for n in g["channels"]]}
            for g in user_inputs.get("groups") or []]
