"""Issue 28: `surrol-data demo`/`eval` roll BC policies out on one torch thread (their matmuls are tiny: torch's
default of a thread per core made each episode 8-15x slower), and give the caller's thread count back."""

import numpy as np
import torch

from surrol_data.algos.bc import BCConfig, BCPolicy
from surrol_data.algos.networks import DeterministicActor
from surrol_data.algos.normalizer import Normalizer
from surrol_data.evaluation.rollout import evaluate, policy_threads

REACH = "SurRoL/NeedleReach-v0"


class _Spy(BCPolicy):
    """A BC policy that notes torch's thread count at every action."""

    def act(self, obs):
        self.seen.append(torch.get_num_threads())
        return super().act(obs)

    __call__ = act


def _policy() -> _Spy:
    torch.manual_seed(0)
    policy = _Spy(DeterministicActor(7, 3, 5, (16, 16)), Normalizer(7), Normalizer(3), BCConfig(hidden_sizes=(16, 16)))
    policy.seen = []
    return policy


def test_evaluate_rolls_a_bc_policy_out_on_one_thread_and_restores_the_count():
    before = torch.get_num_threads()
    torch.set_num_threads(2)   # torch's default on a 2-core machine
    try:
        policy = _policy()
        assert policy.torch_threads == 1
        result = evaluate(REACH, policy, 1, max_steps=3, progress=False)
        assert len(result.proficiency) == 1 and policy.seen and set(policy.seen) == {1}
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_policies_that_name_no_thread_count_run_as_they_are():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    seen = []

    def plain(obs):   # e.g. a LeRobot policy, which may want every core
        seen.append(torch.get_num_threads())
        return np.zeros(5, np.float32)

    try:
        with policy_threads("oracle"):
            assert torch.get_num_threads() == 2
        evaluate(REACH, plain, 1, max_steps=2, progress=False)
        assert set(seen) == {2}
    finally:
        torch.set_num_threads(before)
