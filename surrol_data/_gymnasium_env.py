"""Keep gymnasium's import from changing the process environment, without importing gymnasium (see ``__init__``).

gymnasium's ``__init__`` sets ``os.environ["PYGAME_HIDE_SUPPORT_PROMPT"]``. :func:`install` puts a finder first on
``sys.meta_path`` that answers only for the top-level ``gymnasium`` package: it lets the normal finders locate it,
wraps the loader so the variable is restored once the module has executed, and removes itself (one import only).
"""

from __future__ import annotations

import os
import sys
from importlib.abc import MetaPathFinder

VARIABLE = "PYGAME_HIDE_SUPPORT_PROMPT"


class _RestoringLoader:
    """Delegates to gymnasium's loader; after ``exec_module`` the variable is what it was before."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        saved = os.environ.get(VARIABLE)
        try:
            self._loader.exec_module(module)
        finally:
            if saved is None:
                os.environ.pop(VARIABLE, None)
            else:
                os.environ[VARIABLE] = saved

    def __getattr__(self, name):   # get_data, get_filename, get_resource_reader, ... as the real loader has them
        return getattr(self._loader, name)


class _GymnasiumFinder(MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        uninstall()   # before the search below, which would otherwise come back here
        spec = None
        for finder in sys.meta_path:   # the normal search, as the import system would make it
            find = getattr(finder, "find_spec", None)
            spec = find(fullname, path, target) if find is not None else None
            if spec is not None:
                break
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        spec.loader = _RestoringLoader(spec.loader)
        return spec


_FINDER = _GymnasiumFinder()


def install() -> None:
    """Watch for the first import of gymnasium (a no-op if it is imported already or the finder is installed)."""
    if "gymnasium" not in sys.modules and _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)


def uninstall() -> None:
    while _FINDER in sys.meta_path:
        sys.meta_path.remove(_FINDER)
