"""Foxglove, live and recorded: a service in process (realtime, CAN on a loopback hub started here, Zenoh
off) serves a Foxglove WebSocket on a free port and records an MCAP. A client speaking the Foxglove
WebSocket protocol (subprotocol foxglove.sdk.v1, formerly foxglove.websocket.v1: serverInfo, advertise,
subscribe, binary message data) receives the scene, transform, road and state topics; the recording holds the same scene topics
with the foxglove SDK's protobuf schemas. Each scene message is decoded with the schema it declares (a
FileDescriptorSet, parsed by the protobuf library: independent of the SDK that wrote it) and the
vehicle's pose in it is compared with the state published at the same stamp, through the definitions
of the state's angles (rtsim.channels: the car's Euler z-y-x; the two-wheeler's from its frame's axes).
Waits are bounded (tests/waits.py), never criteria."""
from __future__ import annotations

import base64
import json
import math
import struct
import threading
import time

import numpy as np
import pytest
# Hard dependencies (websockets: rtsim's; protobuf: the test extra's): missing, they fail the module.
import websockets.sync.client as websockets_sync
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from drivers.scenario import load_scenario
from bridge.can_bus import LoopbackHub
from rtsim.errors import ConfigError
from rtsim.service.server import ServeOptions, Service
from service_harness import free_port
from waits import EVENT, HUB_START

# The Foxglove WebSocket protocol's names: the SDK's server speaks it as foxglove.sdk.v1 (the same messages
# as foxglove.websocket.v1, renamed); a client offers both, as the Foxglove app does.
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")


def message_class(schema_name: str, fds_bytes: bytes):
    """The protobuf message class of `schema_name` built from a FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(fds_bytes)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def rotation(q) -> np.ndarray:
    """Rotation matrix of a quaternion message (x, y, z, w)."""
    x, y, z, w = q.x, q.y, q.z, q.w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    assert n == pytest.approx(1.0, abs=1e-9)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def euler_zyx(roll, pitch, yaw) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def check_pose(kind: str, pose, state: dict) -> None:
    """`pose` (position, orientation messages) is the state's pose (rtsim.channels' definitions)."""
    p = pose.position
    assert (p.x, p.y, p.z) == pytest.approx((state["pos_x"], state["pos_y"], state["pos_z"]), abs=1e-9)
    r = rotation(pose.orientation)
    if kind == "car":       # Euler z-y-x
        assert np.abs(r - euler_zyx(state["roll_angle"], state["pitch_angle"], state["yaw_angle"])).max() < 1e-9
    else:                   # the rear frame's axes: roll from its y axis, yaw from its heading, pitch of its x
        v, x = r[:, 1], r[:, 0]
        assert math.asin(v[2]) == pytest.approx(state["roll_angle"], abs=1e-9)
        assert math.atan2(-v[0], v[1]) == pytest.approx(state["yaw_angle"], abs=1e-9)
        assert math.asin(-x[2]) == pytest.approx(state["pitch_angle"], abs=1e-9)


def stamp(ts) -> int:
    return ts.seconds * 1_000_000_000 + ts.nanos     # google.protobuf.Timestamp


def run_service(tmp_path, scenario: str, vehicle: str | None, live, seconds: float = 2.0):
    """Run a service with a recording (and a Foxglove server when `live` is a function of it, called
    while it runs); returns (path of the recording, what `live` returned, the closing summary)."""
    hub = LoopbackHub(0, start_timeout=HUB_START)
    path = tmp_path / f"{scenario}.mcap"
    svc = Service(ServeOptions(scenario=scenario, vehicle=vehicle, can_interface="remote", can_channel=hub.channel,
                               start_hub=False, zenoh=False, record=path,
                               foxglove_port=free_port() if live else None), out=lambda *a: None)
    summary = {}
    th = threading.Thread(target=lambda: summary.update(svc.run()), daemon=True)
    th.start()
    got = None
    try:
        if live:
            got = live(svc)
        else:
            deadline = time.monotonic() + EVENT
            while svc.loop.sim_time < seconds and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        svc.stop()
        th.join(EVENT)
        hub.close()
    assert not th.is_alive()
    return path, got, summary


def foxglove_client(url: str, topics: tuple[str, ...], until) -> dict:
    """Connect as a Foxglove client: serverInfo, advertise, subscribe to `topics`; collect
    {topic: [(log time ns, payload bytes)]} until `until(collected)` (bounded by EVENT s)."""
    out: dict[str, list] = {t: [] for t in topics}
    with websockets_sync.connect(url, subprotocols=list(SUBPROTOCOLS), max_size=None, open_timeout=EVENT) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        info = json.loads(ws.recv(timeout=EVENT))
        assert info["op"] == "serverInfo", info
        channels = {}
        deadline = time.monotonic() + EVENT
        while not all(t in channels for t in topics):
            assert time.monotonic() < deadline, f"not advertised: {set(topics) - set(channels)}"
            msg = ws.recv(timeout=EVENT)
            if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                for ch in json.loads(msg)["channels"]:
                    channels[ch["topic"]] = ch
        subs = {k + 1: channels[t] for k, t in enumerate(topics)}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": ch["id"]}
                                                                  for i, ch in subs.items()]}))
        while not until(out):
            assert time.monotonic() < deadline + EVENT, {t: len(v) for t, v in out.items()}
            msg = ws.recv(timeout=EVENT)
            if isinstance(msg, bytes) and msg[0] == 0x01:          # message data
                sub, t_ns = struct.unpack_from("<IQ", msg, 1)
                out[subs[sub]["topic"]].append((t_ns, msg[13:]))
    return {"channels": {t: channels[t] for t in topics}, "messages": out}


@pytest.fixture(scope="module")
def car_session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fox")
    vid = "xbw"
    topics = tuple(f"rtsim/{vid}/{k}" for k in ("scene", "tf", "road", "state", "sensors"))

    def live(svc):
        assert svc.vehicle_id == vid
        return foxglove_client(svc.foxglove.url, topics,
                               lambda got: len(got[topics[0]]) >= 50 and len(got[topics[3]]) >= 50 and got[topics[2]])
    return run_service(tmp, "steady_circle", None, live)


def test_live_scene_and_state_topics(car_session):
    _path, got, summary = car_session
    ch, msgs = got["channels"], got["messages"]
    assert summary["foxglove"]["errors"] == 0 and summary["scene_errors"] == 0
    for key in ("state", "sensors"):            # the Zenoh/MCAP topics, JSON with their JSON schemas
        c = ch[f"rtsim/xbw/{key}"]
        assert c["encoding"] == "json" and c["schemaEncoding"] == "jsonschema"
    scene_ch = ch["rtsim/xbw/scene"]
    assert (scene_ch["encoding"], scene_ch["schemaName"], scene_ch["schemaEncoding"]) == (
        "protobuf", "foxglove.SceneUpdate", "protobuf")
    SceneUpdate = message_class("foxglove.SceneUpdate", base64.b64decode(scene_ch["schema"]))
    FrameTransforms = message_class("foxglove.FrameTransforms", base64.b64decode(ch["rtsim/xbw/tf"]["schema"]))
    states = {t: json.loads(d) for t, d in msgs["rtsim/xbw/state"]}
    for t, d in states.items():
        assert t == round(d["time"] * 1e9)
    matched = 0
    for t, data in msgs["rtsim/xbw/scene"]:
        (entity,) = SceneUpdate.FromString(data).entities
        assert stamp(entity.timestamp) == t and entity.frame_id == "world" and entity.id == "xbw"
        assert len(entity.cylinders) == 4 and len(entity.cubes) == 5      # four wheels, body and spokes
        if t in states:
            check_pose("car", entity.arrows[0].pose, states[t])
            # the wheels stand on the flat road (z = 0), neither through it nor floating: each centre its
            # tyre's radius up, less a deflection of at most 3 cm
            for wheel in entity.cylinders:
                assert -0.03 < wheel.pose.position.z - 0.5 * wheel.size.x < 0.0
            matched += 1
    assert matched >= 20
    for t, data in msgs["rtsim/xbw/tf"]:
        (tf,) = FrameTransforms.FromString(data).transforms
        assert (tf.parent_frame_id, tf.child_frame_id, stamp(tf.timestamp)) == ("world", "xbw", t)
    # the car moves: the scene follows it
    xs = [json.loads(d)["pos_x"] for _t, d in msgs["rtsim/xbw/state"]]
    assert max(xs) - min(xs) > 1.0
    (road,) = SceneUpdate.FromString(msgs["rtsim/xbw/road"][0][1]).entities
    assert road.id == "road" and road.frame_id == "world" and len(road.triangles[0].indices) == 6


def recorded_scenes(path, vid: str):
    """(scene messages decoded with their recorded schema, tf messages, states by log time, the
    schemas by topic) of a recording, read with the mcap library."""
    from mcap.reader import make_reader

    schemas, scenes, tfs, states = {}, [], [], {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        classes = {}
        for schema, channel, message in reader.iter_messages():
            schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
            if channel.topic == f"rtsim/{vid}/state":
                states[message.log_time] = json.loads(message.data)
            elif channel.topic in (f"rtsim/{vid}/scene", f"rtsim/{vid}/tf", f"rtsim/{vid}/road"):
                assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
                cls = classes.get(schema.name) or classes.setdefault(schema.name, message_class(schema.name, schema.data))
                msg = cls.FromString(message.data)
                if channel.topic.endswith("/scene"):
                    scenes.append((message.log_time, msg))
                elif channel.topic.endswith("/tf"):
                    tfs.append((message.log_time, msg))
    return scenes, tfs, states, schemas


def test_recording_holds_the_scene(car_session):
    path, _got, _summary = car_session
    scenes, tfs, states, schemas = recorded_scenes(path, "xbw")
    assert schemas["rtsim/xbw/scene"] == ("foxglove.SceneUpdate", "protobuf", "protobuf")
    assert schemas["rtsim/xbw/tf"] == ("foxglove.FrameTransforms", "protobuf", "protobuf")
    assert schemas["rtsim/xbw/road"] == ("foxglove.SceneUpdate", "protobuf", "protobuf")
    assert len(scenes) == len(states) and len(tfs) == len(states) >= 50       # one per state sample (100 Hz)
    for t, msg in scenes:
        (entity,) = msg.entities
        assert stamp(entity.timestamp) == t
        check_pose("car", entity.arrows[0].pose, states[t])
    for t, msg in tfs:
        (tf,) = msg.transforms
        check_pose("car", type("P", (), {"position": tf.translation, "orientation": tf.rotation}), states[t])


def test_two_wheeler_recording(tmp_path):
    path, _got, summary = run_service(tmp_path, "motorcycle_hil", "motorcycle", None, seconds=1.0)
    assert summary["scene_errors"] == 0
    scenes, _tfs, states, _schemas = recorded_scenes(path, "motorcycle")
    assert len(scenes) == len(states) >= 50
    for t, msg in scenes:
        (entity,) = msg.entities
        assert len(entity.cylinders) == 3 and len(entity.cubes) == 4     # two wheels and the fork; body, arm, spokes
        check_pose("two_wheeler", entity.arrows[0].pose, states[t])
        rear, front = entity.cylinders[1:]
        for wheel in (rear, front):             # upright-ish on the flat road: centre about a radius up
            assert wheel.pose.position.z == pytest.approx(0.5 * wheel.size.x, abs=0.05)


def test_foxglove_binds_loopback_unless_allowed():
    with pytest.raises(ConfigError, match="allow-remote"):
        ServeOptions(foxglove_port=8765, foxglove_host="192.0.2.1").check()
    ServeOptions(foxglove_port=8765, foxglove_host="192.0.2.1", foxglove_allow_remote=True).check()
    ServeOptions(foxglove_port=8765, foxglove_host="::1").check()


def test_offline_run_recording_holds_the_scene(tmp_path):
    """`rtsim run ... --out X.mcap` (bridge.mcap_log.write_run with the run's simulation): the same scene
    topics, one scene per 10 ms of the run, each with the pose of the state row of its time."""
    from bridge.mcap_log import write_run
    from rtsim.service.server import resolve_scenario
    from rtsim.vehicle.offline import prepare, run

    sim, sc = prepare(None, load_scenario(resolve_scenario("step_steer_80kph"), check_files=True))
    res = run(sim, sc)
    path = tmp_path / "run.mcap"
    write_run(path, res.columns, res.data, sim.vm.config.id, sim.vm.channels, sim=sim)
    scenes, tfs, states, schemas = recorded_scenes(path, sim.vm.config.id)
    assert schemas[f"rtsim/{sim.vm.config.id}/road"] == ("foxglove.SceneUpdate", "protobuf", "protobuf")
    times = sorted(states)
    assert len(scenes) == len(tfs) == pytest.approx(sc.duration / 0.01, abs=2)
    yaw = []
    for t, msg in scenes:
        (entity,) = msg.entities
        check_pose("car", entity.arrows[0].pose, states[t])
        yaw.append(states[t]["yaw_angle"])
    assert times[0] <= scenes[0][0] and max(yaw) - min(yaw) > 0.5       # the step steer turns the car


def test_new_scenario_brings_its_road(tmp_path):
    """load_scenario (lockstep, in process): the recording gets the new scenario's road when simulation
    time restarts, and the scenes after it carry the state's pose on that road (a 5 % grade: the road's
    corners rise 5 cm per metre along x)."""
    from rtsim.service.server import ROOT

    grade = tmp_path / "grade.toml"
    grade.write_text((ROOT / "configs" / "scenarios" / "hil_flat.toml").read_text().replace(
        'road = "../roads/flat.toml"', f'road = "{(ROOT / "configs" / "roads" / "grade_5pct.toml").as_posix()}"'))
    hub = LoopbackHub(0, start_timeout=HUB_START)
    path = tmp_path / "two.mcap"
    svc = Service(ServeOptions(mode="lockstep", can_interface="remote", can_channel=hub.channel, start_hub=False,
                               zenoh=False, record=path, scenario_dirs=[tmp_path]), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    try:
        assert svc.control({"op": "step", "n": 50})["ok"]
        assert svc.control({"op": "load_scenario", "scenario": "grade"})["ok"]
        assert svc.control({"op": "step", "n": 50})["ok"]
    finally:
        svc.stop()
        th.join(EVENT)
        hub.close()
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        roads = [(m.log_time, message_class(s.name, s.data).FromString(m.data))
                 for s, _c, m in make_reader(fh).iter_messages(topics=["rtsim/xbw/road"], log_time_order=False)]
    assert len(roads) == 2
    for (_t, msg), slope in zip(roads, (0.0, 0.05)):
        (entity,) = msg.entities
        pts = entity.triangles[0].points
        dz = pts[1].z - pts[0].z
        assert dz == pytest.approx(slope * (pts[1].x - pts[0].x), abs=1e-9)
    with open(path, "rb") as fh:            # in recording order: the log times restart with the scenario
        got = {"scene": [], "state": []}
        for s, c, m in make_reader(fh).iter_messages(topics=["rtsim/xbw/scene", "rtsim/xbw/state"],
                                                     log_time_order=False):
            key = c.topic.rsplit("/", 1)[1]
            got[key].append((m.log_time, message_class(s.name, s.data).FromString(m.data) if key == "scene"
                             else json.loads(m.data)))
    assert len(got["scene"]) == len(got["state"]) == 10
    for (t, scene), (ts, state) in zip(got["scene"], got["state"]):
        assert t == ts
        check_pose("car", scene.entities[0].arrows[0].pose, state)
    # the car stands on the new road: nose up the 5 % grade (pitch positive nose down), as the road drawn
    assert got["state"][0][1]["pitch_angle"] == pytest.approx(0.0, abs=0.01)
    assert got["state"][-1][1]["pitch_angle"] == pytest.approx(-math.atan(0.05), abs=0.01)


def test_survey_mesh_road_scene():
    """The campus survey road as one triangle list: every vertex and triangle of the road model."""
    import numpy as np
    from bridge.scene import road_scene, topic_schemas
    from rtsim.road.config import load_road
    from rtsim.service.server import ROOT

    road = load_road(ROOT / "configs" / "roads" / "campus.toml")
    name, _enc, data = topic_schemas()["road"]
    (entity,) = message_class(name, data).FromString(road_scene(road)).entities
    (tri,) = entity.triangles
    assert np.allclose([[p.x, p.y, p.z] for p in tri.points], road.vert, atol=0, rtol=0)
    assert list(tri.indices) == [int(i) for i in np.asarray(road.tri).ravel()]


def test_offline_two_wheeler_recording_holds_the_scene(tmp_path):
    """`rtsim run` of a motorcycle scenario to MCAP: the two-wheeler's scene every 10 ms with the pose of
    its state row, the wheels about a radius above the road, and the counter-steer's turn in the yaw."""
    from rtsim.service.server import resolve_scenario
    from bridge.mcap_log import write_run
    from rtsim.vehicle.motorcycle.offline import CHANNELS, prepare, run, scene_source

    ride, sc = prepare(None, load_scenario(resolve_scenario("motorcycle_counter_steer"), check_files=True))
    res = run(ride, sc)
    vid = ride.sim.mm.config.id
    path = tmp_path / "moto.mcap"
    write_run(path, res.columns, res.data, vid, CHANNELS, sim=scene_source(ride.sim.mm))
    scenes, tfs, states, schemas = recorded_scenes(path, vid)
    assert schemas[f"rtsim/{vid}/scene"] == ("foxglove.SceneUpdate", "protobuf", "protobuf")
    assert len(scenes) == len(tfs) == pytest.approx(sc.duration / 0.01, abs=2)
    yaw = []
    for t, msg in scenes:
        (entity,) = msg.entities
        check_pose("two_wheeler", entity.arrows[0].pose, states[t])
        for wheel in entity.cylinders[1:]:
            assert wheel.pose.position.z == pytest.approx(0.5 * wheel.size.x, abs=0.05)
        yaw.append(states[t]["yaw_angle"])
    assert max(yaw) - min(yaw) > 0.1
