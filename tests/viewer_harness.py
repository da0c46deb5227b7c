"""Helpers for the browser tests of `rtsim view`: the headless browser (Debian's chromium driven by
Playwright with that executable; never a browser download) and the view server run in a thread.

``chromium_path()`` (rtsim.viewer.browser) finds the browser. ``./tools/test`` installs Debian's ``chromium`` package when it is missing and it may (root, apt-get);
elsewhere the browser tests skip, naming what to install."""
from __future__ import annotations

import asyncio
import shutil
import threading
from contextlib import contextmanager

import playwright.sync_api as playwright_api      # the test extra (a hard dependency of the suite)
import pytest

from rtsim.viewer.browser import CHROMIUM_ARGS, NO_CHROMIUM, chromium_path
from waits import EVENT

def require_page_libraries() -> None:
    """Skip (no npm on this machine to install them) or fail (set-up not run) without the page's libraries."""
    from rtsim.errors import RtsimError
    from rtsim.viewer.server import check_libraries

    try:
        check_libraries()
    except RtsimError as exc:
        if shutil.which("npm") is None:
            pytest.skip(f"{exc} (and npm is not installed here)")
        raise


def launch(playwright):
    exe = chromium_path()
    if exe is None:
        pytest.skip(NO_CHROMIUM)
    return playwright.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)


class ViewThread:
    """A ViewServer (rtsim.viewer.server) on a free port of 127.0.0.1, in a thread with its own event loop:
    of a live service (``vehicle_id``, ``connect``) or of recordings (``recordings``: MCAP paths)."""

    def __init__(self, vehicle_id: str | None = None, connect: list[str] | None = None, timeout: float = 60.0,
                 recordings=(), token: str | None = None):
        from rtsim.viewer.recording import Recording
        from rtsim.viewer.relay import Relay
        from rtsim.viewer.server import ViewServer

        relay = Relay(vehicle_id, connect) if not recordings else None
        self.server = ViewServer(relay, "127.0.0.1", 0, recordings=[Recording(r) for r in recordings], token=token)
        self._started = threading.Event()
        self._loop = None
        self._stop = None
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()
        if not self._started.wait(timeout):
            raise RuntimeError("rtsim view server did not start")
        self.base_url = f"http://127.0.0.1:{self.server.port}/"
        self.url = self.base_url + (f"?token={token}" if token else "")     # as `rtsim view` prints it

    async def _run(self):
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        await self.server.serve(self._stop, lambda s: self._started.set())

    def close(self) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10.0)
        self.server.close()


def open_page(browser, url: str, width: int = 1280, height: int = 720):
    """A new page of ``browser`` at ``url``, its console messages and page errors collected in ``logs``, returned
    once the page has drawn its first state sample: (page, logs)."""
    pg = browser.new_page(viewport={"width": width, "height": height})
    logs: list = []
    pg.on("console", lambda m: logs.append((m.type, m.text)))
    pg.on("pageerror", lambda e: logs.append(("pageerror", str(e))))
    pg.goto(url)
    pg.wait_for_function("window.rtsimView && window.rtsimView.pose !== null", timeout=EVENT * 1000)
    return pg, logs


def sim_time(pg) -> float:
    """The simulation time (s) of the last state sample the page drew."""
    return float(pg.evaluate("rtsimView.pose.t"))


#: s of simulated time the page must advance by within EVENT s of wall time while a wait lasts: a loaded
#: machine may run the service many times slower than real time, a stopped clock does not advance at all
PROGRESS_S = 0.5


class SimStalled(AssertionError):
    """The page's simulated time stopped: no PROGRESS_S of it within EVENT s of wall time."""


def wait_sim(pg, t: float) -> None:
    """Until the page has drawn a state sample of simulation time >= t, however slowly the machine runs the
    service, as long as the page's time keeps advancing: SimStalled when it does not advance by PROGRESS_S
    (or reach t) within EVENT s of wall time (a service that stopped, a motorcycle that fell: its clock
    stops; a page that stopped drawing)."""
    now = float(pg.evaluate("rtsimView.pose ? rtsimView.pose.t : -1"))     # no sample drawn yet: -1
    while now < t:
        goal = min(t, now + PROGRESS_S)
        try:
            pg.wait_for_function(f"rtsimView.pose && rtsimView.pose.t >= {goal}", timeout=EVENT * 1000, polling=50)
        except playwright_api.TimeoutError:
            raise SimStalled(f"the page's simulated time stayed below {goal:.3f} s (from {now:.3f} s) for "
                             f"{EVENT:g} s of wall time, waiting for {t:.3f} s") from None
        now = float(pg.evaluate("rtsimView.pose.t"))


#: what the page's input reads once a key's ramp is full
FULL_KEY = {"ArrowUp": "throttle >= 1", "ArrowDown": "brake >= 1", "ArrowLeft": "steer <= -1",
            "ArrowRight": "steer >= 1"}

STARVED = ("the page was starved on this loaded machine: its drive requests came more than the service's "
           "hold (1 s of wall time) apart {n} times, and each time the channels went back (the lapses are in "
           "the recording); the key-by-key criteria need an unbroken hold")


def drive_reply(pg) -> dict:
    """The service's reply to a drive request the page sent from now on (its ``sim_time``: when the values
    it carried were applied; ``user.lapses``: hand-backs so far for want of a request)."""
    seq = pg.evaluate("rtsimView.drive.seq")
    pg.wait_for_function(f"rtsimView.drive.last && rtsimView.drive.last.seq >= {seq}", timeout=EVENT * 1000)
    return pg.evaluate("rtsimView.drive.last")


def press_full(pg, key: str) -> dict:
    """Press ``key`` and wait until the page's ramp of it is full and the service has applied it: the reply to
    the request that carried the full key, or a later one (drive_reply). Under load the page's view of the
    simulated clock and its requests both lag the service: spans are measured from the reply's sim_time."""
    pg.keyboard.down(key)
    pg.wait_for_function(f"rtsimView.input.{FULL_KEY[key]}", timeout=EVENT * 1000)
    return drive_reply(pg)


def lapses(reply: dict) -> int:
    return int(reply["user"].get("lapses", 0))


@contextmanager
def served_page(vehicle_id: str, endpoint: str):
    """A browser page of `rtsim view` (a ViewThread) of the service at ``endpoint``, once it has drawn its first
    state sample: (page, logs); the page, browser, Playwright and view server closed on exit."""
    import playwright.sync_api as playwright_api

    view = pw = browser = None
    try:
        view = ViewThread(vehicle_id, [endpoint])
        pw = playwright_api.sync_playwright().start()
        browser = launch(pw)
        yield open_page(browser, view.url)
    finally:
        if browser is not None:
            browser.close()
        if pw is not None:
            pw.stop()
        if view is not None:
            view.close()
