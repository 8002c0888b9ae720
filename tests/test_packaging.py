"""The install is honest: every direct import declared (deptry), optional parts name their extra, and the wheel
carries what `surrol-data train` and `demo` need when installed outside the repository."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_every_direct_import_is_declared():
    deptry = Path(sys.executable).parent / "deptry"
    out = subprocess.run([str(deptry), "surrol_data"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr


def test_a_missing_optional_package_names_its_extra(monkeypatch):
    from surrol_data import extras

    monkeypatch.setitem(extras.OPTIONAL, "surrol_data_no_such_module", ("devices", "no-such-dist"))
    with pytest.raises(extras.MissingExtra, match=r"pip install 'surrol-data\[devices\]'"):
        extras.require("surrol_data_no_such_module")
    assert extras.require("pygame").__name__ == "pygame"     # the test install has every extra


@pytest.mark.slow
def test_wheel_installed_outside_the_repo_trains_and_runs_the_demo(tmp_path):
    """Build the wheel, install it (core only, no extras) into a fresh venv, run `train` and `demo` elsewhere."""
    uv = shutil.which("uv")
    if uv is None:
        pytest.skip("needs uv")
    dist = tmp_path / "dist"
    subprocess.run([uv, "build", "--wheel", "--out-dir", str(dist)], cwd=REPO, check=True, capture_output=True,
                   timeout=600)
    wheel = next(dist.glob("surrol_data-*.whl"))
    venv = tmp_path / "venv"
    subprocess.run([uv, "venv", "--python", sys.executable, str(venv)], check=True, capture_output=True, timeout=120)
    py = venv / "bin" / "python"
    # the locked versions, so the install resolves offline from uv's cache like the project's own
    reqs = tmp_path / "requirements.txt"
    subprocess.run([uv, "export", "--locked", "--no-dev", "--no-hashes", "--no-emit-project", "-o", str(reqs)],
                   cwd=REPO, check=True, capture_output=True, timeout=300)
    subprocess.run([uv, "pip", "install", "--python", str(py), "-r", str(reqs), str(wheel)], check=True,
                   capture_output=True, timeout=1800)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    cli = venv / "bin" / "surrol-data"
    demo = subprocess.run([str(cli), "demo", "--out", "demo", "--num-episodes", "3", "--eval-episodes", "2"], cwd=work,
                          env=env, capture_output=True, text=True, timeout=1200)
    assert demo.returncode == 0, demo.stdout[-2000:] + demo.stderr[-2000:]
    # the default tensorboard=auto: no TensorBoard on the core install, and the run goes on without it
    train = subprocess.run([str(cli), "train", "task=NeedleReach", "demos=none", "algo=ddpg", "experiment=smoke",
                            "progress=false", "run_dir=run"], cwd=work, env=env,
                           capture_output=True, text=True, timeout=1200)
    assert train.returncode == 0, train.stdout[-2000:] + train.stderr[-2000:]
    assert (work / "run" / "metrics.jsonl").is_file()
    wheel_only = subprocess.run([str(py), "-c", "import surrol_data.train_app as t; print(t.config_dir())"], cwd=work,
                                env=env, capture_output=True, text=True, timeout=120)
    assert "site-packages" in wheel_only.stdout    # configs came from the wheel, not from a checkout


def test_the_lerobot_train_extra_brings_what_each_documented_policy_needs():
    """Every LeRobot policy the docs name (`--policy.type=X`, and ACT / Diffusion in prose) trains after
    `pip install 'surrol-data[lerobot-train]'`: where lerobot has an extra for the policy (Diffusion: diffusers),
    ours asks for it, and uv.lock resolves it."""
    import importlib.metadata
    import re
    import tomllib

    root = Path(__file__).resolve().parents[1]
    text = " ".join(p.read_text() for p in [root / "README.md", *sorted((root / "docs").glob("*.md"))])
    named = {m.lower() for m in re.findall(r"--policy\.type=(\w+)", text)}
    named |= {name for name, word in (("act", "ACT"), ("diffusion", "Diffusion")) if re.search(rf"\b{word}\b", text)}
    assert {"act", "diffusion"} <= named
    lerobot_extras = set(importlib.metadata.metadata("lerobot").get_all("Provides-Extra") or [])
    needed = sorted(named & lerobot_extras)   # the policies lerobot installs extra packages for
    assert "diffusion" in needed
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    ours = " ".join(project["optional-dependencies"]["lerobot-train"])
    for policy in needed:
        assert re.search(rf"lerobot\[[\w,-]*\b{policy}\b", ours), f"the lerobot-train extra lacks lerobot[{policy}]"
    lock = tomllib.loads((root / "uv.lock").read_text())
    ours_locked = next(p for p in lock["package"] if p["name"] == "surrol-data")
    locked = {d["name"] for d in ours_locked["optional-dependencies"]["lerobot-train"]}
    assert "lerobot" in locked
    assert any(p["name"] == "diffusers" for p in lock["package"])   # what lerobot[diffusion] brings


def test_uv_run_does_not_compile_the_environment_at_every_start():
    """`uv run` with `compile-bytecode = true` in [tool.uv] recompiles every file of the environment (~15,000,
    seconds) at every start, printing "Bytecode compiled N files"; a second `uv run` must go straight to the command."""
    uv = shutil.which("uv")
    if uv is None:
        pytest.skip("needs uv")
    command = [uv, "run", "--locked", "--group", "test", "python", "-c", "pass"]
    subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=600, check=True)   # any sync first
    again = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=600, check=True)
    assert "Bytecode compiled" not in again.stderr, again.stderr


def test_the_sdist_holds_code_configs_and_docs_only(tmp_path):
    """The source distribution is small (it carried the demo sets and the study's runs: 34 MB): code, configs and the
    docs' text, no `datasets/` nor `docs/results/`, under 2 MB."""
    import tarfile

    uv = shutil.which("uv")
    if uv is None:
        pytest.skip("needs uv")
    subprocess.run([uv, "build", "--sdist", "--out-dir", str(tmp_path)], cwd=REPO, check=True, capture_output=True,
                   timeout=600)
    sdist = next(tmp_path.glob("surrol_data-*.tar.gz"))
    assert sdist.stat().st_size <= 2_000_000, f"{sdist.stat().st_size / 1e6:.1f} MB"
    with tarfile.open(sdist) as tar:
        names = {"/".join(n.split("/")[1:]) for n in tar.getnames()}
    assert {"surrol_data/cli.py", "configs/config.yaml", "pyproject.toml", "README.md", "docs/index.md"} <= names
    assert not any(n.startswith(("datasets/", "docs/results/")) for n in names)
