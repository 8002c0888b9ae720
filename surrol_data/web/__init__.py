"""The web console: human demonstrations from any browser (``surrol-data serve``).

One server (:mod:`~surrol_data.web.server`), one process per browser running its operator's env and endoscope view
(:mod:`~surrol_data.web.worker`), one writer for every browser's episodes (:mod:`~surrol_data.web.writer`), and the
page (``static/``). :func:`serve` runs it.
"""

from __future__ import annotations

import logging
import secrets
import socket
import sys
from pathlib import Path

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8765


def pick_renderer(renderer: str) -> str:
    """``auto``: Panda3D where it can render offscreen here, else TinyRenderer; a name is taken as it is."""
    if renderer != "auto":
        return renderer
    try:
        from surrol_data.render.display import best_renderer
    except ImportError:   # no panda3d: TinyRenderer draws everywhere
        return "tiny"
    return best_renderer()


def serve(out: str | Path, tasks: list[str], host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
          token: str | None = None, size: tuple[int, int] = (640, 480), renderer: str = "auto",
          realtime: bool = True, announce=print) -> None:
    """Serve the console until Ctrl-C: episodes into ``out/<Task>``, one process per browser. ``port`` 0 picks a free
    one; ``token`` (default: a new random one) is what every browser needs; the address with it is announced."""
    import uvicorn

    from surrol_data.web.server import MAX_MESSAGE_BYTES, WebConsole

    token = token or secrets.token_urlsafe(16)
    renderer = pick_renderer(renderer)
    console = WebConsole(out, tasks, token, size=size, renderer=renderer, realtime=realtime)
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    announce(f"web console for {', '.join(tasks)} ({renderer} view {size[0]}x{size[1]}): episodes into {Path(out)}/<task>")
    announce(f"open http://{shown}:{bound}/?token={token}")
    if host in ("127.0.0.1", "localhost", "::1"):
        announce("(this machine only; --host 0.0.0.0 serves the network, with the same token)")
    config = uvicorn.Config(console.app(), log_level="warning", ws_max_size=16 * MAX_MESSAGE_BYTES,
                            ws_ping_interval=10, ws_ping_timeout=10, ws="websockets-sansio")
    uvicorn.Server(config).run(sockets=[sock])
