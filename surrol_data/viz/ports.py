"""Local TCP ports for the servers ``view --web`` starts: a free one, whether one is taken, whether a page answers."""

from __future__ import annotations

import socket
import time
import urllib.request


def free_port() -> int:
    """A port no program listens on now (the OS picks it)."""
    with socket.socket() as s:
        s.bind(("", 0))
        return int(s.getsockname()[1])


def port_taken(port: int) -> bool:
    """Whether a program already listens on ``port`` (binding it fails)."""
    with socket.socket() as s:
        try:
            s.bind(("", port))
        except OSError:
            return True
    return False


def wait_for_http(port: int, timeout_s: float = 30.0) -> bool:
    """Whether an HTTP server answers on ``localhost:port`` within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2):
                return True
        except OSError:
            time.sleep(0.2)
    return False
