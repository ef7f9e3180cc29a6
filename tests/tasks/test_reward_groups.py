"""RewardGroupsTask: named groups of a task's reward terms, accumulated in order, rounded to the groups' dtype.

Expected values are written here from the definition: numpy's in-place ``vec += term`` on a float32 vector (what
MO-Gymnasium computes) and plain float64 sums of the terms the task reports, never from the groups under test.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchtasks.rewards import CompoundReward, ConstantReward, ControlCostReward, VelocityReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import (
    ConstrainedTask,
    FinalRewardTask,
    GoallessTask,
    MaskedTask,
    ParallelTasks,
    PotentialShapingTask,
    RewardGroupsTask,
)


def _compound() -> CompoundReward:
    return CompoundReward(
        {"forward": VelocityReward(1.25, index=0), "ctrl": ControlCostReward(0.1), "alive": ConstantReward(5.0)}
    )


def _leaf() -> GoallessTask:
    return GoallessTask(EnvSpec(2, 3), _compound())


def _draws(n: int = 4000, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    state = torch.randn(n, 2, generator=generator, dtype=torch.float64) * 3.0
    action = torch.rand(n, 3, generator=generator, dtype=torch.float64) * 2.0 - 1.0
    return state, action


GROUPS = {"speed": {"forward": 0.8, "alive": 1.0}, "energy": {"ctrl": 10.0, "alive": 1.0}}


def test_float32_groups_round_after_every_addition_as_numpy_in_place_adds() -> None:
    task = RewardGroupsTask(_leaf(), GROUPS, dtype=torch.float32).double()
    state, action = _draws()
    out = task.transition(state, action, state, task.reset(state))
    terms = {name: value.numpy() for name, value in out.terms.items()}
    for group, weights in GROUPS.items():
        expected = np.empty(len(state), dtype=np.float32)
        for i in range(len(state)):
            sources = iter(weights.items())
            first, c = next(sources)
            vec = np.array([c * terms[first][i]], dtype=np.float32)
            for source, c in sources:
                vec += np.float64(c * terms[source][i])  # numpy: float64(vec) + term, rounded to float32
            expected[i] = vec[0]
        got = out.groups[group]
        assert got.dtype == torch.float32
        assert torch.equal(got, torch.from_numpy(expected)), group
    # rounding once at the end differs on some rows: the rule above is not a plain cast of the float64 sum
    once = (0.8 * out.terms["forward"] + out.terms["alive"]).float()
    assert not torch.equal(once, out.groups["speed"])


def test_groups_without_dtype_are_plain_sums_in_the_terms_dtype() -> None:
    task = RewardGroupsTask(_leaf(), {"all": {"step": 1.0}, **GROUPS}).double()
    state, action = _draws(64)
    out = task.transition(state, action, state, task.reset(state))
    assert out.groups["all"].dtype == torch.float64
    assert torch.equal(out.groups["all"], out.step_reward)
    assert torch.equal(out.groups["speed"], 0.8 * out.terms["forward"] + out.terms["alive"])
    assert task.group_names == ("all", "speed", "energy") and task.group_dtype is None


def test_extra_terms_are_reported_in_groups_and_never_paid() -> None:
    height = VelocityReward(10.0, index=1)
    base = _leaf().double()
    task = RewardGroupsTask(base, {"up": {"height": 1.0, "alive": 1.0}}, terms={"height": height}).double()
    state, action = _draws(64)
    out = task.transition(state, action, state, task.reset(state))
    plain = base.transition(state, action, state, base.reset(state))
    assert torch.equal(out.reward, plain.reward)
    assert torch.equal(out.groups["up"], 10.0 * state[:, 1] + 5.0)


def _wrappers():
    spec = EnvSpec(2, 3)
    return {
        "final_reward": lambda task: FinalRewardTask(task),
        "constrained": lambda task: ConstrainedTask(task, {"speed": VelocityReward(1.0, index=0)}),
        "masked": lambda task: MaskedTask(spec, task, None),
        "shaping": lambda task: PotentialShapingTask(task, lambda s: -(s[..., 0] ** 2), 0.99),
    }


@pytest.mark.parametrize("wrapper", sorted(_wrappers()))
def test_wrappers_keep_the_groups_of_the_task_they_wrap(wrapper: str) -> None:
    grouped = RewardGroupsTask(_leaf(), {**GROUPS, "all": {"step": 1.0, "final": 1.0}})
    task = _wrappers()[wrapper](grouped).double()
    assert task.group_names == ("speed", "energy", "all") and task.facts.has_groups
    state, action = _draws(64)
    next_state = state + 0.1
    done = torch.zeros(64, dtype=torch.bool)
    done[::3] = True
    out = task.transition(state, action, next_state, task.reset(state), truncated=done)
    assert torch.equal(out.groups["speed"], 0.8 * out.terms["forward"] + out.terms["alive"])
    assert torch.equal(out.groups["energy"], 10.0 * out.terms["ctrl"] + out.terms["alive"])
    assert torch.equal(out.groups["all"], out.step_reward + out.final_reward)  # the whole tree's step and final


def test_a_composite_refuses_grouped_sub_tasks_and_takes_groups_around_it() -> None:
    with pytest.raises(ValueError, match=r"tasks\[1\] has reward groups \['speed', 'energy'\].*wrap the composite"):
        ParallelTasks([_leaf(), RewardGroupsTask(_leaf(), GROUPS)])
    task = RewardGroupsTask(ParallelTasks([_leaf(), _leaf()]), {"all": {"step": 1.0}}).double()
    state, action = _draws(8)
    out = task.transition(state, action, state, task.reset(state))
    assert torch.equal(out.groups["all"], out.step_reward)


def test_the_coefficients_are_a_buffer_and_the_groups_report_them() -> None:
    task = RewardGroupsTask(_leaf(), GROUPS)
    assert "coefficients" in dict(task.named_buffers())
    assert task.groups == GROUPS
    task.coefficients.fill_(2.0)
    state, action = _draws(8)
    task = task.double()
    out = task.transition(state, action, state, task.reset(state))
    assert torch.equal(out.groups["energy"], 2.0 * out.terms["ctrl"] + 2.0 * out.terms["alive"])


def test_the_transition_compiles_with_fullgraph() -> None:
    torch._dynamo.reset()
    task = FinalRewardTask(RewardGroupsTask(_leaf(), GROUPS, dtype=torch.float32)).double()
    state, action = _draws(16)
    arguments = (state, action, state, task.reset(state), task.no_remaining_steps)
    want = task._transition(*arguments)
    got = torch.compile(task._transition, fullgraph=True, backend="eager")(*arguments)
    for name in GROUPS:
        assert torch.equal(got.groups[name], want.groups[name])


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"groups": {"x": {"forwrd": 1.0}}}, ValueError, r"reads 'forwrd'.*did you mean 'forward'"),
        ({"groups": {}}, TypeError, r"groups must be a non-empty mapping"),
        ({"groups": {"x": {}}}, TypeError, r"the group 'x' must be a non-empty mapping"),
        ({"groups": {"a b": {"step": 1.0}}}, ValueError, r"group names must be identifiers"),
        ({"groups": {"x": {"step": float("nan")}}}, ValueError, r"groups\['x'\]\['step'\] must be finite"),
        ({"groups": {"x": {"step": "1"}}}, TypeError, r"groups\['x'\]\['step'\]"),
        ({"groups": {"x": {"step": 1.0}}, "dtype": torch.int64}, TypeError, r"dtype must be torch.float32"),
        ({"groups": {"x": {"step": 1.0}}, "terms": {"ctrl": ConstantReward(1.0)}}, ValueError, r"'ctrl' is taken"),
        ({"groups": {"x": {"step": 1.0}}, "terms": {"z": lambda s: s}}, TypeError, r"must be a torchtasks Reward"),
    ],
)
def test_bad_groups_are_refused_with_the_argument_named(kwargs: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        RewardGroupsTask(_leaf(), **kwargs)


def test_a_tree_holds_one_set_of_groups() -> None:
    with pytest.raises(ValueError, match=r"already has reward groups"):
        RewardGroupsTask(FinalRewardTask(RewardGroupsTask(_leaf(), GROUPS)), {"all": {"step": 1.0}})
