"""The viewer in a real headless browser (Debian's chromium, driven over the DevTools protocol).

Skipped where no chromium is installed; `.ci/run` installs it. Set OGSCENE3D_TEST_ARTIFACTS to a
folder to keep the screenshot.
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from viewer_runs import make_scene

from ogscene3d.viewer.headless import HeadlessBrowser, find_chromium

pytestmark = pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed")

WIDTH, HEIGHT = 800, 600
PANEL_WIDTH = 340  # viser's control panel on the right; the notification box sits top-left


def scene_pixels(png: bytes) -> dict[str, int]:
    """Counts of saturated green / blue pixels (the test objects' colours) in the 3D canvas area."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "screenshot is not a PNG"
    b, g, r = (img[..., i].astype(int) for i in range(3))
    h, w = img.shape[:2]
    canvas = np.ones((h, w), bool)
    canvas[:, w - PANEL_WIDTH :] = False
    canvas[:170, :340] = False
    green = (g > 150) & (r < 120) & (b < 120) & canvas
    blue = (b > 150) & (r < 120) & (g < 120) & canvas
    return {"green": int(green.sum()), "blue": int(blue.sum()), "std": float(img[canvas].std())}


def _wait_clients(viewer, n: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if viewer.num_clients == n:
            return True
        time.sleep(0.1)
    return False


def test_browser_shows_the_streamed_map_and_graph(tmp_path):
    from ogscene3d.viewer.app import LiveViewer

    viewer = LiveViewer(port=0, max_rate_hz=10)
    stop = threading.Event()

    def stream() -> None:
        # A growing map, as live mapping produces: 1, 2, then 3 objects.
        for k in (1, 2, 3):
            if stop.is_set():
                return
            viewer.publish(make_scene(300, objects=k))
            time.sleep(0.3)

    producer = threading.Thread(target=stream, daemon=True)
    try:
        with HeadlessBrowser(viewer.url, WIDTH, HEIGHT) as first:
            producer.start()
            ready = viewer.wait_until(
                lambda s: s["clients"] >= 1 and s["gaussians"] == 900 and s["nodes"] == 3, 45
            )
            assert ready, f"scene not ready: {viewer.shown()}\n{first.log_tail()}"
            assert viewer.shown()["edges"] == 2 and viewer.shown()["render"] == "splats"
            # A second browser joins late and gets the whole scene; then the first one leaves.
            with HeadlessBrowser(viewer.url, WIDTH, HEIGHT) as late:
                assert _wait_clients(viewer, 2, 30), late.log_tail()
                first.close()
                assert _wait_clients(viewer, 1, 30)
                # The stream goes on for the remaining browser: a fourth object appears.
                viewer.publish(make_scene(300, objects=4))
                assert viewer.wait_until(lambda s: s["gaussians"] == 1200 and s["nodes"] == 4, 30), (
                    viewer.shown()
                )
                assert viewer.stats["errors"] == 0
                # Software WebGL needs a moment to sort and fade the splats in: poll the screenshot.
                deadline = time.monotonic() + 60
                while True:
                    png = late.screenshot()
                    px = scene_pixels(png)
                    if (px["green"] > 400 and px["blue"] > 400) or time.monotonic() > deadline:
                        break
                    time.sleep(1.0)
        shot = tmp_path / "viewer.png"
        shot.write_bytes(png)
        if os.environ.get("OGSCENE3D_TEST_ARTIFACTS"):
            out = Path(os.environ["OGSCENE3D_TEST_ARTIFACTS"])
            out.mkdir(parents=True, exist_ok=True)
            shutil.copy(shot, out / "viewer_browser.png")
        assert px["std"] > 10, f"blank canvas: {px}"
        assert px["green"] > 400 and px["blue"] > 400, f"splats not visible: {px}"
    finally:
        stop.set()
        viewer.close()


def _map_box(png: bytes) -> tuple[int, int, int, int, int, int, int] | None:
    """(x0, y0, x1, y1, pixels, width, height) of the test objects' green and blue pixels in the canvas
    left of the GUI panel (viser's axes gizmo left out), or None when there are none."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    b, g, r = (img[..., i].astype(int) for i in range(3))
    coloured = ((g > 150) & (r < 120) & (b < 120)) | ((b > 150) & (r < 120) & (g < 120))
    h, w = coloured.shape
    coloured[h - 70 :, :70] = False  # viser's axes gizmo (green and blue arrows)
    coloured[:, w - PANEL_WIDTH :] = False  # the GUI panel (blue checkboxes)
    ys, xs = np.nonzero(coloured)
    if not len(xs):
        return None
    return int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()), len(xs), w, h


def _inside(box) -> bool:
    x0, y0, x1, y1, _, w, h = box
    return x0 > 5 and y0 > 5 and x1 < w - PANEL_WIDTH - 5 and y1 < h - 5


def test_browser_opens_on_the_whole_map_and_our_layers_send_no_nan_geometry(tmp_path):
    """The first view shows the whole map from outside (every coloured point inside the canvas, none cut
    off at its edges), and no layer of ours (points, graph, trajectory, camera, Find boxes) makes three.js
    log a NaN bounding sphere. (viser's splat mesh does on its own: its quad corners are a 2-component
    "position" attribute; see docs/viewer.md.)"""

    from ogscene3d.viewer.app import LiveViewer
    from ogscene3d.viewer.scene import ViewerSettings

    viewer = LiveViewer(port=0, max_rate_hz=10, settings=ViewerSettings(render="points", point_size=0.03))
    try:
        viewer.publish(make_scene(300, objects=3))
        with HeadlessBrowser(viewer.url, 1280, 800) as browser:
            assert viewer.wait_until(lambda s: s["clients"] == 1 and s["gaussians"] == 900, 45), (
                browser.log_tail()
            )
            deadline = time.monotonic() + 60
            while True:  # until the points are drawn from the whole-map view (software WebGL is slow)
                png = browser.screenshot()
                box = _map_box(png)
                if (box is not None and box[4] > 300 and _inside(box)) or time.monotonic() > deadline:
                    break
                time.sleep(1.0)
            view = viewer.views[0]
            view._txt_query.value = "lamp"  # a Find box around a node, and the other nodes dimmed
            assert viewer.wait_until(lambda s: view.layers._highlight_handle is not None, 30)
            browser.screenshot()  # a frame drawn with the box
            messages = browser.console_messages()
        if os.environ.get("OGSCENE3D_TEST_ARTIFACTS"):
            out = Path(os.environ["OGSCENE3D_TEST_ARTIFACTS"])
            out.mkdir(parents=True, exist_ok=True)
            (out / "viewer_first_view.png").write_bytes(png)
        assert box is not None and box[4] > 300, f"map not visible: {box}"
        assert _inside(box), f"the map is cut off at the canvas edges or hidden by the panel: {box}"
        assert len(messages) > 0, "no console messages captured"
        nan = [m for m in messages if "Computed radius is NaN" in m]
        assert not nan, nan
    finally:
        viewer.close()


def _page_text(browser: HeadlessBrowser) -> str:
    return browser.call("Runtime.evaluate", {"expression": "document.body.innerText", "returnByValue": True})[
        "result"
    ]["value"]


def test_two_browsers_keep_their_own_gui_state_and_the_legend_shows():
    """In Chromium: the first browser switches to semantic colours and finds a node; a second browser
    opens with RGB and an empty Find box, and only the first shows the semantic legend."""
    from ogscene3d.viewer.app import LiveViewer

    viewer = LiveViewer(port=0, max_rate_hz=10)
    try:
        viewer.publish(make_scene(100, objects=3))
        with HeadlessBrowser(viewer.url, WIDTH, HEIGHT) as first:
            # a browser counts as a client before its view is set up: wait for both
            assert viewer.wait_until(
                lambda s: s["clients"] == 1 and s["nodes"] == 3 and len(viewer.views) == 1, 45
            ), first.log_tail()
            view1 = viewer.views[0]
            view1._dd_color.value = "Semantic label"
            view1._txt_query.value = "lamp"
            assert viewer.wait_until(lambda s: "1 match" in view1._md_matches.content, 30)
            deadline = time.monotonic() + 30
            while "sofa (#0)" not in (text1 := _page_text(first)) and time.monotonic() < deadline:
                time.sleep(0.5)
            assert "sofa (#0)" in text1 and "1 match" in text1, text1[-1500:]
            with HeadlessBrowser(viewer.url, WIDTH, HEIGHT) as second:
                assert viewer.wait_until(
                    lambda s: s["clients"] == 2 and len(viewer.views) == 2, 45
                ), second.log_tail()
                view2 = viewer.views[1]
                assert viewer.wait_until(lambda s: view2.layers.shown_gaussians == 300, 30)
                deadline = time.monotonic() + 30
                while (
                    "RGB: the Gaussians" not in (text2 := _page_text(second)) and time.monotonic() < deadline
                ):
                    time.sleep(0.5)
                assert "RGB: the Gaussians" in text2 and "sofa (#0)" not in text2, text2[-1500:]
                assert "match" not in text2
                assert view2._dd_color.value == "RGB" and view2._txt_query.value == ""
                # and the first browser still shows its own choices
                assert "sofa (#0)" in _page_text(first) and view1.settings.color_mode == "semantic"
    finally:
        viewer.close()
