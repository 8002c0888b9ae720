"""Every lerobot internal surrol_data patches or relies on, in one place, checked against one lerobot version.

The recorder needs five things lerobot 0.6 has no public API for (shared/docs/reference/lerobot.md §1–2):

* **creating a dataset in a folder that exists** (the recorder's lock, journal and sidecar are there before lerobot
  is imported): :func:`create_dataset` creates it in a staging subfolder and points the dataset object at the
  folder (``root`` / ``_requested_root`` of the dataset and its metadata, ``_root`` of its writer, each checked);

* **per-episode provenance columns**: ``LeRobotDatasetMetadata.save_episode`` is wrapped so extra columns
  reach ``meta/episodes`` (:func:`attach_episode_columns`), and its ``_metadata_buffer_size`` is set to 1 so
  an episode's row is flushed with the episode;
* **whole-episode writes**: ``save_episode(episode_data=...)`` takes a pre-built frame buffer whose layout
  (:func:`episode_buffer`) is lerobot's own ``add_frame`` accumulator;
* **cheap checkpoints**: :func:`close_files_and_continue` closes the open parquet writers and sets the writer
  state (``_latest_episode``, ``latest_episode``, ``episodes``) exactly as ``resume()`` leaves it;
* **fast saves**: :func:`install_fast_save` computes the per-episode statistics of vector features with
  whole-array numpy (:mod:`surrol_data.datasets.fast_stats`, bit for bit lerobot's, checked once per feature set),
  remembers the per-episode ``get_hf_features_from_features`` and the per-frame task lookups, guards
  ``dataset_writer.embed_images``, a per-row map that only matters for ``image`` features, and hands lerobot's
  ``_save_episode_data`` each episode's arrow table built directly (:func:`fast_episode_table`) instead of through
  ``datasets.Dataset.from_dict``, whose per-call fingerprint (a dill hash of the whole episode) cost more than the
  rest of ``save_episode``; the table is checked equal to ``from_dict``'s (schema metadata included) once per
  feature set, else that set keeps ``from_dict``.

and validate's lerobot check loads through :func:`quick_parquet_load` (a Hugging Face ``datasets`` schema built once
per load, not per batch), and the tools use ``compute_stats.aggregate_stats`` / ``io_utils.write_stats`` (repair, upgrade),
``feature_utils.get_hf_features_from_features`` (upgrade) and ``aggregate.aggregate_datasets`` /
``io_utils.write_table_one_row_group_per_episode`` (merge; it also repairs two things 0.6.1's aggregation gets
wrong for our datasets: the data files lose their fixed-size vector types, and the episodes-metadata rows of a
source recorded in several files name files they are not in). :data:`CHECKED_VERSIONS` lists the lerobot
releases these were read and tested against; on any other, :func:`check_lerobot` warns once
(:class:`UntestedLerobotWarning`) and ``tests/test_lerobot_compat.py`` fails, naming what to re-check.
Each patch also checks that what it touches is there and otherwise falls back to lerobot's public path
(``finalize`` + ``resume``, the unpatched ``embed_images``) or raises :class:`LerobotIncompatible`.
"""

from __future__ import annotations

import contextlib
import warnings
from importlib.metadata import PackageNotFoundError, version

import numpy as np

CHECKED_VERSIONS = ("0.6.1",)

# (module, attribute path) of each internal relied on; tests/test_lerobot_compat.py checks them all.
INTERNALS = (
    ("lerobot.datasets.dataset_writer", "embed_images"),
    ("lerobot.datasets.dataset_writer", "datasets.Dataset.from_dict"),
    ("lerobot.datasets.dataset_writer", "get_hf_features_from_features"),
    ("lerobot.datasets.dataset_writer", "compute_episode_stats"),
    ("lerobot.datasets.dataset_writer", "DatasetWriter.close_writer"),
    ("lerobot.datasets.dataset_writer", "DatasetWriter.flush_pending_videos"),
    ("lerobot.datasets.dataset_metadata", "LeRobotDatasetMetadata.save_episode"),
    ("lerobot.datasets.dataset_metadata", "LeRobotDatasetMetadata._close_writer"),
    ("lerobot.datasets.dataset_metadata", "LeRobotDatasetMetadata._save_episode_metadata"),
    ("lerobot.datasets.io_utils", "write_info"),
    ("lerobot.datasets.utils", "serialize_dict"),
    ("lerobot.datasets.utils", "DatasetInfo.to_dict"),
    ("lerobot.utils.utils", "flatten_dict"),
    ("lerobot.datasets.compute_stats", "aggregate_stats"),
    ("lerobot.datasets.compute_stats", "compute_episode_stats"),
    ("lerobot.datasets.io_utils", "write_stats"),
    ("lerobot.datasets.feature_utils", "get_hf_features_from_features"),
    ("lerobot.datasets.utils", "create_lerobot_dataset_card"),
    # merge (surrol_data.datasets.merge): aggregate_datasets itself, and the writer that restores one row group per
    # episode after its pandas rewrite of the data files
    ("lerobot.datasets.aggregate", "aggregate_datasets"),
    ("lerobot.datasets.io_utils", "write_table_one_row_group_per_episode"),
    # validate's lerobot check (quick_parquet_load): what Hugging Face datasets loads lerobot's parquet files with
    ("datasets.packaged_modules.parquet.parquet", "Parquet._cast_table"),
    ("datasets.table", "table_cast"),
)

_warned = False
_frozen = False   # lerobot_dataset_class has frozen the objects alive after lerobot's import


class UntestedLerobotWarning(RuntimeWarning):
    """The installed lerobot is not one of :data:`CHECKED_VERSIONS`."""


class LerobotIncompatible(RuntimeError):
    """An internal the recorder relies on is not in the installed lerobot."""


def lerobot_version() -> str:
    try:
        return version("lerobot")
    except PackageNotFoundError:
        return ""


def check_lerobot() -> None:
    """Warn once when the installed lerobot is not a version these internals were checked against."""
    global _warned
    installed = lerobot_version()
    if installed in CHECKED_VERSIONS or _warned:
        return
    _warned = True
    warnings.warn(f"surrol_data relies on lerobot internals checked against lerobot {', '.join(CHECKED_VERSIONS)}; "
                  f"lerobot {installed or '(not installed)'} is installed: recording may fall back to slower paths "
                  "or fail. Install lerobot==" + CHECKED_VERSIONS[-1] + " or re-check "
                  "surrol_data/datasets/lerobot_compat.py (tests/test_lerobot_compat.py).",
                  UntestedLerobotWarning, stacklevel=2)


def missing_internals() -> list[str]:
    """The :data:`INTERNALS` the installed lerobot lacks ("module:attr"), empty when all are there."""
    import importlib

    missing = []
    for module, path in INTERNALS:
        try:
            obj = importlib.import_module(module)
            for part in path.split("."):
                obj = getattr(obj, part)
        except (ImportError, AttributeError):
            missing.append(f"{module}:{path}")
    return missing


def lerobot_dataset_class():
    """``LeRobotDataset``, imported on first use (~6 s, ~0.9 GB), after the version check."""
    global _frozen
    check_lerobot()
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not _frozen:
        # lerobot brings torch, datasets and pandas: ~380,000 objects that live as long as the process, and every
        # full collection of the cyclic GC walks them all (~250 ms, a few times per hundred recorded episodes).
        # Frozen, the collector leaves them out (gc.freeze; they are still freed normally by reference counting).
        import gc

        gc.freeze()
        _frozen = True
    return LeRobotDataset


CREATE_STAGING = ".surrol_data_create"


def create_dataset(root, **create_kwargs):
    """``LeRobotDataset.create(root=root, **create_kwargs)`` in a folder that already exists.

    The recorder creates its LeRobot dataset lazily, at its first checkpoint (lerobot's import, ~5 s, is not paid
    before the first episode), and by then ``root`` holds the lock, the journal and the sidecar; lerobot's ``create``
    refuses an existing folder. So the dataset is created in ``root/.surrol_data_create`` (``create`` writes nothing
    but ``meta/info.json`` there), the ``info.json`` is moved into ``root/meta/`` (atomically) and the dataset object is
    pointed at ``root``: the same object, and the same files, as ``create(root=root)`` in an empty folder. Raises
    :class:`LerobotIncompatible`, with ``root`` untouched, when the installed lerobot's ``create`` writes more than
    that file or keeps its folder in attributes other than the ones re-pointed here."""
    import os
    import shutil
    from pathlib import Path

    root = Path(root)
    wait_for_background_import()
    staging = root / CREATE_STAGING
    if staging.exists():
        shutil.rmtree(staging)   # left by a process killed while creating: it held nothing else
    ds = lerobot_dataset_class().create(root=staging, **create_kwargs)
    written = sorted(str(p.relative_to(staging)) for p in staging.rglob("*") if p.is_file())
    pointers = ((ds, "root"), (ds, "_requested_root"), (getattr(ds, "meta", None), "root"),
                (getattr(ds, "meta", None), "_requested_root"), (getattr(ds, "writer", None), "_root"))
    if written != ["meta/info.json"] or any(getattr(obj, name, None) != staging for obj, name in pointers):
        shutil.rmtree(staging, ignore_errors=True)
        raise LerobotIncompatible(f"lerobot {lerobot_version()}: LeRobotDataset.create wrote {written} / keeps its "
                                  "folder elsewhere than checked by lerobot_compat.create_dataset; record with "
                                  f"lerobot {CHECKED_VERSIONS[-1]}")
    (root / "meta").mkdir(parents=True, exist_ok=True)
    os.replace(staging / "meta" / "info.json", root / "meta" / "info.json")
    shutil.rmtree(staging)
    for obj, name in pointers:
        setattr(obj, name, root)
    left = [f"{type(obj).__name__}.{k}" for obj in (ds, ds.meta, ds.writer) for k, v in vars(obj).items()
            if isinstance(v, Path) and (v == staging or staging in v.parents)]
    if left:
        raise LerobotIncompatible(f"lerobot {lerobot_version()}: {', '.join(left)} still name the staging folder of "
                                  "lerobot_compat.create_dataset")
    return ds


_background_import = None   # the thread of import_in_background, once started


def import_in_background() -> None:
    """Start importing lerobot (:func:`lerobot_dataset_class`) in a daemon thread, once per process, for a caller whose
    main thread is about to wait (on worker processes): the dataset created later then finds it imported. Not for a
    main thread that computes meanwhile: PyBullet keeps the GIL while it steps (it never releases it), so the two
    would only take turns. Whoever uses lerobot next calls :func:`wait_for_background_import` first; an import that
    failed in the thread fails again, with its error, in the caller's."""
    global _background_import
    if _background_import is not None:
        return
    import threading

    def run():
        try:
            lerobot_dataset_class()
        except BaseException:  # noqa: BLE001 - the caller's own import raises it again, where it is handled
            pass

    thread = threading.Thread(target=run, name="surrol_data-import-lerobot", daemon=True)
    thread.start()
    _background_import = thread   # only a started thread is ever joined


def background_import_running() -> bool:
    return _background_import is not None and _background_import.is_alive()


def wait_for_background_import() -> None:
    """Join the thread :func:`import_in_background` started (if any), so that no two threads import lerobot at once."""
    if _background_import is not None:
        _background_import.join()


def install_fast_save() -> None:
    """Skip lerobot's per-row ``embed_images`` map for episodes without ``image`` features, build each episode's
    arrow table directly instead of through ``datasets.Dataset.from_dict`` (:class:`_FastDatasets`), compute the
    statistics of vector features with :mod:`surrol_data.datasets.fast_stats` and remember the episode schema.

    The ``embed_images`` guard calls the original whenever an episode has an ``image`` feature, and the table
    builder and the statistics fall back to lerobot's own for anything they do not reproduce exactly, so all stay
    correct for any dataset written in the process; nothing is patched when lerobot no longer has what they replace.
    """
    from lerobot.datasets import dataset_writer

    original = getattr(dataset_writer, "embed_images", None)
    real_datasets = getattr(dataset_writer, "datasets", None)
    if real_datasets is not None and not isinstance(real_datasets, _FastDatasets):
        dataset_writer.datasets = _FastDatasets(real_datasets)
    hf = getattr(dataset_writer, "get_hf_features_from_features", None)
    if hf is not None and not getattr(hf, "_surrol_cache", False):
        dataset_writer.get_hf_features_from_features = _cached_hf_features(hf)
    stats = getattr(dataset_writer, "compute_episode_stats", None)
    if stats is not None and not getattr(stats, "_surrol_fast", False):
        dataset_writer.compute_episode_stats = _fast_episode_stats(stats)
    if original is None or getattr(original, "_surrol_guard", False):
        return
    import datasets

    def embed_images_if_any(dataset):
        if any(isinstance(ft, datasets.Image) for ft in dataset.features.values()):
            return original(dataset)
        return dataset

    embed_images_if_any._surrol_guard = True
    dataset_writer.embed_images = embed_images_if_any


def _fast_episode_stats(original):
    """lerobot's ``compute_episode_stats`` through :func:`surrol_data.datasets.fast_stats.episode_stats` where it
    applies; on the first episode of each feature set both run and the fast one is kept only if every statistic is
    identical (values, dtypes, shapes)."""
    from surrol_data.datasets.fast_stats import episode_stats

    verified: dict[str, bool] = {}

    def compute_episode_stats(episode_data, features, quantile_list=None):
        if quantile_list is not None:
            return original(episode_data, features, quantile_list)
        key = repr(sorted((k, features[k]["dtype"]) for k in episode_data))
        if verified.get(key) is False:
            return original(episode_data, features)
        fast = episode_stats(episode_data, features)
        if fast is None:
            return original(episode_data, features)
        if key not in verified:
            expected = original(episode_data, features)
            verified[key] = same_stats(fast, expected)
            return expected
        return fast

    compute_episode_stats._surrol_fast = True
    compute_episode_stats.verified = verified   # read by tests/test_writer_batching.py
    return compute_episode_stats


def same_stats(a: dict, b: dict) -> bool:
    """Two ``{feature: {stat: array}}`` dicts hold the same keys in the same order and identical arrays."""
    if list(a) != list(b):
        return False
    for key in a:
        if list(a[key]) != list(b[key]):
            return False
        for stat, x in a[key].items():
            y = b[key][stat]
            if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
                return False
    return True


def _cached_hf_features(original):
    """``get_hf_features_from_features`` remembered per feature set: lerobot rebuilds the ``datasets.Features`` of
    the whole schema for every episode it saves (~3 ms), and only reads it."""
    import json

    cache: dict[str, object] = {}

    def cached(features):
        key = json.dumps(features, sort_keys=True, default=str)
        if key not in cache:
            cache[key] = original(features)
        return cache[key]

    cached._surrol_cache = True
    return cached


class _EpisodeTable:
    """What lerobot 0.6.1's ``DatasetWriter._save_episode_data`` uses of the ``datasets.Dataset`` it builds from an
    episode: ``len``, ``features`` (``embed_images``) and ``with_format("arrow")[:]`` (the arrow table it writes)."""

    def __init__(self, table, features):
        self._table, self.features = table, features

    def __len__(self) -> int:
        return self._table.num_rows

    def with_format(self, kind: str):
        if kind != "arrow":
            raise LerobotIncompatible(f"lerobot asked an episode table for format {kind!r}; only 'arrow' is built")
        return self

    def __getitem__(self, key):
        if key != slice(None):
            raise LerobotIncompatible(f"lerobot indexed an episode table with {key!r}; only [:] is built")
        return self._table


class _FastDatasets:
    """Stands in for the ``datasets`` module inside ``lerobot.datasets.dataset_writer`` (its only use there is
    ``datasets.Dataset.from_dict`` on one episode): ``Dataset.from_dict`` returns an :class:`_EpisodeTable` of
    :func:`fast_episode_table`'s table; every other attribute is the real module's."""

    def __init__(self, real):
        self._real = real
        self._verified: dict[str, object] = {}   # repr(features) -> arrow schema, or None: use from_dict
        self.Dataset = self

    def __getattr__(self, name):
        return getattr(self._real, name)

    def from_dict(self, mapping, features=None, split=None, **kwargs):
        key = repr(features)
        schema = self._verified.get(key, False)
        if schema is not False and schema is not None and not kwargs:
            table = fast_episode_table(mapping, schema)
            if table is not None:
                return _EpisodeTable(table, features)
        real = self._real.Dataset.from_dict(mapping, features=features, split=split, **kwargs)
        if schema is False and features is not None and not kwargs:
            # First episode with this feature set: keep the direct build only if it gives the very same table.
            expected = real.with_format("arrow")[:]
            ours = fast_episode_table(mapping, expected.schema)
            same = ours is not None and ours.equals(expected, check_metadata=True)
            self._verified[key] = expected.schema if same else None
        return real


def fast_episode_table(mapping: dict, schema):
    """The arrow table of one episode (``mapping``: column -> (T, ...) array or list) with ``schema``, built with
    pyarrow alone; None when a column is of a type not built here (images, nested lists, strings)."""
    import pyarrow as pa

    arrays = []
    for field in schema:
        if field.name not in mapping:
            return None
        values = mapping[field.name]
        if pa.types.is_fixed_size_list(field.type):
            child = field.type.value_type
            if not (pa.types.is_floating(child) or pa.types.is_integer(child) or pa.types.is_boolean(child)):
                return None
            flat = np.asarray(values, dtype=child.to_pandas_dtype())
            if flat.ndim != 2 or flat.shape[1] != field.type.list_size:
                return None
            arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1), type=child),
                                                            field.type.list_size))
        elif pa.types.is_floating(field.type) or pa.types.is_integer(field.type) or pa.types.is_boolean(field.type):
            flat = np.asarray(values)
            if flat.ndim != 1:
                return None
            arrays.append(pa.array(flat, type=field.type))
        else:
            return None
    return pa.Table.from_arrays(arrays, schema=schema)


def attach_episode_columns(ds, columns, batch: int = 1) -> None:
    """Make ``ds`` write ``columns()`` (a dict) into each episode's ``meta/episodes`` row.

    ``columns(episode_metadata)`` is called inside every ``save_episode``, after lerobot has written the episode's
    videos (``episode_metadata`` says where: ``videos/<key>/*``); it raises to refuse an episode saved without them.
    Call again after each ``resume()`` (a new metadata object).

    ``batch`` = 1: each episode's row is flushed with it, and ``info.json`` / ``stats.json`` are rewritten per
    episode (lerobot's own behaviour). ``batch`` = N > 1: the rows are written N at a time (one parquet row group per
    N episodes instead of per episode: each row group repeats ~250 columns' metadata, ~60 KB) and ``info.json`` /
    ``stats.json`` are written only by :func:`write_episode_totals`, which the caller runs before every close of the
    files (its checkpoints): between two checkpoints the files on disk are unreadable anyway until their footers are
    written, and what a kill leaves is rebuilt from the journal.
    """
    meta = ds.meta
    if not hasattr(meta, "_metadata_buffer_size") or not callable(getattr(meta, "save_episode", None)):
        raise LerobotIncompatible(f"lerobot {lerobot_version()}: LeRobotDatasetMetadata has no save_episode / "
                                  "_metadata_buffer_size; surrol_data cannot attach provenance columns")
    if batch > 1 and not callable(getattr(meta, "_save_episode_metadata", None)):
        batch = 1   # lerobot's save_episode is reimplemented below; without the internal it calls, per episode
    # resume() has no metadata_buffer_size argument and defaults to 10.
    meta._metadata_buffer_size = batch
    original = meta.save_episode

    def save_episode_with_columns(episode_index, episode_length, episode_tasks, episode_stats, episode_metadata):
        return original(episode_index, episode_length, episode_tasks, episode_stats,
                        {**episode_metadata, **columns(episode_metadata)})

    def save_episode_batched(episode_index, episode_length, episode_tasks, episode_stats, episode_metadata):
        # lerobot 0.6.1's LeRobotDatasetMetadata.save_episode, less its per-episode write_info / write_stats
        from lerobot.utils.utils import flatten_dict

        episode = {"episode_index": episode_index, "tasks": episode_tasks, "length": episode_length,
                   **episode_metadata, **columns(episode_metadata)}
        episode.update(flatten_dict({"stats": episode_stats}))
        meta._save_episode_metadata(episode)
        meta.info.total_episodes += 1
        meta.info.total_frames += episode_length
        meta.info.total_tasks = len(meta.tasks)
        meta.info.splits = {"train": f"0:{meta.info.total_episodes}"}
        meta._surrol_pending_stats.append(episode_stats)

    meta._surrol_pending_stats = []
    meta.save_episode = save_episode_with_columns if batch == 1 else save_episode_batched
    _remember_task_indices(meta)


def _remember_task_indices(meta) -> None:
    """``meta.get_task_index`` remembered while ``meta.tasks`` is the same table: lerobot's ``save_episode`` looks up
    every frame's task in the pandas table (~0.1 ms each). A task's index never changes once given
    (``save_episode_tasks`` only adds rows), so only found indices are remembered, and a new table empties the memo."""
    original = getattr(meta, "get_task_index", None)
    if original is None or getattr(original, "_surrol_memo", False):
        return
    memo: dict = {"tasks": None, "index": {}}

    def get_task_index(task):
        if memo["tasks"] is not meta.tasks:
            memo["tasks"], memo["index"] = meta.tasks, {}
        found = memo["index"].get(task)
        if found is None:
            found = original(task)
            if found is not None:
                memo["index"][task] = found
        return found

    get_task_index._surrol_memo = True
    meta.get_task_index = get_task_index


def write_episode_totals(ds) -> None:
    """Write ``info.json`` and ``stats.json`` for the episodes saved since the last call (see
    :func:`attach_episode_columns` with ``batch`` > 1; a no-op otherwise)."""
    meta = ds.meta
    pending = getattr(meta, "_surrol_pending_stats", None)
    if not pending:
        return
    from lerobot.datasets.compute_stats import aggregate_stats as _aggregate

    everything = [meta.stats, *pending] if meta.stats is not None else list(pending)
    meta.stats = everything[0] if len(everything) == 1 else _aggregate(everything)
    pending.clear()
    # lerobot's write_info / write_stats open the file for writing in place: a full disk or an I/O error in the
    # middle would leave half a file. The same bytes are written whole beside it, then renamed over it.
    from lerobot.datasets.utils import serialize_dict

    _write_json_atomically(meta.info.to_dict(), meta.root / "meta" / "info.json")
    _write_json_atomically(serialize_dict(meta.stats), meta.root / "meta" / "stats.json")


def _write_json_atomically(data, path) -> None:
    """lerobot's ``write_json`` (indent 4, UTF-8), through a temporary file and ``os.replace``."""
    import json
    import os

    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=4, ensure_ascii=False)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def episode_buffer(frames: dict[str, np.ndarray], T: int, episode_index: int, task: str, fps: int) -> dict:
    """The frame buffer ``LeRobotDataset.save_episode(episode_data=...)`` takes: what ``add_frame`` would
    accumulate for ``frames`` (feature -> (T, ...) arrays already of their declared dtype and shape)."""
    frame_index = np.arange(T, dtype=np.int64)
    buffer = {"size": T, "task": [task] * T, "episode_index": episode_index,
              "frame_index": frame_index, "timestamp": (frame_index / fps).astype(np.float32),
              # placeholders: save_episode assigns the global index and the task index itself
              "index": frame_index, "task_index": np.zeros(T, dtype=np.int64)}
    buffer.update(frames)
    return buffer


def close_files_and_continue(ds) -> bool:
    """Checkpoint without reloading: close the data and episodes parquet files (writing their footers) and
    point lerobot's writer at new files for the next episode, exactly where ``resume()`` would.

    ``resume()`` reloads the whole episodes table through ``datasets`` (~1 s, growing with the dataset); this
    keeps the in-memory metadata instead. Returns False, touching nothing, when lerobot's writer state is not
    the one checked here (or a streaming / batched video encoder is on); the caller then resumes instead.
    """
    writer, meta = getattr(ds, "writer", None), getattr(ds, "meta", None)
    needed = (hasattr(writer, "close_writer") and hasattr(writer, "_latest_episode")
              and hasattr(meta, "_close_writer") and hasattr(meta, "latest_episode") and hasattr(meta, "episodes"))
    if not needed or getattr(writer, "_batch_encoding_size", 1) != 1 or getattr(writer, "_streaming_encoder", None):
        return False
    if meta.latest_episode is None:
        return True  # nothing written since the last checkpoint: every file is already closed
    writer.flush_pending_videos()
    writer.close_writer()
    meta._close_writer()  # flushes the buffered episode rows, then writes the footer
    # With no "latest episode", lerobot's writers take the last row of meta.episodes and start the next
    # chunk/file after it, for data, episodes metadata and videos alike — what they do after resume().
    meta.episodes = [{k: v[0] if isinstance(v, list) else v for k, v in meta.latest_episode.items()}]
    meta.latest_episode = None
    writer._latest_episode = None
    return True


def aggregate_stats(stats_list: list[dict]) -> dict:
    from lerobot.datasets.compute_stats import aggregate_stats as _aggregate

    return _aggregate(stats_list)


def compute_episode_stats(frames: dict[str, np.ndarray], features: dict) -> dict:
    from lerobot.datasets.compute_stats import compute_episode_stats as _compute

    return _compute(frames, features)


def write_stats(stats: dict, root) -> None:
    from lerobot.datasets.io_utils import write_stats as _write

    _write(stats, root)


def hf_features(features: dict):
    """The ``datasets.Features`` lerobot stores a data parquet with (its arrow schema carries them)."""
    from lerobot.datasets.feature_utils import get_hf_features_from_features

    return get_hf_features_from_features(features)


@contextlib.contextmanager
def quick_parquet_load():
    """Inside the block, Hugging Face ``datasets`` (through which ``LeRobotDataset`` loads the parquet files) builds
    the features' arrow schema once per load instead of once per record batch.

    Its parquet builder reads a file one batch per row group — lerobot writes one row group per episode — and casts
    each batch to ``features.arrow_schema``, a property that rebuilds the schema from the features every time
    (~5 ms): 10,000 episodes spent ~50 s of CPU there, most of validate's lerobot check. The cast itself and the
    loaded dataset are unchanged. Without that builder (another ``datasets``), the block changes nothing."""
    try:
        from datasets.packaged_modules.parquet import parquet as hf_parquet
        from datasets.table import table_cast

        original = hf_parquet.Parquet._cast_table
    except (ImportError, AttributeError):
        yield
        return

    def _cast_table(self, pa_table):
        features = self.info.features
        if features is None:
            return original(self, pa_table)
        cached = getattr(self, "_surrol_schema", None)
        if cached is None or cached[0] is not features:
            cached = self._surrol_schema = (features, features.arrow_schema)
        return table_cast(pa_table, cached[1])

    hf_parquet.Parquet._cast_table = _cast_table
    try:
        yield
    finally:
        hf_parquet.Parquet._cast_table = original
