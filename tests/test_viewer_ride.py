"""`rtsim view` rides the motorcycle: headless Chromium (Debian's, driven by Playwright) opens the page of a
served motorcycle (realtime, recorded; its rider on the figure-eight at 12 m/s) and the keyboard leans it,
opens the throttle and brakes. The page scales each key by what the motorcycle says its controls mean
(rtsim.vehicle.motorcycle.inputs: 40 % throttle, 30 degrees of lean, the brakes for 0.5 g) and takes
over only the channels of the key's group; the recording is the evidence.

One service, one view server and one browser for the module (the tests ride on, one after the other).
Waits are bounded by the simulated time the page reports (waits.py bounds them in wall time, generously,
never asserted); every criterion is on recorded samples and their simulated time stamps.
"""
from __future__ import annotations

import math
import os
from contextlib import contextmanager

import numpy as np
import playwright.sync_api  # noqa: F401  (the test extra: a hard dependency of the suite)
import pytest

from service_harness import ServiceProcess, free_port
from viewer_harness import (NO_CHROMIUM, STARVED, SimStalled, chromium_path, drive_reply, lapses, press_full,
                            require_page_libraries, served_page, sim_time, wait_sim)

LEAN = math.radians(30.0)            # the lean demand at full key (rtsim.vehicle.motorcycle.inputs)
THROTTLE = 0.4                       # the throttle at full key
G = 9.81


@pytest.fixture(scope="module")
def moto(tmp_path_factory):
    require_page_libraries()
    if chromium_path() is None:
        pytest.skip(NO_CHROMIUM)
    rec = tmp_path_factory.mktemp("ride") / "moto.mcap"
    zport = free_port()
    svc = ServiceProcess("virtual", f"rtsim-view-moto-{os.getpid()}", "--vehicle", "configs/vehicles/motorcycle.toml",
                         "--zenoh-listen", f"tcp/127.0.0.1:{zport}", "--record", str(rec), "--mode", "realtime")
    try:
        with served_page("motorcycle", f"tcp/127.0.0.1:{zport}") as (pg, logs):
            yield pg, logs, rec
    finally:
        svc.stop()
        svc.close()



#: lapses a test of this module saw (its ride and the rest share one service: a starved page's lapses step the
#: lean demand, and the motorcycle may have fallen since, which stops its clock)
_STARVED: list[int] = []


def _skip_starved(n: int):
    _STARVED.append(n)
    pytest.skip(STARVED.format(n=n))


@contextmanager
def _starved_if_stalled(pg, lapsed: int):
    """A stopped clock (SimStalled) after lapses beyond ``lapsed`` is the starved page's doing (each lapse
    steps the lean demand; a fall stops the clock): skip as STARVED; without a lapse it fails."""
    try:
        yield
    except SimStalled:
        n = lapses(drive_reply(pg)) - lapsed
        if n:
            _skip_starved(n)
        raise


def _hold(pg, key: str, seconds: float) -> tuple[float, float]:
    """Hold ``key`` until ``seconds`` of simulated time have passed, without a lapse, since the service
    applied the page's full key (press_full); returns the page's simulated times at key down and key up. A
    lapse starts the hold again (twice at most, then the test skips: STARVED); so does a clock that stopped
    after a lapse (_starved_if_stalled)."""
    t0 = sim_time(pg)
    applied = press_full(pg, key)
    for _attempt in range(3):
        with _starved_if_stalled(pg, lapses(applied)):
            wait_sim(pg, max(applied["sim_time"], sim_time(pg)) + seconds)
        t1 = sim_time(pg)
        now = drive_reply(pg)
        if lapses(now) == lapses(applied):
            pg.keyboard.up(key)
            return t0, t1
        applied = now
    pg.keyboard.up(key)
    _skip_starved(lapses(now))


def _recorded(rec):
    from bridge.mcap_recorder import read_recording

    msgs, _info = read_recording(rec)
    state = [m.data for m in msgs["rtsim/motorcycle/state"]]
    col = lambda name: np.array([s[name] for s in state], dtype=float)      # noqa: E731
    return msgs, col


def test_the_motorcycle_leans_with_the_key(moto):
    """Holding the right arrow key asks for a lean to the right (the user's ``roll_angle_demand``, 30 deg at
    full key); the recorded roll angle follows the recorded demand (the lean loop in the step holds it),
    and the key takes over the lean only: the rider keeps the throttle and the brakes."""
    pg, _logs, rec = moto
    assert pg.evaluate("rtsimView.info.kind") == "two_wheeler"
    _down, t1 = _hold(pg, "ArrowRight", 2.5)       # (the roll is asserted from 2 s after the full demand on)
    wait_sim(pg, t1 + 1.5)                        # the recorder closes a chunk every second
    msgs, col = _recorded(rec)
    changes = [m.data for m in msgs["rtsim/motorcycle/user"]]
    demand = [c for c in changes if c["time"] <= t1 and (c["channels"].get("roll_angle_demand") or 0.0) > 0.0]
    assert demand and demand[-1]["channels"]["roll_angle_demand"] == pytest.approx(LEAN, abs=1e-3)
    assert all(c["channels"].get(n) is None for c in demand
               for n in ("throttle_cmd", "brake_pressure_front_cmd", "brake_pressure_rear_cmd"))
    t, roll = col("time"), col("roll_angle")
    full = demand[-1]["time"]                                # from here on the demand is the full 30 deg
    hold = (t >= full + 2.0) & (t <= t1)    # the lean loop settles within 2 s (1 s: 0.47 of 0.52 rad)
    assert hold.sum() >= 20, (full, t1)
    assert np.all(np.abs(roll[hold] - LEAN) < 0.05), roll[hold]
    status = [m.data for m in msgs["rtsim/motorcycle/status"] if full <= m.data["time"] <= t1]
    assert status and all(s["drivers"]["roll_angle_demand"] == "user" for s in status)
    assert all(s["drivers"]["throttle_cmd"] == "rider" for s in status)     # the rider holds the speed


def test_the_keyboard_rides_the_motorcycle_for_20_s_without_a_fall(moto):
    """Riding on from where the page is (the service's recording keeps one clock): lean right, lean left,
    straight, throttle, brake, straight, for at least 20 s of simulated time, every key held at full after
    its ramp. The recording shows: no model fault (a fall is one) and the service running throughout; the
    roll bounded by the demand's 30 deg plus 0.1 rad; the front tyre loaded throughout (the throttle at
    full key does not lift the front wheel: wide open did, and the motorcycle fell within 3 s); the speed
    held between half and twice the start's 12 m/s (the rider keeps it whenever no throttle or brake key
    is down: those groups are handed back on release); the throttle at full key is 40 %, and it and the
    brakes act only while their keys drive them."""
    pg, _logs, rec = moto
    if _STARVED:
        pytest.skip(STARVED.format(n=_STARVED[-1]) + " (in an earlier test of this module)")
    start = sim_time(pg)
    lapsed = lapses(drive_reply(pg))
    keys = {}
    with _starved_if_stalled(pg, lapsed):
        keys["right"] = _hold(pg, "ArrowRight", 2.0)
        keys["left"] = _hold(pg, "ArrowLeft", 2.0)
        wait_sim(pg, sim_time(pg) + 1.5)
        keys["throttle"] = _hold(pg, "ArrowUp", 2.0)
        wait_sim(pg, sim_time(pg) + 2.0)
        keys["brake"] = _hold(pg, "ArrowDown", 1.0)
        wait_sim(pg, max(start + 20.0, sim_time(pg) + 2.0))
    end = sim_time(pg)
    lapsed = lapses(drive_reply(pg)) - lapsed     # each one a step in the lean demand, back to the rider's
    if lapsed:
        _skip_starved(lapsed)
    wait_sim(pg, end + 1.5)                                  # the recorder closes a chunk every second
    assert end - start >= 20.0
    msgs, col = _recorded(rec)
    t = col("time")
    ride = (t >= start) & (t <= end)
    assert ride.sum() >= 0.9 * 100 * (end - start)           # state at 100 Hz, all of the ride recorded
    status = [m.data for m in msgs["rtsim/motorcycle/status"] if start <= m.data["time"] <= end]
    assert status and all(s["run_state"] == "running" and not s.get("model_fault") for s in status)
    roll, speed, fzf = col("roll_angle")[ride], col("speed")[ride], col("tyre_fz_front")[ride]
    assert np.all(np.isfinite(roll)) and np.max(np.abs(roll)) < LEAN + 0.1, np.max(np.abs(roll))
    assert np.min(fzf) > 0.2 * np.median(fzf), np.min(fzf)
    v0 = speed[0]
    assert 10.0 < v0 < 14.0 and np.all((speed > 0.5 * v0) & (speed < 2.0 * v0)), (speed.min(), speed.max())
    changes = [m.data for m in msgs["rtsim/motorcycle/user"] if start <= m.data["time"] <= end]
    thr = [c["channels"].get("throttle_cmd") for c in changes]
    assert max(x for x in thr if x is not None) == pytest.approx(THROTTLE, abs=1e-4)
    t_up, t_release = keys["throttle"]
    # the throttle is the user's only from its key to its release: every change carrying it comes after the
    # key went down and before the brake key (pressed 2 s of simulated time after the release); the
    # release's ramp is the page's, in wall time, so under load its changes land later in simulated time
    # than the page saw the release, and are bounded by the next key instead
    first_brake = min(c["time"] for c in changes if (c["channels"].get("brake_pressure_front_cmd") or 0.0) > 0.0)
    for c in changes:
        if c["channels"].get("throttle_cmd") is not None:
            assert t_up - 0.2 <= c["time"] < first_brake, c
    assert changes[-1]["channels"].get("throttle_cmd") is None
    assert changes[-1]["channels"].get("brake_pressure_front_cmd") is None
    brake = [c["channels"].get("brake_pressure_front_cmd") or 0.0 for c in changes]
    assert max(brake) > 0.0
    # the speed falls while the brake key is down, the throttle raised it while its key was
    t_b0, t_b1 = keys["brake"]
    assert np.interp(t_b1, t, col("speed")) < np.interp(t_b0, t, col("speed")) - 1.0
    assert np.interp(t_release, t, col("speed")) > np.interp(t_up, t, col("speed")) + 1.0


def test_no_console_errors(moto):
    pg, logs, _rec = moto
    errors = [text for kind, text in logs if kind in ("error", "pageerror")]
    errors += pg.evaluate("rtsimView.errors")
    assert errors == []
