"""Reward groups whose weights a Curriculum ramps: stored data are recomputed with the weights each step used.

The expected vectors are the online ones (the env's own step); the weights per frame are read from the data.
"""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import CompoundReward, ConstantReward, ControlCostReward, QuadraticErrorReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import GoallessTask, RewardGroupsTask
from torchtasks.transforms import Curriculum, TaskTransform, linear


def _task() -> RewardGroupsTask:
    reward = CompoundReward(
        {
            "track": QuadraticErrorReward([1.0, 0.1], None),
            "effort": ControlCostReward(0.01),
            "alive": ConstantReward(1.0),
        }
    )
    groups = {"track": {"track": 1.0, "alive": 1.0}, "effort": {"effort": 100.0}}
    return RewardGroupsTask(GoallessTask(EnvSpec(2, 1), reward), groups)


def _env() -> tuple[TransformedEnv, TaskTransform]:
    transform = TaskTransform(_task())
    ramp = Curriculum({"weights_track": linear([1.0, 1.0], [3.0, 5.0], 0, 40)})
    env = TransformedEnv(PendulumEnv(batch_size=[4], seed=0), Compose(StepCounter(50), transform, ramp))
    return env, transform


@pytest.mark.parametrize("frames", [1, 2, 3, 6])
def test_offline_groups_use_the_weights_each_step_used(frames: int) -> None:
    env, transform = _env()
    data = env.rollout(6, break_when_any_done=False)
    weights = data["curriculum", "weights_track"]
    assert not torch.equal(weights[0, 0], weights[0, -1])  # the ramp moved during the rollout
    online = data["next", "vector_reward"].clone()
    stored = data[:, :frames].reshape(-1).clone()  # a flat sample of the first frames of each env
    stored["next", "vector_reward"].zero_()
    transform(stored)
    assert torch.equal(stored["next", "vector_reward"], online[:, :frames].reshape(-1, 2))
    assert torch.equal(transform.reward_fn(stored), data["next", "reward"][:, :frames].reshape(-1, 1))


def test_a_schedule_of_non_finite_weights_is_refused() -> None:
    transform = TaskTransform(_task())
    ramp = Curriculum({"weights_effort": linear([100.0], [float("inf")], 0, 40)})
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(StepCounter(5), transform, ramp))
    with pytest.raises(ValueError, match=r"reward group 'effort'.*must be finite"):
        env.reset()


def test_a_vector_key_where_reward_sum_writes_an_episode_sum_is_refused() -> None:
    with pytest.raises(ValueError, match=r"'episode_reward' \(vector_reward_key\) is written beside 'reward'"):
        TaskTransform(_task(), vector_reward_key="episode_reward")


def test_group_keys_list_the_vector_then_each_group() -> None:
    assert TaskTransform(_task()).group_keys == [
        "vector_reward",
        ("reward_groups", "track"),
        ("reward_groups", "effort"),
    ]
    assert TaskTransform(_task().wrapped_task).group_keys == []
