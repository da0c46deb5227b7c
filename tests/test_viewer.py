"""`rtsim view` in a real browser: headless Chromium (Debian's, driven by Playwright) opens the page of a
running service (realtime, recorded), holds the throttle key and steers; the service's recording shows
the car accelerating and turning left, driven by the user's command source; a screenshot shows the car
(pixel statistics against the same view with the car hidden); the page draws at least 30 frames a
second and reports no console error.

One service, one view server and one browser page for the module (a few tens of seconds in all). The
waits are bounded by simulated time the page reports and by generous wall-clock limits (waits.py),
never asserted; the frame rate is the one figure the bar asks of the browser.
"""
from __future__ import annotations

import io
import os

import numpy as np
import playwright.sync_api as playwright_api      # the test extra (a hard dependency of the suite)
import pytest

from service_harness import ServiceProcess, free_port
from viewer_harness import NO_CHROMIUM, ViewThread, chromium_path, launch, require_page_libraries
from waits import EVENT

SHOT = os.environ.get("RTSIM_VIEW_SCREENSHOT")     # save the test's screenshot here (the README's)


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    require_page_libraries()
    if chromium_path() is None:
        pytest.skip(NO_CHROMIUM)
    rec = tmp_path_factory.mktemp("view") / "view.mcap"
    zport = free_port()
    svc = ServiceProcess("virtual", f"rtsim-view-test-{os.getpid()}", "--zenoh-listen", f"tcp/127.0.0.1:{zport}",
                         "--record", str(rec), "--mode", "realtime")
    try:
        yield svc, f"tcp/127.0.0.1:{zport}", rec
    finally:
        svc.stop()
        svc.close()


@pytest.fixture(scope="module")
def page(service):
    _, endpoint, _ = service
    view = ViewThread("xbw", [endpoint])
    pw = playwright_api.sync_playwright().start()
    browser = None
    try:
        browser = launch(pw)
        pg = browser.new_page(viewport={"width": 1280, "height": 720})
        logs = []
        pg.on("console", lambda m: logs.append((m.type, m.text)))
        pg.on("pageerror", lambda e: logs.append(("pageerror", str(e))))
        pg.goto(view.url)
        pg.wait_for_function("window.rtsimView && window.rtsimView.pose !== null", timeout=EVENT * 1000)
        yield pg, logs, view
    finally:
        if browser is not None:
            browser.close()
        pw.stop()
        view.close()


def _sim_time(pg) -> float:
    return float(pg.evaluate("rtsimView.pose.t"))


def _wait_sim(pg, t: float) -> None:
    """Until the page has drawn a state sample of simulation time >= t (bounded by EVENT s of wall time)."""
    pg.wait_for_function(f"rtsimView.pose && rtsimView.pose.t >= {t}", timeout=EVENT * 1000, polling=50)


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def test_the_page_draws_the_car_while_the_service_runs(page):
    """The page keeps drawing new frames while the car's simulated time advances, and shows the car.

    The frame rate itself (30 frames/s or more from software rendering) is a wall-clock figure: it is measured by
    `rtsim bench --suite service --pages 1`, not asserted here, so a loaded machine cannot fail this test."""
    pg, _logs, _view = page
    _wait_sim(pg, _sim_time(pg) + 1.0)
    frames0, t0 = pg.evaluate("rtsimView.frames"), _sim_time(pg)
    _wait_sim(pg, t0 + 1.0)
    frames1 = pg.evaluate("rtsimView.frames")
    assert frames1 > frames0, f"no frame drawn over 1 s of simulated time ({frames0} -> {frames1})"
    with_car = pg.screenshot()
    pg.evaluate("rtsimView.setVehicleVisible(false)")
    pg.wait_for_timeout(300)
    empty = pg.screenshot()
    pg.evaluate("rtsimView.setVehicleVisible(true)")
    a, b = _pixels(with_car), _pixels(empty)
    assert a.std() > 20.0, "the screenshot is blank"
    red = lambda im: (im[..., 0] > 140) & (im[..., 1] < 80) & (im[..., 2] < 80)       # the car's paint
    changed = np.abs(a - b).max(axis=2) > 40
    h, w = changed.shape
    assert red(a).sum() - red(b).sum() > 0.002 * h * w, "no car paint in the view"
    assert changed.mean() > 0.005, "the car changes less than 0.5 % of the view"
    ys, xs = np.nonzero(changed)
    # the chase camera looks at the car: what it changes lies about the middle of the view
    assert 0.25 * w < np.median(xs) < 0.75 * w and 0.25 * h < np.median(ys) < 0.85 * h


def test_the_keyboard_drives_the_car_through_the_service(page, service):
    from bridge.mcap_recorder import read_recording

    pg, _logs, _view = page
    _, _, rec = service
    t0 = _sim_time(pg)
    pg.keyboard.down("ArrowUp")
    _wait_sim(pg, t0 + 3.0)
    t1 = _sim_time(pg)
    pg.keyboard.down("ArrowLeft")
    _wait_sim(pg, t1 + 2.0)
    t2 = _sim_time(pg)
    pg.keyboard.up("ArrowUp")
    pg.keyboard.up("ArrowLeft")
    latency = pg.evaluate("rtsimView.latency")
    if SHOT:                                            # the README's picture: the car turning, the plots live
        os.makedirs(os.path.dirname(SHOT) or ".", exist_ok=True)
        pg.screenshot(path=SHOT)
    _wait_sim(pg, t2 + 1.5)                             # the recorder closes a chunk every second
    msgs, _info = read_recording(rec)
    state = [m.data for m in msgs["rtsim/xbw/state"]]
    t = np.array([s["time"] for s in state])
    col = lambda name: np.array([s[name] for s in state], dtype=float)
    speed, yaw, yaw_rate, thr = col("speed"), col("yaw_angle"), col("yaw_rate"), col("throttle_angle")
    before = t <= t0
    assert before.any() and np.max(speed[before][-50:]) < 0.5      # held by the watchdog's brake pressure
    accel = (t >= t0 + 0.5) & (t <= t1)
    assert np.max(thr[accel]) > 0.5, "the throttle never opened"
    speed_t1 = np.interp(t1, t, speed)
    assert speed_t1 > 3.0, f"speed {speed_t1:.2f} m/s after {t1 - t0:.1f} s of throttle"
    turn = (t >= t1 + 0.7) & (t <= t2)
    assert np.all(yaw_rate[turn] > 0.0), "steering left must turn the car left (yaw rate > 0, ISO 8855)"
    dyaw = np.interp(t2, t, np.unwrap(yaw)) - np.interp(t1, t, np.unwrap(yaw))
    assert dyaw > 0.2, f"yaw changed by {dyaw:.3f} rad while steering left"
    status = [m.data for m in msgs["rtsim/xbw/status"] if t1 <= m.data["time"] <= t2]
    assert status and all(set(s["drivers"].values()) == {"user"} for s in status)
    assert latency["key_to_model_ms"] is not None and latency["server_to_screen_ms"] is not None


def test_a_recording_replays_with_the_recorded_poses(page, service):
    """`rtsim view A.mcap B.mcap`: the service's recording (its complete chunks, while it still records)
    twice side by side; seeking to a time between two samples shows, for both cars, the pose of the last
    sample at or before it, exactly; play moves on."""
    from bridge.mcap_recorder import read_recording

    pg, logs, _view = page
    _, _, rec = service
    replay = ViewThread(recordings=[rec, rec])
    pg2 = pg.context.browser.new_page(viewport={"width": 1280, "height": 720})
    pg2.on("console", lambda m: logs.append((m.type, m.text)))
    pg2.on("pageerror", lambda e: logs.append(("pageerror", str(e))))
    try:
        pg2.goto(replay.url)
        pg2.wait_for_function("window.rtsimView && rtsimView.replayLoaded === 2", timeout=EVENT * 1000)
        n = pg2.evaluate("rtsimView.replay.recs[0].state.length")
        msgs, _ = read_recording(rec)
        state = [m.data for m in msgs["rtsim/xbw/state"]][:n]     # what the server read (the file grows)
        k = int(0.8 * n)
        assert state[k]["speed"] > 1.0                           # the car is moving there
        t = 0.5 * (state[k]["time"] + state[k + 1]["time"])       # between two samples
        pg2.evaluate(f"rtsimView.seek({t!r})")
        pg2.wait_for_function(f"rtsimView.poses.length === 2 && rtsimView.poses.every(p => p.t === {state[k]['time']!r})",
                              timeout=EVENT * 1000)
        poses = pg2.evaluate("rtsimView.poses")
        names = {"x": "pos_x", "y": "pos_y", "z": "pos_z", "roll": "roll_angle", "pitch": "pitch_angle",
                 "yaw": "yaw_angle", "speed": "speed"}
        for p in poses:
            assert {k2: p[k2] for k2 in names} == {k2: state[k][c] for k2, c in names.items()}
        pg2.click("#play")
        pg2.wait_for_function(f"rtsimView.poses[0].t > {state[k]['time']!r}", timeout=EVENT * 1000)
    finally:
        pg2.close()
        replay.close()


GAMEPAD = """
localStorage.setItem('rtsim.view.gamepad', JSON.stringify({
  steer: {axis: 2, invert: true}, throttle: {axis: 1, button: -1, invert: false, pedal: true},
  brake: {axis: -1, button: 6, invert: false, pedal: false}, deadzone: 0.1}));
const pad = {index: 0, id: 'test wheel', connected: true, axes: [0.9, 0.0, -0.55, 0.0],
             buttons: Array.from({length: 8}, () => ({value: 0, pressed: false}))};
navigator.getGamepads = () => [pad];
"""


def test_a_gamepad_drives_with_the_mapping_the_browser_remembers(page):
    """A wheel seen through the Gamepad API (a stand-in object here: no device on this machine) with a
    mapping kept in localStorage (steering on axis 2, inverted; a pedal on axis 1 from -1 released to 1
    pressed; dead zone 0.1): the service receives what that mapping gives, steering-wheel angle
    -((0.55 - 0.1) / 0.9) * 3 rad, throttle ((0 + 1) / 2 - 0.1) / 0.9 of the wide-open 1.4 rad, no brake."""
    pg, logs, view = page
    pg.click("#release")                                  # the keyboard's page hands the car back
    pg2 = pg.context.browser.new_page(viewport={"width": 800, "height": 450})
    pg2.on("console", lambda m: logs.append((m.type, m.text)))
    pg2.on("pageerror", lambda e: logs.append(("pageerror", str(e))))
    pg2.add_init_script(GAMEPAD)
    try:
        pg2.goto(view.url)
        pg2.wait_for_function("rtsimView.drive.last && rtsimView.drive.last.ok && "
                              "'steering_wheel_angle_cmd' in rtsimView.drive.last.user.channels", timeout=EVENT * 1000)
        ch = pg2.evaluate("rtsimView.drive.last.user.channels")
        assert ch["steering_wheel_angle_cmd"] == pytest.approx(-(0.45 / 0.9) * 3.0)
        assert ch["throttle_angle_cmd"] == pytest.approx((0.4 / 0.9) * 1.4)
        assert ch["brake_pressure_cmd"] == 0.0
        assert pg2.evaluate("rtsimView.drive.last.drivers.throttle_angle_cmd") == "user"
    finally:
        pg2.evaluate("document.getElementById('release').click()")
        pg2.close()


def test_only_its_own_pages_may_open_the_websocket(page):
    """The WebSocket drives the car: a browser page of another origin (any site open in the engineer's
    browser) is refused; the server's own origin and clients that send none (tools) get the scene."""
    import json

    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    _pg, _logs, view = page
    url = f"ws://127.0.0.1:{view.server.port}/ws"
    with pytest.raises(InvalidStatus, match="403"):
        connect(url, origin="http://evil.example:8000", open_timeout=EVENT).close()
    for origin in (f"http://127.0.0.1:{view.server.port}", None):
        with connect(url, origin=origin, open_timeout=EVENT) as ws:
            hello = json.loads(ws.recv(timeout=EVENT))
            assert hello["type"] == "hello" and hello["info"]["vehicle_id"] == "xbw"


def test_the_motorcycle_leans_with_the_key(page, tmp_path):
    """A two-wheeler served (its rider on the figure-eight at 12 m/s): the page draws the two-wheeler, and
    holding the right arrow key asks for a lean to the right (the user's ``roll_angle_demand``, 30 deg at
    full key); the recorded roll angle follows the recorded demand (the lean loop in the step holds it)."""
    from bridge.mcap_recorder import read_recording

    pg0, logs, _view = page
    rec = tmp_path / "moto.mcap"
    zport = free_port()
    svc = ServiceProcess("virtual", f"rtsim-view-moto-{os.getpid()}", "--vehicle", "configs/vehicles/motorcycle.toml",
                         "--zenoh-listen", f"tcp/127.0.0.1:{zport}", "--record", str(rec), "--mode", "realtime")
    view = pg = None
    try:
        view = ViewThread("motorcycle", [f"tcp/127.0.0.1:{zport}"])
        pg = pg0.context.browser.new_page(viewport={"width": 800, "height": 450})
        pg.on("console", lambda m: logs.append((m.type, m.text)))
        pg.on("pageerror", lambda e: logs.append(("pageerror", str(e))))
        pg.goto(view.url)
        pg.wait_for_function("window.rtsimView && window.rtsimView.pose !== null", timeout=EVENT * 1000)
        assert pg.evaluate("rtsimView.info.kind") == "two_wheeler"
        t0 = _sim_time(pg)
        pg.keyboard.down("ArrowRight")
        _wait_sim(pg, t0 + 2.5)
        # the key ramps on the page's frames (wall clock, at most 0.1 s a frame): wait until it is full,
        # then hold it 1.5 s of simulated time (the roll is asserted from 1 s after the full demand on)
        pg.wait_for_function("rtsimView.input.steer >= 1.0", timeout=EVENT * 1000)
        _wait_sim(pg, _sim_time(pg) + 1.5)
        t1 = _sim_time(pg)
        pg.keyboard.up("ArrowRight")
        _wait_sim(pg, t1 + 1.5)                             # the recorder closes a chunk every second
    finally:
        if pg is not None:
            pg.evaluate("document.getElementById('release').click()")
            pg.close()
        if view is not None:
            view.close()
        svc.stop()
        svc.close()
    msgs, _info = read_recording(rec)
    changes = [m.data for m in msgs["rtsim/motorcycle/user"]]
    demand = [c for c in changes if c["time"] <= t1 and (c["channels"]["roll_angle_demand"] or 0.0) > 0.0]
    assert demand and demand[-1]["channels"]["roll_angle_demand"] == pytest.approx(0.5236, abs=1e-3)   # 30 deg
    state = [m.data for m in msgs["rtsim/motorcycle/state"]]
    t = np.array([s["time"] for s in state])
    roll = np.array([s["roll_angle"] for s in state])
    full = demand[-1]["time"]                                # from here on the demand is the full 30 deg
    hold = (t >= full + 1.0) & (t <= t1)
    assert hold.sum() >= 20, (full, t1)
    assert np.all(np.abs(roll[hold] - 0.5236) < 0.05), roll[hold]
    status = [m.data for m in msgs["rtsim/motorcycle/status"] if full <= m.data["time"] <= t1]
    assert status and all(s["drivers"]["roll_angle_demand"] == "user" for s in status)


def test_no_console_errors(page):
    pg, logs, _view = page
    errors = [text for kind, text in logs if kind in ("error", "pageerror")]
    errors += pg.evaluate("rtsimView.errors")
    assert errors == []
