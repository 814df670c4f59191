"""Headless Chromium on the editor page: what the browser tests and studies/editor_latency.py drive.

Debian's ``chromium`` through Debian's ``chromedriver`` and Selenium (all
installed by ``make setup``); nothing is downloaded at run time. Pointer
drags are real WebDriver input (trusted pointer events), not synthetic
JavaScript events, so the page sees what a mouse would give it.
"""
from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--hide-scrollbars",
         "--enable-unsafe-swiftshader")      # WebGL without a GPU (Chromium's software one) for the 3D view


class BrowserMissing(RuntimeError):
    """Chromium or its driver is not installed."""


def chrome(width: int = 1280, height: int = 860):
    """A headless Chromium (Selenium WebDriver) with a fresh profile; quit() removes the profile."""
    for exe, package in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not Path(exe).exists():
            raise BrowserMissing(f"{exe} is missing: install Debian's {package} (make setup installs chromium "
                                 "and chromium-driver)")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError as exc:
        raise BrowserMissing(f"selenium is missing ({exc}): install python3-selenium (make setup does)") from None
    profile = tempfile.mkdtemp(prefix="skelfem-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS + (f"--user-data-dir={profile}", f"--window-size={width},{height}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    try:
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    except Exception:
        shutil.rmtree(profile, ignore_errors=True)
        raise
    quit_ = driver.quit

    def quit():
        try:
            quit_()
        finally:
            shutil.rmtree(profile, ignore_errors=True)
    driver.quit = quit
    return driver


class Page:
    """The editor page in a WebDriver: state read through ``window.skelfemEditor``, real pointer drags."""

    def __init__(self, driver, url: str, timeout: float = 60.0):
        self.driver = driver
        driver.get(url)
        self.wait("S.ready && S.answer && S.answer.mesh && !S.inflight", timeout)

    # -- reading the page -------------------------------------------------------------------------------
    def js(self, expr: str, *args):
        return self.driver.execute_script(f"const S = window.skelfemEditor; return ({expr});", *args)

    def wait(self, expr: str, timeout: float = 30.0, *args):
        t_end = time.monotonic() + timeout
        while True:
            value = self.js(expr, *args)
            if value:
                return value
            if time.monotonic() > t_end:
                raise TimeoutError(f"page: waited {timeout:g} s for {expr}")
            time.sleep(0.02)

    def idle(self, timeout: float = 60.0) -> None:
        """Wait until no request is in flight or waiting, and the last one is painted."""
        self.wait("!S.inflight && !S.queued && S.inputs.length === 0", timeout)

    def tip(self, marker: str = "tip") -> np.ndarray:
        return np.array(self.js(f"S.answer.markers[{marker!r}].position"))

    def solves(self) -> int:
        return int(self.js("S.solves"))

    def screen(self, point_mm) -> tuple[float, float]:
        """Viewport pixel of a point in mm (the page's view)."""
        return tuple(self.js("(() => { const r = document.getElementById('view').getBoundingClientRect();"
                             " const q = px(arguments[0]); return [r.left + q[0], r.top + q[1]]; })()",
                             [float(v) for v in point_mm]))

    def handle3d(self, kind: str, **match) -> tuple[float, float]:
        """Viewport pixel of a 3D handle (``S.handles3d``, editor3d.js) of this kind whose other fields match
        (e.g. ``name="distal", axis=2`` or ``path=["markers", "tip"]``)."""
        found = self.js("(() => { const b = document.getElementById('view3d').getBoundingClientRect();"
                        " const m = arguments[1];"
                        " const h = S.handles3d.find((h) => h.kind === arguments[0] && Object.keys(m).every("
                        "(k) => JSON.stringify(h[k]) === JSON.stringify(m[k])));"
                        " return h ? [b.left + h.x, b.top + h.y] : null; })()", kind, match)
        if found is None:
            raise LookupError(f"page: no 3D handle {kind} {match}")
        return tuple(found)

    def center(self, css: str) -> tuple[float, float]:
        return tuple(self.js("(() => { const b = document.querySelector(arguments[0]).getBoundingClientRect();"
                             " return [b.left + b.width / 2, b.top + b.height / 2]; })()", css))

    def handle_css(self, path: list) -> str:
        import json
        return f"[data-path='{json.dumps(path, separators=(',', ':'))}']"

    def console_errors(self) -> list:
        return [e for e in self.driver.get_log("browser") if e["level"] == "SEVERE"]

    # -- input ------------------------------------------------------------------------------------------------
    def drag(self, start, points, step_ms: int = 16, hold: bool = False) -> None:
        """Press at start (viewport px), move through points, release (unless hold)."""
        from selenium.webdriver.common.actions.action_builder import ActionBuilder
        ab = ActionBuilder(self.driver, duration=step_ms)
        ab.pointer_action.move_to_location(int(round(start[0])), int(round(start[1])))
        ab.pointer_action.pointer_down()
        for x, y in points:
            ab.pointer_action.move_to_location(int(round(x)), int(round(y)))
        if not hold:
            ab.pointer_action.pointer_up()
        ab.perform()

    def drag_by(self, css: str, dx: float, dy: float, steps: int = 10, step_ms: int = 16) -> None:
        """Drag the element matching css by (dx, dy) px in `steps` moves."""
        x0, y0 = self.center(css)
        self.drag((x0, y0), [(x0 + dx * k / steps, y0 + dy * k / steps) for k in range(1, steps + 1)], step_ms)

    def click(self, css: str) -> None:
        self.driver.find_element("css selector", css).click()

    def screenshot(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.driver.save_screenshot(str(path))
        return path
