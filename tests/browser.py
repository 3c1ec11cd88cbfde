"""Headless Chromium for the page tests, driven over the DevTools protocol on a pipe.

Chromium started with ``--remote-debugging-pipe`` reads commands on its file descriptor 3
and writes answers and events on 4, each a JSON message ending in a NUL byte: no port, no
websocket library, nothing but the standard library and the browser (Debian's
``chromium``).  Every wait is for a message (a command's answer, the page's load event),
bounded by a deadline; none sleeps.

Where the browser is missing the tests skip, saying how to install it, unless
``FAIRINO_REQUIRE_BROWSER`` is set (``.ci/run`` sets it where it installed the browser):
then a missing browser fails them.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["REQUIRE_ENV", "Browser", "Page", "find_chromium"]

REQUIRE_ENV = "FAIRINO_REQUIRE_BROWSER"

#: Seconds any one answer may take (a page with charts loads in well under one).
TIMEOUT = 60.0


def find_chromium() -> str | None:
    """The headless browser: ``$FAIRINO_CHROMIUM``, else the first of the usual names."""
    given = os.environ.get("FAIRINO_CHROMIUM")
    if given:
        return given
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class BrowserError(RuntimeError):
    pass


class Browser:
    """One headless Chromium; :meth:`open` gives a page (a tab) to load, measure and shoot."""

    def __init__(self, executable: str) -> None:
        self._profile = tempfile.TemporaryDirectory(prefix="fairino-chromium-")
        to_browser, self._commands = os.pipe()  # we write commands; it reads fd 3
        self._answers, from_browser = os.pipe()  # it writes fd 4; we read answers

        def wire() -> None:  # in the child: its fds 3 and 4 (copies first: one may be 3 or 4)
            a, b = os.dup(to_browser), os.dup(from_browser)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [
                executable,
                "--headless",
                "--no-sandbox",  # the tests may run as root, where the sandbox refuses
                "--disable-gpu",
                "--disable-extensions",
                "--no-first-run",
                "--hide-scrollbars",
                "--force-device-scale-factor=1",
                "--font-render-hinting=none",
                f"--user-data-dir={self._profile.name}",
                "--remote-debugging-pipe",
                "about:blank",
            ],
            pass_fds=(3, 4, to_browser, from_browser),
            preexec_fn=wire,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(to_browser)
        os.close(from_browser)
        self._buf = b""
        self._next = 0
        self._events: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ the protocol

    def _read(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError("Chromium did not answer in time")
            ready, _, _ = select.select([self._answers], [], [], left)
            if not ready:
                continue
            chunk = os.read(self._answers, 1 << 20)
            if not chunk:
                raise BrowserError(f"Chromium closed its pipe (exit code {self.proc.poll()})")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        msg: dict[str, Any] = json.loads(raw)
        return msg

    def call(self, method: str, params: dict[str, Any] | None = None, session: str = "") -> Any:
        """Send a command; its result (an error answer raises)."""
        self._next += 1
        msg: dict[str, Any] = {"id": self._next, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._commands, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + TIMEOUT
        while True:
            answer = self._read(deadline)
            if answer.get("id") == self._next:
                if "error" in answer:
                    raise BrowserError(f"{method}: {answer['error']}")
                return answer.get("result", {})
            self._events.append(answer)

    def event(self, name: str, session: str) -> dict[str, Any]:
        """The first event ``name`` of ``session`` (waiting for it if it has not come)."""
        deadline = time.monotonic() + TIMEOUT
        while True:
            for k, ev in enumerate(self._events):
                if ev.get("method") == name and ev.get("sessionId") == session:
                    del self._events[k]
                    return ev
            self._events.append(self._read(deadline))

    def open(self, url: str, *, width: int, height: int = 900) -> Page:
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        page = Page(self, session)
        self.call("Page.enable", session=session)
        page.resize(width, height)
        self._events = [e for e in self._events if e.get("sessionId") != session]
        self.call("Page.navigate", {"url": url}, session=session)
        self.event("Page.loadEventFired", session)
        return page

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except (BrowserError, OSError):
            self.proc.kill()
        self.proc.wait(TIMEOUT)
        os.close(self._commands)
        os.close(self._answers)
        self._profile.cleanup()


class Page:
    """A loaded page: evaluate script in it, resize it, take a screenshot of it."""

    def __init__(self, browser: Browser, session: str) -> None:
        self.browser = browser
        self.session = session

    def evaluate(self, expression: str) -> Any:
        result = self.browser.call(
            "Runtime.evaluate",
            {"expression": expression, "returnByValue": True, "awaitPromise": True},
            session=self.session,
        )
        if "exceptionDetails" in result:
            raise BrowserError(f"{expression!r}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def resize(self, width: int, height: int) -> None:
        self.browser.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            session=self.session,
        )

    def screenshot(self, path: Path, *, max_height: int = 2400) -> None:
        """The page from its top, as tall as its content (at most ``max_height``), as PNG."""
        width = int(self.evaluate("document.documentElement.clientWidth"))
        height = min(int(self.evaluate("document.documentElement.scrollHeight")), max_height)
        shot = self.browser.call(
            "Page.captureScreenshot",
            {
                "format": "png",
                "captureBeyondViewport": True,
                "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1},
            },
            session=self.session,
        )
        path.write_bytes(base64.b64decode(shot["data"]))
