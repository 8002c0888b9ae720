"""Importing the package, its envs, the CLI and the recorder leaves the process environment as it was."""

import json
import subprocess
import sys


def test_imports_change_no_environment_variable():
    # gymnasium sets PYGAME_HIDE_SUPPORT_PROMPT when imported; our import of it must not leak that either.
    code = (
        "import json, os\n"
        "before = dict(os.environ)\n"
        "import surrol_data.envs, surrol_data.cli, surrol_data.datasets.recorder, surrol_data.datasets.validate\n"
        "changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))\n"
        "print(json.dumps(changed))\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("HF_HUB_OFFLINE", "SVT_LOG")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []


def test_hub_offline_is_scoped_to_the_block():
    from huggingface_hub import constants
    from huggingface_hub.errors import OfflineModeIsEnabled
    from huggingface_hub.utils import get_session

    from surrol_data.datasets.hub_offline import hub_offline

    saved = constants.HF_HUB_OFFLINE
    constants.HF_HUB_OFFLINE = False
    try:
        with hub_offline():
            try:
                get_session().get("http://127.0.0.1:9/never-reached")
            except OfflineModeIsEnabled:
                pass
            else:
                raise AssertionError("a Hub request went out inside hub_offline()")
        assert constants.HF_HUB_OFFLINE is False
    finally:
        constants.HF_HUB_OFFLINE = saved
