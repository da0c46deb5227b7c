"""On-disk cache of the suspension kinematics fits.

Solving the four linkages over their travel and rack grids and fitting the polynomials takes seconds
(4-12 s on this machine), the biggest part of starting `rtsim serve`, a test or a validation run. The
fits depend only on the axle configuration (hardpoints, camber, toe, suspension type, travel) and on
the solver's code, so they are stored as ``.npz`` files under ``$RTSIM_CACHE/kinematics`` (default
``~/.cache/rtsim/kinematics``), named by a SHA-256 of exactly those inputs: the configuration as JSON
plus the source text of the linkage solver and of the assembly's builder. A changed hardpoint or a changed solver
makes a new key; nothing is ever reused across different inputs. Writes are atomic (temporary file,
then rename); an unreadable or foreign file is ignored and recomputed. Set ``RTSIM_CACHE=off`` to
disable the cache.
"""
from __future__ import annotations

import hashlib
import inspect
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from . import linkages
from .linkages import CornerKinematics

_FIELDS = ("exponents", "vec_coef", "spring_coef", "z_range", "s_range", "fit_error", "steered")


def cache_dir() -> Path | None:
    root = os.environ.get("RTSIM_CACHE", "")
    if root.strip().lower() == "off":
        return None
    return (Path(root) if root else Path.home() / ".cache" / "rtsim") / "kinematics"


def cache_key(cfg, solve=None) -> str:
    """SHA-256 of the axles' configuration, the linkage solver's source and the source of the module
    that defines `solve` (the assembly's builder, which turns the config into linkages)."""
    h = hashlib.sha256()
    h.update(json.dumps({"front": cfg.front.model_dump(mode="json"), "rear": cfg.rear.model_dump(mode="json")},
                        sort_keys=True).encode())
    sources = {Path(linkages.__file__)}
    if solve is not None:
        sources.add(Path(inspect.getsourcefile(solve)))
    for path in sorted(sources):
        h.update(path.read_bytes())
    return h.hexdigest()[:32]


def _save(path: Path, corners: list[CornerKinematics]) -> None:
    arrays = {}
    for i, c in enumerate(corners):
        for f in _FIELDS:
            arrays[f"{i}_{f}"] = np.asarray(getattr(c, f))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _load(path: Path) -> list[CornerKinematics] | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            out = []
            for i in range(4):
                v = {f: z[f"{i}_{f}"] for f in _FIELDS}
                out.append(CornerKinematics(
                    exponents=v["exponents"], vec_coef=v["vec_coef"], spring_coef=v["spring_coef"],
                    z_range=tuple(float(x) for x in v["z_range"]), s_range=tuple(float(x) for x in v["s_range"]),
                    fit_error=float(v["fit_error"]), steered=bool(v["steered"])))
            return out
    except Exception:  # noqa: BLE001  (missing, truncated, foreign: recompute)
        return None


def cached_corner_kinematics(cfg, solve) -> list[CornerKinematics]:
    """``solve(cfg)`` (the four corners), or its stored result for the same inputs."""
    folder = cache_dir()
    if folder is None:
        return solve(cfg)
    path = folder / f"{cache_key(cfg, solve)}.npz"
    corners = _load(path) if path.exists() else None
    if corners is None:
        corners = solve(cfg)
        try:
            _save(path, corners)
        except OSError:
            pass            # a read-only home: run without the cache
    return corners
