"""The headless browser `rtsim bench --suite service --pages N` and the browser tests open pages with:
Debian's ``chromium`` (``$RTSIM_CHROMIUM``, else ``chromium`` / ``chromium-browser`` on the PATH) driven by
Playwright with that executable; never a browser download. Software WebGL (SwiftShader): no GPU here."""
from __future__ import annotations

import os
import shutil

CHROMIUM_ARGS = ["--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                 "--disable-backgrounding-occluded-windows"]
NO_CHROMIUM = ("headless Chromium not found: install Debian's chromium package (as root: apt-get update && "
               "apt-get install -y chromium; ./tools/test does this by itself when run as root), or point "
               "RTSIM_CHROMIUM at a Chromium binary")


def chromium_path() -> str | None:
    env = os.environ.get("RTSIM_CHROMIUM")
    if env:
        return env if os.path.isfile(env) else None
    for name in ("chromium", "chromium-browser"):
        p = shutil.which(name)
        if p:
            return p
    return None
