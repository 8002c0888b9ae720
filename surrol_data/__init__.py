"""surrol_data."""

import os as _os
import sys as _sys

# Importing gymnasium sets PYGAME_HIDE_SUPPORT_PROMPT in os.environ. Most of the package imports gymnasium, and
# importing the package must leave the process environment as it was, so the first import happens here and the
# variable is put back. (The gamepad device hides pygame's banner itself when it connects.)
if "gymnasium" not in _sys.modules:
    _saved = _os.environ.get("PYGAME_HIDE_SUPPORT_PROMPT")
    import gymnasium as _gymnasium  # noqa: F401

    if _saved is None:
        _os.environ.pop("PYGAME_HIDE_SUPPORT_PROMPT", None)
    else:
        _os.environ["PYGAME_HIDE_SUPPORT_PROMPT"] = _saved
    del _saved, _gymnasium
