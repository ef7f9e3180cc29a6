"""What a TaskTransform writes per frame: no breakdown entry that carries no information.

A task tree that pays no final reward (``Task.pays_final_reward`` is False) writes neither
``(terms_key, "step")`` (it equals the reward) nor ``(terms_key, "final")`` (always 0); its named
terms still come. The property itself is checked against behaviour: a tree that says it pays no
final reward never pays one, over random transitions with random episode ends.
"""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from task_trees import all_task_cases, class_cases, random_transitions
from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.rewards import CompoundReward, ConstantReward, QuadraticErrorReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import FinalRewardTask, GoallessTask
from torchtasks.transforms import TaskTransform

TASKS = all_task_cases()


@pytest.mark.parametrize("name", sorted(TASKS))
def test_a_tree_that_pays_no_final_reward_never_pays_one(name: str) -> None:
    task = TASKS[name]().double()
    draws = random_transitions(task, torch.Generator().manual_seed(0), 12, batch=16)
    state, memory = draws["states"][0], task.reset(draws["states"][0])
    paid = torch.zeros((), dtype=torch.bool)
    for t in range(12):
        out = task.transition(
            state,
            draws["actions"][t],
            draws["states"][t + 1],
            memory,
            draws["remaining"][t],
            terminated=draws["terminated"][t],
            truncated=draws["truncated"][t],
        )
        paid = paid | (out.final_reward != 0).any()
        state, memory = draws["states"][t + 1], out.memory
    if not task.pays_final_reward:
        assert not paid
    assert task.pays_final_reward == any("Final" in type(t).__name__ for t in task.modules()), (
        "pays_final_reward must follow the final-reward tasks of the tree"
    )


def test_every_class_case_is_covered() -> None:
    assert set(class_cases()) <= set(TASKS)


def _env(task, log_terms: bool = True) -> TransformedEnv:
    return TransformedEnv(
        PendulumEnv(batch_size=[4], seed=0),
        Compose(StepCounter(20), TaskTransform(task, log_terms=log_terms), RewardSum()),
    )


def _terms_task(final: bool):
    reward = CompoundReward({"track": QuadraticErrorReward([1.0, 0.5]), "alive": ConstantReward(1.0)})
    task = GoallessTask(EnvSpec(2, 1), reward)
    return FinalRewardTask(task, factor=5.0) if final else task


def test_no_final_reward_no_step_or_final_entry() -> None:
    env = _env(_terms_task(final=False))
    nxt = env.rollout(5, break_when_any_done=False)["next"]
    assert set(nxt["task_reward"].keys()) == {"track", "alive", "episode_track", "episode_alive"}
    torch.testing.assert_close(nxt["reward"], nxt["task_reward", "track"] + nxt["task_reward", "alive"])
    assert set(env.reward_keys) == {"reward", ("task_reward", "track"), ("task_reward", "alive")}


def test_a_final_reward_keeps_the_step_and_final_entries() -> None:
    nxt = _env(_terms_task(final=True)).rollout(5, break_when_any_done=False)["next"]
    assert {"step", "final", "track", "alive"} <= set(nxt["task_reward"].keys())
    torch.testing.assert_close(nxt["reward"], nxt["task_reward", "step"] + nxt["task_reward", "final"])


def test_a_tree_without_final_reward_or_terms_writes_no_breakdown() -> None:
    task = GoallessTask(EnvSpec(2, 1), ConstantReward(1.0))
    nxt = _env(task).rollout(3, break_when_any_done=False)["next"]
    assert "task_reward" not in nxt.keys()
    swing_up = swing_up_task()
    keys = set(_env(swing_up).rollout(3)["next"]["task_reward"].keys())
    assert ("step" in keys) == ("final" in keys) == swing_up.pays_final_reward


class _PaysOnFinalReward(GoallessTask):
    """A task of one's own that pays its final reward by overriding ``_final_reward`` itself."""

    def _final_reward(self, state, memory, remaining_steps, done, flags=None):
        return torch.where(done, 7.0, 0.0).to(state.dtype), memory


def test_a_task_overriding_final_reward_pays_it() -> None:
    task = _PaysOnFinalReward(EnvSpec(2, 1), ConstantReward(1.0))
    assert task.pays_final_reward
    state = torch.zeros(2, 2)
    out = task.transition(state, torch.zeros(2, 1), state, task.reset(state), truncated=torch.tensor([True, False]))
    assert out.final_reward.tolist() == [7.0, 0.0]
