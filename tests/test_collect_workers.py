"""`collect --workers N`: episodes rolled out in N processes, recorded in seed order — the same dataset as one."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.collect.script_source import collect_script
from surrol_data.datasets.reader import DatasetReader


def _provenance(root):
    episodes = DatasetReader(root).episodes.drop(columns=["duration_s", "command"], errors="ignore")
    return episodes[[c for c in episodes.columns if not c.startswith(("seal/", "provenance_seal"))]]


def test_two_workers_record_the_same_episodes_as_one(tmp_path):
    # a short horizon: short episodes, some of them failures (kept), from seeds 0..3 in every process
    one = collect_script("NeedleReach", 4, tmp_path / "one", max_steps=12, keep_failures=True, progress=False)
    two = collect_script("NeedleReach", 4, tmp_path / "two", max_steps=12, keep_failures=True, progress=False,
                         workers=2)
    assert two.seeds == one.seeds and two.attempts == one.attempts
    a, b = DatasetReader(tmp_path / "one"), DatasetReader(tmp_path / "two")
    for ep in range(4):
        ta, tb = a.trajectory(ep), b.trajectory(ep)
        for name in ("observation", "action", "reward", "success", "tip_position", "jaw_angle"):
            np.testing.assert_array_equal(getattr(ta, name), getattr(tb, name), err_msg=f"episode {ep} {name}")
    pa_, pb = _provenance(tmp_path / "one"), _provenance(tmp_path / "two")
    assert list(pa_["content_hash"]) == list(pb["content_hash"])
    assert list(pa_["seed"]) == list(pb["seed"]) == one.seeds


def test_workers_need_the_script_source(tmp_path):
    result = CliRunner().invoke(app, ["collect", "--source", "haptic", "--device", "operator", "--task",
                                      "NeedleReach", "--num-episodes", "1", "--out", str(tmp_path / "x"),
                                      "--workers", "2"])
    assert result.exit_code == 2 and "--workers" in result.output and "Traceback" not in result.output
