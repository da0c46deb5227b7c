"""An OpenDRIVE road in the Foxglove scene and in `rtsim view`: `rtsim run` of the shipped example
(configs/scenarios/opendrive_curve.toml) to an MCAP, whose road scene carries the lanes' mesh and the road
marks (one triangle list per colour); the page of a service serving the example draws the lanes and their marks, which show in a screenshot (pixel statistics against the same view with the marks
hidden). `RTSIM_OPENDRIVE_SCREENSHOT=docs/opendrive.png` saves the screenshot (the one in docs/opendrive.md)."""
from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import playwright.sync_api  # noqa: F401  (the test extra: a hard dependency of the suite)
import pytest

from service_harness import ServiceProcess, free_port
from viewer_harness import NO_CHROMIUM, chromium_path, require_page_libraries, served_page, sim_time, wait_sim

ROOT = Path(__file__).resolve().parents[1]
SHOT = os.environ.get("RTSIM_OPENDRIVE_SCREENSHOT")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("xodr")
    out = folder / "opendrive_curve.mcap"
    text = (ROOT / "configs" / "scenarios" / "opendrive_curve.toml").read_text()   # the example, cut to 1 s
    text = text.replace("duration = 14.0", "duration = 1.0").replace('"../', f'"{(ROOT / "configs").as_posix()}/')
    sc = folder / "opendrive_curve.toml"
    sc.write_text(text)
    res = subprocess.run([sys.executable, "-m", "rtsim.cli", "run", "--scenario", str(sc), "--out", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout + res.stderr
    return out


def test_the_foxglove_road_scene_carries_the_lanes_and_marks(recording):
    """The recording's road topic (the Foxglove scene, decoded with its recorded schema): the lanes' mesh as
    the contact query's triangles, then the marks, one triangle list per colour, together all of them."""
    from mcap.reader import make_reader

    from rtsim.road.config import opendrive_mesh
    from rtsim.road.opendrive import road_markings
    from test_foxglove import message_class

    with open(recording, "rb") as fh:
        road = [(schema, message) for schema, channel, message in make_reader(fh).iter_messages()
                if channel.topic.endswith("/road")]
    assert road, "no road topic in the recording"
    schema, message = road[0]
    (entity,) = message_class(schema.name, schema.data).FromString(message.data).entities
    tri = entity.triangles
    odr, mesh = opendrive_mesh(ROOT / "configs" / "roads" / "opendrive_curve.toml")
    marks = road_markings(odr)
    assert len(tri[0].indices) == mesh.triangles.size                    # the lanes: the contact mesh
    assert len(tri) == 1 + len(set(marks["colour"]))
    assert sum(len(t.indices) for t in tri[1:]) == marks["triangles"].size
    pts = np.array([[p.x, p.y, p.z] for t in tri[1:] for p in t.points])
    assert len(pts) == len(marks["vertices"])
    assert np.allclose(np.sort(pts, axis=0), np.sort(marks["vertices"], axis=0))


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def test_the_page_draws_the_lanes_and_their_marks():
    """`rtsim view` of a service serving the example scenario: the page draws the OpenDRIVE road's mesh with its
    marks; the screenshot holds the white marks (near-white pixels that vanish with the marks hidden)."""
    require_page_libraries()
    if chromium_path() is None:
        pytest.skip(NO_CHROMIUM)
    from rtsim.road.config import opendrive_mesh
    from rtsim.road.opendrive import road_markings

    odr, _ = opendrive_mesh(ROOT / "configs" / "roads" / "opendrive_curve.toml")
    zport = free_port()
    svc = ServiceProcess("virtual", f"rtsim-xodr-view-{os.getpid()}", "--scenario", "opendrive_curve",
                         "--zenoh-listen", f"tcp/127.0.0.1:{zport}", "--mode", "realtime")
    try:
        with served_page("xbw", f"tcp/127.0.0.1:{zport}") as (pg, logs):
            assert pg.evaluate("rtsimView.marksDrawn()") == len(road_markings(odr)["triangles"])
            wait_sim(pg, sim_time(pg) + 1.0)            # the chase camera settles behind the car
            shot = pg.screenshot()
            pg.evaluate("rtsimView.setMarksVisible(false)")
            pg.wait_for_timeout(300)
            bare = pg.screenshot()
            pg.evaluate("rtsimView.setMarksVisible(true)")
            if SHOT:
                pg.wait_for_timeout(300)
                pg.screenshot(path=SHOT)
            assert not [m for m in logs if m[0] in ("error", "pageerror")], logs
    finally:
        svc.stop()
        svc.close()
    a, b = _pixels(shot), _pixels(bare)
    white = lambda im: (im.min(axis=2) > 200) & (np.ptp(im, axis=2) < 30)
    gone = white(a) & ~white(b)
    h, w = gone.shape
    print(f"mark pixels: {gone.mean() * 100:.2f} % of the view")
    assert gone.mean() > 0.002, "no road marks in the view"
    ys, _xs = np.nonzero(gone)
    assert np.median(ys) > 0.35 * h                   # on the road ahead of and under the camera
