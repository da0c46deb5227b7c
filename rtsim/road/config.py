"""Road configuration files (TOML), validated with pydantic, built into `Road` arrays.

```toml
type = "flat"                 # z = height everywhere
height = 0.0                  # m
mu = 1.0                      # friction scale, (0, 2]
rolling_resistance = 0.010    # rolling-resistance coefficient, [0, 0.1]
```
```toml
type = "grade"                # plane of constant grade
grade = 0.05                  # rise over run along the heading, [-0.5, 0.5]; > 0 uphill
heading_deg = 0.0             # direction of travel the grade refers to, degrees from +x towards +y
origin = [0.0, 0.0, 0.0]      # a point (x, y, z) of the surface, m
```
```toml
type = "mesh"                 # triangle mesh from a topographic survey (rtsim.road.survey)
survey = "campus_survey.csv"  # CSV x, y, z [, mu, rolling_resistance]; relative to this file
grid_spacing = 0.5            # m, [0.05, 10]
alpha_radius = 3.0            # optional, m: outline radius (default: 2 x median point spacing)
mu = 1.0                      # per-triangle values when the survey has no such column
rolling_resistance = 0.010
off_survey_friction = 0.6     # friction scale of the ground beyond the survey's outline, (0, 2]
off_survey_rolling_resistance = 0.02   # its rolling resistance, [0, 0.1]
```
```toml
type = "opendrive"            # an ASAM OpenDRIVE road network (rtsim.road.opendrive, docs/opendrive.md)
file = "curve.xodr"           # relative to this file
mu = 1.0                      # friction scale of lanes without <material friction>
rolling_resistance = 0.010
ds_max = 1.0                  # m, largest mesh step along the reference line, [0.05, 10]
dt_max = 1.0                  # m, largest mesh step across a lane, [0.05, 10]
off_survey_friction = 0.6     # the ground beyond the road's outer lane borders
off_survey_rolling_resistance = 0.02
```
The world does not end where the survey (or the OpenDRIVE road) does: beyond the outline the ground continues at the height
of the nearest outline points, levelling out and taking the off-survey friction within 1 m
(rtsim.road.model, "Off the survey"), so a tyre that rolls off the mesh keeps its load.
Every error is a ConfigError naming the file, the key, the value and what is allowed.
"""
from __future__ import annotations

import contextvars
import math
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import Field, TypeAdapter

from rtsim.configfile import Range, Strict, load, problem
from rtsim.road.model import MU_RANGE, RR_RANGE, Road, make_grade, make_mesh, make_plane
from rtsim.road.survey import read_survey, survey_to_mesh

Mu = Range(MU_RANGE[0], MU_RANGE[1], lo_open=True)    # friction scale of the road surface
RollingResistance = Range(RR_RANGE[0], RR_RANGE[1])    # rolling-resistance coefficient
Place = Range(-1e5, 1e5, "m")                           # a coordinate of a road's point, world frame


class _Road(Strict):
    """A road section: the one config base (unknown keys are errors listing the allowed ones)."""


class FlatRoadConfig(_Road):
    type: Literal["flat"]
    height: Range(-1e4, 1e4, "m") = Field(0.0, description="surface height, m")
    mu: Mu = 1.0
    rolling_resistance: RollingResistance = 0.010


class GradeRoadConfig(_Road):
    type: Literal["grade"]
    grade: Range(-0.5, 0.5) = Field(description="rise over run along the heading, positive uphill")
    heading_deg: Range(-360.0, 360.0, "deg") = Field(
        0.0, description="direction of travel, degrees from +x towards +y")
    origin: tuple[Place, Place, Place] = Field((0.0, 0.0, 0.0), description="a point (x, y, z) of the surface, m")
    mu: Mu = 1.0
    rolling_resistance: RollingResistance = 0.010


class MeshRoadConfig(_Road):
    type: Literal["mesh"]
    survey: str = Field(min_length=1, strict=True, description="survey CSV path, relative to the TOML file")
    grid_spacing: Range(0.05, 10.0, "m") = Field(description="grid spacing, m")
    alpha_radius: Range(0.0, 1e3, "m", lo_open=True) | None = Field(
        None, description="alpha-shape radius, m (default from point spacing)")
    mu: Mu = 1.0
    rolling_resistance: RollingResistance = 0.010
    smooth_normals: bool = Field(True, strict=True,
                                 description="contact normals interpolated from vertex normals, so tyre "
                                             "forces are continuous across triangle edges")
    off_survey_friction: Mu = Field(
        0.6, description="friction scale of the ground beyond "
                                                                "the survey (grass, gravel: about 0.6)")
    off_survey_rolling_resistance: RollingResistance = Field(
        0.02, description="rolling resistance of the ground beyond "
                                                             "the survey")


class OpenDriveRoadConfig(_Road):
    type: Literal["opendrive"]
    file: str = Field(min_length=1, strict=True, description="OpenDRIVE (.xodr) path, relative to the TOML file")
    mu: Mu = 1.0
    rolling_resistance: RollingResistance = 0.010
    ds_max: Range(0.05, 10.0, "m") = Field(1.0, description="largest mesh step along the reference line, m")
    dt_max: Range(0.05, 10.0, "m") = Field(1.0, description="largest mesh step across a lane, m")
    smooth_normals: bool = Field(True, strict=True,
                                 description="contact normals interpolated from vertex normals")
    off_survey_friction: Mu = Field(
        0.6, description="friction scale of the ground beyond the road")
    off_survey_rolling_resistance: RollingResistance = Field(
        0.02, description="rolling resistance of the ground beyond the road")


RoadConfig = Annotated[Union[FlatRoadConfig, GradeRoadConfig, MeshRoadConfig, OpenDriveRoadConfig],
                       Field(discriminator="type")]
_ADAPTER = TypeAdapter(RoadConfig)


def read_road_config(path) -> FlatRoadConfig | GradeRoadConfig | MeshRoadConfig | OpenDriveRoadConfig:
    """Parse and validate a road TOML file (rtsim.configfile: errors name the file, key, value, range)."""
    return load(_ADAPTER, Path(path))


_KEPT: contextvars.ContextVar[dict | None] = contextvars.ContextVar("rtsim_kept_roads", default=None)


@contextmanager
def keeping_roads(kept: dict):
    """While active, `load_road` of a road file it built before returns that road (``kept``: resolved
    path -> Road, filled as roads are built): a batch worker builds each road once, its input files
    taken not to change during the batch. A road is immutable arrays (each run's contact state is the
    vehicle's)."""
    token = _KEPT.set(kept)
    try:
        yield kept
    finally:
        _KEPT.reset(token)


def load_road(path) -> Road:
    """Read a road TOML file and build its arrays (survey paths are relative to the TOML file); the kept
    one inside `keeping_roads`."""
    kept = _KEPT.get()
    if kept is None:
        return _build_road(Path(path))
    key = Path(path).resolve()
    road = kept.get(key)
    if road is None:
        road = kept[key] = _build_road(Path(path))
    return road


def _build_road(path: Path) -> Road:
    cfg = read_road_config(path)
    if isinstance(cfg, FlatRoadConfig):
        return make_plane(cfg.height, cfg.mu, cfg.rolling_resistance)
    if isinstance(cfg, GradeRoadConfig):
        return make_grade(cfg.grade, math.radians(cfg.heading_deg), cfg.origin, cfg.mu,
                          cfg.rolling_resistance)
    if isinstance(cfg, OpenDriveRoadConfig):
        odr, mesh = opendrive_mesh(path, cfg)
        return make_mesh(mesh.vertices, mesh.triangles, mesh.tri_mu, mesh.tri_rr, cell_size=cfg.ds_max,
                         source=odr.path, smooth_normals=cfg.smooth_normals,
                         off_survey_mu=cfg.off_survey_friction,
                         off_survey_rr=cfg.off_survey_rolling_resistance)
    survey_path = path.parent / cfg.survey
    if not survey_path.is_file():
        raise problem(path, "survey", cfg.survey, f"file not found ({survey_path})")
    survey = read_survey(survey_path)
    mesh = survey_to_mesh(survey, cfg.grid_spacing, cfg.alpha_radius, cfg.mu, cfg.rolling_resistance)
    return make_mesh(mesh.vertices, mesh.triangles, mesh.tri_mu, mesh.tri_rr,
                     cell_size=cfg.grid_spacing, source=str(survey_path), smooth_normals=cfg.smooth_normals,
                     off_survey_mu=cfg.off_survey_friction,
                     off_survey_rr=cfg.off_survey_rolling_resistance)


def read_opendrive_of(path, cfg: OpenDriveRoadConfig | None = None):
    """The OpenDRIVE file a road TOML of type "opendrive" points to, read (rtsim.road.opendrive)."""
    from rtsim.road.opendrive import read_opendrive

    path = Path(path)
    cfg = read_road_config(path) if cfg is None else cfg
    if not isinstance(cfg, OpenDriveRoadConfig):
        raise problem(path, "type", cfg.type, "an OpenDRIVE road is needed here (type = \"opendrive\")")
    xodr = path.parent / cfg.file
    if not xodr.is_file():
        raise problem(path, "file", cfg.file, f"file not found ({xodr})")
    return read_opendrive(xodr)


def opendrive_mesh(path, cfg: OpenDriveRoadConfig | None = None):
    """(OpenDrive, RoadMesh) of a road TOML of type "opendrive": its file read and its lanes meshed."""
    from rtsim.road.opendrive import mesh_opendrive

    cfg = read_road_config(path) if cfg is None else cfg
    odr = read_opendrive_of(path, cfg)
    return odr, mesh_opendrive(odr, cfg.mu, cfg.rolling_resistance, cfg.ds_max, cfg.dt_max)


def road_marks_of(path) -> dict | None:
    """The road marks to draw (rtsim.road.opendrive.road_markings) of a road TOML of type "opendrive"; None
    for any other road or a road file that cannot be read (drawing only: the run reports that one)."""
    from rtsim.errors import RtsimError
    from rtsim.road.opendrive import road_markings

    if path is None:
        return None
    try:
        cfg = read_road_config(path)
        if not isinstance(cfg, OpenDriveRoadConfig):
            return None
        return road_markings(read_opendrive_of(path, cfg))
    except (RtsimError, OSError):
        return None
