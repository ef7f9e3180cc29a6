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
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, ParallelTasks, proximity_succeeded
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
        if kinds == {"success": "success", "failure": "failure"}:
            assert out.ended_by == {}  # a tree naming nothing more writes nothing more
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
    assert ParallelTasks([leaf, leaf]).termination_names == {"success": "success", "failure": "failure"}


def _reach_env(batch: int = 6) -> TransformedEnv:
    spec = EnvSpec(Box([-0.9] * 4, [0.9] * 4, labels=["x", "y", "vx", "vy"]), 2)
    near = functools.partial(proximity_succeeded, threshold=0.15)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.5, 0.5], QuadraticErrorReward([1.0, 1.0]), near)
    task = MaskedTask(spec, reach, ["x", "y"])
    return TransformedEnv(
        PointMassEnv(batch_size=[batch], seed=0, max_force=2.0), Compose(StepCounter(25), TaskTransform(task))
    )


def _policy(td):
    state = td["observation"]
    td["action"] = (6.0 * (torch.tensor([0.5, 0.5]) - state[..., :2]) - state[..., 2:]).clamp(-2, 2)
    td["action"][::2] = 2.0  # every other mass runs into the wall: out of bounds
    return td


def test_the_transform_writes_which_condition_ended_the_episode_and_statistics_count_it():
    data = _reach_env().rollout(60, _policy, break_when_any_done=False)
    nxt = data["next"]
    reached, left = nxt["ended_by", "success"], nxt["ended_by", "out_of_bounds"]
    assert torch.equal(reached, nxt["success"]) and torch.equal(left, nxt["failure"])
    assert reached.any() and left.any()
    stats = episode_statistics(data, terms_key=None)
    done = nxt["done"][..., 0]
    ended = done.sum().item()
    assert stats["ended_by/success"] == pytest.approx((reached[..., 0] & done).sum().item() / ended)
    assert stats["ended_by/out_of_bounds"] == pytest.approx((left[..., 0] & done).sum().item() / ended)
    timeouts = (done & ~reached[..., 0] & ~left[..., 0]).sum().item() / ended
    assert stats["timeout_rate"] == pytest.approx(timeouts)
    assert stats["ended_by/success"] + stats["ended_by/out_of_bounds"] + stats["timeout_rate"] == pytest.approx(1.0)
    # the root carries the flags of the reset (all False), as for success and failure
    assert not data["ended_by", "success"][:, 0].any()
