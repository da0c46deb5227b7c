"""`rtsim view` off loopback (rtsim.viewer.cli.remote_policy, rtsim.viewer.server): an address off loopback is
refused without --web-allow-remote; with it a warning is printed and a random per-session token guards every
driving request (drive, reset): a page whose WebSocket URL lacks it, or carries a wrong one, may watch but
its driving requests are refused with a reason, counted and logged, and never reach the service. The
server here binds 127.0.0.1 only (tests stay on loopback) and is given a token as the CLI gives it off
loopback; the service is a stub that records the control requests it gets."""
from __future__ import annotations

import asyncio
import json
import threading

import pytest

from rtsim.errors import RtsimError
from rtsim.viewer import cli as view_cli
from viewer_harness import require_page_libraries

TOKEN = "tok-3f9a1c"


class _Client:
    def __init__(self):
        self.calls = []
        self.lock = threading.Lock()

    def control(self, op, timeout=10.0, **args):
        with self.lock:
            self.calls.append((op, args))
        return {"ok": True, "op": op}


class _Relay:
    """What ViewServer uses of a Relay: the Zenoh client (its control requests), batches, close."""

    def __init__(self):
        self.client = _Client()

    def batch(self, last):
        return json.dumps({"type": "data"})

    def config(self, timeout=10.0):
        raise AssertionError("the scene is given")

    def close(self):
        pass


def _serve_and_talk(token, talk):
    """Run a ViewServer (stub relay, ``token``) on a free port of 127.0.0.1 and ``await talk(server, url)``."""
    from rtsim.viewer.server import ViewServer

    require_page_libraries()
    relay = _Relay()
    server = ViewServer(relay, "127.0.0.1", 0, token=token)
    server._info = {"kind": "car", "stub": True}

    async def main():
        stop, up = asyncio.Event(), asyncio.Event()
        task = asyncio.create_task(server.serve(stop, lambda s: up.set()))
        await asyncio.wait_for(up.wait(), 30)
        try:
            await talk(server, f"ws://127.0.0.1:{server.port}/ws")
        finally:
            stop.set()
            await task

    try:
        asyncio.run(main())
    finally:
        server.close()
    return server, relay


async def _next(ws, kind):
    while True:
        m = json.loads(await asyncio.wait_for(ws.recv(), 30))
        if m["type"] == kind:
            return m


async def _drive_and_reset(url):
    from websockets.asyncio.client import connect

    async with connect(url) as ws:
        hello = await _next(ws, "hello")
        await ws.send(json.dumps({"type": "drive", "seq": 1, "throttle_angle_cmd": 0.1}))
        drive = (await _next(ws, "drive_ack"))["reply"]
        await ws.send(json.dumps({"type": "reset"}))
        reset = (await _next(ws, "reset_ack"))["reply"]
        await ws.send(json.dumps({"type": "fault", "op": "inject_fault",
                                  "args": {"id": "f", "kind": "bus_off", "target": "bus"}}))
        fault = (await _next(ws, "fault_ack"))["reply"]
        assert fault["ok"] is (hello["may_drive"] is True) and (fault["ok"] or "no valid session token" in fault["error"])
        await ws.send(json.dumps({"type": "pull"}))
        await _next(ws, "data")                            # watching is not refused
    return hello["may_drive"], drive, reset


def test_driving_needs_the_session_token(capsys):
    got = {}

    async def talk(server, url):
        for name, suffix in (("none", ""), ("wrong", "?token=tok-3f9a1d"), ("empty", "?token="),
                             ("right", f"?token={TOKEN}")):
            got[name] = await _drive_and_reset(url + suffix)
        got["refused"] = server.refused

    server, relay = _serve_and_talk(TOKEN, talk)
    for name in ("none", "wrong", "empty"):
        may, drive, reset = got[name]
        assert may is False, name
        for r in (drive, reset):
            assert r["ok"] is False and "no valid session token" in r["error"], (name, r)
    assert got["refused"] == 9
    may, drive, reset = got["right"]
    assert may is True and drive["ok"] and reset["ok"], got["right"]
    # only the page with the token reached the service
    assert [op for op, _ in relay.client.calls] == ["drive", "reset", "inject_fault"]
    assert relay.client.calls[0][1] == {"seq": 1, "throttle_angle_cmd": 0.1}
    log = [line for line in capsys.readouterr().err.splitlines() if "refused a" in line]
    assert len(log) == 3 and all("no valid session token" in line for line in log), log   # one line per page


def test_without_a_token_every_page_drives_as_before():
    got = {}

    async def talk(server, url):
        got["r"] = await _drive_and_reset(url)

    server, relay = _serve_and_talk(None, talk)
    may, drive, reset = got["r"]
    assert may is True and drive["ok"] and reset["ok"] and server.refused == 0
    assert [op for op, _ in relay.client.calls] == ["drive", "reset", "inject_fault"]
    assert relay.client.calls[2][1] == {"id": "f", "kind": "bus_off", "target": "bus"}


def test_bind_policy():
    for host in ("127.0.0.1", "127.0.0.2", "::1", "localhost"):
        assert view_cli.remote_policy(host, False) == (None, None), host
        assert view_cli.remote_policy(host, True) == (None, None), host
    for host in ("0.0.0.0", "::", "192.168.1.20", "bench-pc"):
        with pytest.raises(RtsimError, match=f"--bind {host}: not a loopback address.*--web-allow-remote"):
            view_cli.remote_policy(host, False)
        token, warning = view_cli.remote_policy(host, True)
        assert len(token) >= 20 and "warning" in warning and "token" in warning and host in warning
    tokens = {view_cli.remote_policy("0.0.0.0", True)[0] for _ in range(20)}
    assert len(tokens) == 20                                   # a fresh random token per session
    assert view_cli.page_url("192.168.1.20", 8470, "abc") == "http://192.168.1.20:8470/?token=abc"
    assert view_cli.page_url("127.0.0.1", 8470, None) == "http://127.0.0.1:8470/"
    assert view_cli.page_url("::1", 8470, None) == "http://[::1]:8470/"


def test_view_refuses_a_remote_bind_before_listening(capsys):
    from rtsim import cli

    rc = cli.main(["view", "--bind", "0.0.0.0", "--port", "0", "--duration", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--web-allow-remote" in err[0], err


def test_the_page_passes_its_token_on_and_a_page_without_it_only_watches():
    """In the browser, against a running service: the page opened at the printed URL (with the token) drives;
    one opened without it shows the car, has its driving controls off, and its reset is refused."""
    import os

    from playwright import sync_api as playwright_api

    from service_harness import ServiceProcess, free_port
    from viewer_harness import NO_CHROMIUM, ViewThread, chromium_path, launch
    from waits import EVENT

    require_page_libraries()
    if chromium_path() is None:
        pytest.skip(NO_CHROMIUM)
    zport = free_port()
    svc = ServiceProcess("virtual", f"rtsim-view-token-{os.getpid()}", "--zenoh-listen", f"tcp/127.0.0.1:{zport}",
                         "--mode", "realtime")
    view = pw = browser = None
    try:
        view = ViewThread("xbw", [f"tcp/127.0.0.1:{zport}"], token=TOKEN)
        assert view.url.endswith(f"/?token={TOKEN}")
        pw = playwright_api.sync_playwright().start()
        browser = launch(pw)
        ready = "window.rtsimView && window.rtsimView.pose !== null"
        bare = browser.new_page(viewport={"width": 640, "height": 360})
        bare.goto(view.base_url)
        bare.wait_for_function(ready, timeout=EVENT * 1000)
        assert bare.evaluate("['drive', 'takeover', 'release', 'reset'].every((id) => document.getElementById(id).disabled)")
        bare.evaluate("const b = document.getElementById('reset'); b.disabled = false; b.click()")
        bare.wait_for_function("(rtsimView.drive.error || '').includes('reset refused')", timeout=EVENT * 1000)
        refused = view.server.refused
        assert refused == 1
        good = browser.new_page(viewport={"width": 640, "height": 360})
        good.goto(view.url)
        good.wait_for_function(ready, timeout=EVENT * 1000)
        assert not good.evaluate("document.getElementById('drive').disabled")
        good.keyboard.down("ArrowUp")
        good.wait_for_function("rtsimView.drive.last && rtsimView.drive.last.ok === true", timeout=EVENT * 1000)
        good.keyboard.up("ArrowUp")
        good.evaluate("document.getElementById('release').click()")
        assert view.server.refused == refused
    finally:
        if browser is not None:
            browser.close()
        if pw is not None:
            pw.stop()
        if view is not None:
            view.close()
        svc.stop()
        svc.close()
