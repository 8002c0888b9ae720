"""``surrol-data push DIR --repo-id USER/NAME``: publish a dataset on the Hugging Face Hub in one command.

Validates first (a dataset that fails ``surrol-data validate`` is not pushed), refreshes the dataset card,
creates the dataset repo if needed, uploads the folder (minus the PNG staging area ``images/``, repair
backups, partial files and locks), deletes what an earlier push left that the folder no longer has (the repo
mirrors the dataset) and points the LeRobot codebase-version tag (``v3.0``) at the new commit:
``LeRobotDataset(repo_id)`` loads the revision that tag names, so a tag left on the first push would hide every
later one. ``--dry-run`` lists what would be uploaded, selected with huggingface_hub's
own pattern filter, without any network access.

A push needs the Hub reachable (``HF_HUB_OFFLINE`` unset or 0) and a token (``hf auth login`` or ``HF_TOKEN``);
``HF_ENDPOINT`` points it at another Hub (the tests use a local stand-in).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

# What stays on the recording machine: lerobot's PNG staging area, repair backups, the crash journal, the writer's
# lock, partial files and caches.
IGNORE_PATTERNS = ["images/*", ".surrol_data_repair/*", ".surrol_data_journal/*", ".surrol_data.lock", "*.lock",
                   "*.tmp", "*.partial", ".cache/*"]


@dataclass
class PushPlan:
    repo_id: str
    root: Path
    files: list[str] = field(default_factory=list)   # relative paths, sorted
    bytes: int = 0
    revision_tag: str = ""


def plan_push(root: str | Path, repo_id: str) -> PushPlan:
    """What :func:`push_dataset` would upload (no network)."""
    from huggingface_hub.utils import filter_repo_objects

    from surrol_data.datasets.reader import load_info

    root = Path(root)
    info = load_info(root)
    if repo_id.count("/") != 1 or not all(repo_id.split("/")):
        raise ValueError(f"--repo-id must be 'user_or_org/name', got {repo_id!r}")
    paths = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    files = list(filter_repo_objects(paths, ignore_patterns=IGNORE_PATTERNS))
    return PushPlan(repo_id=repo_id, root=root, files=files, bytes=sum((root / f).stat().st_size for f in files),
                    revision_tag=str(info.get("codebase_version", "")))


def push_dataset(root: str | Path, repo_id: str, *, private: bool = False, dry_run: bool = False,
                 skip_validation: bool = False) -> PushPlan:
    """Upload the dataset at ``root`` to the Hub dataset repo ``repo_id`` (see the module docstring)."""
    from surrol_data.datasets.card import write_dataset_card

    root = Path(root)
    plan = plan_push(root, repo_id)
    if dry_run:
        return plan
    if not skip_validation:
        from surrol_data.datasets.validate import validate_dataset

        problems = validate_dataset(root)
        if problems:
            raise ValueError(f"{root} does not validate ({len(problems)} problem(s), first: {problems[0]}); "
                             "fix it or pass --skip-validation")
    from huggingface_hub import HfApi, constants

    if constants.HF_HUB_OFFLINE:
        raise RuntimeError("the Hub is disabled (HF_HUB_OFFLINE=1 in the environment); run the push with "
                           "HF_HUB_OFFLINE=0")
    write_dataset_card(root, repo_id=repo_id)
    plan = plan_push(root, repo_id)
    api = HfApi(token=os.environ.get("HF_TOKEN"))
    api.create_repo(repo_id, repo_type="dataset", private=private, exist_ok=True)
    # delete_patterns="*": files of an earlier push that this dataset no longer has go (a stale episodes-metadata
    # file would otherwise be read as part of the dataset); .gitattributes stays (huggingface_hub keeps it).
    commit = api.upload_folder(folder_path=str(root), repo_id=repo_id, repo_type="dataset",
                               ignore_patterns=IGNORE_PATTERNS, delete_patterns="*",
                               commit_message="surrol_data: push dataset")
    if plan.revision_tag:
        move_tag(api, repo_id, plan.revision_tag, commit.oid)
    return plan


def move_tag(api, repo_id: str, tag: str, revision: str) -> None:
    """Point ``tag`` of the dataset repo at ``revision``, replacing the tag if an earlier push made it."""
    if any(ref.name == tag for ref in api.list_repo_refs(repo_id, repo_type="dataset").tags):
        api.delete_tag(repo_id, tag=tag, repo_type="dataset")
    api.create_tag(repo_id, tag=tag, revision=revision, repo_type="dataset")
