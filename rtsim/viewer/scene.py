"""What the page draws, described once from the service's configuration: the vehicle's drawing (its
wheels, body pieces, steering and camera points: rtsim.vehicle.kit.drawing, built by the vehicle from its
config, the same description the Foxglove scene draws), the road
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
from pathlib import Path


def vehicle_drawing(vehicle: dict, vehicle_path: Path | None) -> tuple[str, dict]:
    """(kind name, the page's drawing: rtsim.vehicle.kit.drawing.Drawing.page) of the served vehicle: its file
    (None: the default vehicle, as the service serves it) when it is here, else its config as the service
    or the recording reports it (a JSON null, a non-finite number or an unset option, takes the field's
    default), its relative files beside its path, else beside the shipped vehicles."""
    from rtsim.vehicle.registry import DEFAULT_VEHICLE, OpenedVehicle, kind_of, open_vehicle

    path = Path(vehicle_path) if vehicle_path is not None else DEFAULT_VEHICLE
    if path.is_file():
        try:
            opened = open_vehicle(path)
            return opened.name, opened.kind.drawing(opened).page()
        except Exception:            # noqa: BLE001  (the file changed since: the reported config)
            pass
    data = _without_nulls(vehicle)
    kind = kind_of(data, path)
    error = None
    for where in (path, DEFAULT_VEHICLE):
        try:
            cfg, base = kind.load(data, where)
            return kind.name, kind.drawing(OpenedVehicle(where, kind, cfg, base)).page()
        except Exception as exc:     # noqa: BLE001  (its files are not here: try the shipped ones)
            error = exc
    raise error


def _without_nulls(d):
    if isinstance(d, dict):
        return {k: _without_nulls(v) for k, v in d.items() if v is not None}
    if isinstance(d, list):
        return [_without_nulls(v) for v in d]
    return d


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
    "origin"}, or {"type": "mesh", "vertices", "triangles", "mu"} (the survey's or an OpenDRIVE road's mesh
    as the service builds it; an OpenDRIVE road also with its "marks"); a road file that cannot be read gives a flat road at 0 with the reason in "note"."""
    if road_path is None:
        return {"type": "flat", "height": 0.0, "mu": 1.0, "note": "road unknown: drawn flat at z = 0"}
    from rtsim.road.config import FlatRoadConfig, GradeRoadConfig, OpenDriveRoadConfig, read_road_config
    from rtsim.road.survey import read_survey, survey_to_mesh
    from rtsim.errors import RtsimError

    try:
        cfg = read_road_config(road_path)
        if isinstance(cfg, FlatRoadConfig):
            return {"type": "flat", "height": cfg.height, "mu": cfg.mu}
        if isinstance(cfg, GradeRoadConfig):
            return {"type": "grade", "grade": cfg.grade, "heading": math.radians(cfg.heading_deg),
                    "origin": list(cfg.origin), "mu": cfg.mu}
        if isinstance(cfg, OpenDriveRoadConfig):
            return opendrive_description(road_path, cfg)
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


def opendrive_description(road_path: Path, cfg) -> dict:
    """An OpenDRIVE road as the page draws it: its lanes' mesh as the service builds it (``type`` "mesh",
    per-triangle friction) and its road marks (``marks``: vertices, triangles, a colour per triangle)."""
    from rtsim.road.config import opendrive_mesh
    from rtsim.road.opendrive import road_markings

    odr, mesh = opendrive_mesh(road_path, cfg)
    marks = road_markings(odr)
    return {"type": "mesh", "vertices": [round(float(v), 4) for v in mesh.vertices.ravel()],
            "triangles": [int(i) for i in mesh.triangles.ravel()],
            "mu": [round(float(v), 4) for v in mesh.tri_mu], "source": road_path.name, "buildings": [],
            "marks": {"vertices": [round(float(v), 4) for v in marks["vertices"].ravel()],
                      "triangles": [int(i) for i in marks["triangles"].ravel()], "colour": marks["colour"]}}


def describe(config: dict) -> dict:
    """The page's scene description from the service's ``config`` reply."""
    vehicle = config["vehicle"]
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
    kind, shape = vehicle_drawing(vehicle, vehicle_path)
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
