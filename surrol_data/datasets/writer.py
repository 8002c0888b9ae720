"""Write trajectories as a LeRobot v3 dataset (the real ``lerobot`` package) with per-episode provenance.

:class:`DatasetWriter` is the writer; :class:`surrol_data.datasets.recorder.DatasetRecorder`, what collectors and
users open, is the writer that first repairs a dataset a killed recording left unfinished before appending to it
(the repair writes its salvaged episodes through a plain :class:`DatasetWriter`, so the two never import each
other round a circle). Usage::

    features = frame_features(obs_dim=19, goal_dim=3, act_dim=5, n_arms=1)
    with DatasetRecorder("datasets/needle_pick", features=features, task="NeedlePick",
                         env_id="SurRoL/NeedlePick-v0", task_description="pick up the needle") as rec:
        for traj, seed in episodes:
            rec.record(traj, {"source": "script", "device": "none", "skill": "scripted", "seed": seed})

Durability — what survives how the process ends:

* normal exit, exception, SIGINT, SIGTERM: the ``with`` block finalizes, so every episode whose
  ``record`` returned is on disk and the dataset loads. The episode in progress is dropped. While
  recording, SIGINT/SIGTERM handlers raise (KeyboardInterrupt / SystemExit(143)) so ``finally`` runs;
  a signal that arrives inside ``save_episode`` or a checkpoint is held until it is done, so no episode is
  ever half written. Previous handlers are restored on close.
* SIGKILL, power loss, ``os._exit``: LeRobot keeps one ParquetWriter open per session and a parquet
  file only becomes readable once its footer is written at close. So every finished episode is first
  written to a per-episode journal (:mod:`surrol_data.datasets.journal`, one small file, atomically) before
  ``record`` returns, and the recorder **checkpoints** every ``checkpoint_every`` episodes or
  ``checkpoint_interval_s`` seconds: it closes every open file, continues in new data / metadata / video
  files (as LeRobot's resume would) and empties the journal, so files stay few and the journal short.
  After a hard kill, :func:`surrol_data.datasets.repair.repair` (``surrol-data repair``, run automatically
  by every command that opens the dataset) cuts the unreadable files back and replays the journal: every
  finished episode is kept; only the one in progress is lost.
* When the session ends, the files its checkpoints left (one data and one ``meta/episodes`` file per checkpoint) are
  rewritten into as few as lerobot's size limit allows (:mod:`surrol_data.datasets.consolidate`; ``consolidate=False``
  keeps them), atomically: a kill in the middle is finished or undone by ``repair``, every episode kept.
* One writer at a time: the recorder holds a lock on the folder (:mod:`surrol_data.datasets.lock`); a
  second writer gets a clear error. A session that records no episode removes the folder it created.

Start-up: a new state-only dataset is opened without lerobot (whose import, torch included, cost ~5 s before the
first episode): the folder, the lock and the sidecar (with the features, ``pending_dataset``) are made at open, the
episodes are journalled as always and held in memory, and the first checkpoint (or ``close``) creates the LeRobot
dataset and saves them in order — the same calls as an eager open, so the same files. A caller whose rollouts run in
other processes imports lerobot in a thread meanwhile (:meth:`DatasetRecorder.import_lerobot_in_background`); the
checkpoints then wait for that import to end (up to ``MAX_UNSAVED_WHILE_IMPORTING`` episodes, all in the journal)
instead of the recording waiting for it, and the dataset is created with a checkpoint after every
``checkpoint_every`` episodes, where an eager open made them. A SIGKILL before then leaves
the journal and the sidecar; :func:`surrol_data.datasets.repair.repair` creates the dataset from the sidecar's
features and replays the journal. Camera datasets, appends and ``lazy=False`` create or resume at open.

Episode metadata rows, ``info.json`` and ``stats.json`` are written at each checkpoint, ``checkpoint_every``
episodes at a time (:func:`lerobot_compat.attach_episode_columns` with ``batch``): so info.json is never ahead of
meta/episodes, and ``meta/episodes`` holds one parquet row group per checkpoint instead of one (~60 KB of column
metadata) per episode.

Provenance goes into the episodes parquet as ``provenance/<name>`` columns (see
:mod:`surrol_data.datasets.schema`) by wrapping ``ds.meta.save_episode`` (re-installed after each resume),
so LeRobot's ``episode_filter`` sees them.

Speed (``benchmarks/dataset_io.py``): a state-only episode is handed to lerobot whole, as the frame buffer
``save_episode(episode_data=...)`` takes, instead of T ``add_frame`` calls that would re-validate every
frame (:meth:`DatasetWriter._frame_arrays` has already checked every dtype and shape); camera episodes
still go through ``add_frame``, which stages the PNGs lerobot's video encoder reads. A checkpoint closes
the open parquet files and points lerobot's writers at new ones (:func:`lerobot_compat.close_files_and_continue`) instead
of ``finalize`` + ``resume``, whose reload of the episodes table costs ~1 s and grows with the dataset; the
files on disk are the same as after a resume. LeRobot's ``save_episode`` also spends most of its remaining
time in ``embed_images`` — a per-row ``datasets.map`` that only matters for ``image`` features (PNG bytes
in the parquet). With ``fast_save=True`` the module-level ``embed_images`` of lerobot's writer is replaced
by a guard that calls the original whenever the episode has an ``image`` feature and skips it otherwise,
so it stays correct for any dataset written in the process. ``fast_save`` also removes the rest of lerobot's
per-episode overhead (:func:`lerobot_compat.install_fast_save`): the episode's arrow table is built with pyarrow
instead of ``datasets.Dataset.from_dict`` (whose dill fingerprint of the episode cost half of ``record``), the
statistics of vector features come from :mod:`surrol_data.datasets.fast_stats`, and lerobot's per-episode
schema rebuild and per-frame task lookups are remembered; the files are identical to lerobot's own (each
replacement is checked against lerobot's result on the first episode of every feature set, and falls back to it
otherwise). CPU per NeedlePick script episode in ``record`` (``benchmarks/record_cpu.py``, see
docs/benchmarks.md): ~76 ms before, ~14 ms after, against ~55-65 ms for the rollout itself.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from surrol_data.datasets import consolidate as files
from surrol_data.datasets import journal
from surrol_data.datasets.card import write_dataset_card
from surrol_data.datasets.hub_offline import hub_offline, lerobot_root, quiet_video_encoder, usable_repo_id
from surrol_data.datasets import lerobot_compat
from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.lock import DatasetLock
from surrol_data.datasets.reader import (
    DATA_DIR,
    EPISODES_DIR,
    INFO_PATH,
    DatasetError,
    parquet_files,
)
from surrol_data.datasets.schema import (
    CAMERA_VERSION,
    DEFAULT_CAMERA_RENDERER,
    ENV_STATE,
    FPS,
    INTERVENTION_ARMS,
    IS_INTERVENTION,
    NEXT_ENV_STATE,
    PENDING_DATASET,
    POLICY_ACTION,
    PROVENANCE_COLUMNS,
    PROVENANCE_PREFIX,
    PROVENANCE_SEAL,
    SCHEMA_VERSION,
    SIDECAR_PATH,
    content_hash,
    camera_renderer_of,
    camera_version_of,
    dims_from_features,
    is_schema1,
    normalize_provenance,
    package_version,
    provenance_seal,
    utc_now_iso,
    video_seal_column,
)
from surrol_data.datasets.trajectory import DEVICE_FLAGS, EVENT_FLAGS, INTERVENTION, Trajectory

ROBOT_TYPE = "dvrk_psm"  # the default; collectors pass surrol_data.envs.names.dimension_names(env).robot_type
VIDEO_BACKEND = "pyav"  # explicit: avoids torchcodec probing (and its 60-line warning without system ffmpeg)
REPAIR_DIR = ".surrol_data_repair"
MAX_UNSAVED = 10   # episodes a lazy open holds in memory at most before it creates the LeRobot dataset
# ... while lerobot is imported in the background (import_lerobot_in_background): creating the dataset would wait
# for the import, and the rollout workers for the recorder. A state-only episode is small (~40 KB at 150 steps).
MAX_UNSAVED_WHILE_IMPORTING = 500


def _lerobot_dataset_class():
    """``LeRobotDataset`` (see :func:`surrol_data.datasets.lerobot_compat.lerobot_dataset_class`)."""
    return lerobot_compat.lerobot_dataset_class()


def git_commit() -> str:
    """Commit of the surrol_data source tree (``-dirty`` if tracked files changed), "" when not in git."""
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if sha.returncode != 0:
            return ""
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=10)
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return ""


def _write_json_atomic(path: Path, data: dict) -> None:
    # A kill mid-write must leave the previous version, not half a file.
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str))
    os.replace(tmp, path)


def _features_mismatch(expected: dict, actual: dict) -> list[str]:
    problems = []
    for key in sorted(set(expected) | set(actual)):
        if key not in actual:
            problems.append(f"{key} missing from the dataset")
        elif key not in expected:
            problems.append(f"{key} in the dataset but not in the given features")
        else:
            a, b = expected[key], actual[key]
            if a["dtype"] != b["dtype"] or tuple(a["shape"]) != tuple(b["shape"]):
                problems.append(f"{key}: given {a['dtype']}{tuple(a['shape'])}, dataset has "
                                f"{b['dtype']}{tuple(b['shape'])}")
    return problems


class DatasetWriter:
    """Context manager writing one :class:`Trajectory` per :meth:`record` call (see the module doc).

    ``root``: the dataset folder. With ``append=False`` it must not exist; with ``append=True`` an
    existing dataset is resumed (and a missing one created). ``features`` (from
    :func:`surrol_data.datasets.schema.frame_features`) is required to create, and checked against the
    dataset when appending. ``task_description`` is LeRobot's natural-language per-frame task; ``task`` and
    ``env_id`` are the defaults of the provenance columns of the same names and go into the sidecar.
    """

    def __init__(self, root: str | Path, *, task: str, env_id: str, task_description: str,
                 features: dict | None = None, repo_id: str | None = None, robot_type: str = ROBOT_TYPE,
                 append: bool = False, checkpoint_every: int = 10, checkpoint_interval_s: float | None = 60.0,
                 command: str | None = None, handle_signals: bool = True, fast_save: bool = True,
                 camera_version: int = CAMERA_VERSION, camera_renderer: str = DEFAULT_CAMERA_RENDERER,
                 lazy: bool = True, consolidate: bool = True):
        from surrol_data.datasets.output_path import new_output

        self.root = new_output(root)   # a link to a folder still to be made: that folder
        # A new state-only dataset is created at the first checkpoint, not at open (see _open_lazily); lazy=False
        # creates it at open, e.g. for an interactive session, whose operator would rather wait before the first
        # episode than after it.
        self.lazy = lazy
        # The images' camera version (schema.CAMERA_VERSION): what this code renders, unless the episodes are
        # copied from a dataset recorded with another (merge, split, repair pass the source's). Likewise the
        # renderer that drew them (the collectors pass the env's camera_renderer, the copies the source's).
        self.camera_version = camera_version
        self.camera_renderer = camera_renderer
        self.repo_id = usable_repo_id(repo_id, self.root)  # lerobot tries the Hub for an id it refuses
        self.task, self.env_id, self.task_description = task, env_id, task_description
        self.robot_type = robot_type
        self.append = append
        if checkpoint_every < 1:
            raise ValueError(f"checkpoint_every must be >= 1, got {checkpoint_every}")
        self.checkpoint_every = checkpoint_every
        self.checkpoint_interval_s = checkpoint_interval_s
        self.command = command if command is not None else shlex.join(sys.argv)
        self.handle_signals = handle_signals
        self.fast_save = fast_save
        self.consolidate = consolidate   # False: keep one file per checkpoint (the layout a killed recording leaves)
        for name, value in (("task", task), ("env_id", env_id), ("task_description", task_description)):
            if not isinstance(value, str) or not value:
                raise ValueError(f"DatasetRecorder: {name} must be a non-empty string, got {value!r}")

        self._exists = self.root.exists()
        if self._exists and not append and _holds_no_episode(self.root):
            # Left by a recording killed before its first episode: nothing to keep, so it must not block a retry.
            print(f"note: {self.root} holds no episode (a recording killed before its first episode); "
                  "replacing it", file=sys.stderr)
            shutil.rmtree(self.root)
            self._exists = False
        if self._exists and not append:
            raise FileExistsError(f"{self.root} already exists: add episodes to it with --append, "
                                  "or choose a new folder")
        if self._exists:
            from surrol_data.datasets.readonly_view import is_writable

            if not is_writable(self.root):   # before the repair an unfinished one needs, which could not be kept
                raise DatasetError(f"{self.root} cannot be written here (a read-only disk or folder); it is "
                                   "unchanged: to add episodes to it, copy it to a writable folder and append there")
            if (self.root / "meta").is_dir():
                # A recording killed before it created its LeRobot dataset left no info.json: the repair builds it.
                self._before_append()
            if not (self.root / INFO_PATH).exists():
                raise DatasetError(f"{self.root} exists but is not a LeRobot dataset ({INFO_PATH} missing); "
                                   "choose a new folder or the root of an existing dataset")
            existing = json.loads((self.root / INFO_PATH).read_text())["features"]
            if is_schema1(existing):
                raise DatasetError(f"{self.root} was written with surrol_data schema 1: run `surrol-data upgrade "
                                   f"{self.root}` before adding episodes to it")
            if features is not None:
                ours = {k: v for k, v in existing.items() if k not in _LEROBOT_DEFAULT_FEATURES}
                optional = {f"complementary_info.{e}" for e in EVENT_FLAGS} - set(ours)
                problems = _features_mismatch({k: v for k, v in features.items() if k not in optional}, ours)
                if problems:
                    raise ValueError(f"cannot append to {self.root}: features differ — " + "; ".join(problems))
            sidecar = read_sidecar(self.root)
            for key, value in (("task", task), ("env_id", env_id)):
                if sidecar.get(key, value) != value:
                    raise ValueError(f"cannot append to {self.root}: it holds {key}={sidecar[key]!r}, "
                                     f"the recorder was given {value!r}; record into another dataset")
            version = camera_version_of(sidecar, existing)
            if version not in (None, camera_version):
                raise ValueError(f"cannot append to {self.root}: its images are of camera version {version}, the "
                                 f"new episodes' of camera version {camera_version} (the endoscope image was turned "
                                 "and reframed; see surrol_data.datasets.schema.CAMERA_VERSION); record into a new "
                                 "dataset")
            renderer = camera_renderer_of(sidecar, existing)
            if renderer not in (None, camera_renderer):
                raise ValueError(f"cannot append to {self.root}: its endoscope images were drawn by the {renderer!r} "
                                 f"renderer, the new episodes' by {camera_renderer!r}; record with --renderer "
                                 f"{renderer}, or into a new dataset")
            features = {k: v for k, v in existing.items() if k not in _LEROBOT_DEFAULT_FEATURES}
            # Episodes of one dataset are sealed all or none (one episodes-table schema): a dataset recorded
            # before seals existed takes new episodes unsealed (`surrol-data filter` makes a sealed copy).
            self._sealed = bool(sidecar.get("seals"))
        elif features is None:
            raise ValueError("DatasetRecorder: features are required to create a dataset "
                             "(use surrol_data.datasets.schema.frame_features)")
        self.features = features
        self.dims = dims_from_features(features)
        if not self._exists:
            self._sealed = True

        self._ds = None
        self._open = False
        # Episodes recorded before the LeRobot dataset exists (see open()): (episode buffer, provenance columns).
        self._unsaved: list[tuple[dict, dict]] = []
        self._git_commit = ""
        self._critical = 0
        self._pending_signal: int | None = None
        self._previous_handlers: dict[int, object] = {}
        self._pending_columns: dict | None = None
        self._since_checkpoint = 0
        self._last_checkpoint_t = 0.0
        self._durable = 0
        self._session: dict = {}
        self._files_at_open: set[str] = set()
        self._lock = DatasetLock(self.root)
        self._created = False
        # A write of this session failed (a full disk, an I/O error): lerobot's open files are in an unknown state,
        # so nothing more is written through them (see _abandon); the journal holds every episode not yet in closed
        # files, and the repair every command runs first rebuilds the dataset from it.
        self._failed = False

    # ------------------------------------------------------------------ lifecycle

    def _before_append(self) -> None:
        """Called when appending to an existing dataset, before its features are read: nothing here;
        :class:`~surrol_data.datasets.recorder.DatasetRecorder` repairs a dataset a killed recording left."""

    def __enter__(self) -> DatasetWriter:
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def open(self) -> None:
        """Create or resume the dataset and install the signal handlers (``with`` does this for you)."""
        if self._open:
            return
        self._git_commit = git_commit()
        self._files_at_open = files.dataset_files(self.root)  # what close() leaves as it is
        if self.lazy and not self._exists and not self.dims["cameras"]:
            self._open_lazily()
            return
        LeRobotDataset = _lerobot_dataset_class()
        if self.fast_save:
            lerobot_compat.install_fast_save()
        if self._exists:
            self._lock.acquire()  # before touching anything: a second writer gets a clear error
            try:
                with hub_offline():
                    self._ds = LeRobotDataset.resume(self.repo_id, root=lerobot_root(self.root),
                                                     video_backend=VIDEO_BACKEND)
            except BaseException:
                self._lock.release()
                raise
        else:
            # create() makes the folder (and refuses an existing one: a concurrent creator loses there).
            with hub_offline():
                self._ds = LeRobotDataset.create(self.repo_id, fps=FPS, features=self.features, root=self.root,
                                                 robot_type=self.robot_type, use_videos=True,
                                                 video_backend=VIDEO_BACKEND, metadata_buffer_size=1)
            self._lock.acquire()
            self._exists = True
            self._created = True
        try:
            self._prepare_writer()
            self._durable = self._ds.meta.total_episodes
            self._start_session(checkpoint=True)
        except BaseException:   # e.g. a full disk: the dataset is left for the next command (its repair), not
            self._lock.release()  # locked by this process until its recorder object happens to be collected
            self._restore_signal_handlers()
            self._open = False
            raise

    def _open_lazily(self) -> None:
        """Open a new state-only dataset without lerobot: its import (~5 s, torch included) would come before the
        first episode. The folder (the claim: a second creator fails here), the lock and the sidecar are made now,
        the sidecar with the features (``pending_dataset``) so that :func:`surrol_data.datasets.repair.repair` can
        create the dataset from them; episodes are journalled as always and kept in memory (a state-only episode
        is small) until the first checkpoint creates the LeRobot dataset (:meth:`_create_dataset`) and saves them,
        in order, as an eager open would have: the files are the same."""
        self.root.mkdir(parents=True, exist_ok=False)
        try:
            (self.root / "meta").mkdir()
            self._lock.acquire()
            self._exists = True
            self._created = True
            self._durable = 0
            self._start_session(checkpoint=False)
        except BaseException:   # e.g. a full disk: nothing recorded, so nothing is left to block a retry
            self._lock.release()
            self._restore_signal_handlers()
            self._open = False
            shutil.rmtree(self.root, ignore_errors=True)
            raise

    def _start_session(self, checkpoint: bool) -> None:
        self._open = True
        self._last_checkpoint_t = time.monotonic()
        self._session = {"started_at": utc_now_iso(), "command": self.command, "git_commit": self._git_commit,
                         "package_version": package_version(), "first_episode": self._durable, "episodes": 0}
        self._write_sidecar(checkpoint=checkpoint)
        self._install_signal_handlers()

    def _create_dataset(self) -> None:
        """Create the LeRobot dataset of a lazy open and save the episodes recorded so far into it, checkpointing
        after every ``checkpoint_every`` of them but the last: where an eager open checkpointed, so the same files
        (the caller checkpoints the last ones if they are due)."""
        lerobot_compat.wait_for_background_import()   # see import_lerobot_in_background
        if self.fast_save:
            lerobot_compat.install_fast_save()
        with hub_offline():
            self._ds = lerobot_compat.create_dataset(self.root, repo_id=self.repo_id, fps=FPS, features=self.features,
                                                     robot_type=self.robot_type, use_videos=True,
                                                     video_backend=VIDEO_BACKEND, metadata_buffer_size=1)
        self._prepare_writer()
        saved = 0
        while self._unsaved:
            if saved and saved % self.checkpoint_every == 0:
                self._close_files_and_continue()
            episode_data, columns = self._unsaved[0]
            self._save(episode_data, columns)
            self._unsaved.pop(0)
            saved += 1
        self._since_checkpoint = (saved - 1) % self.checkpoint_every + 1 if saved else 0

    def _deferring_creation(self) -> bool:
        """A lazy open whose lerobot is still being imported in the background, with room to hold more episodes:
        creating the dataset now would only wait for the import. The journal keeps every episode durable."""
        return (self._ds is None and lerobot_compat.background_import_running()
                and len(self._unsaved) < MAX_UNSAVED_WHILE_IMPORTING)

    def import_lerobot_in_background(self) -> None:
        """For a caller whose main thread waits from now on (on worker processes): import lerobot meanwhile in a
        thread, so that creating the dataset at the first checkpoint does not stall the recording
        (:func:`lerobot_compat.import_in_background`). Nothing to do once the dataset exists."""
        if self._open and self._ds is None:
            lerobot_compat.import_in_background()

    def close(self) -> None:
        """Finalize (drop a partial episode), write the sidecar and dataset card, restore signal handlers."""
        if not self._open:
            return
        try:
            with self._hold_signals():
                if self._failed:
                    self._abandon()
                    return
                try:
                    self._finish()
                except BaseException:
                    self._failed = True
                    self._abandon()
                    raise
        finally:
            self._ds = None
            self._open = False
            self._unsaved.clear()
            self._lock.release()
            self._restore_signal_handlers()

    def _finish(self) -> None:
        """close() of a session whose writes all succeeded: the files' footers, then info.json, then the sidecar's
        checkpoint, and only then the journal entries of the episodes now in closed files go."""
        if self._ds is None and self._unsaved:
            self._create_dataset()
        if self._ds is not None:
            if self._ds.has_pending_frames():
                self._ds.clear_episode_buffer()
            self._ds.finalize()
            lerobot_compat.write_episode_totals(self._ds)
            self._durable = self._ds.meta.total_episodes
        else:
            self._durable = self._total_episodes_on_disk()
        self._ds = None
        if self._created and self._durable == 0:
            # Nothing was recorded (e.g. the first episode failed): leave no folder to block a retry.
            if not journal.entries(self.root):
                shutil.rmtree(self.root, ignore_errors=True)
            return
        self._write_sidecar(checkpoint=True)   # what is in the files, before the journal entries go
        journal.drop_below(self.root, self._durable)   # an episode not in the files keeps its entry
        if self.consolidate:
            self._consolidate()
        self._session["ended_at"] = utc_now_iso()
        self._write_sidecar(checkpoint=True)
        write_dataset_card(self.root)

    def _abandon(self) -> None:
        """End a session whose write failed without writing anything more: lerobot's finalize (and its garbage-
        collection safety net) would flush buffered episode rows into files a failed write left in an unknown state,
        and emptying the journal would trust them. So the journal is kept whole and the session is left unended: the
        dataset is what a killed recording leaves, which every command repairs first (nothing finished is lost)."""
        ds, self._ds = self._ds, None
        if ds is None:
            return
        writer, meta = getattr(ds, "writer", None), getattr(ds, "meta", None)
        image_writer = getattr(writer, "image_writer", None)
        if image_writer is not None:
            with contextlib.suppress(Exception):
                image_writer.stop()
        for obj, flag in ((ds, "_is_finalized"), (writer, "_finalized"), (meta, "_finalized")):
            if obj is not None:
                setattr(obj, flag, True)

    @property
    def failed(self) -> bool:
        """Whether a write of this session failed (the dataset is then left to the repair, see :meth:`_abandon`)."""
        return self._failed

    def _consolidate(self) -> None:
        """The files this session wrote, one per checkpoint, into as few as lerobot's size limit allows
        (:mod:`surrol_data.datasets.consolidate`; before the session is marked ended, so that a kill in the middle
        is a killed recording, which every command repairs). A failure before its commit point changes nothing:
        the dataset stays complete, in more files."""
        try:
            files.consolidate(self.root, keep=self._files_at_open, show_progress=sys.stderr.isatty())
        except Exception as e:  # noqa: BLE001 - e.g. a full disk: the episodes are all in the files already
            if files.interrupted(self.root):
                raise   # past its commit point: left for repair to finish (the session is not marked ended)
            print(f"note: {self.root}: its files were not consolidated ({type(e).__name__}: {e}); the dataset is "
                  "complete, in more files", file=sys.stderr)

    def _prepare_writer(self) -> None:
        # Rows, info.json and stats.json are written once per checkpoint, not per episode: the journal is what makes
        # an episode durable before record() returns, and the files are unreadable between checkpoints anyway.
        lerobot_compat.attach_episode_columns(self._ds, self._episode_columns, batch=self.checkpoint_every)

    def _episode_columns(self, episode_metadata: dict) -> dict:
        if self._pending_columns is None:
            raise RuntimeError("episode saved without provenance: use DatasetRecorder.record, not "
                               "the LeRobotDataset directly")
        columns = dict(self._pending_columns)
        if self._sealed:
            from surrol_data.datasets.seals import segment_seal

            for cam in self.dims["cameras"]:
                key = f"observation.images.{cam}"
                columns[video_seal_column(key)] = segment_seal(self.root, self._ds.meta.video_path, key,
                                                               episode_metadata)
        return columns

    # ------------------------------------------------------------------ signals

    def _install_signal_handlers(self) -> None:
        if not self.handle_signals or threading.current_thread() is not threading.main_thread():
            return  # signal.signal only works in the main thread; finalize then relies on the caller
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous_handlers[sig] = signal.getsignal(sig)
            signal.signal(sig, self._on_signal)

    def _restore_signal_handlers(self) -> None:
        for sig, handler in self._previous_handlers.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        self._previous_handlers.clear()

    def _on_signal(self, signum, frame) -> None:
        if self._critical:
            self._pending_signal = signum  # raised when the episode write / checkpoint is complete
            return
        _raise_for_signal(signum)

    def hold_signals(self):
        """Context manager: SIGINT/SIGTERM wait until the block is done (e.g. an episode and its device trace)."""
        return self._hold_signals()

    @contextlib.contextmanager
    def _hold_signals(self):
        self._critical += 1
        try:
            yield
        finally:
            self._critical -= 1
            if self._critical == 0 and self._pending_signal is not None:
                signum, self._pending_signal = self._pending_signal, None
                _raise_for_signal(signum)

    # ------------------------------------------------------------------ recording

    @property
    def num_episodes(self) -> int:
        """Episodes in the dataset, those recorded by this session included."""
        if self._ds is not None:
            return self._ds.meta.total_episodes
        return self._total_episodes_on_disk() + len(self._unsaved)

    @property
    def durable_episodes(self) -> int:
        """Episodes already in closed dataset files (those before the last checkpoint). Every recorded episode
        survives a SIGKILL either way (the journal holds the rest until the next checkpoint)."""
        return self._durable

    def _total_episodes_on_disk(self) -> int:
        try:
            return int(json.loads((self.root / INFO_PATH).read_text())["total_episodes"])
        except (OSError, KeyError, json.JSONDecodeError):
            return 0

    def record(self, traj: Trajectory, provenance: dict) -> int:
        """Write one episode and its provenance; returns its episode index.

        ``provenance`` follows :data:`surrol_data.datasets.schema.PROVENANCE_COLUMNS`: source, device, skill
        and seed are required; task, env_id, command and git_commit default to the recorder's; metric
        columns left out are computed from ``traj``.
        """
        if not self._open:
            raise RuntimeError("DatasetRecorder is not open: use `with DatasetRecorder(...) as rec:` or call open()")
        frames = self._frame_arrays(traj)
        prov = normalize_provenance(provenance, traj, defaults={
            "task": self.task, "env_id": self.env_id, "command": self.command, "git_commit": self._git_commit})
        prov["content_hash"] = content_hash(frames, self.features)
        ds = self._ds
        episode_index = self.num_episodes
        episode_data = None
        if self.dims["cameras"]:
            # Camera frames go through add_frame, which stages the PNGs that lerobot's video encoder reads.
            try:
                for t in range(len(traj)):
                    frame = {key: values[t] for key, values in frames.items()}
                    frame["task"] = self.task_description
                    ds.add_frame(frame)
            except BaseException:
                ds.clear_episode_buffer()  # also deletes the staged camera PNGs of the episode
                raise
        else:
            # State-only: hand lerobot the whole episode at once. _frame_arrays already checked every dtype
            # and shape, so add_frame's per-frame validation would only repeat it T times.
            episode_data = self._episode_buffer(frames, len(traj), episode_index)
        with self._hold_signals():
            # Durable first (one small file, atomically), then into lerobot's open files; a kill from here on
            # loses nothing: repair() replays the journal entry if the dataset files did not get the episode.
            journal.write_entry(self.root, episode_index, traj, prov)
            columns = {PROVENANCE_PREFIX + k: v for k, v in prov.items()}
            if self._sealed:
                columns[PROVENANCE_SEAL] = provenance_seal(prov)
            if ds is None:   # opened lazily: saved into the dataset when the first checkpoint creates it
                self._unsaved.append((episode_data, columns))
                self._since_checkpoint += 1
                if len(self._unsaved) >= MAX_UNSAVED and not self._deferring_creation():
                    with self._stop_on_failure():
                        self._create_dataset()   # memory stays bounded, whatever checkpoint_every is
            else:
                try:
                    with self._stop_on_failure():
                        self._save(episode_data, columns)
                except BaseException:
                    with contextlib.suppress(OSError):   # not recorded after all (a failing disk may keep it)
                        journal.entry_path(self.root, episode_index).unlink(missing_ok=True)
                    raise
                self._since_checkpoint += 1
            self._session["episodes"] = self._session.get("episodes", 0) + 1
            due_by_time = (self.checkpoint_interval_s is not None
                           and time.monotonic() - self._last_checkpoint_t >= self.checkpoint_interval_s)
            if (self._since_checkpoint >= self.checkpoint_every or due_by_time) and not self._deferring_creation():
                self.checkpoint()
        return episode_index

    def _save(self, episode_data: dict | None, columns: dict) -> None:
        """Hand one episode to lerobot (``episode_data``: a state-only episode's buffer; None: the frames added)."""
        self._pending_columns = columns
        try:
            with hub_offline(), quiet_video_encoder():
                self._ds.save_episode(episode_data=episode_data)
        finally:
            self._pending_columns = None

    def checkpoint(self) -> None:
        """Close every open file (finalize) and resume, so a hard kill cannot lose what is recorded so far."""
        if not self._open:
            raise RuntimeError("DatasetRecorder is not open")
        with self._hold_signals(), self._stop_on_failure():
            if self._ds is None:
                self._create_dataset()
            self._close_files_and_continue()

    @contextlib.contextmanager
    def _stop_on_failure(self):
        """A failure inside the block is a failed write: nothing more is written this session (see _abandon)."""
        if self._failed:
            raise RuntimeError(f"{self.root}: an earlier write of this recording failed; nothing more is recorded")
        try:
            yield
        except BaseException:
            self._failed = True
            raise

    def _close_files_and_continue(self) -> None:
        # The files' footers first, then info.json's totals: info.json never counts an episode whose file is
        # unreadable (a full disk at the footer left it so), and the journal is emptied only after both.
        if lerobot_compat.close_files_and_continue(self._ds):
            lerobot_compat.write_episode_totals(self._ds)
        else:
            self._ds.finalize()
            lerobot_compat.write_episode_totals(self._ds)
            with hub_offline():
                self._ds = _lerobot_dataset_class().resume(self.repo_id, root=lerobot_root(self.root),
                                                           video_backend=VIDEO_BACKEND)
            self._prepare_writer()
        self._durable = self._ds.meta.total_episodes
        self._since_checkpoint = 0
        self._last_checkpoint_t = time.monotonic()
        self._write_sidecar(checkpoint=True)
        journal.drop_below(self.root, self._durable)

    def _episode_buffer(self, frames: dict[str, np.ndarray], T: int, episode_index: int) -> dict:
        return lerobot_compat.episode_buffer(frames, T, episode_index, self.task_description, FPS)

    def _frame_arrays(self, traj: Trajectory) -> dict[str, np.ndarray]:
        """Per-feature (T, ...) arrays with the exact dtype/shape add_frame demands (checked here, clearly)."""
        d = self.dims
        T = len(traj)
        if T == 0:
            raise ValueError("cannot record a trajectory with no actions (T = 0)")

        def vec(name: str, values, rows: int, dim: int, dtype=np.float32) -> np.ndarray:
            arr = np.asarray(values)
            if arr.ndim == 1 and dim == 1:
                arr = arr[:, None]
            arr = arr.reshape(len(arr), -1) if arr.ndim > 2 else arr
            if arr.ndim != 2 or arr.shape != (rows, dim):
                raise ValueError(f"Trajectory.{name} has shape {np.shape(values)}, the dataset expects "
                                 f"({rows}, {dim}) (features {self.root})")
            return np.ascontiguousarray(arr, dtype=dtype)

        obs = vec("observation", traj.observation, T + 1, d["obs_dim"])
        ag = vec("achieved_goal", traj.achieved_goal, T + 1, d["goal_dim"])
        dg = vec("desired_goal", traj.desired_goal, T + 1, d["goal_dim"])
        tip = vec("tip_position", traj.tip_position, T + 1, 3 * d["n_arms"])
        jaw = vec("jaw_angle", traj.jaw_angle, T + 1, d["n_arms"])
        extra = sorted(set(traj.flags) - set(DEVICE_FLAGS) - set(EVENT_FLAGS)
                       - ({INTERVENTION} if IS_INTERVENTION in self.features else set()))
        if extra:
            raise ValueError(f"Trajectory.flags {extra} are not in the dataset schema (only {list(DEVICE_FLAGS)})")
        environment = np.concatenate([ag, dg], axis=1)  # object/goal state: achieved goal, then desired goal
        terminated = vec("terminated", traj.terminated, T, 1, bool)
        truncated = np.zeros((T, 1), bool)
        truncated[-1, 0] = not terminated[-1, 0]  # the episode ended here without the MDP ending
        frames = {
            "observation.state": obs[:-1], ENV_STATE: environment[:-1],
            "action": vec("action", traj.action, T, d["act_dim"]),
            "next.reward": vec("reward", traj.reward, T, 1),
            "next.done": terminated, "next.truncated": truncated,
            "next.success": vec("success", traj.success, T, 1, bool),
            "next.observation.state": obs[1:], NEXT_ENV_STATE: environment[1:],
            "complementary_info.tip_position": tip[:-1], "complementary_info.jaw_angle": jaw[:-1],
            "complementary_info.next_tip_position": tip[1:], "complementary_info.next_jaw_angle": jaw[1:],
        }
        for flag in DEVICE_FLAGS:
            frames[f"complementary_info.{flag}"] = vec(f"flags[{flag!r}]", traj.flags[flag], T, 1, bool)
        for event in EVENT_FLAGS:   # optional features: recorded where the dataset has them
            key = f"complementary_info.{event}"
            if key not in self.features:
                continue
            if event not in traj.flags:
                raise ValueError(f"{self.root} records env events but the trajectory has no {event!r} flags; build "
                                 "it with TrajectoryBuilder.add(..., info=info) at every step")
            frames[key] = vec(f"flags[{event!r}]", traj.flags[event], T, int(self.features[key]["shape"][0]), bool)
        if IS_INTERVENTION in self.features:   # an intervention session's dataset: who acted, and the proposal
            if traj.policy_action is None:
                raise ValueError(f"{self.root} records interventions but the trajectory has none; build it with "
                                 "TrajectoryBuilder.add(..., intervention=..., policy_action=...) at every step")
            arms = vec("flags['intervention']", traj.flags[INTERVENTION], T, d["n_arms"], bool)
            frames[INTERVENTION_ARMS] = arms
            frames[IS_INTERVENTION] = arms.any(axis=1, keepdims=True).astype(np.float32)
            frames[POLICY_ACTION] = vec("policy_action", traj.policy_action, T, d["act_dim"])
        elif traj.policy_action is not None:
            raise ValueError(f"the trajectory records interventions but {self.root} has no intervention features; "
                             "record intervention sessions into a dataset made for them")
        cameras = d["cameras"]
        if set(traj.images) != set(cameras):
            raise ValueError(f"Trajectory.images has cameras {sorted(traj.images)}, the dataset has "
                             f"{sorted(cameras)}: declare them in frame_features(cameras=...) or drop them")
        for cam, (h, w) in cameras.items():
            img = np.asarray(traj.images[cam])
            if img.dtype != np.uint8 or img.ndim != 4 or img.shape[1:] != (h, w, 3) or len(img) < T:
                raise ValueError(f"Trajectory.images[{cam!r}] is {img.dtype}{img.shape}, expected uint8 "
                                 f"(T+1={T + 1}, {h}, {w}, 3)")
            frames[f"observation.images.{cam}"] = img[:T]
        return frames

    # ------------------------------------------------------------------ sidecar

    def _write_sidecar(self, checkpoint: bool = False) -> None:
        side = read_sidecar(self.root)
        side.pop("signature", None)   # it covers the episodes before this session (signing.py): sign again after
        side.update(sidecar_facts(self.repo_id, self.task, self.env_id, self.task_description, self.robot_type))
        if self.dims["cameras"]:
            side["camera_version"] = self.camera_version
            side["camera_renderer"] = self.camera_renderer
        side.setdefault("created_at", side["updated_at"])
        if self._sealed:
            side["seals"] = 1  # every episode carries seal/* columns (see schema.provenance_seal)
        sessions = side.setdefault("sessions", [])
        if sessions and sessions[-1].get("started_at") == self._session.get("started_at"):
            sessions[-1] = dict(self._session)
        else:
            sessions.append(dict(self._session))
        if self._ds is None and not (self.root / INFO_PATH).exists():
            # Opened lazily, the LeRobot dataset not created yet: what repair() needs to create it.
            side[PENDING_DATASET] = {"features": self.features, "fps": FPS, "robot_type": self.robot_type}
        else:
            side.pop(PENDING_DATASET, None)
        if checkpoint:
            # The last consistent info.json: repair() falls back to it if info.json itself was cut short.
            info_text = (self.root / INFO_PATH).read_text()
            side["checkpoint"] = {"at": utc_now_iso(), "episodes": self._durable, "info": json.loads(info_text)}
        _write_json_atomic(self.root / SIDECAR_PATH, side)


_LEROBOT_DEFAULT_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def sidecar_facts(repo_id: str, task: str, env_id: str, task_description: str, robot_type: str) -> dict:
    """The dataset-level facts of ``meta/surrol_data.json`` that every writing session states afresh."""
    return {
        "schema_version": SCHEMA_VERSION, "repo_id": repo_id, "task": task, "env_id": env_id,
        "task_description": task_description, "robot_type": robot_type, "fps": FPS,
        "package_version": package_version(), "updated_at": utc_now_iso(),
        "provenance_columns": {k: t.__name__ for k, t in PROVENANCE_COLUMNS.items()},
        "units": {"positions": "m", "angles": "rad", "path_length": "cm", "control_period_s": 1 / FPS},
    }


def _holds_no_episode(root: Path) -> bool:
    """A folder a killed recorder created before finishing any episode: no live writer, no journal entry,
    no readable row of episode metadata or frames. It holds nothing to keep."""
    from surrol_data.datasets.lock import writer_pid

    if root.is_dir() and not any(root.iterdir()):
        return True   # an empty folder (a recorder that failed at its first write left it)
    if not (root / "meta").is_dir() or writer_pid(root) is not None or journal.entries(root):
        return False
    for sub in (EPISODES_DIR, DATA_DIR):
        for path in parquet_files(root, sub):
            try:
                if pq.read_metadata(path).num_rows > 0:
                    return False
            except (pa.ArrowInvalid, OSError):
                continue
    return True


def _raise_for_signal(signum: int) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise SystemExit(128 + signum)  # like the default SIGTERM exit status, but unwinds through `finally`
