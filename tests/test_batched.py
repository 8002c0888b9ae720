"""The batched training path: stacked DDPG members, the offline→online warm start, runs in one ensemble, resume."""

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from surrol_data.algos.ddpg import DDPG, DDPGConfig, q_term_scale
from surrol_data.algos.demos import DemoSpec
from surrol_data.algos.ensemble import EnsembleDDPG
from surrol_data.algos.env_pool import SnapshotActor, explored_action
from surrol_data.algos.replay import EpisodeReplay
from surrol_data.algos.train import Schedule, TrainConfig, read_metrics, train
from surrol_data.algos.train_batched import train_batched

REACH = "SurRoL/NeedleReach-v0"
REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "surrol_data.cli"]
# every optional piece on, so the member-vs-single comparison covers them: Q-filter, action L2, the warm start
CFG = DDPGConfig(hidden_sizes=(32, 32), bc_weight=5.0, q_filter=True, action_l2=0.5, actor_hold_updates=1,
                 q_ramp_updates=2, q_normalize=True, joint_actor_step=True)


@pytest.fixture(autouse=True)
def one_torch_thread():
    """What the run loops use; more threads than free cores make these small updates crawl on a busy machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def reward(ag, g):
    return (np.linalg.norm(ag - g, axis=-1) < 0.5).astype(np.float32) - 1.0


def random_buffer(seed: int, episodes: int = 6) -> EpisodeReplay:
    buf = EpisodeReplay(10, 20, 4, 3, 2, reward, 4, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(episodes):
        buf.add_episode(rng.standard_normal((21, 4)), rng.standard_normal((21, 3)), rng.standard_normal((20, 3)),
                        rng.uniform(-1, 1, (20, 2)))
    return buf


def members_and_singles(seeds, cfg=CFG):
    singles = [DDPG(4, 3, 2, cfg, seed=s) for s in seeds]
    ensemble = EnsembleDDPG(4, 3, 2, cfg, seeds)
    for i, s in enumerate(seeds):
        data = random_buffer(50 + s)
        for inputs in (singles[i].inputs, ensemble.inputs[i]):
            inputs.update(data.obs.reshape(-1, 4), data.g.reshape(-1, 3))
    return singles, ensemble


@pytest.mark.parametrize("cfg", [CFG, dataclasses.replace(CFG, filtered_bc=True, joint_actor_step=False,
                                                           actor_hold_updates=0)], ids=["joint", "filtered_bc"])
def test_ensemble_members_start_and_learn_like_their_single_runs(cfg):
    seeds = [0, 3]
    singles, ensemble = members_and_singles(seeds, cfg)
    obs = [{"observation": np.ones((2, 4), np.float32) * (i + 1), "desired_goal": np.zeros((2, 3), np.float32)}
           for i in range(2)]
    np.testing.assert_allclose(ensemble.act(obs, explore=False)[1], singles[1].act(obs[1], explore=False), atol=1e-6)
    # the same batches (same generators, same draw order) give the same losses, up to batched-kernel rounding
    for step in range(3):
        mine = ensemble.update([random_buffer(s) for s in seeds], [random_buffer(100 + s) for s in seeds])
        theirs = [single.update(random_buffer(s), random_buffer(100 + s)) for s, single in zip(seeds, singles)]
        for m, t in zip(mine, theirs):
            assert m.keys() == t.keys()
            for key in m:
                assert m[key] == pytest.approx(t[key], rel=1e-3, abs=1e-5), (step, key)
    # members differ from each other (their own seeds), and a member's checkpoint is a single run's
    assert not np.allclose(ensemble.act(obs, False)[0], ensemble.act([obs[0], obs[0]], False)[1])
    restored = DDPG(4, 3, 2, cfg, seed=99)
    restored.load_state_dict(ensemble.member_state_dict(1))
    np.testing.assert_allclose(restored.act(obs[1], explore=False), ensemble.act(obs, explore=False)[1], atol=1e-6)
    assert restored.online_updates == 3
    # and a single run's state loads into a member slot, optimiser moments included
    other = EnsembleDDPG(4, 3, 2, cfg, [7, 8])
    other.load_member_state_dict(0, ensemble.member_state_dict(1))
    np.testing.assert_allclose(other.act([obs[1], obs[1]], False)[0], ensemble.act(obs, False)[1], atol=1e-6)
    for key in ("actor_opt", "critic_opt"):
        a, b = other.member_state_dict(0)[key]["state"], ensemble.member_state_dict(1)[key]["state"]
        assert all(torch.equal(a[i]["exp_avg_sq"], b[i]["exp_avg_sq"]) for i in b)


def test_ensemble_updates_do_not_depend_on_the_learners_thread_count():
    """The batched path widens the learner to the cores the env workers leave idle, at moments that depend on
    timing; that is only sound while torch's CPU kernels give bit-identical updates for any thread count.
    Full-size networks and batches, so the kernels really split their work."""
    cfg = dataclasses.replace(CFG, hidden_sizes=(256, 256, 256), batch_size=128, demo_batch_size=128)

    def trained(threads_at) -> list[torch.Tensor]:
        _, ensemble = members_and_singles([0, 1, 2], cfg)
        for step in range(4):
            torch.set_num_threads(threads_at(step))
            ensemble.update([random_buffer(s) for s in (0, 1, 2)], [random_buffer(100 + s) for s in (0, 1, 2)])
        return [p.detach().clone() for net in (ensemble.actor, ensemble.critic, ensemble.critic_target)
                for p in net.parameters()]

    one, two, mixed = trained(lambda _: 1), trained(lambda _: 2), trained(lambda step: 1 + step % 2)
    assert all(torch.equal(a, b) for a, b in zip(one, two))
    assert all(torch.equal(a, b) for a, b in zip(one, mixed))


@pytest.mark.parametrize("random_eps", [0.0, 0.3])
def test_env_workers_act_as_their_single_runs_would(random_eps):
    """Workers act from a snapshot of the actors, with every member's exploration drawn up front from its own
    generator: step by step, the actions its single run would take (same draws, same order)."""
    cfg = dataclasses.replace(CFG, random_eps=random_eps)
    seeds, steps, n = [0, 3], 6, 2
    singles, ensemble = members_and_singles(seeds, cfg)
    rng = np.random.default_rng(9)
    obs, goals = rng.standard_normal((steps, len(seeds), n, 4)), rng.standard_normal((steps, len(seeds), n, 3))
    actor = SnapshotActor(ensemble.snapshot().for_envs(np.repeat(np.arange(len(seeds)), n)))
    explore = [{k: None if v is None else v.swapaxes(0, 1) for k, v in ensemble.exploration(i, steps, n).items()}
               for i in range(len(seeds))]
    for t in range(steps):
        pi = actor(obs[t].reshape(-1, 4), goals[t].reshape(-1, 3))
        for i, single in enumerate(singles):
            mine = explored_action(pi[i * n:(i + 1) * n], explore[i], t)
            theirs = single.act({"observation": obs[t, i], "desired_goal": goals[t, i]}, explore=True)
            np.testing.assert_allclose(mine, theirs, atol=1e-6, err_msg=f"step {t}, member {i}")
    if random_eps:  # the random-action branch was exercised
        assert any(e["replace"].any() for e in explore)


def test_warm_start_holds_the_actor_then_ramps_the_q_term():
    cfg = DDPGConfig(actor_hold_updates=3, q_ramp_updates=4)
    assert [q_term_scale(u, cfg) for u in range(8)] == [0.0, 0.0, 0.0, 0.25, 0.5, 0.75, 1.0, 1.0]
    assert q_term_scale(0, DDPGConfig()) == 1.0  # the paper's ddpgbc: full Q term from the first update
    held = DDPG(4, 3, 2, DDPGConfig(hidden_sizes=(16,), actor_hold_updates=5, bc_weight=5.0, action_l2=0.0), seed=0)
    no_demos = [p.clone() for p in held.actor.parameters()]
    metrics = held.update(random_buffer(0), None)  # held and no demo batch: the actor does not move at all
    assert "actor_loss" not in metrics and all(torch.equal(a, b) for a, b in zip(no_demos, held.actor.parameters()))
    metrics = held.update(random_buffer(0), random_buffer(1))  # the BC term alone moves it
    assert "bc_loss" in metrics and not all(torch.equal(a, b) for a, b in zip(no_demos, held.actor.parameters()))
    # the normalised Q term keeps its weight against the BC term whatever the scale of Q
    def moved(normalize: bool, q_factor: float) -> torch.Tensor:
        agent = DDPG(4, 3, 2, DDPGConfig(hidden_sizes=(16,), q_normalize=normalize, action_l2=0.0), seed=3)
        with torch.no_grad():
            agent.critic.net[-1].weight.mul_(q_factor)
            agent.critic.net[-1].bias.fill_(-20.0 * q_factor)
        before = torch.cat([p.flatten().clone() for p in agent.actor.parameters()])
        agent._actor_step([(agent._tensors(random_buffer(4).sample(64, np.random.default_rng(0))), True)])
        return torch.cat([p.flatten() for p in agent.actor.parameters()]) - before
    assert torch.allclose(moved(True, 1.0), moved(True, 10.0), atol=1e-6)
    assert not torch.allclose(moved(False, 1.0), moved(False, 10.0), atol=1e-6)
    # offline critic warm-up: TD steps on demo batches lower the TD error of the pre-trained actor's values
    fresh = DDPG(4, 3, 2, DDPGConfig(hidden_sizes=(32, 32)), seed=1)
    demos = random_buffer(2)
    losses = [fresh.pretrain_critic_step(demos) for _ in range(150)]
    assert np.mean(losses[-20:]) < 0.5 * np.mean(losses[:5])


def test_a_batched_sweep_expands_like_hydras_basic_sweeper():
    from surrol_data.train_app import sweep_jobs

    jobs = sweep_jobs(["seed=0,1", "demos=script,expert", "experiment=paper", "algo.params.hidden_sizes=[64,64]"])
    assert len(jobs) == 4 and ["seed=1", "demos=expert", "experiment=paper", "algo.params.hidden_sizes=[64,64]"] in jobs
    with pytest.raises(ValueError, match="share task, algo and experiment"):
        train_batched([run_config("/tmp/a", "/x", 0), run_config("/tmp/b", "/x", 1, bc_weight=1.0)], progress=False)


# --- whole runs ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def reach_demos(tmp_path_factory):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("demos") / "NeedleReach_script"
    collect_script("NeedleReach", 4, root, progress=False)
    return root


def run_config(run_dir, demos, seed, epochs=2, **params):
    return TrainConfig(env_id=REACH, run_dir=str(run_dir), learner="ddpg",
                       learner_params={"hidden_sizes": (32, 32), "bc_weight": 5.0, "q_filter": False,
                                       "action_l2": 0.0, **params},
                       demos=DemoSpec(path=str(demos), num=4),
                       schedule=Schedule(epochs=epochs, cycles=2, episodes_per_cycle=2, updates_per_cycle=3, n_envs=1,
                                         eval_episodes=2, offline_steps=10, buffer_episodes=20),
                       seed=seed, progress=False, tensorboard=False)


def _comparable(rows):
    return json.dumps([{k: v for k, v in r.items() if k != "wall_s" and not k.startswith("time_")} for r in rows])


def test_batched_runs_write_what_single_runs_write(tmp_path, reach_demos):
    warm = {"critic_pretrain_steps": 5, "freeze_normalizer": True, "filtered_bc": True}  # ddpgbc_warm's options
    cfgs = [run_config(tmp_path / f"b{s}", reach_demos, s, **warm) for s in (0, 1)]
    batched = train_batched(cfgs, overlap=False, n_workers=0, progress=False)
    single = train(run_config(tmp_path / "s1", reach_demos, 1, **warm))
    for rows, cfg in zip(batched, cfgs):
        assert read_metrics(cfg.run_dir) == json.loads(json.dumps(rows))
        assert (Path(cfg.run_dir) / "policy.pt").is_file() and (Path(cfg.run_dir) / "checkpoint.pt").is_file()
    b = batched[1]
    untimed = lambda rows: [{k for k in r if not k.startswith("time_") and k != "batched_members"}  # noqa: E731
                            for r in rows]
    # the batched rows add the epoch's CPU seconds (time_cpu_*) and the batch size those seconds were shared by
    assert untimed(b) == untimed(single)
    assert all(r["batched_members"] == len(batched) for r in b)
    for key in ("epoch", "env_steps", "episodes", "updates"):
        assert [r[key] for r in b] == [r[key] for r in single]
    # same seeds, same batches: the offline phase agrees to rounding, the online losses stay close
    assert b[0]["bc_loss"] == pytest.approx(single[0]["bc_loss"], rel=1e-4)
    assert b[0]["critic_pretrain_loss"] == pytest.approx(single[0]["critic_pretrain_loss"], rel=1e-3)
    assert b[1]["critic_loss"] == pytest.approx(single[1]["critic_loss"], rel=0.2)
    assert b[0]["success_rate"] == single[0]["success_rate"]
    # the two members are different runs
    assert batched[0][0]["bc_loss"] != b[0]["bc_loss"]
    # a member's checkpoint is a single run's: the single path loads it (and, the run being complete, adds nothing)
    assert _comparable(train(TrainConfig(**{**cfgs[1].__dict__, "resume": True}))) == _comparable(b)
    # and, as a single run, a batched sweep refuses to start over the runs it wrote unless told to resume
    with pytest.raises(FileExistsError, match="resume=true"):
        train_batched(cfgs, overlap=False, n_workers=0, progress=False)


def test_batched_resume_takes_the_oldest_epoch_when_a_kill_split_the_members(tmp_path, reach_demos):
    """A kill between two members' checkpoint moves leaves them an epoch apart; resume restarts both at the older."""
    cfgs = [run_config(tmp_path / str(s), reach_demos, s, epochs=3) for s in (0, 1)]
    straight = train_batched(cfgs, n_workers=0, progress=False)
    member0 = Path(cfgs[0].run_dir)
    shutil.move(member0 / "checkpoint.prev.pt", member0 / "checkpoint.pt")  # member 0 back at epoch 2
    (member0 / "checkpoint.tmp").write_bytes(b"half written")              # and a torn temporary file
    for cfg in cfgs:
        cfg.resume = True
    resumed = train_batched(cfgs, n_workers=0, progress=False)
    for a, b in zip(resumed, straight):
        assert _comparable(a) == _comparable(b)
    assert json.loads((member0 / "process.json").read_text())["resumed_after_epoch"] == 2


def test_the_actors_of_four_epochs_are_kept_and_load(tmp_path, reach_demos):
    """The study keeps the actor at epochs 25, 50, 75 and 100 (here the four epochs of a 4-epoch run)."""
    from surrol_data.algos.policies import load_policy
    from surrol_data.algos.train_batched import actor_path
    from surrol_data.study.report_eval import actor_epochs

    assert actor_epochs((50, 100), 100) == (25, 50, 75, 100) and actor_epochs((1, 2), 2) == (1, 2)
    cfgs = [run_config(tmp_path / str(s), reach_demos, s, epochs=4) for s in (0, 1)]
    for cfg in cfgs:   # one cycle an epoch: the actors still change from epoch to epoch
        cfg.schedule = dataclasses.replace(cfg.schedule, cycles=1)
    train_batched(cfgs, n_workers=0, progress=False, actor_epochs=(1, 2, 3, 4))
    obs = {"observation": np.linspace(-1, 1, 7, dtype=np.float32), "desired_goal": np.full(3, 0.1, np.float32)}
    for cfg in cfgs:
        actions = {e: load_policy(actor_path(cfg.run_dir, e))(obs) for e in (1, 2, 3, 4)}
        np.testing.assert_array_equal(actions[4], load_policy(Path(cfg.run_dir) / "policy.pt")(obs))
        assert not np.array_equal(actions[1], actions[4])      # each is its epoch's actor, not the last one copied
    assert sorted(p.name for p in (Path(cfgs[0].run_dir) / "actors").iterdir()) == \
        ["epoch001.pt", "epoch002.pt", "epoch003.pt", "epoch004.pt"]


def _cli_overrides(run_root, demos_root, *extra):
    return ["batched=true", "seed=0,1", "task=NeedleReach", "algo=ddpgbc_warm", "demos=script", "demos.num=4",
            f"demos_root={demos_root}", "experiment=smoke", "experiment.epochs=5", "algo.params.hidden_sizes=[64,64]",
            "algo.params.critic_pretrain_steps=20", "algo.params.actor_hold_updates=8", "algo.params.q_ramp_updates=8",
            f"run_dir={run_root}/seed${{seed}}", "progress=false", "tensorboard=false", *extra]


@pytest.mark.slow  # two batched runs and a resume in subprocesses: ~1 min on a quiet 2-core machine
def test_batched_sweep_resumes_exactly_after_sigkill(tmp_path, reach_demos):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    killed = _cli_overrides(tmp_path / "killed", reach_demos.parent)
    proc = subprocess.Popen([*CLI, "train", "-m", *killed], cwd=tmp_path, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    metrics = tmp_path / "killed" / "seed1" / "metrics.jsonl"
    deadline = time.time() + 180
    while time.time() < deadline and proc.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 3:
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"the run ended before it could be killed: {proc.stderr.read().decode()[-2000:]}"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    result = subprocess.run([*CLI, "train", "-m", *killed, "resume=true"], cwd=tmp_path, env=env,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    subprocess.run([*CLI, "train", "-m", *_cli_overrides(tmp_path / "straight", reach_demos.parent)], cwd=tmp_path,
                   env=env, check=True, capture_output=True)
    for seed in (0, 1):
        resumed, straight = read_metrics(tmp_path / "killed" / f"seed{seed}"), read_metrics(tmp_path / "straight" / f"seed{seed}")
        assert [r["epoch"] for r in resumed] == list(range(6))
        assert _comparable(resumed) == _comparable(straight)
    assert json.loads((tmp_path / "killed" / "seed0" / "process.json").read_text())["resumed_after_epoch"] >= 1


@pytest.mark.slow  # ~2 min: the single path's test_her_learners_learn_needle_reach_without_demos, batched
def test_batched_ddpg_her_learns_needle_reach_like_single_runs(tmp_path):
    """Equal in distribution: the bar the single path clears (>= 90 % within 8 epochs), met by every member."""
    cfgs = [TrainConfig(env_id=REACH, run_dir=str(tmp_path / f"seed{s}"), learner="ddpg",
                        learner_params={"bc_weight": 0.0},
                        schedule=Schedule(epochs=8, cycles=10, updates_per_cycle=40, eval_episodes=20,
                                          warmup_steps=1000, n_envs=2),
                        seed=s, progress=False, tensorboard=False) for s in (0, 1)]
    for rows in train_batched(cfgs, overlap=True, n_workers=2, progress=False):
        assert max(r["success_rate"] for r in rows) >= 0.9, [r["success_rate"] for r in rows]


_ORPHAN = """
import os, numpy as np
from surrol_data.algos.env_pool import EnvPool
if __name__ == "__main__":
    pool = EnvPool("SurRoL/NeedleReach-v0", 20, 2, 1)
    explore = {"noise": None, "replace": np.ones((2, 20), bool),
               "random": np.zeros((2, 20, 5), np.float32)}
    pool.rollout_async([0, 1], None, np.zeros(2, int), explore)
    print(pool._procs[0].pid, flush=True)
    os._exit(0)   # killed while its worker plays
"""


def test_a_worker_whose_learner_was_killed_exits_quietly(tmp_path):
    """A killed batched run is resumed from its checkpoints; its orphaned workers must not bury the log in
    BrokenPipeError tracebacks when they finish the episodes nobody will collect."""
    script = tmp_path / "orphan.py"
    script.write_text(_ORPHAN)
    # the worker inherits the parent's stderr pipe, so this returns once the worker, too, has exited
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip().isdigit()   # the worker was started and the rollout sent
    assert "Traceback" not in out.stderr and "BrokenPipeError" not in out.stderr, out.stderr
