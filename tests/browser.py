"""A real headless browser for the report tests: Debian's ``chromium`` driven over the DevTools
protocol on a pipe (``--remote-debugging-pipe``: JSON messages separated by NUL on fds 3 / 4), so
no driver package is needed.

``render(path)`` loads a local HTML file and returns what a person would worry about: console
errors and uncaught exceptions, every request that is not the file itself or a ``data:`` URI, and a
full-page screenshot (PNG bytes).

``chromium_or_skip()`` finds the browser; without it the test is skipped with the reason, except
under CI (``CI`` set), where a missing browser is a failure (``.ci/run`` / ``make test`` as root
install it: ``apt-get install -y chromium``).
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
from dataclasses import dataclass, field
from pathlib import Path

import pytest

CANDIDATES = ("chromium", "chromium-browser", "google-chrome")


def chromium_or_skip() -> str:
    for name in CANDIDATES:
        exe = shutil.which(name)
        if exe:
            return exe
    msg = ("no chromium on PATH: the browser test needs Debian's chromium (apt-get install -y chromium; "
           "`make test` and .ci/run do it when run as root)")
    if os.environ.get("CI"):
        pytest.fail(msg + " [CI is set: a missing browser is a failure here, not a skip]")
    pytest.skip(msg)


@dataclass
class Rendered:
    console_errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)  # every URL the page asked for
    screenshot_png: bytes = b""
    title: str = ""
    value: object = None  # what ``render(..., evaluate=JS)`` returned

    def outside(self, page: Path) -> list[str]:
        """The requests that leave the file: anything but the page itself and data: URIs."""
        own = Path(page).resolve().as_uri()
        return [u for u in self.requests if not (u.startswith("data:") or u == own)]


class _Pipe:
    def __init__(self, exe: str, width: int, height: int):
        self.r_in, self.w_in = os.pipe()  # we write -> chromium reads on fd 3
        self.r_out, self.w_out = os.pipe()  # chromium writes on fd 4 -> we read
        self.profile = tempfile.mkdtemp(prefix="hc-chromium-")
        args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe", "--no-first-run",
                "--disable-extensions", "--disable-background-networking", "--disable-component-update",
                "--disable-sync", "--metrics-recording-only", "--no-default-browser-check", "--mute-audio",
                f"--user-data-dir={self.profile}", f"--window-size={width},{height}", "about:blank"]

        def fds():  # in the child: our ends to 3 / 4, inheritable (os.pipe fds are close-on-exec)
            import fcntl

            hi_in, hi_out = fcntl.fcntl(self.r_in, fcntl.F_DUPFD, 10), fcntl.fcntl(self.w_out, fcntl.F_DUPFD, 10)
            os.dup2(hi_in, 3)
            os.dup2(hi_out, 4)

        # close_fds would run after preexec_fn and close fds 3 / 4 again
        self.proc = subprocess.Popen(args, preexec_fn=fds, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                     close_fds=False)
        os.close(self.r_in)
        os.close(self.w_out)
        self.buf = b""
        self.next_id = 0
        self.events: list[dict] = []

    def send(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 30.0):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.w_in, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            m = self.recv(deadline)
            if m.get("id") == self.next_id:
                if "error" in m:
                    raise RuntimeError(f"chromium {method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def recv(self, deadline: float) -> dict:
        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.r_out], [], [], left)[0]:
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self.r_out, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe (did it start?)")
            self.buf += chunk
        raw, self.buf = self.buf.split(b"\0", 1)
        return json.loads(raw)

    def wait_event(self, method: str, timeout: float = 30.0) -> dict:
        deadline = time.monotonic() + timeout
        for m in self.events:
            if m.get("method") == method:
                return m
        while True:
            m = self.recv(deadline)
            self.events.append(m)
            if m.get("method") == method:
                return m

    def close(self):
        try:
            os.write(self.w_in, json.dumps({"id": 0, "method": "Browser.close"}).encode() + b"\0")
            self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        for fd in (self.w_in, self.r_out):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)


def render(path: str | Path, exe: str | None = None, width: int = 1200, settle_s: float = 0.5,
           evaluate: str | None = None) -> Rendered:
    """Load ``path`` in headless chromium; collect console errors, requests and a full-page screenshot;
    with ``evaluate``, run that JavaScript expression after the load (its value in ``Rendered.value``)."""
    exe = exe or chromium_or_skip()
    page = Path(path).resolve()
    p = _Pipe(exe, width, 900)
    try:
        target = p.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        s = p.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            p.send(f"{domain}.enable", session=s)
        p.send("Page.navigate", {"url": page.as_uri()}, session=s)
        p.wait_event("Page.loadEventFired")
        time.sleep(settle_s)  # late console messages / requests
        title = p.send("Runtime.evaluate", {"expression": "document.title", "returnByValue": True},
                       session=s)["result"].get("value", "")
        value = None
        if evaluate:
            value = p.send("Runtime.evaluate", {"expression": evaluate, "returnByValue": True},
                           session=s)["result"].get("value")
        shot = p.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True}, session=s,
                      timeout=60)
        out = Rendered(screenshot_png=base64.b64decode(shot["data"]), title=title, value=value)
        for m in p.events:
            meth, prm = m.get("method"), m.get("params", {})
            if meth == "Runtime.consoleAPICalled" and prm.get("type") in ("error", "assert"):
                out.console_errors.append(" ".join(str(a.get("value", a.get("description", ""))) for a in prm["args"]))
            elif meth == "Runtime.exceptionThrown":
                out.console_errors.append(prm["exceptionDetails"].get("exception", {}).get("description", "exception"))
            elif meth == "Log.entryAdded" and prm["entry"].get("level") == "error":
                out.console_errors.append(prm["entry"].get("text", ""))
            elif meth == "Network.requestWillBeSent":
                out.requests.append(prm["request"]["url"])
        return out
    finally:
        p.close()
