"""The kinematics cache returns exactly what the solver computes, keys on the axle configuration,
and recovers from a damaged file."""
from __future__ import annotations

import numpy as np

from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.kit.linkage_cache import cache_key, cached_corner_kinematics
from rtsim.vehicle.car.build import corner_kinematics
from rtsim.vehicle.offline import default_vehicle_path


def test_cache_round_trip_key_and_damage(tmp_path, monkeypatch):
    monkeypatch.setenv("RTSIM_CACHE", str(tmp_path))
    cfg, _ = load_vehicle(default_vehicle_path())
    calls = []

    def solve(c):
        calls.append(1)
        return corner_kinematics(c)
    first = cached_corner_kinematics(cfg, solve)
    again = cached_corner_kinematics(cfg, solve)
    assert len(calls) == 1
    for a, b in zip(first, again):
        for f in ("exponents", "vec_coef", "spring_coef"):
            assert np.array_equal(getattr(a, f), getattr(b, f))
        assert (a.z_range, a.s_range, a.fit_error, a.steered) == (b.z_range, b.s_range, b.fit_error, b.steered)
        assert np.array_equal(a.evaluate(0, 0.01, 0.02), b.evaluate(0, 0.01, 0.02))
    # a different hardpoint is a different key
    x, y, z = cfg.front.hardpoints.tie_outer
    hp = cfg.front.hardpoints.model_copy(update={"tie_outer": (x, y, z + 0.001)})
    moved = cfg.model_copy(update={"front": cfg.front.model_copy(update={"hardpoints": hp})})
    assert cache_key(moved) != cache_key(cfg)
    # a damaged file is recomputed, not trusted
    path = next((tmp_path / "kinematics").glob("*.npz"))
    path.write_bytes(b"not an npz")
    cached_corner_kinematics(cfg, solve)
    assert len(calls) == 2
    monkeypatch.setenv("RTSIM_CACHE", "off")
    cached_corner_kinematics(cfg, solve)
    assert len(calls) == 3
