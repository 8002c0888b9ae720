"""surrol_data.

Importing gymnasium sets ``PYGAME_HIDE_SUPPORT_PROMPT`` in ``os.environ``, and importing this package must leave the
process environment as it was. Importing gymnasium here to put the variable back would cost every command
(``surrol-data --help`` included) gymnasium's and numpy's import, so instead a finder waits for the first import of
gymnasium in this process, whoever makes it, and restores the variable once that import is done (pygame, if
gymnasium's import pulls it in, still sees it set and stays quiet; the gamepad device hides pygame's banner itself
when it connects). The finder answers only for the top-level ``gymnasium`` package: it lets the normal finders
locate it, wraps its loader, and removes itself (one import only).
"""

import os as _os
import sys as _sys

_VARIABLE = "PYGAME_HIDE_SUPPORT_PROMPT"


class _RestoringLoader:
    """Delegates to gymnasium's loader; after ``exec_module`` the variable is what it was before."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        saved = _os.environ.get(_VARIABLE)
        try:
            self._loader.exec_module(module)
        finally:
            if saved is None:
                _os.environ.pop(_VARIABLE, None)
            else:
                _os.environ[_VARIABLE] = saved

    def __getattr__(self, name):   # get_data, get_filename, get_resource_reader, ... as the real loader has them
        return getattr(self._loader, name)


class _GymnasiumFinder:   # a meta path finder: find_spec is all it needs
    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        _uninstall()   # before the search below, which would otherwise come back here
        spec = None
        for finder in _sys.meta_path:   # the normal search, as the import system would make it
            find = getattr(finder, "find_spec", None)
            spec = find(fullname, path, target) if find is not None else None
            if spec is not None:
                break
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        spec.loader = _RestoringLoader(spec.loader)
        return spec


_FINDER = _GymnasiumFinder()


def _install() -> None:
    """Watch for the first import of gymnasium (a no-op if it is imported already or the finder is installed)."""
    if "gymnasium" not in _sys.modules and _FINDER not in _sys.meta_path:
        _sys.meta_path.insert(0, _FINDER)


def _uninstall() -> None:
    while _FINDER in _sys.meta_path:
        _sys.meta_path.remove(_FINDER)


_install()
