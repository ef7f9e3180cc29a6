"""Factories of common task trees (Pyrado's ``predefined`` module).

Each factory selects state entries by label, builds a task on the sub-spec and wraps it in a
:class:`~torchtasks.tasks.MaskedTask`, except :func:`check_all_boundaries_task`, which watches
the whole state.
"""

from __future__ import annotations

import functools
import math
import numbers
from collections.abc import Sequence

import torch

from torchtasks._checks import as_constant, check_finite_scalar, check_weight
from torchtasks.rewards import (
    AbsoluteErrorReward,
    ConstantReward,
    CosineReward,
    ExpQuadraticErrorReward,
    QuadraticErrorReward,
    RewardFunction,
)
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import (
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    FlippingTask,
    MaskedTask,
    Task,
    never_succeeded,
    proximity_succeeded,
)

__all__ = [
    "check_all_boundaries_task",
    "collision_task",
    "flipping_task",
    "force_min_task",
    "goal_distance_task",
    "goal_distance_velocity_task",
    "home_position_task",
    "lifting_task",
    "task_space_discrepancy_task",
]


def _masked_desired_state(
    spec: EnvSpec,
    labels: Sequence[str | int],
    state_des: object,
    reward: RewardFunction,
    success: object = None,
) -> MaskedTask:
    sub_spec = spec.select_state(labels)
    inner = DesiredStateTask(sub_spec, state_des, reward, success)  # type: ignore[arg-type]
    return MaskedTask(spec, inner, labels)


def _labels(labels: Sequence[str | int] | str, name: str) -> list[str | int]:
    if isinstance(labels, (str, numbers.Integral)):  # one label or position (NumPy integers too)
        return [labels]
    labels = list(labels)
    if not labels:
        raise ValueError(f"{name} must name at least one state entry")
    return labels


def _proximity(threshold: float) -> functools.partial:
    threshold = check_finite_scalar(threshold, "success_threshold")
    if threshold <= 0:
        raise ValueError(f"success_threshold must be positive, got {threshold}")
    return functools.partial(proximity_succeeded, threshold=threshold)


def check_all_boundaries_task(spec: EnvSpec, penalty: float) -> Task:
    """Pay ``-|penalty|`` once when any state bound is violated; 0 per step; never succeeds.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> task = check_all_boundaries_task(EnvSpec(Box([-1.0, -1.0], [1.0, 1.0]), 1), penalty=5.0)
        >>> state = torch.tensor([[0.0, 2.0]])
        >>> memory = task.reset(state)
        >>> task.final_reward(state, memory, 0, task.is_done(state, memory))[0]
        tensor([-5.])
    """
    inner = DesiredStateTask(spec, torch.zeros(spec.state_size), ConstantReward(0.0), never_succeeded)
    return FinalRewardTask(inner, FinalRewardMode(always_negative=True), factor=penalty)


def task_space_discrepancy_task(spec: EnvSpec, reward: RewardFunction) -> Task:
    """Penalise the task-space discrepancy: a reward on every state entry whose label contains ``DiscrepTS``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import AbsoluteErrorReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> spec = EnvSpec(Box.unbounded(3, labels=["x", "DiscrepTS_y", "DiscrepTS_z"]), 1)
        >>> task = task_space_discrepancy_task(spec, AbsoluteErrorReward([1.0, 1.0]))
        >>> task.step_reward(torch.tensor([[9.0, 0.5, -0.5]]), torch.zeros(1, 1), task.reset(torch.zeros(1, 3)))[0]
        tensor([-1.])
    """
    labels = [label for label in (spec.state_space.labels or ()) if "DiscrepTS" in label]
    if not labels:
        raise ValueError("the state space has no entry whose label contains 'DiscrepTS'")
    return _masked_desired_state(spec, labels, torch.zeros(len(labels)), reward, never_succeeded)


def collision_task(spec: EnvSpec, factor: float) -> Task:
    """Penalise collisions: ``-factor·|CollCost|`` per step from the state entry labelled ``CollCost``.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> task = collision_task(EnvSpec(Box.unbounded(2, labels=["x", "CollCost"]), 1), factor=2.0)
        >>> task.step_reward(torch.tensor([[5.0, 0.25]]), torch.zeros(1, 1), task.reset(torch.zeros(1, 2)))[0]
        tensor([-0.5000])
    """
    factor = check_weight(factor, "factor")
    reward = AbsoluteErrorReward(q=[factor], r=torch.zeros(spec.action_size))
    return _masked_desired_state(spec, ["CollCost"], torch.zeros(1), reward, never_succeeded)


def force_min_task(spec: EnvSpec, state_labels: Sequence[str | int], Q: object) -> Task:
    """Minimise forces: ``-fᵀQf`` on the labelled state entries (no action cost); never succeeds.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> task = force_min_task(EnvSpec(Box.unbounded(2, labels=["f0", "f1"]), 1), ["f1"], Q=[[2.0]])
        >>> task.step_reward(torch.tensor([[5.0, 3.0]]), torch.zeros(1, 1), task.reset(torch.zeros(1, 2)))[0]
        tensor([-18.])
    """
    labels = _labels(state_labels, "state_labels")
    reward = QuadraticErrorReward(Q, torch.zeros(spec.action_size, spec.action_size))
    return _masked_desired_state(spec, labels, torch.zeros(len(labels)), reward, never_succeeded)


def lifting_task(
    spec: EnvSpec, state_labels: Sequence[str | int], des_height: float, success_threshold: float = 0.01
) -> Task:
    """Lift to a height: exp-quadratic reward (``Q = 600``, ``R = 0.1·I``), success within ``success_threshold``.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> task = lifting_task(EnvSpec(Box.unbounded(2, labels=["x", "z"]), 1), ["z"], des_height=0.5)
        >>> memory = task.reset(torch.zeros(1, 2))
        >>> task.has_succeeded(torch.tensor([[0.0, 0.505]]), memory)
        tensor([True])
    """
    labels = _labels(state_labels, "state_labels")
    height = as_constant(des_height, "des_height").reshape(-1)
    reward = ExpQuadraticErrorReward(Q=600.0 * torch.ones(len(labels)), R=0.1 * torch.ones(spec.action_size))
    return _masked_desired_state(spec, labels, height, reward, _proximity(success_threshold))


def flipping_task(
    spec: EnvSpec, state_labels: Sequence[str | int], angle_delta: float = math.pi / 2, endless: bool = True
) -> Task:
    """Flip the labelled angle by ``±angle_delta`` repeatedly, rewarded by the cosine of the error.

    Example:
        >>> import math, torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> task = flipping_task(EnvSpec(Box.unbounded(2, labels=["x", "phi"]), 1), ["phi"])
        >>> task.step_reward(torch.tensor([[0.0, math.pi / 2]]), torch.zeros(1, 1), task.reset(torch.zeros(1, 2)))[0]
        tensor([1.])
    """
    labels = _labels(state_labels, "state_labels")
    inner = FlippingTask(spec.select_state(labels), angle_delta, CosineReward(0), endless=endless)
    return MaskedTask(spec, inner, labels)


def home_position_task(spec: EnvSpec, state_labels: Sequence[str | int], state_des: object) -> Task:
    """Stay at a home position: exp-quadratic reward (``Q = 10·I``, ``R = 0.1·I``); never succeeds.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> task = home_position_task(EnvSpec(Box.unbounded(2, labels=["q0", "q1"]), 1), ["q0", "q1"], [0.0, 0.0])
        >>> task.step_reward(torch.zeros(1, 2), torch.zeros(1, 1), task.reset(torch.zeros(1, 2)))[0]
        tensor([1.])
    """
    labels = _labels(state_labels, "state_labels")
    goal = as_constant(state_des, "state_des").reshape(-1)
    if goal.numel() != len(labels):
        raise ValueError(f"state_des must have {len(labels)} entries (one per label), got {goal.numel()}")
    reward = ExpQuadraticErrorReward(Q=10.0 * torch.ones(len(labels)), R=0.1 * torch.ones(spec.action_size))
    return _masked_desired_state(spec, labels, goal, reward, never_succeeded)


def goal_distance_task(
    spec: EnvSpec, ds_label: int | str, reward: RewardFunction, success_threshold: float = 0.01
) -> Task:
    """Drive the distance to goal ``ds_label`` (state entry ``GD_DS{ds_label}``) to zero.

    The goal is one zero for the one selected entry (Pyrado used a 2-entry goal that broadcast).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> spec = EnvSpec(Box.unbounded(2, labels=["GD_DS0", "GD_DS0d"]), 1)
        >>> task = goal_distance_task(spec, 0, QuadraticErrorReward([1.0], None))
        >>> task.step_reward(torch.tensor([[0.5, 3.0]]), torch.zeros(1, 1), task.reset(torch.zeros(1, 2)))[0]
        tensor([-0.2500])
    """
    return _masked_desired_state(spec, [f"GD_DS{ds_label}"], torch.zeros(1), reward, _proximity(success_threshold))


def goal_distance_velocity_task(
    spec: EnvSpec, ds_label: int | str, reward: RewardFunction, success_threshold: float = 0.01
) -> Task:
    """Drive the distance to goal ``ds_label`` and its rate (``GD_DS{l}``, ``GD_DS{l}d``) to zero.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> spec = EnvSpec(Box.unbounded(2, labels=["GD_DS0", "GD_DS0d"]), 1)
        >>> task = goal_distance_velocity_task(spec, 0, QuadraticErrorReward([1.0, 1.0], None))
        >>> task.has_succeeded(torch.tensor([[0.001, 0.001]]), task.reset(torch.zeros(1, 2)))
        tensor([True])
    """
    labels = [f"GD_DS{ds_label}", f"GD_DS{ds_label}d"]
    return _masked_desired_state(spec, labels, torch.zeros(2), reward, _proximity(success_threshold))
