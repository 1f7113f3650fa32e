"""What the browser tests (and scripts/screenshots.py) share: Debian's headless Chromium
through Playwright, a screenshot as an array, and where a lab point lands on the page.

    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        page.goto(live.url + "/")
        px = project_initial(live, page, [[0.0, 0.0, 1.0]])

Never ``playwright install``: the browser is the system's (/usr/bin/chromium), started
with nothing that reaches the network on its own.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Iterator

import numpy as np

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
]
HAVE_CHROMIUM = os.path.exists(CHROMIUM)
NEEDS_CHROMIUM = "needs " + CHROMIUM
CLIENT_FOV_RAD = float(np.radians(75.0))
"""The vertical field of view of a camera pose sent to a client without a field of view:
viser's default (the initial camera's is app.backend.scene.CAMERA_FOV_RAD)."""


@contextlib.contextmanager
def chromium() -> Iterator:
    """A Playwright browser on the system's headless Chromium, closed on leaving."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def screenshot(page) -> np.ndarray:
    """The page as it is drawn: an (height, width, 3) integer RGB array."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(int)


def project(box: dict, position_W, look_at_W, points_W, fov_rad: float) -> np.ndarray:
    """Page pixels (x right, y down) of lab points seen by a pinhole camera at position_W
    looking at look_at_W, z up, with vertical field of view fov_rad, drawn in the viewer's
    frame at box (Playwright's bounding box: x, y, width, height): one row per point."""
    pos, look = np.asarray(position_W, float), np.asarray(look_at_W, float)
    forward = (look - pos) / np.linalg.norm(look - pos)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    f_px = (box["height"] / 2) / np.tan(fov_rad / 2)
    v = np.atleast_2d(np.asarray(points_W, float)) - pos
    depth = v @ forward
    return np.column_stack([box["x"] + box["width"] / 2 + f_px * (v @ right) / depth,
                            box["y"] + box["height"] / 2 + f_px * (v @ down) / depth])


def project_initial(live, page, points_W) -> np.ndarray:
    """Page pixels of lab points through viser's initial camera (its position, look-at
    point and field of view) in the page's #viewer frame."""
    cam = live.app.state.viser.initial_camera
    box = page.locator("#viewer").bounding_box()
    return project(box, cam.position, cam.look_at, points_W, cam.fov)
