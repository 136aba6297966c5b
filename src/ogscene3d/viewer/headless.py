"""Headless browser screenshots of the viewer with the system's Chromium (no Playwright, no downloads).

Chromium runs ``--headless`` with a DevTools port; the page is captured through the DevTools protocol
(``Page.captureScreenshot``) over a websocket (the ``websockets`` package, a viser dependency), so
the caller decides when the scene is ready instead of guessing a virtual-time budget. WebGL falls back
to software rendering (SwiftShader), which is enough for small scenes.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--remote-debugging-address=127.0.0.1",
    "--remote-debugging-port=0",
    # the page's console messages go to the log (console_messages() reads them back)
    "--enable-logging=stderr",
    "--v=0",
]


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable ($OGSCENE3D_CHROMIUM first), or None."""
    env = os.environ.get("OGSCENE3D_CHROMIUM")
    if env:
        return env if Path(env).is_file() else None
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


class HeadlessBrowser:
    """One headless Chromium showing ``url``; :meth:`screenshot` captures the page as PNG bytes.

    Use as a context manager; the process and its profile folder are removed on exit.
    """

    def __init__(
        self,
        url: str,
        width: int = 1024,
        height: int = 768,
        executable: str | None = None,
        timeout: float = 30.0,
    ) -> None:
        exe = executable or find_chromium()
        if exe is None:
            raise FileNotFoundError("no chromium executable found (install Debian's `chromium`)")
        self._profile = tempfile.mkdtemp(prefix="ogscene3d-chromium-")
        args = [
            exe,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={self._profile}",
            f"--window-size={width},{height}",
            url,
        ]
        self._log = open(Path(self._profile) / "chromium.log", "wb")  # noqa: SIM115 - closed in close()
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=self._log)
        try:
            self.devtools_port = self._wait_devtools_port(timeout)
        except Exception:
            self.close()
            raise

    def _wait_devtools_port(self, timeout: float) -> int:
        marker = Path(self._profile) / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"chromium exited with code {self.proc.returncode}: {self.log_tail()}")
            try:
                first = marker.read_text().split()
                if first:
                    return int(first[0])
            except (OSError, ValueError):
                pass
            time.sleep(0.05)
        raise TimeoutError(f"chromium did not open its DevTools port within {timeout} s: {self.log_tail()}")

    def log_tail(self, n: int = 2000) -> str:
        try:
            return (Path(self._profile) / "chromium.log").read_bytes()[-n:].decode("utf-8", "replace")
        except OSError:
            return ""

    def console_messages(self) -> list[str]:
        """The page's console messages so far (three.js warnings among them), oldest first."""
        try:
            text = (Path(self._profile) / "chromium.log").read_text("utf-8", "replace")
        except OSError:
            return []
        return [line.split("] ", 1)[1] for line in text.splitlines() if ":CONSOLE" in line and "] " in line]

    def _page_ws_url(self) -> str:
        with urllib.request.urlopen(f"http://127.0.0.1:{self.devtools_port}/json/list", timeout=10) as r:
            targets = json.load(r)
        pages = [t for t in targets if t.get("type") == "page"]
        if not pages:
            raise RuntimeError("chromium has no page target")
        return pages[0]["webSocketDebuggerUrl"]

    def call(self, method: str, params: dict | None = None, timeout: float = 30.0) -> dict:
        """One DevTools protocol call on the page; returns its ``result``."""
        from websockets.sync.client import connect

        with connect(self._page_ws_url(), max_size=None, open_timeout=timeout) as ws:
            ws.send(json.dumps({"id": 1, "method": method, "params": params or {}}))
            deadline = time.monotonic() + timeout
            while True:
                msg = json.loads(ws.recv(timeout=max(0.1, deadline - time.monotonic())))
                if msg.get("id") == 1:
                    if "error" in msg:
                        raise RuntimeError(f"DevTools {method} failed: {msg['error']}")
                    return msg.get("result", {})

    def screenshot(self, timeout: float = 90.0) -> bytes:
        """The page as PNG bytes (software WebGL can take long to draw a frame of a big map)."""
        result = self.call("Page.captureScreenshot", {"format": "png"}, timeout=timeout)
        return base64.b64decode(result["data"])

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> HeadlessBrowser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["CHROMIUM_FLAGS", "HeadlessBrowser", "find_chromium"]
