"""``surrol-data info``'s answer remembered by the dataset's content digest, so that asking again is seconds.

At 10,000 episodes the answer costs ~20 s of CPU however it is computed: 1,000 ``meta/episodes`` footers of ~230
columns each to parse (~5 ms each), the metadata checks over every row, and the data files' tip columns for the
smoothness (LDLJ) column. Hashing the whole dataset costs ~0.5 s. So :func:`checked_info` hashes it
(:func:`~surrol_data.datasets.validated_cache.dataset_digest`: every file's path and bytes, and the checking and
summarising code) and, for bytes and code it has answered for before, returns the remembered answer — which was
only ever remembered after the metadata checks passed on those very bytes. Any changed byte (an edited provenance
value, a cut-short file, a swapped video) changes the digest, so the dataset is checked again and the damage is
reported, exactly as without the memory.

What does not change: a dataset left unfinished by a killed recording is found (and repaired or refused,
:func:`~surrol_data.datasets.guard.ensure_finished`) before anything is hashed or looked up; a dataset a full
check already passed (``surrol-data validate``, the commands' own frame check) is not checked again for its
metadata, a part of that check; and nothing is ever written into the dataset: the memory lives in the user's cache
folder (``$XDG_CACHE_HOME/surrol_data/info``), and a cache that cannot be written is simply not used.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from surrol_data.datasets.guard import _stderr, check_finished, ensure_finished, require_dataset_folder
from surrol_data.datasets.info import info_facts
from surrol_data.datasets.validated_cache import cache_dir, dataset_digest, known_valid


def info_cache_dir() -> Path:
    return cache_dir().parent / "info"


def _plain(value):
    """json.dumps' fallback for numpy scalars and arrays (pandas group keys, counts)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _recall(digest: str) -> dict | None:
    try:
        facts = json.loads((info_cache_dir() / f"{digest}.json").read_text())
    except (OSError, ValueError):
        return None   # never remembered, or a cache file cut short: answer afresh
    return facts if isinstance(facts, dict) and {"summary", "by_skill"} <= facts.keys() else None


def _remember(digest: str, text: str) -> None:
    """Write atomically (a killed ``info`` leaves no half file to be recalled); silently nothing if unwritable."""
    try:
        folder = info_cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".json")
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, folder / f"{digest}.json")
    except OSError:
        pass


def checked_info(root: str | Path, notify: Callable[[str], None] = _stderr) -> tuple[Path, dict]:
    """(the folder read, :func:`~surrol_data.datasets.info.info_facts` of it) after the metadata checks of
    :func:`~surrol_data.datasets.guard.require_valid` (``frames=False``) — or the remembered facts of the same
    bytes, which passed them. DatasetError as ``require_valid`` raises it."""
    require_dataset_folder(root)
    target = ensure_finished(root, notify)   # a killed recording is found before any lookup
    digest = dataset_digest(target)
    checked = "full" if known_valid(digest) else "metadata"   # what the answer rests on; shown by render_info
    facts = _recall(digest)
    if facts is not None:
        return target, {**facts, "checked": checked}
    if checked != "full":   # a full check of these bytes passed: the metadata checks are a part of it
        check_finished(root, target, frames=False)
    # rendered from the JSON round trip, remembered or not, so a recalled answer reads exactly like a fresh one
    text = json.dumps(info_facts(target), default=_plain)
    # remembered only under the digest of the bytes the facts were read from: a change while they were read (another
    # process writing) would otherwise leave an answer for bytes that are not the ones it was drawn from
    if dataset_digest(target) == digest:
        _remember(digest, text)
    return target, {**json.loads(text), "checked": checked}
