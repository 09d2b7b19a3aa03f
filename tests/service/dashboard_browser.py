"""Headless Chromium driven over the DevTools protocol on a pipe, for the dashboard test.

    with Chromium.start(profile_dir) as browser:
        page = browser.new_page(width=1400, height=1000)
        page.navigate("http://127.0.0.1:8000/")
        page.wait_for("document.querySelector('#live').dataset.state === 'live'", timeout=30)
        page.evaluate("document.title"); page.screenshot(path)
        page.requests, page.console_errors       # every URL the page asked for; JS errors and console.error calls

Why a pipe: ``--remote-debugging-pipe`` makes Chromium read protocol messages (JSON, each ended by a NUL byte) on
its fd 3 and write them on fd 4, so no port is opened, no chromedriver and no Python browser library is needed: only
Debian's ``chromium`` (scripts/install-chromium.sh). Flags: what works on a closed network with no GPU and as root.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Self

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--mute-audio", "--remote-debugging-pipe")


class BrowserError(RuntimeError):
    """The browser answered a command with an error, or did not answer in time, or is gone."""


def find_chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def free_port() -> int:
    """A loopback port nothing listens on now (for the server the page is opened on)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _above(fd: int, lowest: int) -> int:
    """A copy of ``fd`` numbered ``lowest`` or more; the original closed."""
    high = fcntl.fcntl(fd, fcntl.F_DUPFD, lowest)
    os.close(fd)
    return high


class Chromium:
    """One browser process; messages to and from it over two pipes, read on a thread of our own."""

    def __init__(self, proc: subprocess.Popen[bytes], to_browser: int, from_browser: int) -> None:
        self._proc = proc
        self._out = to_browser
        self._in = from_browser
        self._next_id = 0
        self._replies: dict[int, dict[str, Any]] = {}
        self._events: list[dict[str, Any]] = []
        self._cond = threading.Condition()
        self._closed = False
        self._reader = threading.Thread(target=self._read_loop, name="chromium-pipe", daemon=True)
        self._reader.start()

    @classmethod
    def start(cls, profile_dir: Path, binary: str | None = None) -> Self:
        binary = binary or find_chromium()
        if binary is None:
            raise BrowserError("no chromium on PATH (scripts/install-chromium.sh installs Debian's)")
        cmd_r, cmd_w = os.pipe()  # we write commands, the browser reads them on its fd 3
        evt_r, evt_w = os.pipe()  # the browser writes replies and events on its fd 4
        # the child's ends moved above 9: putting them on 3 and 4 then cannot overwrite one with the other
        cmd_r, evt_w = (_above(fd, 10) for fd in (cmd_r, evt_w))
        # a small Python trampoline puts the two pipe ends on fds 3 and 4, closes the originals and becomes chromium
        # (a shell would do, but dash redirects only fds 0-9 and ours may be higher)
        trampoline = ("import os, sys; r, w = int(sys.argv[1]), int(sys.argv[2]); os.dup2(r, 3); os.dup2(w, 4); "
                      "os.close(r); os.close(w); os.execv(sys.argv[3], sys.argv[3:])")
        argv = [binary, *FLAGS, f"--user-data-dir={profile_dir}", "about:blank"]
        proc = subprocess.Popen([sys.executable, "-c", trampoline, str(cmd_r), str(evt_w), *argv],
                                pass_fds=(cmd_r, evt_w), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        os.close(cmd_r)
        os.close(evt_w)
        return cls(proc, cmd_w, evt_r)

    def _read_loop(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._in, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                break
            buf += chunk
            *messages, buf = buf.split(b"\0")
            with self._cond:
                for raw in messages:
                    msg = json.loads(raw)
                    if "id" in msg:
                        self._replies[msg["id"]] = msg
                    else:
                        self._events.append(msg)
                self._cond.notify_all()
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def send(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
             timeout: float = 30.0) -> dict[str, Any]:
        with self._cond:
            self._next_id += 1
            msg_id = self._next_id
        msg: dict[str, Any] = {"id": msg_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        try:
            os.write(self._out, json.dumps(msg).encode() + b"\0")
        except OSError as exc:
            raise BrowserError(f"{method}: the browser is gone ({exc})") from exc
        deadline = time.monotonic() + timeout
        with self._cond:
            while msg_id not in self._replies:
                left = deadline - time.monotonic()
                if self._closed or left <= 0:
                    raise BrowserError(f"{method}: no answer from the browser in {timeout:.0f} s")
                self._cond.wait(left)
            reply = self._replies.pop(msg_id)
        if "error" in reply:
            raise BrowserError(f"{method}: {reply['error'].get('message')}")
        return reply.get("result", {})

    def events(self, session: str | None = None) -> list[dict[str, Any]]:
        with self._cond:
            return [e for e in self._events if session is None or e.get("sessionId") == session]

    def new_page(self, width: int = 1400, height: int = 1000) -> Page:
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        page = Page(self, session)
        for domain in ("Page", "Runtime", "Log", "Network"):
            page.send(f"{domain}.enable")
        page.send("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})
        return page

    def close(self) -> None:
        with contextlib.suppress(BrowserError):
            self.send("Browser.close", timeout=5)
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        for fd in (self._out, self._in):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._reader.join(timeout=5)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Page:
    """One tab: navigate, evaluate JavaScript, wait for a condition, take a screenshot, read what it logged."""

    def __init__(self, browser: Chromium, session: str) -> None:
        self.browser = browser
        self.session = session

    def send(self, method: str, params: dict[str, Any] | None = None, timeout: float = 30.0) -> dict[str, Any]:
        return self.browser.send(method, params, session=self.session, timeout=timeout)

    def navigate(self, url: str, timeout: float = 30.0) -> None:
        reply = self.send("Page.navigate", {"url": url})
        if reply.get("errorText"):
            raise BrowserError(f"navigate {url}: {reply['errorText']}")
        self.wait_for(f"document.readyState === 'complete' && location.href.startsWith({json.dumps(url)})", timeout)

    def evaluate(self, expression: str) -> Any:
        reply = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in reply:
            raise BrowserError(f"{expression!r}: {reply['exceptionDetails'].get('text')} "
                               f"{reply['exceptionDetails'].get('exception', {}).get('description', '')}")
        return reply["result"].get("value")

    def wait_for(self, expression: str, timeout: float, poll_s: float = 0.25) -> Any:
        """Polls a JavaScript expression until it is truthy; returns its value or raises after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise BrowserError(f"not true after {timeout:.0f} s: {expression} (last value {value!r})")
            time.sleep(poll_s)

    def screenshot(self, path: Path) -> None:
        """The whole page (not only the viewport) as a PNG."""
        size = self.send("Page.getLayoutMetrics")["cssContentSize"]
        clip = {"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1}
        data = self.send("Page.captureScreenshot", {"format": "png", "clip": clip, "captureBeyondViewport": True})
        path.write_bytes(base64.b64decode(data["data"]))

    def _events(self, method: str) -> Iterator[dict[str, Any]]:
        return (e["params"] for e in self.browser.events(self.session) if e["method"] == method)

    @property
    def requests(self) -> list[str]:
        """Every URL the page requested (documents, scripts, styles, fetches, the event stream)."""
        return [p["request"]["url"] for p in self._events("Network.requestWillBeSent")]

    @property
    def failed_responses(self) -> list[tuple[str, int]]:
        return [(p["response"]["url"], p["response"]["status"]) for p in self._events("Network.responseReceived")
                if p["response"]["status"] >= 400]

    @property
    def console_errors(self) -> list[str]:
        """Uncaught exceptions, console.error/assert calls and the browser's own error entries (a script that failed
        to load, a refused request), each as one line."""
        out = [f"exception: {p['exceptionDetails'].get('exception', {}).get('description') or p['exceptionDetails']['text']}"
               for p in self._events("Runtime.exceptionThrown")]
        out += [f"console.{p['type']}: " + " ".join(str(a.get("value", a.get("description", ""))) for a in p["args"])
                for p in self._events("Runtime.consoleAPICalled") if p["type"] in ("error", "assert")]
        out += [f"{e['entry']['source']}: {e['entry']['text']} ({e['entry'].get('url', '')})"
                for e in self._events("Log.entryAdded") if e["entry"]["level"] == "error"]
        return out
