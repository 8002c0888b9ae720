"""Optional parts of the toolkit and the install extra that brings each one.

The core install records, reads, trains and reports; devices, exports, the Panda3D renderer and GUI, cluster
sweeps and TensorBoard logs need packages few users want, so they come as extras (``pip install
'surrol-data[devices]'``, ``uv sync --extra devices``). :func:`require` imports such a package, or says which
extra to install.
"""

from __future__ import annotations

import importlib
from types import ModuleType

# import name -> (extra, distribution that provides it)
OPTIONAL = {
    "pygame": ("devices", "pygame"),
    "hid": ("devices", "hidapi"),
    "minari": ("export", "minari"),
    "h5py": ("export", "h5py"),
    "robomimic": ("export", "robomimic"),
    "panda3d": ("render", "panda3d"),
    "tensorboard": ("tensorboard", "tensorboard"),
    "hydra_plugins.hydra_submitit_launcher": ("cluster", "hydra-submitit-launcher"),
    "submitit": ("cluster", "submitit"),
    "starlette": ("web", "starlette"),
    "uvicorn": ("web", "uvicorn"),
    "websockets": ("web", "websockets"),
    "cryptography": ("sign", "cryptography"),
}


class MissingExtra(ImportError):
    """An optional package is not installed; the message names the extra that brings it."""


def install_hint(module: str) -> str:
    extra, dist = OPTIONAL[module]
    return (f"this needs the optional package {dist!r}: install the {extra!r} extra, "
            f"`pip install 'surrol-data[{extra}]'` (or `uv sync --extra {extra}` in a clone)")


def require(module: str) -> ModuleType:
    """Import ``module`` (a key of :data:`OPTIONAL`) or raise :class:`MissingExtra` naming its extra."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise MissingExtra(install_hint(module)) from e
