"""What `rtsim view` draws, described from the configuration (rtsim.viewer.scene, the vehicle's drawing:
rtsim.vehicle.kit.drawing), against the files it comes from: the car's wheel centres from its hardpoints
relative to its centre of mass, its tyre from the .tir file; the two-wheeler's points from its geometry;
the campus road as the survey mesh the service builds (same vertices, triangles, friction); a grade's plane;
a road file that cannot be read drawn flat with the reason."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.road.config import read_road_config
from rtsim.road.survey import read_survey, survey_to_mesh
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.drawing import car_drawing
from rtsim.vehicle.motorcycle.drawing import two_wheeler_drawing
from rtsim.viewer.scene import road_description, vehicle_drawing

ROOT = Path(__file__).resolve().parents[1]


def test_car_drawing_from_its_config():
    path = ROOT / "configs" / "vehicles" / "xbw.toml"
    cfg, base = load_vehicle(path)
    d = cfg.model_dump(mode="json")
    s = car_drawing(cfg, base)
    cg = np.array(d["chassis"]["cg_m"])
    wc = np.array(d["front"]["hardpoints"]["wheel_centre"])
    wheels = {w.name: w for w in s.wheels}
    assert wheels["fl"].centre == pytest.approx(list(wc - cg))
    assert wheels["fr"].centre == pytest.approx([wc[0] - cg[0], -wc[1] - cg[1], wc[2] - cg[2]])
    assert (wheels["fl"].radius, wheels["fl"].stiffness) == (0.289, 165000.0)      # michelin_155_80_r13.tir
    assert (wheels["fl"].steer, wheels["rl"].steer, wheels["rr"].load) == ("steer_angle_fl", None, "tyre_fz_rr")
    lower = s.pieces[0]
    x_front, x_rear = lower["at"][0] + lower["size"][0] / 2, lower["at"][0] - lower["size"][0] / 2
    assert x_front > wheels["fl"].centre[0] > wheels["rl"].centre[0] > x_rear
    assert s.steering is None and s.attitude == "zyx"


def test_two_wheeler_points_from_its_geometry():
    from rtsim.vehicle.motorcycle.config import load_motorcycle

    cfg, _ = load_motorcycle(ROOT / "configs" / "vehicles" / "motorcycle.toml")
    d = cfg.model_dump(mode="json")
    s = two_wheeler_drawing(cfg)
    rear, front = s.wheels
    px, pz = d["geometry"]["swingarm_pivot_m"]
    assert front.centre[0] - rear.centre[0] == pytest.approx(d["geometry"]["wheelbase_m"])
    assert rear.centre == pytest.approx([-px, 0.0, d["rear_wheel"]["radius_m"] - pz])
    # the steering axis leans back by the caster angle and meets the ground one trail ahead of the front contact
    ax = np.array(s.steering.axis)
    assert np.degrees(np.arctan2(-ax[0], ax[2])) == pytest.approx(d["geometry"]["caster_deg"])
    head = np.array(s.steering.head) + [px, 0.0, pz]
    ground_x = head[0] - head[2] * ax[0] / ax[2]
    assert ground_x == pytest.approx(d["geometry"]["wheelbase_m"] + d["geometry"]["trail_m"])
    # the articulation at the design position puts the wheels at their design centres
    centres, axes, parts = s.articulate(lambda name, default: default)
    assert centres[0] == pytest.approx(rear.centre, abs=1e-9) and centres[1] == pytest.approx(front.centre, abs=1e-9)
    assert axes[1] == pytest.approx(ax) and [p[0] for p in parts] == ["cylinder", "box"]


@pytest.mark.parametrize("name", [p.stem for p in sorted((ROOT / "configs" / "vehicles").glob("*.toml"))])
def test_the_page_and_the_scene_draw_one_description(name, tmp_path):
    """Every vehicle describes how it is drawn (rtsim.vehicle.kit.drawing); the page gets it from the
    service's config reply (its file, else the reported config, as JSON: non-finite numbers null) as the
    Foxglove scene gets it from the served sim."""
    import json

    from bridge.payloads import encode_json
    from rtsim.vehicle.registry import open_vehicle
    from rtsim.viewer.scene import describe

    opened = open_vehicle(ROOT / "configs" / "vehicles" / f"{name}.toml")
    drawing = opened.kind.drawing(opened)
    reported = json.loads(encode_json({"vehicle": opened.config.model_dump(mode="json")}))["vehicle"]
    config = {"vehicle": reported, "options": {"vehicle": str(opened.path)}}
    assert describe(config)["shape"] == drawing.page()
    elsewhere = tmp_path / "another_machine" / f"{name}.toml"          # a recording made elsewhere
    assert vehicle_drawing(reported, elsewhere) == (opened.name, drawing.page())
    if name == "xbw":                                                   # the service's default vehicle
        assert describe({"vehicle": reported})["shape"] == drawing.page()
    assert [w.name for w in drawing.wheels] and all(w.radius > 0 for w in drawing.wheels)


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
    """What the page's controls mean comes from the vehicle's one declaration of what a person may drive
    (rtsim.vehicle.kit.user_inputs), for every shipped vehicle: each user channel in exactly one group,
    driven by one of the page's three controls, its value at a full control inside the channel's range;
    every control drives something. The service sends it (``user_inputs`` in its configuration) and the
    page's scene turns it into the page's control groups, the same channels and full values."""
    import json

    from rtsim.vehicle.registry import open_vehicle
    from rtsim.viewer.scene import describe

    vehicle = open_vehicle(ROOT / "configs" / "vehicles" / f"{name}.toml")
    inputs = vehicle.user_inputs
    sent = json.loads(json.dumps(inputs.as_json()))           # as the config answer carries it
    page = describe({"vehicle": vehicle.config.model_dump(mode="json"), "user_inputs": sent})
    got = [c for g in page["controls"] for c in g["channels"]]
    assert sorted(c["channel"] for c in got) == sorted(inputs.names)
    assert {c["control"] for c in got} == {"throttle", "brake", "steer"}
    table = inputs.table()
    for c in got:
        lo, hi, _unit, _meaning = table[c["channel"]]
        assert 0.0 < c["full_scale"] and lo <= c["sign"] * c["full_scale"] <= hi, c
        assert c["sign"] * c["full_scale"] == inputs.full_scales()[c["channel"]]
    assert [g["name"] for g in page["controls"]] == [g.name for g in inputs.groups]
    assert all(g["release"] in ("hold", "hand_back") for g in page["controls"])
    assert page["plots"] == list(inputs.plots) and page["plots"]


def test_a_config_without_user_inputs_gives_nothing_to_drive():
    """A service (or a recording) that does not declare its user inputs: no control group, no default
    plot (the page turns driving off and says why)."""
    from rtsim.viewer.scene import describe

    cfg, _ = load_vehicle(ROOT / "configs" / "vehicles" / "xbw.toml")
    page = describe({"vehicle": cfg.model_dump(mode="json")})
    assert page["controls"] == [] and page["plots"] == []


def test_the_motorcycles_full_keys():
    """The motorcycle's full throttle key is 40 % (wide open lifts its front wheel); its full brake key
    0.5 g of deceleration, 80 % of it on the front: the calipers' torques over the wheel radii, against
    the machine's weight with its rider (275 kg); the full lean key 30 degrees, right key leaning right."""
    from rtsim.vehicle.registry import open_vehicle

    vehicle = open_vehicle(ROOT / "configs" / "vehicles" / "motorcycle.toml")
    cfg, full = vehicle.config, vehicle.user_inputs.full_scales()
    assert full["throttle_cmd"] == 0.4
    front = full["brake_pressure_front_cmd"] * cfg.brakes.front_nm_per_kpa / cfg.front_wheel.radius_m
    rear = full["brake_pressure_rear_cmd"] * cfg.brakes.rear_nm_per_kpa / cfg.rear_wheel.radius_m
    assert front + rear == pytest.approx(0.5 * 9.81 * 275.0, rel=1e-9)
    assert front == pytest.approx(4 * rear, rel=1e-9)
    assert full["roll_angle_demand"] == pytest.approx(np.radians(30.0), rel=1e-12)
