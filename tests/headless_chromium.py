"""A real headless Chromium driven through the DevTools protocol (no Selenium): pages, keys, scripts, screenshots.

Used by the web console's tests and ``benchmarks/web_console.py``. :func:`chromium` is None where Debian's
``chromium`` is not installed (the tests then skip, naming it). Each :meth:`Chromium.new_page` opens a page in a
browser context of its own (its own localStorage, as another person's browser).
"""

from __future__ import annotations

import base64
import io
import itertools
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
         "--disable-backgrounding-occluded-windows", "--window-size=1400,900"]
PACKAGE = "chromium"


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Chromium:
    """One Chromium process (``with Chromium() as browser:``)."""

    def __init__(self, width: int = 1400, height: int = 900):
        from websockets.sync.client import connect

        self._connect = connect
        self.profile = tempfile.TemporaryDirectory(prefix="surrol-chromium-")
        self.proc = subprocess.Popen([chromium(), *FLAGS, f"--window-size={width},{height}",
                                      f"--user-data-dir={self.profile.name}", "--remote-debugging-port=0",
                                      "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = Path(self.profile.name) / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (port_file.exists() and port_file.read_text().count("\n") >= 1):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError("headless Chromium did not start")
            time.sleep(0.1)
        self.port = int(port_file.read_text().split()[0])
        version = json.load(urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/version", timeout=10))
        self.browser = _Endpoint(connect(version["webSocketDebuggerUrl"], max_size=2 ** 26))

    def new_page(self) -> Page:
        context = self.browser.call("Target.createBrowserContext")["browserContextId"]
        target = self.browser.call("Target.createTarget", url="about:blank", browserContextId=context)["targetId"]
        ws = self._connect(f"ws://127.0.0.1:{self.port}/devtools/page/{target}", max_size=2 ** 26)
        return Page(self, target, _Endpoint(ws))

    def close_page(self, page: Page) -> None:
        """Close the page's tab at once (no unload handshake: as a person closing it)."""
        self.browser.call("Target.closeTarget", targetId=page.target)

    def close(self) -> None:
        try:
            self.browser.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.profile.cleanup()

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Endpoint:
    def __init__(self, ws):
        self.ws = ws
        self._ids = itertools.count(1)

    def call(self, method: str, timeout: float = 60, **params) -> dict:
        ident = next(self._ids)
        self.ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            message = json.loads(self.ws.recv(timeout=max(0.1, deadline - time.monotonic())))
            if message.get("id") == ident:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})


_KEYS = {"Enter": ("Enter", 13, "\r"), "Escape": ("Escape", 27, "")}


class Page:
    def __init__(self, browser: Chromium, target: str, endpoint: _Endpoint):
        self.browser, self.target, self.cdp = browser, target, endpoint

    def goto(self, url: str) -> None:
        # The old document is 'complete' too until the navigation commits (a loaded machine commits late, and a
        # fetch made meanwhile went to the old page and failed): wait for a document without the old one's mark.
        self.js("window.__leaving = true")
        self.cdp.call("Page.navigate", url=url)
        self.wait_for("!window.__leaving && document.readyState === 'complete'")

    def js(self, expression: str, timeout: float = 60):
        """The value of ``expression`` in the page (promises awaited)."""
        result = self.cdp.call("Runtime.evaluate", timeout=timeout, expression=expression, returnByValue=True,
                               awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 120, every: float = 0.1):
        """Wait until ``expression`` is truthy in the page; its value."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.js(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"waited {timeout} s for {expression}")
            time.sleep(every)

    def key(self, key: str, down: bool) -> None:
        """Press (``down``) or release a key as the keyboard does: a letter, ``Enter`` or ``Escape``."""
        code, vk, text = _KEYS[key] if key in _KEYS else (f"Key{key.upper()}", ord(key.upper()), key)
        params = {"type": "keyDown" if down else "keyUp", "key": key, "code": code, "windowsVirtualKeyCode": vk}
        if down and text:
            params["text"] = text
        self.cdp.call("Input.dispatchKeyEvent", **params)

    def tap(self, key: str) -> None:
        self.key(key, True)
        self.key(key, False)

    def type_text(self, text: str) -> None:
        self.cdp.call("Input.insertText", text=text)

    def canvas(self, selector: str = "#frame"):
        """The pixels of a canvas (H, W, 3) uint8."""
        import numpy as np
        from PIL import Image

        url = self.js(f"document.querySelector('{selector}').toDataURL('image/png')")
        png = base64.b64decode(url.split(",", 1)[1])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def screenshot(self, path: str | Path) -> Path:
        data = self.cdp.call("Page.captureScreenshot", format="png")["data"]
        path = Path(path)
        path.write_bytes(base64.b64decode(data))
        return path
