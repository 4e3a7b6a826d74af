"""Open a page in headless Chromium (Debian's ``chromium``; ``scripts/install_browser.sh``) and
report what a person would see: console errors and uncaught exceptions, whether the report says
its plots are drawn (``data-report``), how many plots hold drawn traces, the time to draw, and
optionally a PNG screenshot. Talks the DevTools protocol over its WebSocket (``websockets``).

Chromium starts with a fresh profile and no network features (no sandbox: tests run as root)."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["CHROMIUM_FLAGS", "BrowserError", "PageCheck", "check_page", "check_pages", "find_chromium"]

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--no-first-run", "--disable-sync", "--disable-dev-shm-usage")

_STATE_JS = """JSON.stringify({
  state: document.body ? document.body.dataset.report : null,
  drawn_ms: document.body ? Number(document.body.dataset.drawnMs) : null,
  stages_ms: document.body ? {unpacked: Number(document.body.dataset.unpackedMs),
                              plotly: Number(document.body.dataset.plotlyMs)} : null,
  plots: document.querySelectorAll('div.plot').length,
  drawn: [...document.querySelectorAll('div.plot')].filter(d =>
      d.querySelector('svg.main-svg') && d.querySelectorAll('.scatterlayer .trace path.js-line').length > 0).length,
  traces: document.querySelectorAll('div.plot .scatterlayer .trace').length,
  error: (document.getElementById('report-error') || {}).textContent || '',
  height: document.documentElement.scrollHeight
})"""


class BrowserError(RuntimeError):
    """Chromium is missing, would not start, or the page never settled."""


@dataclass
class PageCheck:
    state: str | None  # "drawn", "failed", "loading" (never settled) or None (not a report page)
    plots: int  # div.plot elements
    drawn: int  # of those, the ones with an SVG and at least one drawn line
    traces: int
    drawn_ms: float | None  # navigation start to every plot drawn, from the page's own clock
    stages_ms: dict[str, float] | None = None  # navigation start to plotly.js unpacked, and evaluated
    errors: list[str] = field(default_factory=list)  # console errors, exceptions, failed loads
    page_error: str = ""
    screenshot: Path | None = None


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class _Cdp:
    """A DevTools session on one page target (flat mode over the browser's WebSocket)."""

    def __init__(self, ws_url: str) -> None:
        from websockets.sync.client import connect

        self.ws = connect(ws_url, max_size=None, open_timeout=30).__enter__()
        self._id = 0
        self.session: str | None = None
        self.events: list[dict[str, Any]] = []

    def call(self, method: str, params: dict[str, Any] | None = None, timeout_s: float = 60.0) -> dict[str, Any]:
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if self.session and not method.startswith("Target."):
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError(f"DevTools: no answer to {method} in {timeout_s:.0f} s")
            reply = json.loads(self.ws.recv(timeout=left))
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise BrowserError(f"DevTools {method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            if "method" in reply:
                self.events.append(reply)

    def drain(self, wait_s: float) -> None:
        end = time.monotonic() + wait_s
        while (left := end - time.monotonic()) > 0:
            try:
                m = json.loads(self.ws.recv(timeout=left))
            except TimeoutError:
                return
            if "method" in m:
                self.events.append(m)

    def close(self) -> None:
        self.ws.close()


def _errors(events: list[dict[str, Any]]) -> list[str]:
    out = []
    for e in events:
        p = e.get("params", {})
        if e["method"] == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            out.append("console: " + " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", [])))
        elif e["method"] == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif e["method"] == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            out.append("log: " + p["entry"].get("text", ""))
    return out


def _start(chromium: str, profile: Path) -> tuple[subprocess.Popen[bytes], str]:
    proc = subprocess.Popen([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0",
                             "--remote-debugging-address=127.0.0.1", "about:blank"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    port_file = profile / "DevToolsActivePort"
    deadline = time.monotonic() + 60.0  # a first start on a loaded machine is slow
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            err = proc.stderr.read().decode(errors="replace")[-400:] if proc.stderr else ""
            raise BrowserError(f"{chromium} exited ({proc.returncode}) before DevTools was up: {err}")
        if port_file.is_file():
            lines = port_file.read_text().split()
            if len(lines) >= 2:
                return proc, f"ws://127.0.0.1:{lines[0]}{lines[1]}"
        time.sleep(0.05)
    proc.kill()
    raise BrowserError(f"{chromium}: DevTools did not start in 60 s")


def check_page(path: str | Path, screenshot: str | Path | None = None, width: int = 1300,
               settle_timeout_s: float = 120.0) -> PageCheck:
    """Load ``path`` (a local file) in a fresh headless Chromium and wait until the report says drawn
    or failed (or ``settle_timeout_s``: a limit against a hang, not a speed figure)."""
    return check_pages([path], [screenshot], width, settle_timeout_s)[0]


def check_pages(paths: list[str | Path], screenshots: list[str | Path | None] | None = None, width: int = 1300,
                settle_timeout_s: float = 120.0) -> list[PageCheck]:
    """``check_page`` for each path in turn, in one browser (each page in a new tab)."""
    chromium = find_chromium()
    if chromium is None:
        raise BrowserError("no chromium on PATH: run scripts/install_browser.sh (as root)")
    shots = screenshots or [None] * len(paths)
    with tempfile.TemporaryDirectory(prefix="rehab-hil-chromium-") as tmp:
        proc, ws_url = _start(chromium, Path(tmp))
        cdp = None
        try:
            cdp = _Cdp(ws_url)
            return [_check(cdp, Path(p), s, width, settle_timeout_s) for p, s in zip(paths, shots, strict=True)]
        finally:
            if cdp is not None:
                try:
                    cdp.call("Browser.close", timeout_s=5.0)
                except Exception:  # closing a browser that may be gone already
                    pass
                cdp.close()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _check(cdp: _Cdp, path: Path, screenshot: str | Path | None, width: int, settle_timeout_s: float) -> PageCheck:
    url = path.resolve().as_uri()
    cdp.session = None
    target = cdp.call("Target.createTarget", {"url": "about:blank"})["targetId"]
    cdp.session = cdp.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
    cdp.events = []
    for domain in ("Page", "Runtime", "Log"):
        cdp.call(f"{domain}.enable")
    cdp.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": 900, "deviceScaleFactor": 1,
                                                    "mobile": False})
    cdp.call("Page.navigate", {"url": url})
    deadline = time.monotonic() + settle_timeout_s
    while True:
        res = cdp.call("Runtime.evaluate", {"expression": _STATE_JS, "returnByValue": True})["result"]
        st = json.loads(res["value"]) if "value" in res else None  # none while the page is replaced
        if st is not None and (st["state"] in ("drawn", "failed") or time.monotonic() > deadline):
            break
        if st is None and time.monotonic() > deadline:
            raise BrowserError(f"{url}: the page never loaded")
        cdp.drain(0.1)
    cdp.drain(0.3)  # late console messages
    shot = None
    if screenshot is not None:
        cdp.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": int(st["height"]),
                                                        "deviceScaleFactor": 1, "mobile": False})
        cdp.drain(0.5)
        png = cdp.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True})["data"]
        shot = Path(screenshot)
        shot.write_bytes(base64.b64decode(png))
    errors = _errors([e for e in cdp.events if e.get("sessionId") == cdp.session])
    cdp.session = None
    cdp.call("Target.closeTarget", {"targetId": target})
    return PageCheck(state=st["state"], plots=st["plots"], drawn=st["drawn"], traces=st["traces"],
                     drawn_ms=st["drawn_ms"], stages_ms=st["stages_ms"], errors=errors, page_error=st["error"],
                     screenshot=shot)
