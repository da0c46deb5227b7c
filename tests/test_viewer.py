"""`rtsim view` in a real browser: headless Chromium (Debian's, driven by Playwright) opens the page of a
running service (realtime, recorded), holds the throttle key and steers; the service's recording shows
the car accelerating and turning left, driven by the user's command source, each key taking over its own
channels; a screenshot shows the car (pixel statistics against the same view with the car hidden); every
panel fits its box, the axes' tick labels tell ticks apart, and the page reports no console error. The
motorcycle's ride from the keyboard is tests/test_viewer_ride.py.

One service, one view server and one browser page for the module (a few tens of seconds in all). The
waits are bounded by simulated time the page reports and by generous wall-clock limits (waits.py),
never asserted; the frame rate is measured by `rtsim bench --suite service --pages 1`.
"""
from __future__ import annotations

import io
import os

import numpy as np
import playwright.sync_api as playwright_api      # the test extra (a hard dependency of the suite)
import pytest

from service_harness import ServiceProcess, free_port
from viewer_harness import (NO_CHROMIUM, STARVED, ViewThread, chromium_path, drive_reply, lapses, launch, open_page,
                            press_full, require_page_libraries, sim_time, wait_sim)
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
        pg, logs = open_page(browser, view.url)
        yield pg, logs, view
    finally:
        if browser is not None:
            browser.close()
        pw.stop()
        view.close()



def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def test_the_page_draws_the_car_while_the_service_runs(page):
    """The page keeps drawing new frames while the car's simulated time advances, and shows the car.

    The frame rate itself (30 frames/s or more from software rendering) is a wall-clock figure: it is measured by
    `rtsim bench --suite service --pages 1`, not asserted here, so a loaded machine cannot fail this test."""
    pg, _logs, _view = page
    wait_sim(pg, sim_time(pg) + 1.0)
    frames0, t0 = pg.evaluate("rtsimView.frames"), sim_time(pg)
    wait_sim(pg, t0 + 1.0)
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
    t0 = sim_time(pg)
    # each key held for a span of the service's clock from when it applied the full key (press_full)
    up = press_full(pg, "ArrowUp")
    wait_sim(pg, max(up["sim_time"], sim_time(pg)) + 3.0)
    t1 = sim_time(pg)
    left = press_full(pg, "ArrowLeft")
    wait_sim(pg, max(left["sim_time"], sim_time(pg)) + 2.0)
    t2 = sim_time(pg)
    lapsed = lapses(drive_reply(pg)) - lapses(up)
    pg.keyboard.up("ArrowUp")
    pg.keyboard.up("ArrowLeft")
    if lapsed:                     # the throttle and the steering went back to the watchdog's safe values
        pytest.skip(STARVED.format(n=lapsed))
    latency = pg.evaluate("rtsimView.latency")
    if SHOT:                                            # the README's picture: the car turning, the plots live
        os.makedirs(os.path.dirname(SHOT) or ".", exist_ok=True)
        pg.screenshot(path=SHOT)
    wait_sim(pg, t2 + 1.5)                             # the recorder closes a chunk every second
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
    # the turn from the steering the service applied (the key reaches it later than the page's clock on a
    # busy machine): the wheel at least 0.05 rad left, then 0.7 s for the yaw to build up
    steer = col("steering_wheel_angle")
    left = np.nonzero((t >= t1) & (steer > 0.05))[0]
    assert left.size and t[left[0]] < t2 - 1.0, "the steering wheel never turned left while ArrowLeft was held"
    turn = (t >= t[left[0]] + 0.7) & (t <= t2)
    assert np.all(yaw_rate[turn] > 0.0), "steering left must turn the car left (yaw rate > 0, ISO 8855)"
    dyaw = np.interp(t2, t, np.unwrap(yaw)) - np.interp(t1, t, np.unwrap(yaw))
    assert dyaw > 0.2, f"yaw changed by {dyaw:.3f} rad while steering left"
    # the up key took the pedals (throttle and brake: one group), the left key the steering, each from
    # its own press on: before the left key the steering stayed with the watchdog
    users = [m.data for m in msgs["rtsim/xbw/user"]]
    pedals = min(c["time"] for c in users if c["channels"].get("throttle_angle_cmd") is not None)
    steer = min(c["time"] for c in users if c["channels"].get("steering_wheel_angle_cmd") is not None)
    assert pedals < t1 <= steer + 0.2
    # a page stalled for USER_HOLD (1 s of wall time, a loaded machine) lets the user's channels lapse: the
    # service records that (cause "lapse") and the page's next request drives again; those spans are the
    # service's rule working, not the keys' mapping, and are left out below
    sent = [c for c in users if c["time"] >= pedals and c["cause"] != "lapse"]
    assert all(c["channels"].get("brake_pressure_cmd") == 0.0 for c in sent), \
        f"the up key's brake pressure (time, Pa): {[(c['time'], c['channels']) for c in sent]}"
    edges = sorted((c["time"], c["cause"] == "lapse") for c in users)
    lapsed = lambda t: any(lap for _, lap in [e for e in edges if e[0] < t][-1:])
    status = [m.data for m in msgs["rtsim/xbw/status"]]
    early = [(s["time"], s["drivers"]) for s in status if pedals < s["time"] < steer]
    assert all(d["steering_wheel_angle_cmd"] != "user" for _, d in early), f"before the left key: {early}"
    during = [(s["time"], s["drivers"]) for s in status if steer < s["time"] <= t2 and not lapsed(s["time"])]
    assert during and all(set(d.values()) == {"user"} for _, d in during), \
        f"drivers while both keys were held: {[x for x in during if set(x[1].values()) != {'user'}]}"
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
        # a sample where the car moves (the keyboard's drive, before the watchdog's brakes stop it again;
        # where in the recording depends on how fast this machine ran the tests before this one)
        moving = [i for i in range(n - 1) if state[i]["speed"] > 1.0]
        assert moving, "the car never moved faster than 1 m/s in the recording"
        k = moving[len(moving) // 2]
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


PANELS = """(() => {
  const out = [];
  for (const id of ['hud', 'plots', 'timeline', 'settings']) {
    const el = document.getElementById(id);
    if (!el || el.hidden || !el.offsetParent) continue;
    const box = el.getBoundingClientRect();
    out.push({id, scroll: el.scrollWidth, client: el.clientWidth, kind: 'panel'});
    for (const c of el.querySelectorAll('table, div, canvas, select, span')) {
      const r = c.getBoundingClientRect();
      if (r.width === 0) continue;
      out.push({id: id + ' > ' + (c.id || c.className || c.tagName), left: r.left - box.left, right: box.right - r.right,
                scroll: c.scrollWidth, client: c.clientWidth, kind: c.tagName});
    }
  }
  return out;
})()"""


def _fits(pg) -> list:
    """What does not fit its panel: a panel whose content is wider than its box (scrollWidth >
    clientWidth), or an element reaching out of its panel's box (by more than half a pixel)."""
    bad = []
    for e in pg.evaluate(PANELS):
        if e["kind"] == "panel" and e["scroll"] > e["client"]:
            bad.append(e)
        elif e["kind"] != "panel" and (e["left"] < -0.5 or e["right"] < -0.5):
            bad.append(e)
    return bad


def test_every_panel_fits_its_box(page):
    """The loop-health table, the latency table, the plots and the rest: nothing wider than its panel,
    with the loop's health filled (status received) and the widest figures the table can show
    (a stall of seconds, every fault named)."""
    pg, _logs, _view = page
    pg.wait_for_function("document.querySelectorAll('#health tr').length >= 4", timeout=EVENT * 1000)
    assert _fits(pg) == []
    # the widest status the panel can show: large numbers, every fault flag set
    pg.evaluate(r"""(() => {
      const tr = document.querySelector('#health');
      tr.innerHTML = tr.innerHTML.replace(/<td class="v">[^<]*<\/td>/g, '<td class="v">12345.67 ms</td>')
        .replace(/faults: [^<]*/, 'faults: model_fault, watchdog_timeout, bus_off, e2e_counter, e2e_crc, overrun_burst, stall');
    })()""")
    assert _fits(pg) == []


def test_axis_tick_labels_tell_ticks_apart(page):
    """Ticks 1e-4 apart near zero read differently (uPlot's default kept three decimals: "0, 0, 0"):
    as many decimals as the step needs, or an SI prefix; each label reads back as its tick's value to
    within a hundredth of the step. And the charts use these labels (their drawn labels)."""
    pg, _logs, _view = page
    prefix = {"p": 1e-12, "n": 1e-9, "µ": 1e-6, "m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9}
    for lo, step, n in ((0.0, 1e-4, 4), (-2e-4, 1e-4, 5), (0.0, 0.25, 5), (0.0, 2e-7, 4), (1e5, 5e4, 4),
                        (-3.0, 1.0, 7), (0.0, 0.002, 5), (0.0, 2.5e-5, 5)):
        splits = [lo + k * step for k in range(n)]
        labels = pg.evaluate(f"rtsimView.tickLabels({splits!r}, {step!r})")
        assert len(set(labels)) == n, (splits, labels)
        for v, lab in zip(splits, labels):
            scale = prefix.get(lab[-1], 1.0)
            got = float(lab[:-1] if lab[-1] in prefix else lab) * scale
            assert abs(got - v) <= 0.01 * step, (splits, labels)
    drawn = pg.evaluate("rtsimView.plots.chart.axes[1]._values")
    assert drawn and len(set(drawn)) == len(drawn), drawn


def test_the_fault_panel_arms_and_clears_a_fault_in_the_service(page, service):
    """The faults panel (the catalogue from the service): a bad target is refused with the service's one-line
    reason; a valid fault is armed (control op inject_fault), then cleared (clear_fault); the recording has its
    onset and end; the panel still fits its box with the longest reply."""
    from bridge.mcap_recorder import read_recording

    pg, _logs, _view = page
    _, _, rec = service
    kinds = pg.evaluate("[...document.querySelectorAll('#fault-kind option')].map(o => o.value)")
    assert "stuck_value" in kinds and "bus_off" in kinds and "power_stage_off" in kinds
    pg.select_option("#fault-kind", "offset")
    pg.fill("#fault-target", "accel_q")
    pg.fill("#fault-params", "offset=2.5")
    pg.click("#fault-arm")
    pg.wait_for_function("document.getElementById('fault-reply').textContent.includes('accel_q')", timeout=EVENT * 1000)
    assert "not a sensor channel" in pg.text_content("#fault-reply")
    assert _fits(pg) == []
    pg.fill("#fault-target", "accel_x")
    pg.fill("#fault-params", "offset=2.5 duration=30")
    pg.click("#fault-arm")
    pg.wait_for_function("document.getElementById('fault-reply').textContent.includes('(offset on accel_x)')",
                         timeout=EVENT * 1000)
    fid = pg.input_value("#fault-id")
    assert fid.startswith("view-") and "armed" in pg.text_content("#fault-reply")
    wait_sim(pg, sim_time(pg) + 0.5)
    pg.click("#fault-clear")
    pg.wait_for_function("document.getElementById('fault-reply').textContent.includes('ended')", timeout=EVENT * 1000)
    t = sim_time(pg)
    wait_sim(pg, t + 1.5)                               # the recorder closes a chunk every second
    msgs, _ = read_recording(rec)
    ev = [(m.data["id"], m.data["event"]) for m in msgs["rtsim/xbw/faults"]]
    assert ev == [(fid, "onset"), (fid, "end")]


def test_a_replay_marks_the_faults_on_its_time_bar(page, service):
    """The recording of the fault the panel armed (the test before): a replay shows its onset and end on the
    time bar and names it while it is active."""
    from bridge.mcap_recorder import read_recording

    pg, logs, _view = page
    _, _, rec = service
    msgs, _ = read_recording(rec)
    ev = [m.data for m in msgs["rtsim/xbw/faults"]]
    assert [e["event"] for e in ev] == ["onset", "end"]
    replay = ViewThread(recordings=[rec])
    pg2 = pg.context.browser.new_page(viewport={"width": 1280, "height": 720})
    pg2.on("console", lambda m: logs.append((m.type, m.text)))
    pg2.on("pageerror", lambda e: logs.append(("pageerror", str(e))))
    try:
        pg2.goto(replay.url)
        pg2.wait_for_function("window.rtsimView && rtsimView.replayLoaded === 1", timeout=EVENT * 1000)
        marks = pg2.evaluate("[...document.querySelectorAll('#fault-marks span')].map(e => [e.className, e.title])")
        assert [c for c, _ in marks] == ["onset", "end"] and ev[0]["id"] in marks[0][1]
        for t, want in ((0.5 * (ev[0]["time"] + ev[1]["time"]), [ev[0]["id"]]), (ev[0]["time"] - 0.2, []),
                        (ev[1]["time"] + 0.2, [])):
            pg2.evaluate(f"rtsimView.seek({t!r})")
            pg2.wait_for_function(f"JSON.stringify(rtsimView.activeFaults) === {str(want).replace(chr(39), chr(34))!r}",
                                  timeout=EVENT * 1000)
        assert _fits(pg2) == []
    finally:
        pg2.close()
        replay.close()


def test_no_console_errors(page):
    pg, logs, _view = page
    errors = [text for kind, text in logs if kind in ("error", "pageerror")]
    errors += pg.evaluate("rtsimView.errors")
    assert errors == []
