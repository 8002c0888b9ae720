"""Keep the Hugging Face Hub out of local dataset work, without touching the process environment at import.

lerobot falls back to the Hub when a local dataset lacks a metadata file (it tries to download it). For our
local datasets that must fail at once, not reach out. :func:`hub_offline` switches huggingface_hub's own offline
flag — the one its HTTP hook checks before every request — for the duration of a block and restores it, so the
user's own code around ours keeps its Hub access. SVT-AV1 prints ~20 lines per encoded episode unless ``SVT_LOG``
is set; :func:`quiet_video_encoder` sets it for the block only. :func:`local_repo_id` names a local dataset in the
form lerobot accepts whatever its folder is called (``$HOME``, ``[1]``, spaces): an id it refuses makes it try
the Hub instead, and :func:`lerobot_root` gives it a path without the characters that the file patterns of
Hugging Face ``datasets`` expand (``[1]`` would match nothing and the dataset would look empty).
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

_REPO_NAME = re.compile(r"^\w[\w.-]{0,95}$", re.ASCII)


def local_repo_id(root: str | Path) -> str:
    """``local/<folder name>`` with every character huggingface_hub's repo-id check refuses replaced by ``_``
    (lerobot only uses the id as a label for a dataset it opens from ``root``)."""
    name = re.sub(r"[^\w.-]", "_", Path(root).resolve().name, flags=re.ASCII)
    name = re.sub(r"-{2,}", "-", re.sub(r"\.{2,}", ".", name)).strip(".-")[:96].strip(".-") or "dataset"
    return f"local/{name}"


# glob characters, and ``$``: a path holding ``$HOME`` has it expanded on the way (to the user's home folder), so
# lerobot found no local file under a folder literally named so and went to the Hub
_PATTERN_CHARS = re.compile(r"[][*?{}$]")


def lerobot_root(root: str | Path) -> Path:
    """``root`` itself, or, when its absolute path holds a character that Hugging Face ``datasets`` expands in a
    file pattern (lerobot loads ``meta/episodes/*/*.parquet`` through one) or expands (``$HOME``), a symbolic link to it from a plain path
    in a temporary folder (removed at exit). ``root`` must exist."""
    import atexit
    import shutil
    import tempfile

    real = Path(root).resolve()
    if not _PATTERN_CHARS.search(str(real)):
        return Path(root)
    folder = Path(tempfile.mkdtemp(prefix="surrol_data_path_"))
    atexit.register(shutil.rmtree, folder, True)
    link = folder / local_repo_id(real).removeprefix("local/")
    link.symlink_to(real, target_is_directory=True)
    return link


def usable_repo_id(repo_id: str | None, root: str | Path) -> str:
    """``repo_id`` when huggingface_hub accepts it, else :func:`local_repo_id` of ``root``."""
    if repo_id and repo_id.count("/") <= 1 and all(_REPO_NAME.match(part) and ".." not in part and "--" not in part
                                                   and not part.endswith((".", "-"))
                                                   for part in repo_id.split("/")):
        return repo_id
    return local_repo_id(root)


@contextlib.contextmanager
def hub_offline():
    """huggingface_hub refuses every request inside the block (``OfflineModeIsEnabled``)."""
    from huggingface_hub import constants

    saved = constants.HF_HUB_OFFLINE
    constants.HF_HUB_OFFLINE = True
    try:
        yield
    finally:
        constants.HF_HUB_OFFLINE = saved


@contextlib.contextmanager
def quiet_video_encoder():
    """SVT-AV1 and FFmpeg (through PyAV) log errors only inside the block (the user's own ``SVT_LOG`` wins if set);
    without this each encoded episode prints ~20 SVT lines and the mp4 muxer's "Starting second pass" note.

    lerobot's encoder hands FFmpeg's log back to its default (print everything from INFO up) after each episode,
    before it appends the episode to the dataset's video file; inside the block that hand-back keeps errors only.
    """
    import av.logging

    saved = os.environ.get("SVT_LOG")
    saved_level = av.logging.get_level()
    restore_default = av.logging.restore_default_callback
    if saved is None:
        os.environ["SVT_LOG"] = "1"
    av.logging.set_level(av.logging.ERROR)
    av.logging.restore_default_callback = lambda: av.logging.set_level(av.logging.ERROR)
    try:
        yield
    finally:
        av.logging.restore_default_callback = restore_default
        if saved_level is None:
            restore_default()
        else:
            av.logging.set_level(saved_level)
        if saved is None:
            os.environ.pop("SVT_LOG", None)
