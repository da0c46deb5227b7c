"""What `rtsim view` draws, described from the configuration (rtsim.viewer.scene), against the files it
comes from: the car's wheel centres from its hardpoints relative to its centre of mass, its tyre from the
.tir file; the campus road as the survey mesh the service builds (same vertices, triangles, friction);
a grade's plane; a road file that cannot be read drawn flat with the reason."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.road.config import read_road_config
from rtsim.road.survey import read_survey, survey_to_mesh
from rtsim.vehicle.car.config import load_vehicle
from rtsim.viewer.scene import car_shape, road_description, two_wheeler_shape

ROOT = Path(__file__).resolve().parents[1]


def test_car_shape_from_its_config():
    path = ROOT / "configs" / "vehicles" / "xbw.toml"
    cfg, _ = load_vehicle(path)
    d = cfg.model_dump(mode="json")
    s = car_shape(d, path)
    cg = np.array(d["chassis"]["cg_m"])
    wc = np.array(d["front"]["hardpoints"]["wheel_centre"])
    assert s["wheels"]["fl"] == pytest.approx(list(wc - cg))
    assert s["wheels"]["fr"] == pytest.approx([wc[0] - cg[0], -wc[1] - cg[1], wc[2] - cg[2]])
    assert s["wheel_radius"] == 0.289 and s["tyre_kz"] == 165000.0      # michelin_155_80_r13.tir
    assert s["body"]["x_front"] > s["wheels"]["fl"][0] > s["wheels"]["rl"][0] > s["body"]["x_rear"]


def test_two_wheeler_points_from_its_geometry():
    from rtsim.vehicle.motorcycle.config import load_motorcycle

    cfg, _ = load_motorcycle(ROOT / "configs" / "vehicles" / "motorcycle.toml")
    d = cfg.model_dump(mode="json")
    s = two_wheeler_shape(d)
    px, pz = d["geometry"]["swingarm_pivot_m"]
    assert s["front_wheel"][0] - s["rear_wheel"][0] == pytest.approx(d["geometry"]["wheelbase_m"])
    assert s["rear_wheel"] == pytest.approx([-px, 0.0, d["rear_wheel"]["radius_m"] - pz])
    # the steering axis leans back by the caster angle and meets the ground one trail ahead of the front contact
    ax = np.array(s["steer_axis"])
    assert np.degrees(np.arctan2(-ax[0], ax[2])) == pytest.approx(d["geometry"]["caster_deg"])
    head = np.array(s["steer_head"]) + [px, 0.0, pz]
    ground_x = head[0] - head[2] * ax[0] / ax[2]
    assert ground_x == pytest.approx(d["geometry"]["wheelbase_m"] + d["geometry"]["trail_m"])


def test_roads_as_drawn(tmp_path):
    campus = ROOT / "configs" / "roads" / "campus.toml"
    r = road_description(campus)
    cfg = read_road_config(campus)
    mesh = survey_to_mesh(read_survey(campus.parent / cfg.survey), cfg.grid_spacing, cfg.alpha_radius, cfg.mu,
                          cfg.rolling_resistance)
    assert r["type"] == "mesh"
    assert np.array(r["vertices"]).reshape(-1, 3) == pytest.approx(mesh.vertices, abs=1e-4)
    assert np.array_equal(np.array(r["triangles"]).reshape(-1, 3), mesh.triangles)
    assert np.array(r["mu"]) == pytest.approx(mesh.tri_mu, abs=1e-4)
    g = road_description(ROOT / "configs" / "roads" / "grade_5pct.toml")
    assert (g["type"], g["grade"], g["heading"]) == ("grade", 0.05, 0.0)
    bad = tmp_path / "bad.toml"
    bad.write_text('type = "grade"\ngrade = 3.0\n')
    f = road_description(bad)
    assert f["type"] == "flat" and "grade" in f["note"] and "drawn flat" in f["note"]


def test_buildings_beside_the_survey(tmp_path):
    from rtsim.viewer.scene import read_buildings

    r = road_description(ROOT / "configs" / "roads" / "campus.toml")
    rows = [line.split(",") for line in (ROOT / "configs" / "roads" / "campus_survey_buildings.csv").read_text()
            .splitlines() if line and not line.startswith("#")][1:]
    assert [(b["x"], b["y"], b["height"]) for b in r["buildings"]] == [(float(x), float(y), float(h))
                                                                       for x, y, _l, _w, h, _a in rows]
    v = np.array(r["vertices"]).reshape(-1, 3)
    assert all(v[:, 2].min() <= b["z"] <= v[:, 2].max() for b in r["buildings"])
    bad = tmp_path / "b.csv"
    bad.write_text("x,y,length,width,height,yaw_deg\n1,2,3,-4,5,0\n")
    with pytest.raises(ValueError, match=r"b.csv:2: length, width and height"):
        read_buildings(bad, v)
    bad.write_text("x,y,length\n1,2,3\n")
    with pytest.raises(ValueError, match="header"):
        read_buildings(bad, v)


CARS = ("xbw", "xbw_fwd", "eps_car")
TWO_WHEELERS = ("motorcycle", "whipple_benchmark")


@pytest.mark.parametrize("name", CARS + TWO_WHEELERS)
def test_every_vehicle_describes_its_controls(name):
    """What the page's controls mean comes from the vehicle (its config's ``user_controls()``), for every
    shipped vehicle: each of its user channels (rtsim.service.user_input) in exactly one group, driven by
    one of the page's three controls, its full scale inside the channel's range; every control drives
    something. The service sends it (``view`` in its configuration) and the page's scene passes it on."""
    from rtsim.service.user_input import user_channels
    from rtsim.vehicle.motorcycle.config import load_motorcycle
    from rtsim.viewer.scene import describe

    path = ROOT / "configs" / "vehicles" / f"{name}.toml"
    cfg, _ = (load_vehicle if name in CARS else load_motorcycle)(path)
    view = cfg.user_controls()
    chans = user_channels("car" if name in CARS else "two_wheeler")
    got = [c for g in view["controls"] for c in g["channels"]]
    assert sorted(c["channel"] for c in got) == sorted(chans)
    assert {c["control"] for c in got} == {"throttle", "brake", "steer"}
    for c in got:
        lo, hi, _unit, _meaning = chans[c["channel"]]
        assert 0.0 < c["full_scale"] and lo <= c["sign"] * c["full_scale"] <= hi, c
    assert all(g["release"] in ("hold", "hand_back") for g in view["controls"])
    page = describe({"vehicle": cfg.model_dump(mode="json"), "view": view})
    assert page["controls"] == view["controls"] and page["plots"] == view["plots"]


def test_the_motorcycles_full_keys():
    """The motorcycle's full throttle key is 40 % (wide open lifts its front wheel); its full brake key
    0.5 g of deceleration, 80 % of it on the front: the calipers' torques over the wheel radii, against
    the machine's weight with its rider (275 kg); the full lean key 30 degrees, right key leaning right."""
    from rtsim.vehicle.motorcycle.config import load_motorcycle

    cfg, _ = load_motorcycle(ROOT / "configs" / "vehicles" / "motorcycle.toml")
    full = {c["channel"]: c["sign"] * c["full_scale"] for g in cfg.user_controls()["controls"] for c in g["channels"]}
    assert full["throttle_cmd"] == 0.4
    front = full["brake_pressure_front_cmd"] * cfg.brakes.front_nm_per_kpa / cfg.front_wheel.radius_m
    rear = full["brake_pressure_rear_cmd"] * cfg.brakes.rear_nm_per_kpa / cfg.rear_wheel.radius_m
    assert front + rear == pytest.approx(0.5 * 9.81 * 275.0, rel=1e-9)
    assert front == pytest.approx(4 * rear, rel=1e-9)
    assert full["roll_angle_demand"] == pytest.approx(np.radians(30.0), rel=1e-12)
