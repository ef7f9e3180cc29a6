"""RewardGroupsTask: named groups of a task's reward terms, accumulated in order, rounded to the groups' dtype.

Expected values are written here from the definition: numpy's in-place ``vec += term`` on a float32 vector (what
MO-Gymnasium computes) and plain float64 sums of the terms the task reports, never from the groups under test.
"""

from __future__ import annotations

import io

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


def test_each_group_s_coefficients_are_a_buffer_and_the_groups_report_them() -> None:
    task = RewardGroupsTask(_leaf(), GROUPS)
    assert {"weights_speed", "weights_energy"} <= set(dict(task.named_buffers()))
    assert task.groups == GROUPS
    task.weights_energy.fill_(2.0)
    state, action = _draws(8)
    task = task.double()
    out = task.transition(state, action, state, task.reset(state))
    assert torch.equal(out.groups["energy"], 2.0 * out.terms["ctrl"] + 2.0 * out.terms["alive"])
    assert torch.equal(out.groups["speed"], 0.8 * out.terms["forward"] + out.terms["alive"])


def test_a_checkpoint_of_other_groups_or_non_finite_weights_is_refused_and_changes_nothing() -> None:
    task = RewardGroupsTask(_leaf(), GROUPS)
    saved = task.state_dict()
    reordered = RewardGroupsTask(_leaf(), {"speed": {"alive": 1.0, "forward": 0.8}, "energy": GROUPS["energy"]})
    with pytest.raises(ValueError, match=r"checkpoint holds other reward groups"):
        reordered.load_state_dict(saved)
    assert reordered.groups == {"speed": {"alive": 1.0, "forward": 0.8}, "energy": GROUPS["energy"]}
    bad = {key: value.clone() if hasattr(value, "clone") else value for key, value in saved.items()}
    bad["weights_energy"][0] = float("nan")
    with pytest.raises(ValueError, match=r"reward group 'energy'.*must be finite"):
        task.load_state_dict(bad)
    assert task.groups == GROUPS
    float32 = RewardGroupsTask(_leaf(), GROUPS, dtype=torch.float32)
    with pytest.raises(ValueError, match=r"other reward groups"):
        float32.load_state_dict(saved)
    twin = RewardGroupsTask(_leaf(), GROUPS)
    twin.weights_speed.fill_(3.0)
    twin.load_state_dict(saved)
    assert twin.groups == GROUPS


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
        ({"groups": {"x": {"step": 1.0}}, "terms": {"z": ConstantReward(1.0)}}, ValueError, r"\['z'\] are read by no"),
    ],
)
def test_bad_groups_are_refused_with_the_argument_named(kwargs: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        RewardGroupsTask(_leaf(), **kwargs)


def test_a_tree_holds_one_set_of_groups() -> None:
    with pytest.raises(ValueError, match=r"already has reward groups"):
        RewardGroupsTask(FinalRewardTask(RewardGroupsTask(_leaf(), GROUPS)), {"all": {"step": 1.0}})


def _saved(task: RewardGroupsTask) -> dict:
    """What ``torch.save`` wrote of the task's state, read back as a checkpoint is (``weights_only``)."""
    buffer = io.BytesIO()
    torch.save(task.state_dict(), buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def test_a_checkpoint_loads_the_coefficients_of_the_same_groups() -> None:
    saved = RewardGroupsTask(_leaf(), GROUPS)
    saved.weights_speed.copy_(torch.tensor([1.0, 2.0], dtype=torch.float64))
    saved.weights_energy.copy_(torch.tensor([3.0, 4.0], dtype=torch.float64))
    task = RewardGroupsTask(_leaf(), GROUPS)
    task.load_state_dict(_saved(saved))
    assert task.groups == {"speed": {"forward": 1.0, "alive": 2.0}, "energy": {"ctrl": 3.0, "alive": 4.0}}


@pytest.mark.parametrize(
    ("groups", "match"),
    [
        # the same sources, the groups in another order: the coefficients would be cross-loaded by position
        ({"energy": GROUPS["energy"], "speed": GROUPS["speed"]}, r"saved \{'speed': \['forward', 'alive'\], 'energy'"),
        ({"speed": {"alive": 1.0, "forward": 0.8}, "energy": GROUPS["energy"]}, r"here \{'speed': \['alive', 'forw"),
        ({"speed": {"forward": 0.8}, "energy": GROUPS["energy"]}, r"here \{'speed': \['forward'\], 'energy'"),
    ],
    ids=["groups_reordered", "sources_reordered", "fewer_coefficients"],
)
def test_a_checkpoint_of_other_groups_is_refused_and_changes_nothing(groups: dict, match: str) -> None:
    saved = _saved(RewardGroupsTask(_leaf(), GROUPS))
    task = RewardGroupsTask(_leaf(), groups)
    before = task.groups
    with pytest.raises(ValueError, match=r"RewardGroupsTask.load_state_dict: the checkpoint holds other reward groups"):
        task.load_state_dict(saved)
    with pytest.raises(ValueError, match=match):
        task.load_state_dict(saved)
    assert task.groups == before


def test_loaded_coefficients_pass_the_constructors_check() -> None:
    saved = _saved(RewardGroupsTask(_leaf(), GROUPS))
    saved["weights_energy"] = torch.tensor([float("inf"), 1.0], dtype=torch.float64)
    task = RewardGroupsTask(_leaf(), GROUPS)
    with pytest.raises(ValueError, match=r"load_state_dict can write \[inf, 1.0\] into the reward group 'energy'"):
        task.load_state_dict(saved)
    assert task.groups == GROUPS
