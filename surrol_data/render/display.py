"""Where Panda3D draws: an offscreen OpenGL context through EGL (no display needed), or a window.

Panda3D is configured here once, before its first graphics pipe exists: no audio, no default window,
quiet logs. Offscreen rendering goes through Panda3D's ``p3headlessgl`` (EGL); on a machine without a GPU
Mesa's software rasteriser (llvmpipe) serves it. When the system lacks EGL or Mesa the error names the
Debian packages that provide them.
"""

from __future__ import annotations

import functools

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
