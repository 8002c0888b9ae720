"""A camera dataset end to end through the command line: ``collect --camera`` (script and haptic sources), the
reader's decoded frames, ``validate``, ``view`` (camera frames in the Rerun recording), the robomimic export
(images under ``obs/endoscope_image``), and ``merge`` through lerobot's aggregate_datasets, whose copied video
decodes to exactly the inputs' frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets.reader import DatasetReader

TASK = "NeedleReach"
W, H = 40, 32
STEPS = 6


def _ok(args: list[str]) -> str:
    run = CliRunner().invoke(app, args)
    assert run.exit_code == 0, f"{args}: {run.output}"
    return " ".join(run.output.split())


def _collect(out: Path, seed: int, source: str = "script") -> Path:
    device = ["--device", "operator", "--skill", "expert", "--operator-id", "e1"] if source == "haptic" else []
    _ok(["collect", "--source", source, *device, "--task", TASK, "--num-episodes", "2", "--seed", str(seed),
         "--max-steps", str(STEPS), "--keep-failures", "--camera", "--camera-size", f"{W}x{H}", "--out", str(out)])
    return out


@pytest.fixture(scope="module")
def camera_datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera")
    return _collect(root / "script", 0), _collect(root / "haptic", 50, source="haptic")


def test_collect_records_the_endoscope_and_the_reader_decodes_it(camera_datasets):
    for root in camera_datasets:
        reader = DatasetReader(root)
        assert reader.cameras == ["endoscope"]
        assert reader.features["observation.images.endoscope"]["shape"] == [H, W, 3]
        for ep in reader.select():
            frames = reader.frames(ep)["endoscope"]
            length = int(reader.episodes["length"].iloc[ep])
            assert frames.shape == (length, H, W, 3) and frames.dtype == np.uint8
            assert frames.std() > 5, "a blank image: the endoscope saw nothing"
            traj = reader.trajectory(ep, images=True)
            assert traj.images["endoscope"].shape == (length + 1, H, W, 3)


def test_camera_dataset_validates_views_and_exports(camera_datasets, tmp_path):
    import h5py
    from rerun.experimental import RrdReader

    root = camera_datasets[0]
    assert "is a valid surrol_data dataset" in _ok(["validate", str(root)])
    rrd = tmp_path / "eps.rrd"
    _ok(["view", str(root), "--episodes", "0-1", "--out", str(rrd)])
    cameras = [ch for ch in RrdReader(rrd).stream() if ch.entity_path.startswith("/camera/")]
    assert {ch.entity_path.split("/")[-1] for ch in cameras} == {"endoscope"}
    assert len({ch.entity_path for ch in cameras}) == 2  # one camera stream per episode shown
    assert sum(ch.to_record_batch().num_rows for ch in cameras if not ch.is_static) == sum(
        len(DatasetReader(root).trajectory(ep)) + 1 for ep in (0, 1))

    out = tmp_path / "demos.hdf5"
    said = _ok(["export", str(root), "--format", "robomimic", "--out", str(out), "--episodes", "1"])
    assert "obs/endoscope_image" in said
    with h5py.File(out, "r") as f:
        assert list(f["data"]) == ["demo_0"] and f["data/demo_0"].attrs["episode_index"] == 1
        images = f["data/demo_0/obs/endoscope_image"][()]
        assert images.dtype == np.uint8 and images.shape == (len(f["data/demo_0/actions"]), H, W, 3)
        assert np.array_equal(images, DatasetReader(root).frames(1)["endoscope"])


def test_merge_copies_video_without_reencoding(camera_datasets, tmp_path):
    script, haptic = camera_datasets
    out = tmp_path / "merged"
    _ok(["merge", str(script), str(haptic), "--out", str(out)])
    assert "is a valid surrol_data dataset" in _ok(["validate", str(out), "--no-reward"])
    merged = DatasetReader(out)
    sources = [(script, ep) for ep in range(2)] + [(haptic, ep) for ep in range(2)]
    assert len(merged) == len(sources)
    assert list(merged.episodes["source"]) == ["script", "script", "haptic", "haptic"]
    for new, (root, ep) in enumerate(sources):
        # aggregate_datasets concatenates the mp4 streams: the decoded frames are the inputs' own, bit for bit
        assert np.array_equal(merged.frames(new)["endoscope"], DatasetReader(root).frames(ep)["endoscope"])
        trace = root / "meta" / "device_traces" / f"episode_{ep:06d}.npz"
        if trace.exists():
            assert (out / "meta" / "device_traces" / f"episode_{new:06d}.npz").read_bytes() == trace.read_bytes()


def test_camera_version_is_recorded_and_not_mixed(camera_datasets, tmp_path):
    # The endoscope image was turned and reframed (camera version 2): a dataset says which images it holds, and
    # images of two versions never end up in one dataset.
    import json
    import re
    import shutil

    from surrol_data.datasets.schema import CAMERA_VERSION, SIDECAR_PATH

    script, haptic = camera_datasets
    side = json.loads((script / SIDECAR_PATH).read_text())
    assert side["camera_version"] == CAMERA_VERSION == 2
    assert re.search(r"camera version\W+2\b", _ok(["info", str(script)]))
    old = tmp_path / "old"          # the same dataset as recorded before the bump: no camera_version
    shutil.copytree(script, old)
    del side["camera_version"]
    (old / SIDECAR_PATH).write_text(json.dumps(side))
    run = CliRunner().invoke(app, ["collect", "--source", "script", "--task", TASK, "--num-episodes", "1",
                                   "--max-steps", str(STEPS), "--keep-failures", "--camera", "--camera-size",
                                   f"{W}x{H}", "--out", str(old), "--append"])
    assert run.exit_code != 0 and "camera version 1" in run.output, run.output
    run = CliRunner().invoke(app, ["merge", str(old), str(haptic), "--out", str(tmp_path / "mixed")])
    assert run.exit_code != 0 and "camera version" in run.output, run.output
    assert not (tmp_path / "mixed").exists()
