"""Named end conditions: which condition ended each episode, from the same transition call.

For every task case the named conditions of each kind must OR to the task's own success and failure
flags (so they name, never change, the verdict); the transform writes them and the statistics count them.
"""

from __future__ import annotations

import functools

import pytest
import torch
from torchrl.envs import Compose, StepCounter, TransformedEnv

from task_trees import all_task_cases, random_transitions
from torchtasks.envs import PointMassEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.rewards.terms import HealthyReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import (
    DesiredStateTask,
    FinalRewardTask,
    GoallessTask,
    MaskedTask,
    ParallelTasks,
    proximity_succeeded,
)
from torchtasks.transforms import TaskTransform

CASES = all_task_cases()


@pytest.mark.parametrize("name", sorted(CASES))
def test_named_conditions_or_to_the_success_and_failure_flags(name: str):
    task = CASES[name]()
    kinds = task.termination_names
    data = random_transitions(task, torch.Generator().manual_seed(7), steps=6, batch=8)
    memory = task.reset(data["states"][0])
    for t in range(6):
        goal = data["goals"][t] if "goals" in data else None
        out = task.transition(
            data["states"][t], data["actions"][t], data["states"][t + 1], memory, data["remaining"][t], goal=goal
        )
        if list(kinds.values()).count("failure") < 2 and list(kinds.values()).count("success") < 2:
            assert out.ended_by == {}  # the flags say which condition held: nothing more is written
        else:
            assert list(out.ended_by) == list(kinds)
            for kind, flag in (("success", out.success), ("failure", out.failure)):
                parts = [out.ended_by[n] for n, k in kinds.items() if k == kind]
                combined = torch.stack(parts).any(0) if parts else torch.zeros_like(flag)
                assert torch.equal(combined, flag), (name, t, kind)
        memory = out.memory


def test_leaf_tasks_name_their_failures_and_wrappers_keep_the_names():
    names = {name: CASES[name]().termination_names for name in CASES}
    assert any("unhealthy" in n for n in names.values())  # a reward that can fail names its failure
    assert any(set(n) == {"success", "out_of_bounds"} for n in names.values())
    spec = EnvSpec(Box([-1.0, -1.0], [1.0, 1.0]), 1)
    leaf = DesiredStateTask(spec, [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]))
    assert FinalRewardTask(leaf, factor=2.0).termination_names == leaf.termination_names
    # a leaf without a success function cannot succeed: neither can a composite that needs its success
    assert leaf.termination_names == {"out_of_bounds": "failure"}
    assert ParallelTasks([leaf, leaf]).termination_names == {"failure": "failure"}
    reach = DesiredStateTask(spec, [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), threshold=0.1)
    assert ParallelTasks([reach, reach]).termination_names == {"success": "success", "failure": "failure"}
    assert ParallelTasks([reach, leaf]).termination_names == {"failure": "failure"}
    assert ParallelTasks([reach, leaf], easily_satisfied=True).termination_names == {
        "success": "success",
        "failure": "failure",
    }


def _walk_env(batch: int = 8) -> TransformedEnv:
    """Point masses that fail by leaving the box (|x|, |y| > 0.9) or by running too fast (|vx| > 0.8)."""
    spec = EnvSpec(Box([-0.9, -0.9, -10.0, -10.0], [0.9, 0.9, 10.0, 10.0], labels=["x", "y", "vx", "vy"]), 2)
    alive = HealthyReward(1.0, index=[2], low=-0.8, high=0.8, terminate_when_unhealthy=True)
    task = GoallessTask(spec, alive)
    env = PointMassEnv(batch_size=[batch], seed=0, max_force=2.0)
    return TransformedEnv(env, Compose(StepCounter(25), TaskTransform(task)))


def _policy(td):
    action = torch.zeros_like(td["observation"][..., :2])
    action[0::3, 0] = 2.0  # fast along x: unhealthy, or out of the box first when starting near the wall
    action[1::3, 1] = 0.6  # slowly along y: out of the box
    td["action"] = action  # the rest stand still: the time limit
    return td


def test_the_transform_writes_which_condition_ended_the_episode_and_statistics_count_it():
    data = _walk_env().rollout(80, _policy, break_when_any_done=False)
    nxt = data["next"]
    left, fast = nxt["ended_by", "out_of_bounds"][..., 0], nxt["ended_by", "unhealthy"][..., 0]
    assert torch.equal(left | fast, nxt["failure"][..., 0])
    assert "success" not in nxt.keys() and "success" not in nxt["ended_by"].keys()  # walking never succeeds
    done = nxt["done"][..., 0]
    assert (left & done).any() and (fast & done).any() and (done & ~left & ~fast).any()
    stats = episode_statistics(data, terms_key=None)
    ended = done.sum().item()
    assert stats["ended_by/out_of_bounds"] == pytest.approx((left & done).sum().item() / ended)
    assert stats["ended_by/unhealthy"] == pytest.approx((fast & done).sum().item() / ended)
    assert "ended_by/success" not in stats and "success_rate" not in stats
    assert stats["timeout_rate"] == pytest.approx((done & ~left & ~fast).sum().item() / ended)
    assert not data["ended_by", "unhealthy"][:, 0].any()  # the root of the first step: the reset's flags


def test_one_condition_per_kind_writes_no_extra_entry():
    spec = EnvSpec(Box([-0.9] * 4, [0.9] * 4, labels=["x", "y", "vx", "vy"]), 2)
    near = functools.partial(proximity_succeeded, threshold=0.15)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.5, 0.5], QuadraticErrorReward([1.0, 1.0]), near)
    task = MaskedTask(spec, reach, ["x", "y"])
    assert set(task.termination_names) == {"success", "out_of_bounds"}
    transform = TaskTransform(task)
    env = TransformedEnv(PointMassEnv(batch_size=[2], seed=0), Compose(StepCounter(5), transform))
    data = env.rollout(3)
    assert transform.termination_names == () and "ended_by" not in data["next"].keys()
