"""Costs beside the reward (ConstrainedTask): one transition call, every task and wrapper, nothing else changed.

The expected costs are the cost functions applied by hand to the state the step reward sees; the
expected rewards, flags and memories are those of the same tree without the constraint.
"""

from __future__ import annotations

import functools
import math

import pytest
import torch
from tensordict import TensorDictBase

from task_trees import all_task_cases, full_spec, random_transitions
from torchtasks.rewards import ConstantReward, QuadraticErrorReward, StateFunctionReward
from torchtasks.rewards.terms import VelocityReward
from torchtasks.tasks import (
    ConstrainedTask,
    Constraint,
    DesiredStateTask,
    FinalRewardTask,
    GoallessTask,
    MaskedTask,
    ParallelTasks,
    PotentialShapingTask,
    SequentialTasks,
    proximity_succeeded,
)

CASES = all_task_cases()


def _squares(state: torch.Tensor) -> torch.Tensor:
    return state.square().sum(-1)


def _above_one(state: torch.Tensor) -> torch.Tensor:
    return (state[..., 0] > 1.0).to(state.dtype)


def _constrained(task, **limits):
    return ConstrainedTask(
        task,
        {
            "energy": Constraint(StateFunctionReward(_squares, negate=False), limit=limits.get("energy")),
            "speeding": StateFunctionReward(_above_one, negate=False),
        },
    )


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    return torch.equal(a, b) or (a.dtype.is_floating_point and torch.allclose(a, b, rtol=0, atol=0, equal_nan=True))


def _leaves(memory: TensorDictBase) -> dict:
    return {key: memory.get(key) for key in memory.keys(True, True)}


@pytest.mark.parametrize("reward_on", ["next", "state"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_a_constraint_adds_costs_and_changes_nothing_else(name: str, reward_on: str):
    plain, constrained = CASES[name](), _constrained(CASES[name](), energy=2.0)
    data = random_transitions(plain, torch.Generator().manual_seed(len(name)), steps=6, batch=5)
    memory_plain = plain.reset(data["states"][0])
    memory_constrained = constrained.reset(data["states"][0])
    for t in range(6):
        goal = data["goals"][t] if "goals" in data else None
        args = (data["states"][t], data["actions"][t], data["states"][t + 1])
        kwargs = dict(terminated=data["terminated"][t], truncated=data["truncated"][t], reward_on=reward_on, goal=goal)
        want = plain.transition(*args, memory_plain, data["remaining"][t], **kwargs)
        got = constrained.transition(*args, memory_constrained, data["remaining"][t], **kwargs)
        for field in ("reward", "step_reward", "final_reward", "success", "failure", "terminated", "done"):
            assert _same(getattr(got, field), getattr(want, field)), (name, t, field)
        assert set(got.terms) == set(want.terms) and all(_same(got.terms[k], want.terms[k]) for k in want.terms)
        assert _leaves(got.memory).keys() == _leaves(want.memory).keys()
        assert all(_same(v, _leaves(want.memory)[k]) for k, v in _leaves(got.memory).items())
        seen = args[2] if reward_on == "next" else args[0]
        assert want.costs == {}
        assert list(got.costs) == ["energy", "speeding"]
        assert torch.equal(got.costs["energy"], seen.square().sum(-1))
        assert torch.equal(got.costs["speeding"], (seen[..., 0] > 1.0).to(seen.dtype))
        memory_plain, memory_constrained = want.memory, got.memory
    assert constrained.cost_names == ("energy", "speeding")
    assert constrained.cost_limits == {"energy": 2.0, "speeding": None}


def _reach(spec):
    near = functools.partial(proximity_succeeded, threshold=0.3)
    return DesiredStateTask(spec, [0.5] * spec.state_size, QuadraticErrorReward([1.0] * spec.state_size), near)


WRAPPERS = {
    "final_reward": lambda task: FinalRewardTask(task, factor=3.0),
    "shaping": lambda task: PotentialShapingTask(task, lambda s: -s.square().sum(-1), 0.9),
    "parallel": lambda task: ParallelTasks([task, GoallessTask(task.spec, ConstantReward(1.0))]),
    "sequential": lambda task: SequentialTasks([task, GoallessTask(task.spec, ConstantReward(1.0))]),
    "nested": lambda task: FinalRewardTask(PotentialShapingTask(task, lambda s: s[..., 0], 0.5), factor=2.0),
}


@pytest.mark.parametrize("wrapper", sorted(WRAPPERS))
def test_costs_reach_the_root_through_every_wrapper_unshaped(wrapper: str):
    spec = full_spec()
    inner = _constrained(_reach(spec))
    task = WRAPPERS[wrapper](inner)
    plain = WRAPPERS[wrapper](_reach(spec))
    data = random_transitions(task, torch.Generator().manual_seed(3), steps=5, batch=4)
    memory, plain_memory = task.reset(data["states"][0]), plain.reset(data["states"][0])
    for t in range(5):
        args = (data["states"][t], data["actions"][t], data["states"][t + 1])
        out = task.transition(*args, memory, terminated=data["terminated"][t], truncated=data["truncated"][t])
        ref = plain.transition(*args, plain_memory, terminated=data["terminated"][t], truncated=data["truncated"][t])
        assert torch.equal(out.reward, ref.reward) and torch.equal(out.done, ref.done)
        assert torch.equal(out.costs["energy"], args[2].square().sum(-1))  # not shaped, not paid once
        memory, plain_memory = out.memory, ref.memory
    assert task.cost_names == ("energy", "speeding")


def test_a_masked_constraint_sees_the_selection_and_two_constraints_add_up():
    spec = full_spec()
    inner_spec = spec.select_state(["c", "a"])
    inner = ConstrainedTask(
        GoallessTask(inner_spec, ConstantReward(0.0)),
        {"first": StateFunctionReward(lambda s: s[..., 0], negate=False)},
    )
    task = ConstrainedTask(
        MaskedTask(spec, inner, ["c", "a"]), {"effort": Constraint(VelocityReward(1.0, index=1), limit=1.0)}
    )
    state = torch.tensor([[1.0, 2.0, 3.0, 4.0]])
    out = task.transition(state, torch.zeros(1, 2), state * 2, task.reset(state))
    assert out.costs["first"].tolist() == [6.0]  # "c" of next_state, the masked task's first entry
    assert out.costs["effort"].tolist() == [4.0]  # entry 1 ("b") of the full next_state
    assert task.cost_names == ("first", "effort") and task.cost_limits == {"first": None, "effort": 1.0}


def test_the_transition_with_costs_compiles_with_fullgraph():
    torch._dynamo.reset()
    task = _constrained(FinalRewardTask(_reach(full_spec()), factor=2.0))
    state = torch.rand(3, 4, dtype=torch.float64)
    memory = task.reset(state)
    remaining = torch.zeros((), dtype=torch.long)
    compiled = torch.compile(task._transition, fullgraph=True, backend="aot_eager")
    got = compiled(state, torch.zeros(3, 2, dtype=torch.float64), state * 1.5, memory, remaining)
    want = task._transition(state, torch.zeros(3, 2, dtype=torch.float64), state * 1.5, memory, remaining)
    assert set(got.costs) == set(want.costs) == {"energy", "speeding"}
    assert all(torch.equal(got.costs[k], want.costs[k]) for k in want.costs)


@pytest.mark.parametrize(
    ("build", "error", "match"),
    [
        (lambda t: ConstrainedTask(t, {}), TypeError, "non-empty mapping"),
        (lambda t: ConstrainedTask(t, {"not a name": ConstantReward(1.0)}), ValueError, "identifiers"),
        (lambda t: ConstrainedTask(t, {"c": 3.0}), TypeError, "Constraint or a RewardFunction"),
        (lambda t: ConstrainedTask(_constrained(t), {"energy": ConstantReward(1.0)}), ValueError, "unique"),
        (lambda t: ParallelTasks([_constrained(t), _constrained(t)]), ValueError, "'energy' names a cost of tasks"),
        (lambda t: SequentialTasks([t, _constrained(t), _constrained(t)]), ValueError, r"tasks\[1\] and of tasks\[2\]"),
        (lambda t: ConstrainedTask(t, {"q": QuadraticErrorReward([1.0, 1.0])}), ValueError, "4"),
        (lambda t: Constraint(ConstantReward(1.0), limit=-1.0), ValueError, "finite and >= 0"),
        (lambda t: Constraint(ConstantReward(1.0), limit=math.inf), ValueError, "finite and >= 0"),
        (lambda t: Constraint(ConstantReward(1.0), limit="25"), TypeError, "number or None"),
        (lambda t: Constraint(lambda s: s, limit=1.0), TypeError, "RewardFunction"),
        (lambda t: ConstrainedTask("task", {"c": ConstantReward(1.0)}), TypeError, "torchtasks Task"),
    ],
)
def test_bad_constraints_are_refused_at_construction(build, error, match):
    with pytest.raises(error, match=match):
        build(GoallessTask(full_spec(), ConstantReward(0.0)))


def test_a_stateful_cost_is_refused():
    from torchtasks.rewards import ForwardVelocityReward

    with pytest.raises(ValueError, match="stateless"):
        Constraint(ForwardVelocityReward(dt=0.1, index=0))
