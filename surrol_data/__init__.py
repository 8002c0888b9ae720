"""surrol_data."""

import sys as _sys

# Importing gymnasium sets PYGAME_HIDE_SUPPORT_PROMPT in os.environ, and importing this package must leave the
# process environment as it was. Importing gymnasium here to put the variable back would cost every command
# (`surrol-data --help` included) gymnasium's and numpy's import, so instead a finder waits for the first import of
# gymnasium in this process, whoever makes it, and restores the variable when that import is done (pygame, if
# gymnasium's import pulls it in, still sees it set and stays quiet). (The gamepad device hides pygame's banner
# itself when it connects.)
if "gymnasium" not in _sys.modules:
    from surrol_data._gymnasium_env import install as _install

    _install()
    del _install
