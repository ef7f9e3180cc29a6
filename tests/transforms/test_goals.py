"""Goals passed per transition: ``Task.transition(..., goal=)`` and the fine-grained calls, masks and composites,
and ``TaskTransform(goal_key=..., achieved_goal_key=...)`` online and offline (relabelled goals re-judge success)."""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.data import Unbounded
from torchrl.envs import Compose, StepCounter, Transform, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, ParallelTasks, proximity_succeeded
from torchtasks.transforms import TaskTransform

NEAR = functools.partial(proximity_succeeded, threshold=0.1)


def reach(size: int = 2, goal: float = 0.0) -> FinalRewardTask:
    spec = EnvSpec(Box([-5.0] * size, [5.0] * size), 1)
    return FinalRewardTask(DesiredStateTask(spec, [goal] * size, QuadraticErrorReward([1.0] * size), NEAR), factor=10.0)


def test_a_goal_replaces_the_desired_state_in_transition_and_the_fine_grained_calls():
    task = reach()
    state = torch.zeros(3, 2)
    next_state = torch.tensor([[1.0, 1.0], [0.0, 0.0], [2.0, 0.0]])
    goal = torch.tensor([[1.0, 1.0], [1.0, 1.0], [2.0, 0.05]])
    out = task.transition(state, torch.zeros(3, 1), next_state, task.reset(state), goal=goal)
    assert out.success.tolist() == [True, False, True]
    torch.testing.assert_close(out.step_reward, torch.tensor([0.0, -2.0, -0.0025]))
    assert torch.equal(out.memory["wrapped", "state_des"], goal)  # the memory carries the goal it was judged with
    # the fine-grained calls take the same goal and give the same numbers
    memory = task.reset(state)
    reward, memory = task.step_reward(next_state, torch.zeros(3, 1), memory, goal=goal)
    assert torch.equal(reward, out.step_reward)
    assert torch.equal(task.has_succeeded(next_state, memory, goal=goal), out.success)


def test_a_mask_takes_a_goal_of_the_selected_entries():
    spec = EnvSpec(Box([-5.0] * 4, [5.0] * 4, labels=["x", "y", "vx", "vy"]), 1)
    inner = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), NEAR)
    task = FinalRewardTask(MaskedTask(spec, inner, ["x", "y"]))
    (slot,) = task.goal_slots
    assert slot.size == 2 and slot.state_indices == (0, 1)
    state = torch.tensor([[1.0, 2.0, 9.0, 9.0]])
    out = task.transition(state, torch.zeros(1, 1), state, task.reset(state), goal=torch.tensor([[1.0, 2.0]]))
    assert out.success.tolist() == [True]
    assert torch.equal(slot.achieved(state), torch.tensor([[1.0, 2.0]]))
    with pytest.raises(ValueError, match=r"goal must have shape \[\*B, 2\], got \(1, 4\)"):
        task.transition(state, torch.zeros(1, 1), state, task.reset(state), goal=state)


def test_a_tree_with_several_goal_tasks_names_them():
    task = ParallelTasks([reach(goal=0.0), reach(goal=1.0)])
    names = [slot.name for slot in task.goal_slots]
    assert names == ["task0.wrapped.state_des", "task1.wrapped.state_des"]
    state = torch.zeros(2, 2)
    with pytest.raises(ValueError, match=r"2 tasks that take a goal .*pass goal=\{name: tensor\}"):
        task.transition(state, torch.zeros(2, 1), state, task.reset(state), goal=torch.zeros(2, 2))
    goals = {"task1.wrapped.state_des": torch.zeros(2, 2)}  # both sub-tasks now reach 0: both succeed
    out = task.transition(state, torch.zeros(2, 1), state, task.reset(state), goal=goals)
    assert out.success.tolist() == [True, True]
    with pytest.raises(ValueError, match=r"unknown goal name\(s\) \['task2'\]"):
        task.transition(state, torch.zeros(2, 1), state, task.reset(state), goal={"task2": torch.zeros(2, 2)})
    with pytest.raises(ValueError, match="no task of this GoallessTask tree takes a goal"):
        from torchtasks.rewards import ConstantReward
        from torchtasks.tasks import GoallessTask

        goalless = GoallessTask(EnvSpec(2, 1), ConstantReward(1.0))
        goalless.transition(state, torch.zeros(2, 1), state, goalless.reset(state), goal=torch.zeros(2, 2))


class FixedGoal(Transform):
    """Writes a per-env goal into the observation (a stand-in for GoalCommand in these tests)."""

    def __init__(self, goals: torch.Tensor) -> None:
        super().__init__(in_keys=[], out_keys=["goal"])
        self.goals = goals

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset.set("goal", self.goals.clone())
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set("goal", self.goals.clone())
        return next_tensordict

    def transform_observation_spec(self, observation_spec):
        observation_spec["goal"] = Unbounded(shape=self.goals.shape, dtype=self.goals.dtype)
        return observation_spec


def _env(goals: torch.Tensor) -> TransformedEnv:
    task = reach()
    transform = TaskTransform(task, goal_key="goal", achieved_goal_key="achieved_goal")
    return TransformedEnv(PendulumEnv(batch_size=[4], seed=0), Compose(StepCounter(20), FixedGoal(goals), transform))


def test_task_transform_reads_the_goal_the_policy_saw_and_writes_the_achieved_goal():
    goals = torch.tensor([[0.0, 0.0], [3.0, 0.0], [-3.0, 1.0], [1.0, 1.0]])
    env = _env(goals)
    data = env.rollout(15, break_when_any_done=False)
    task = reach()
    # offline recomputation with the goal at the root (the one the policy saw)
    for t in range(15):
        step = data[:, t]
        out = task.transition(
            step["observation"], step["action"], step["next", "observation"], step["task"], goal=step["goal"]
        )
        torch.testing.assert_close(out.reward, step["next", "reward"][..., 0])
        assert torch.equal(out.success, step["next", "success"][..., 0])
    assert torch.equal(data["next", "achieved_goal"], data["next", "observation"])
    assert torch.equal(data["achieved_goal"][:, 0], data["observation"][:, 0])  # written at reset too


def test_offline_relabelling_rejudges_reward_success_and_episode_end():
    env = _env(torch.full((4, 2), 4.0))  # far goals: no success online
    data = env.rollout(10, break_when_any_done=False)
    assert not data["next", "success"].any()
    transform = env.transform[-1]
    relabelled = data.clone()
    relabelled["goal"] = data["next", "achieved_goal"].clone()  # hindsight: the goal is where it got to
    transform.forward(relabelled)
    assert relabelled["next", "success"].all() and relabelled["next", "terminated"].all()
    assert relabelled["next", "done"].all()
    torch.testing.assert_close(transform.reward_fn(relabelled), relabelled["next", "reward"])


def test_task_transform_goal_errors():
    from torchtasks.rewards import ConstantReward
    from torchtasks.tasks import GoallessTask

    with pytest.raises(ValueError, match="no task of the GoallessTask tree takes a goal"):
        TaskTransform(GoallessTask(EnvSpec(2, 1), ConstantReward(0.0)), goal_key="goal")
    with pytest.raises(ValueError, match=r"2 goal tasks .*goal_name"):
        TaskTransform(ParallelTasks([reach(), reach()]), goal_key="goal")
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(StepCounter(5), TaskTransform(reach(), goal_key="goal")))
    with pytest.raises(KeyError, match="the goal 'goal' is missing"):
        env.rollout(2)


def test_her_relabelled_batches_carry_the_tasks_reward_success_and_episode_end():
    from torchrl.data import HERReplayBuffer, LazyTensorStorage

    from torchtasks.transforms import GoalCommand

    task = reach()
    transform = TaskTransform(task, goal_key="goal", achieved_goal_key="achieved_goal")
    command = GoalCommand(Box([-2.0, -2.0], [2.0, 2.0]), resample_steps=(4, 8), seed=0)
    env = TransformedEnv(PendulumEnv(batch_size=[4], seed=1), Compose(StepCounter(12), transform, command))
    torch.manual_seed(0)
    data = env.rollout(36, break_when_any_done=False)
    data["next", "done"][:, -1] = True  # each env's chunk ends an episode in storage (a trajectory split)
    data["next", "truncated"][:, -1] = True
    buffer = HERReplayBuffer(
        reward_fn=transform.relabel,
        goal_key="goal",
        achieved_goal_key=("next", "achieved_goal"),
        her_ratio=1.0,
        strategy="future",
        storage=LazyTensorStorage(200),
        batch_size=64,
    )
    buffer.extend(data.reshape(-1))
    batch = buffer.sample()
    assert batch["next", "success"].any()  # relabelled goals are reached: the episode end changes
    out = task.transition(
        batch["observation"],
        batch["action"],
        batch["next", "observation"],
        batch["task"],
        truncated=batch["next", "truncated"][..., 0],
        goal=batch["goal"],
    )
    torch.testing.assert_close(out.reward, batch["next", "reward"][..., 0])
    assert torch.equal(out.success, batch["next", "success"][..., 0])
    assert torch.equal(out.terminated, batch["next", "terminated"][..., 0])
    assert torch.equal(out.done, batch["next", "done"][..., 0])
    # the rest of the relabelled transition too: the breakdown adds up to the reward, the next memory is the task's
    torch.testing.assert_close(
        batch["next", "task_reward", "step"] + batch["next", "task_reward", "final"], batch["next", "reward"]
    )
    assert (batch["next", "task"] == out.memory).all()
