"""A headless Chromium driven over the Chrome DevTools Protocol, for page tests.

Only what the tests need: open a page, evaluate JavaScript, collect console errors, exceptions and
network requests, take a screenshot. The protocol travels over the websocket client the project
already uses (``websockets``), so no browser driver package is needed. Chromium listens on
127.0.0.1 only, with a fresh profile, no background networking, and a time limit of its own.
"""
from __future__ import annotations

import base64
import inspect
import itertools
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--disable-extensions", "--mute-audio")
NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """``$RSB_CHROMIUM``, else the first Chromium / Chrome on PATH."""
    env = os.environ.get("RSB_CHROMIUM")
    if env:
        return env
    return next(filter(None, (shutil.which(n) for n in NAMES)), None)


def _chromium() -> str:
    """The Chromium a page test runs: missing on Debian fails (setup installs it), elsewhere skips."""
    binary = find_chromium()
    if binary:
        return binary
    release = Path("/etc/os-release").read_text() if Path("/etc/os-release").exists() else ""
    if shutil.which("apt-get") and re.search(r"^ID=debian$", release, re.M):
        pytest.fail("Chromium is not installed: `make setup` (scripts/setup.sh) installs Debian's chromium; "
                    "or set RSB_CHROMIUM to a Chromium / Chrome binary")
    pytest.skip("no Chromium or Chrome here, and this is not Debian, where scripts/setup.sh installs it: "
                "set RSB_CHROMIUM to run the report's browser test")


class Browser:
    """One headless Chromium with one page; use as a context manager."""

    def __init__(self, binary: str, width: int = 1400, height: int = 1000, lifetime_s: int = 600) -> None:
        self.profile = Path(tempfile.mkdtemp(prefix="rsb-chromium-"))
        argv = [binary, *FLAGS, f"--user-data-dir={self.profile}", "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0", f"--window-size={width},{height}", "about:blank"]
        if shutil.which("timeout"):  # the browser stops by itself even if the test process dies
            argv = ["timeout", "-k", "5", str(lifetime_s), *argv]
        self.log = open(self.profile / "chromium.log", "w")
        self.proc = subprocess.Popen(argv, stdout=self.log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        self.events: list[dict] = []
        self._ids = itertools.count(1)
        try:
            self.ws = self._connect(time.monotonic() + 60)
        except Exception:
            self.close()
            raise

    def _connect(self, deadline: float) -> Any:
        from websockets.sync.client import connect

        port_file = self.profile / "DevToolsActivePort"
        while not (port_file.exists() and port_file.read_text().strip()):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"Chromium did not start (exit {self.proc.poll()}):\n{self.chromium_log()}")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        direct = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # 127.0.0.1, never via a proxy
        while True:
            with direct.open(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                pages = [t for t in json.load(r) if t.get("type") == "page"]
            if pages or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        if not pages:
            raise RuntimeError("Chromium opened no page")
        kwargs: dict[str, Any] = {"max_size": None, "open_timeout": 30}
        params = inspect.signature(connect).parameters
        if "proxy" in params:
            kwargs["proxy"] = None  # websockets >= 15 would honour a proxy from the environment
        if "legacy" in params:
            kwargs["legacy"] = True  # websockets >= 17: a plain connection object
        return connect(pages[0]["webSocketDebuggerUrl"], **kwargs)

    def chromium_log(self) -> str:
        self.log.flush()
        return (self.profile / "chromium.log").read_text(errors="replace")[-3000:]

    # ------------------------------------------------------------ protocol
    def send(self, method: str, timeout: float = 60, **params: Any) -> dict:
        """Call ``method`` and return its result; events that arrive meanwhile go to ``events``."""
        msg_id = next(self._ids)
        self.ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            msg = json.loads(self.ws.recv(timeout=max(0.1, deadline - time.monotonic())))
            if msg.get("id") == msg_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            self.events.append(msg)

    def wait_event(self, method: str, timeout: float = 60) -> dict:
        """The first event ``method`` (already received or next to come)."""
        for e in self.events:
            if e.get("method") == method:
                return e
        deadline = time.monotonic() + timeout
        while True:
            msg = json.loads(self.ws.recv(timeout=max(0.1, deadline - time.monotonic())))
            self.events.append(msg)
            if msg.get("method") == method:
                return msg

    def evaluate(self, expression: str) -> Any:
        """Value of a JavaScript expression (awaited if it is a promise)."""
        res = self.send("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in res:
            raise RuntimeError(f"JavaScript error in {expression!r}: {res['exceptionDetails']}")
        return res["result"].get("value")

    def open(self, url: str) -> None:
        """Navigate and wait for the load event, with console, errors and network being recorded."""
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.send(f"{domain}.enable")
        self.events.clear()
        self.send("Page.navigate", url=url)
        self.wait_event("Page.loadEventFired")

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and error log entries seen so far."""
        out = []
        for e in self.events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append("console: " + " ".join(str(a.get("value", a.get("description"))) for a in p.get("args", [])))
            elif m == "Runtime.exceptionThrown":
                out.append("exception: " + json.dumps(p.get("exceptionDetails", {}))[:500])
            elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
                out.append("log: " + p["entry"].get("text", ""))
        return out

    def requested_urls(self) -> list[str]:
        return [e["params"]["request"]["url"] for e in self.events if e.get("method") == "Network.requestWillBeSent"]

    def screenshot(self, path: str | os.PathLike, full_page: bool = True) -> Path:
        """PNG of the viewport, or of the whole page."""
        params: dict[str, Any] = {"format": "png"}
        if full_page:
            size = self.send("Page.getLayoutMetrics")["cssContentSize"]
            params.update(captureBeyondViewport=True,
                          clip={"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1})
        data = self.send("Page.captureScreenshot", **params)["data"]
        path = Path(path)
        path.write_bytes(base64.b64decode(data))
        return path

    def close(self) -> None:
        ws = getattr(self, "ws", None)
        if ws is not None:
            ws.close()
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def checked_screenshot(browser: Browser, path: str | os.PathLike, keep_env: str) -> Path:
    """A self-contained page's last checks and its full-page screenshot: no console error or
    exception, nothing fetched but the file and data: URIs. The PNG is copied to ``$keep_env``
    when that is set, to look at."""
    assert browser.errors() == []
    assert {u.split(":", 1)[0] for u in browser.requested_urls()} <= {"file", "data"}
    shot = browser.screenshot(path)
    if os.environ.get(keep_env):
        shutil.copy(shot, os.environ[keep_env])
    return shot
