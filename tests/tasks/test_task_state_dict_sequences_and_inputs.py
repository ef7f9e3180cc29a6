"""Regression tests of issue 14's task-level items: state_dict loading (item 11), finite rewards at the end
of a sequential task (item 5), memory of another tree (item 8) and unvalidated transition inputs (item 7).

Each test failed on the code before its fix (values and messages written out by hand next to each assertion).
"""

from __future__ import annotations

import functools

import pytest
import torch
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import ConstantReward, StateFunctionReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    DesiredStateTask,
    FinalRewardTask,
    GoallessTask,
    ParallelTasks,
    SequentialTasks,
    proximity_succeeded,
)
from torchtasks.transforms import TaskTransform


def _goalless(box: Box | int) -> FinalRewardTask:
    return FinalRewardTask(GoallessTask(EnvSpec(box, 1), ConstantReward(0.0)), factor=1.0)


# ------------------------------------------------------------------------- item 11: load_state_dict
def test_loading_bounds_into_an_unbounded_task_makes_it_fail_outside_them():
    bounded, unbounded = _goalless(Box([-1.0], [1.0])), _goalless(1)
    unbounded.load_state_dict(bounded.state_dict())
    state = torch.tensor([[2.0], [0.5]])
    assert unbounded.has_failed(state, unbounded.reset(state)).tolist() == [True, False]
    assert unbounded.spec.state_space.high.tolist() == [1.0]
    assert unbounded.wrapped_task.spec.state_space.low.tolist() == [-1.0]


def test_loading_bounds_into_a_bounded_task_updates_its_spec_and_check():
    narrow, wide = _goalless(Box([-1.0], [1.0], labels=["x"])), _goalless(Box([-5.0], [5.0], labels=["x"]))
    wide.load_state_dict(narrow.state_dict())
    assert wide.spec.state_space.high.tolist() == [1.0] and wide.spec.state_space.labels == ("x",)
    state = torch.tensor([[2.0]])
    assert wide.has_failed(state, wide.reset(state)).tolist() == [True]
    # and back: unbounded bounds make it an all-infinite box that only rejects NaN
    wide.load_state_dict(_goalless(1).state_dict())
    state = torch.tensor([[1e9], [float("nan")]])
    assert wide.has_failed(state, wide.reset(state)).tolist() == [False, True]


# ------------------------------------------------------------- item 5: the end of a sequential task
def _goal(position: float) -> DesiredStateTask:
    near = functools.partial(proximity_succeeded, threshold=0.1)
    return DesiredStateTask(EnvSpec(2, 1), [position, 0.0], ConstantReward(-1.0), near)


def test_a_best_state_sub_task_that_never_became_current_pays_zero_not_minus_inf():
    task = SequentialTasks([_goal(1.0), BestStateFinalRewardTask(_goal(2.0), factor=1.0)])
    state = torch.zeros(2, 2)
    out = task.transition(state, torch.zeros(2, 1), state, task.reset(state), truncated=torch.tensor([True, False]))
    # env0 is truncated at its first step: sub-task 0 paid -1 (its step reward), sub-task 1 never ran -> 0
    assert out.reward.tolist() == [-1.0, -1.0]
    assert out.final_reward.tolist() == [0.0, 0.0]


def test_rollout_of_a_sequential_task_with_an_unreached_best_state_sub_task_is_finite():
    task = SequentialTasks([_goal(1.0), BestStateFinalRewardTask(_goal(2.0), factor=1.0)])
    env = TransformedEnv(PendulumEnv(batch_size=[3], seed=0), Compose(StepCounter(5), TaskTransform(task)))
    rollout = env.rollout(12, break_when_any_done=False)
    assert torch.isfinite(rollout["next", "reward"]).all()
    assert rollout["next", "truncated"].any()  # episodes did end (by the time limit) inside the rollout


def test_a_best_state_sub_task_that_ran_pays_its_best_at_the_end():
    # sub-task 1 is current from the start (start_index=1): it sees rewards -1 then ends by truncation
    task = SequentialTasks([_goal(1.0), BestStateFinalRewardTask(_goal(2.0), factor=3.0)], start_index=1)
    state = torch.zeros(1, 2)
    memory = task.reset(state)
    out = task.transition(state, torch.zeros(1, 1), state, memory)
    out = task.transition(state, torch.zeros(1, 1), state, out.memory, truncated=torch.tensor([True]))
    assert out.final_reward.tolist() == [-3.0]  # factor 3 x best step reward -1


# -------------------------------------------------------------------- items 7 and 8: inputs, memory
def test_transition_refuses_unvalidated_next_state_and_flags():
    task = _goalless(Box([-1.0, -1.0], [1.0, 1.0]).select([0]))
    state = torch.zeros(4, 1)
    memory = task.reset(state)
    with pytest.raises(ValueError, match=r"truncated must have the batch shape \(4,\), got \(4, 1\)"):
        task.transition(state, torch.zeros(4, 1), state, memory, truncated=torch.zeros(4, 1, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"next_state must have the shape of state \(4, 1\), got \(1, 1\)"):
        task.transition(state, torch.zeros(4, 1), torch.zeros(1, 1), memory)
    with pytest.raises(TypeError, match=r"next_state must be a float32 or float64 tensor"):
        task.transition(state, torch.zeros(4, 1), torch.zeros(4, 1, dtype=torch.long), memory)
    with pytest.raises(TypeError, match=r"truncated must be None or a bool tensor of shape \(4,\), got a torch.float"):
        task.transition(state, torch.zeros(4, 1), state, memory, truncated=torch.zeros(4))


def test_parallel_tasks_refuse_the_memory_of_a_three_task_tree():
    a, b, c = (_goal(float(g)) for g in range(3))
    state = torch.zeros(2, 2)
    with pytest.raises(ValueError, match=r"unexpected key\(s\) \['task2'\]"):
        ParallelTasks([a, b]).step_reward(state, torch.zeros(2, 1), ParallelTasks([a, b, c]).reset(state))


def test_a_stateful_reward_memory_from_another_tree_names_the_missing_key():
    task = GoallessTask(EnvSpec(1, 1), StateFunctionReward(lambda s: s[..., 0]))
    other = BestStateFinalRewardTask(task, factor=1.0)
    state = torch.zeros(2, 1)
    with pytest.raises(ValueError, match=r"missing key\(s\) \['best', 'paid', 'wrapped'\]"):
        other.transition(state, torch.zeros(2, 1), state, task.reset(state))
