"""Where Panda3D draws: an offscreen OpenGL context through EGL (no display needed), or a window.

Panda3D is configured here once, before its first graphics pipe exists: no audio, no default window,
quiet logs. Offscreen rendering goes through Panda3D's ``p3headlessgl`` (EGL); on a machine without a GPU
Mesa's software rasteriser (llvmpipe) serves it. When the system lacks EGL or Mesa the error names the
Debian packages that provide them.
"""

from __future__ import annotations

import functools
import os

# Debian packages that provide EGL and Mesa's software OpenGL (named in errors and test skips).
GL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri"
# How an env's camera does without Panda3D, in the API's words; a command says it in its own (`in_words_of`).
TINY_INSTEAD = ", or draw with TinyRenderer (camera_renderer='tiny')"

_PRC = """
audio-library-name null
window-type none
notify-level warning
notify-level-display error
default-directnotify-level warning
sync-video false
textures-power-2 none
framebuffer-multisample true
multisamples 4
"""


def in_words_of(message: str, instead: str) -> str:
    """``message`` with the API's way around Panda3D replaced by a command's (``""``: a command that has none)."""
    return message.replace(TINY_INSTEAD, instead)


def display_name() -> str:
    """The X or Wayland display named by DISPLAY / WAYLAND_DISPLAY ("" for none)."""
    return os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or ""


def has_display() -> bool:
    """Whether a window can be asked for: an X or Wayland display is named (DISPLAY / WAYLAND_DISPLAY)."""
    return bool(display_name())


def no_window_here(offscreen: bool | None, runs_alone: bool) -> str | None:
    """Why the training GUI must not start, or None: a window needs a display, and a window drawn offscreen is seen
    by nobody and takes no input, so it runs only when it plays by itself (``runs_alone``: ``--autoplay``). Without
    this, a GUI started where there is no display would draw an invisible window until killed."""
    headless = "or headless with --offscreen --task TASK --autoplay N (records N episodes; --screenshot FILE.png)"
    if offscreen is None and not has_display():
        return ("no display to open the GUI's window on (DISPLAY and WAYLAND_DISPLAY are unset): run it on a "
                "desktop, under a virtual display (`xvfb-run -a surrol-data gui --onscreen`, Debian package xvfb), "
                + headless)
    if offscreen and not runs_alone:
        return ("--offscreen draws a window nobody sees and that takes no input: add --task TASK --autoplay N to "
                "record N episodes headless, or open a window with --onscreen (on a display or under Xvfb)")
    return None


class RendererUnavailable(RuntimeError):
    """Panda3D cannot render here (no EGL/OpenGL); the message says what to install."""


@functools.cache
def configure() -> None:
    """Apply the project's Panda3D settings (once, before any pipe or ShowBase exists)."""
    from panda3d.core import loadPrcFileData

    loadPrcFileData("surrol_data", _PRC)


@functools.cache
def offscreen_pipe():
    """Panda3D's EGL pipe for rendering into buffers without a display (one per process)."""
    configure()
    from panda3d.core import GraphicsPipeSelection

    pipe = GraphicsPipeSelection.get_global_ptr().make_module_pipe("p3headlessgl")
    if pipe is None or not pipe.is_valid():
        raise RendererUnavailable(
            "Panda3D found no EGL/OpenGL to render offscreen; install the system packages "
            f"`apt-get install {GL_PACKAGES}` (Mesa's software GL works without a GPU){TINY_INSTEAD}")
    return pipe


@functools.cache
def unavailable_reason() -> str | None:
    """None when Panda3D can render offscreen here, else why not (for test skips and CLI errors)."""
    try:
        pipe = offscreen_pipe()
        from panda3d.core import FrameBufferProperties, GraphicsEngine, GraphicsPipe, WindowProperties

        engine = GraphicsEngine(pipe)
        buffer = engine.make_output(pipe, "probe", 0, FrameBufferProperties.get_default(),
                                    WindowProperties.size(8, 8), GraphicsPipe.BF_refuse_window)
        if buffer is None:
            raise RendererUnavailable(f"Panda3D could not open an offscreen OpenGL buffer through EGL; install "
                                      f"`apt-get install {GL_PACKAGES}`{TINY_INSTEAD}")
        engine.remove_all_windows()
    except (RendererUnavailable, ImportError) as e:
        return str(e)
    return None


def best_renderer() -> str:
    """``panda3d`` where it can render offscreen here, else ``tiny`` (TinyRenderer draws everywhere)."""
    return "panda3d" if unavailable_reason() is None else "tiny"
