"""Text that fits the room it has in the window: shrunk a little, then cut in the middle, never past the edge.

Panda3D draws a text as long as it is, over the window's edge if need be (a long recording path in the status line
was cut off by the window's border at 1280×720). A text given its room is first drawn smaller (down to
``min_scale``: smaller still would not read), and a line that still does not fit loses characters from its middle,
marked by ``...``, so that its start (what it is) and its end (the task, the file) stay readable.
"""

from __future__ import annotations

from collections.abc import Callable

ELLIPSIS = "..."   # the default font has no single-character ellipsis


def fit_text(text: str, width_of: Callable[[str], float], available: float, scale: float,
             min_scale: float) -> tuple[str, float]:
    """``(text, scale)`` to draw so that every line's ``width_of(line) * scale`` is at most ``available``:
    ``scale`` when it fits, else the largest scale that does (not below ``min_scale``), with the lines still too
    wide cut in the middle."""
    lines = text.split("\n")
    widest = max(width_of(line) for line in lines)
    if widest * scale <= available:
        return text, scale
    fitted = max(min_scale, available / widest)
    return "\n".join(_elide(line, width_of, available / fitted) for line in lines), fitted


def _elide(line: str, width_of: Callable[[str], float], room: float) -> str:
    """``line``, or its start and end joined by ``...`` as long as fits in ``room`` (the end gets the odd character)."""
    if width_of(line) <= room:
        return line
    for keep in range(len(line) - 1, -1, -1):
        candidate = line[:keep // 2] + ELLIPSIS + line[len(line) - (keep - keep // 2):]
        if width_of(candidate) <= room:
            return candidate
    return ""
