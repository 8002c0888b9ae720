"""Every registered task can be trained by name: `surrol-data train task=<Name>` needs configs/task/<Name>.yaml."""

from surrol_data.envs import TASKS
from surrol_data.train_app import config_dir, to_train_config


def test_every_registered_task_has_a_train_config(tmp_path, monkeypatch):
    from hydra import compose, initialize_config_dir

    monkeypatch.chdir(tmp_path)
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        for name in TASKS:
            cfg = to_train_config(compose("config", [f"task={name}", "demos=none", "algo=ddpg"]))
            assert cfg.env_id == f"SurRoL/{name}-v0", name
    shipped = {p.stem for p in (config_dir() / "task").glob("*.yaml")}
    assert shipped == set(TASKS), f"configs/task does not match the registered tasks: {shipped ^ set(TASKS)}"
