"""Roads: plane, constant grade, and triangle meshes built from survey points; tyre contact queries.

- `model`: every road as the same named tuple of arrays (`Road`), kind codes, builders
  (`make_plane`, `make_grade`, `make_mesh`) and the grid hash of a mesh.
- `query`: the compiled kernels `road_query` (height, normal, friction, rolling resistance, triangle
  under a point) and `wheel_contact` (disc-on-plane tyre contact), callable from vehicle kernels.
- `survey`: offline survey -> mesh pipeline (CSV reader, Sibson natural-neighbour interpolation,
  alpha-shape outline, grid triangulation, per-triangle friction).
- `config`: `load_road(path)` for the TOML files in configs/roads/.
"""
from rtsim.road.config import load_road, read_road_config
from rtsim.road.model import ROAD_MESH, ROAD_PLANE, Road, make_grade, make_mesh, make_plane
from rtsim.road.query import road_query, wheel_contact

__all__ = ["Road", "ROAD_PLANE", "ROAD_MESH", "make_plane", "make_grade", "make_mesh", "road_query",
           "wheel_contact", "load_road", "read_road_config"]
