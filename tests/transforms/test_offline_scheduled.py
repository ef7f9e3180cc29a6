"""Offline recomputation puts one value per frame in a task buffer's place: every kernel must take it.

Every float buffer of every task tree takes one value per row (what recomputation of stored data puts in
the buffers' places), checked against an independent loop that evaluates the batch once per row with that
row's value in the buffer's own shape.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from torch import nn

from task_trees import all_task_cases, example_trees, predefined_cases, random_transitions
from torchtasks.envs import swing_up_task
from torchtasks.envs.locomotion import safety_velocity_task
from torchtasks.rewards import (
    AbsoluteErrorReward,
    CompoundReward,
    ExpQuadraticErrorReward,
    QuadraticErrorReward,
    ScaledExpQuadraticErrorReward,
    ToleranceReward,
)
from torchtasks.rewards.terms import AboveThresholdIndicator, ContactCostReward, HealthyReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, Task, proximity_succeeded

# ------------------------------------------------------------------------------------------------------------------
# Kernels: one value per row of every float buffer
# ------------------------------------------------------------------------------------------------------------------
ROWS = 7


def _kernel_zoo() -> dict[str, Callable[[], Task]]:
    """Rewards whose constants meet the state in a product, a clamp or a matrix (not only elementwise)."""
    spec = EnvSpec(Box([-2.0] * 3, [2.0] * 3), Box([-1.0] * 2, [1.0] * 2))
    rewards = {
        "matrix": QuadraticErrorReward(torch.eye(3) * 2 + 0.25, torch.eye(2)),
        "exp": ExpQuadraticErrorReward([1.0, 2.0, 3.0], [1.0, 0.5]),
        "absolute": AbsoluteErrorReward([1.0, 2.0, 3.0], [1.0, 1.0]),
        "scaled": ScaledExpQuadraticErrorReward([1.0] * 3, [1.0] * 2, spec.state_space, spec.action_space),
        "contacts": ContactCostReward(0.5, start=1, force_range=(-1.0, 1.0), cost_range=(0.0, 1.0)),
        "one_contact": ContactCostReward(0.5, start=2, force_range=(-1.0, 1.0)),  # [*B, 1] forces
        "healthy": HealthyReward(1.0, index=[0, 1], low=-1.0, high=1.0),
        "above": AboveThresholdIndicator(0.3, index=[0, 1], norm=True),
        "tolerance": ToleranceReward(([-0.5, -0.2, 0.0], [0.5, 0.3, 0.4]), margin=[0.3, 0.1, 0.2]),
    }
    near = functools.partial(proximity_succeeded, threshold=1.0)
    return {
        "kernel_zoo": lambda: FinalRewardTask(
            DesiredStateTask(spec, [0.0] * 3, CompoundReward(rewards, weights={"matrix": 0.5}), near)
        ),
        "swing_up": swing_up_task,
        "safety_ant": lambda: safety_velocity_task("Ant-v5"),  # locomotion terms, contact clamps, a cost
    }


KERNEL_CASES = {**all_task_cases(), **predefined_cases(), **_kernel_zoo()}
KERNEL_CASES.update({f"tree_{name}": functools.partial(lambda n: example_trees()[n], name) for name in example_trees()})


def _owner(task: nn.Module, name: str) -> tuple[nn.Module, str]:
    *path, leaf = name.split(".")
    for part in path:
        task = task._modules[part]
    return task, leaf


def _evaluate(task: Task, values: dict[tuple[nn.Module, str], torch.Tensor], arguments: tuple) -> tuple:
    saved = {slot: slot[0]._buffers[slot[1]] for slot in values}
    try:
        for (module, leaf), value in values.items():
            module._buffers[leaf] = value
        return task._transition(*arguments, "next", True)
    finally:
        for (module, leaf), buffer in saved.items():
            module._buffers[leaf] = buffer


def _row(value: object, row: int) -> object:
    if isinstance(value, dict):
        return {name: _row(entry, row) for name, entry in value.items()}
    if isinstance(value, TensorDictBase):
        return value[row]
    return value.expand(ROWS)[row] if value.dim() == 0 else value[row]


@pytest.mark.parametrize("case", KERNEL_CASES)
def test_every_float_buffer_takes_one_value_per_row(case: str) -> None:
    task = KERNEL_CASES[case]().double()
    generator = torch.Generator().manual_seed(0)
    draws = random_transitions(task, generator, 1, ROWS)
    state, next_state = draws["states"][0], draws["states"][1]
    remaining = draws["remaining"][0] if task.uses_remaining_steps else task.no_remaining_steps.expand(ROWS)
    arguments = (
        state,
        draws["actions"][0],
        next_state,
        task._reset(state, {}),
        remaining,
        draws["terminated"][0],
        draws["truncated"][0],
    )
    # every float buffer gets a different value in each row: its value times a factor in [0.5, 1.5)
    per_row = {}
    for name, buffer in task.named_buffers():
        if buffer.is_floating_point():
            factor = 0.5 + torch.rand(ROWS, generator=generator, dtype=buffer.dtype)
            per_row[_owner(task, name)] = buffer * factor.reshape(ROWS, *[1] * buffer.dim())
    assert per_row
    task._transition(*arguments, "next", True)  # derives what a task caches (memory layouts) from its own buffers
    outputs = _evaluate(task, per_row, arguments)
    for row in range(ROWS):  # the batch evaluated with row `row`'s values in the buffers' own shapes
        expected = _evaluate(task, {slot: value[row] for slot, value in per_row.items()}, arguments)
        for i, (got, want) in enumerate(zip(outputs, expected, strict=True)):
            got, want = _row(got, row), _row(want, row)
            if isinstance(want, dict):
                assert got.keys() == want.keys(), i
                for name in want:
                    assert torch.equal(got[name], want[name]), (row, i, name)
            elif isinstance(want, TensorDictBase):
                assert (got == want).all(), (row, i)
            else:
                assert torch.equal(got, want), (row, i)
