"""Make docs/web_console.png: the web console's page in headless Chromium, mid-attempt on NeedlePick.

Usage: ``uv run python docs/make_web_console_image.py`` (needs Debian's ``chromium``). A server on a free port, one
page, an operator who presses play and brings the tool down towards the needle; the screenshot is the page at
1280×800.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent / "tests"))
from headless_chromium import Chromium  # noqa: E402

SERVER = "import sys; from surrol_data.web import serve; serve(sys.argv[1], ['NeedlePick', 'NeedleReach', " \
         "'PegTransfer', 'GauzeRetrieve', 'NeedleRegrasp', 'BiPegTransfer'], port=0)"


def main() -> None:
    out = tempfile.mkdtemp(prefix="surrol-web-shot-")
    proc = subprocess.Popen([sys.executable, "-c", SERVER, out], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    url = None
    for line in proc.stdout:
        if (found := re.search(r"open (http://\S+)", line)):
            url = found.group(1)
            break
    threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()
    try:
        with Chromium(1280, 800) as browser:
            page = browser.new_page()
            page.cdp.call("Emulation.setDeviceMetricsOverride", width=1280, height=800, deviceScaleFactor=1,
                          mobile=False)
            page.goto(url)
            page.wait_for("document.getElementById('who').open")
            page.js("localStorage.setItem('surrol.operator', 'resident07'); localStorage.setItem('surrol.skill', "
                    "'novice'); location.reload()")
            page.wait_for("window.consoleStats && window.consoleStats.frames > 0 && "
                          "!document.getElementById('play').disabled", timeout=300)
            page.js("document.getElementById('play').click()")
            page.wait_for("window.consoleStats.hud && window.consoleStats.hud.playing", timeout=300)
            for key, steps in (("s", 6), ("a", 2)):
                page.key(key, True)
                start = page.js("window.consoleStats.hud.step")
                page.wait_for(f"window.consoleStats.hud.step >= {start + steps}", timeout=300)
                page.key(key, False)
            page.wait_for(f"window.consoleStats.lastAck >= {page.js('window.consoleStats.sent')}")
            page.screenshot(DOCS / "web_console.png")
            page.tap("Escape")
    finally:
        proc.send_signal(2)
        proc.wait(120)
    print(DOCS / "web_console.png")


if __name__ == "__main__":
    main()
