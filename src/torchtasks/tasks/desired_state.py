"""Tasks that drive the state to a desired state (optionally with angles wrapped)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase

from torchtasks._checks import as_constant, cast_like, check_input
from torchtasks._memory import read
from torchtasks.rewards.base import RewardFunction
from torchtasks.spaces import EnvSpec
from torchtasks.tasks.goals import GOAL_ENTRY, GoalSlot
from torchtasks.tasks.leaf import RewardTask
from torchtasks.tasks.success import check_success_fn, never_succeeded, proximity_success_fn

__all__ = ["DesiredStateTask", "RadiallySymmetricDesiredStateTask", "SuccessFn", "check_flag"]

SuccessFn = Callable[[torch.Tensor], torch.Tensor]


def check_flag(value: object, reference: torch.Tensor, name: str) -> torch.Tensor:
    """Check that a user function returned ``bool[*B]`` for a ``[*B, n]`` input."""
    batch = reference.shape[:-1]
    if not isinstance(value, torch.Tensor) or value.dtype != torch.bool or value.shape != batch:
        got = f"{value.dtype} {tuple(value.shape)}" if isinstance(value, torch.Tensor) else type(value).__name__
        raise ValueError(f"{name} must return a bool tensor of shape {tuple(batch)}, got {got}")
    return value


class DesiredStateTask(RewardTask):
    """Reach a desired state: the reward sees the errors ``(state_des - s, -a)``.

    The episode is a success when ``success(state_des - s)`` holds and a failure when the state
    leaves ``spec.state_space``. The desired state is a per-environment memory entry
    (``"state_des"``), set at reset from the constructor's value or from the ``state_des``
    override (goal sampling: ``task.reset(s0, state_des=goals)`` with ``goals`` of shape
    ``[*B, n]``).

    Args:
        spec: state and action boxes.
        state_des: the desired state, ``n`` numbers.
        reward: reward function of the errors.
        success: ``error [*B, n] -> bool[*B]``, called with the error alone (a function with other
            required arguments, such as :func:`~torchtasks.tasks.proximity_succeeded` unbound, is a
            ``TypeError`` at construction); ``None`` never succeeds.
        threshold: shortcut for ``success=functools.partial(proximity_succeeded, threshold=threshold)``:
            a success when the L2 norm of the error is below it. Positive and finite; not with ``success``.

    Pyrado name: ``DesStateTask``.

    Example:
        >>> import functools, torch
        >>> from torchtasks.rewards import ExpQuadraticErrorReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, proximity_succeeded
        >>> task = DesiredStateTask(EnvSpec(2, 1), [1.0, 0.0], ExpQuadraticErrorReward([1.0, 1.0], [0.1]),
        ...                         success=functools.partial(proximity_succeeded, threshold=0.1))
        >>> memory = task.reset(torch.zeros(3, 2), state_des=torch.tensor([[1.0, 0.0], [0.0, 0.0], [2.0, 2.0]]))
        >>> task.has_succeeded(torch.zeros(3, 2), memory)
        tensor([False,  True, False])
        >>> reward = ExpQuadraticErrorReward([1.0, 1.0], [0.1])
        >>> same = DesiredStateTask(EnvSpec(2, 1), [1.0, 0.0], reward, threshold=0.1)
        >>> same.has_succeeded(torch.zeros(3, 2), memory)
        tensor([False,  True, False])
    """

    reset_keys = ("state_des",)
    kept_at_start = (GOAL_ENTRY,)
    reward_sees_state = False

    def __init__(
        self,
        spec: EnvSpec,
        state_des: Sequence[float] | torch.Tensor,
        reward: RewardFunction,
        success: SuccessFn | None = None,
        *,
        threshold: float | None = None,
    ) -> None:
        super().__init__(spec, reward)
        state_des = as_constant(state_des, "state_des", ndim=(0, 1)).reshape(-1)
        if state_des.numel() != spec.state_size:
            raise ValueError(f"state_des must have {spec.state_size} entries (the state size), got {state_des.numel()}")
        self.register_buffer("state_des", state_des)
        success = check_success_fn(success, "success")
        if threshold is not None:
            if success is not None:
                raise ValueError(
                    f"give success= or threshold= (which means success=proximity_succeeded with that threshold), "
                    f"not both; got success={success!r} and threshold={threshold!r}"
                )
            success = proximity_success_fn(threshold, "threshold")
        self.success = never_succeeded if success is None else success

    def _own_memory(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> dict[str, Any]:
        batch = init_state.shape[:-1]
        goal = overrides.get("state_des")
        if goal is None:
            goal = self.state_des.to(device=init_state.device, dtype=init_state.dtype)
        else:
            if isinstance(goal, torch.Tensor):  # as goal=...: a float tensor, cast to the state's dtype
                check_input(goal, "state_des override")
            else:
                goal = as_constant(goal, "state_des override")
            goal = goal.to(device=init_state.device, dtype=init_state.dtype)
            if goal.shape not in (torch.Size([self.state_size]), (*batch, self.state_size)):
                raise ValueError(
                    f"state_des override must have shape [{self.state_size}] or "
                    f"{[*batch, self.state_size]}, got {list(goal.shape)}"
                )
        return {"state_des": goal.expand(*batch, self.state_size).clone()}

    def _goal_slots(self, prefix: tuple[str, ...], indices: tuple[int, ...] | None) -> list[GoalSlot]:
        path = (*prefix, GOAL_ENTRY)
        return [GoalSlot(".".join(path), path, self.state_size, indices)]

    def state_error(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        """Return ``state_des - state`` (``[*B, n]``)."""
        return read(memory, "state_des") - state

    def _reward_inputs(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.state_error(state, memory), -action

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return check_flag(self.success(self.state_error(state, memory)), state, "success")

    def _has_success_condition(self) -> bool:
        return self.success is not never_succeeded


def _indices(spec: EnvSpec, indices: Iterable[int | str] | int | str) -> list[int]:
    return spec.state_space.indices(indices)


class RadiallySymmetricDesiredStateTask(DesiredStateTask):
    """Reach a desired state where some entries are angles: their errors are wrapped.

    The error of each entry listed in ``indices`` is wrapped into ``[-m/2, m/2)`` for its
    modulation ``m`` (2π for an angle), other entries are left untouched; the reward and the
    success function both see the wrapped error. (Pyrado folded every entry, with a sign flip,
    and judged success on the unwrapped error.)

    Args:
        spec: state and action boxes.
        state_des: the desired state.
        reward: reward function of the errors.
        indices: entries (ints or labels) that are angles.
        modulation: period of the wrapped entries, one number or one per index.
        success: ``error -> bool[*B]``, called with the error alone; ``None`` never succeeds.
        threshold: shortcut for ``success=functools.partial(proximity_succeeded, threshold=threshold)``
            on the wrapped error (as :class:`DesiredStateTask`); not with ``success``.

    Pyrado name: ``RadiallySymmDesStateTask``.

    Example:
        >>> import math, torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import RadiallySymmetricDesiredStateTask
        >>> reward = QuadraticErrorReward([1.0, 1.0], [0.0])
        >>> task = RadiallySymmetricDesiredStateTask(EnvSpec(2, 1), [0.0, math.pi], reward, indices=[1])
        >>> memory = task.reset(torch.zeros(1, 2))
        >>> task.state_error(torch.tensor([[0.0, -math.pi + 0.1]]), memory)
        tensor([[ 0.0000, -0.1000]])
        >>> near = RadiallySymmetricDesiredStateTask(EnvSpec(2, 1), [0.0, math.pi], reward, indices=[1], threshold=0.2)
        >>> near.has_succeeded(torch.tensor([[0.0, -math.pi + 0.1]]), memory)
        tensor([True])
    """

    def __init__(
        self,
        spec: EnvSpec,
        state_des: Sequence[float] | torch.Tensor,
        reward: RewardFunction,
        indices: Iterable[int | str] | int | str,
        modulation: float | Sequence[float] = 2 * math.pi,
        success: SuccessFn | None = None,
        *,
        threshold: float | None = None,
    ) -> None:
        super().__init__(spec, state_des, reward, success, threshold=threshold)
        positions = _indices(spec, indices)
        if not positions:
            raise ValueError("indices must name at least one entry")
        modulation_t = as_constant(modulation, "modulation", ndim=(0, 1)).reshape(-1)
        if modulation_t.numel() == 1:
            modulation_t = modulation_t.expand(len(positions))
        if modulation_t.numel() != len(positions):
            raise ValueError(
                f"modulation must be one number or one per index ({len(positions)}), got {modulation_t.numel()}"
            )
        if not (torch.isfinite(modulation_t).all() and (modulation_t > 0).all()):
            raise ValueError(f"modulation must be finite and positive, got {modulation_t.tolist()}")
        full = torch.ones(spec.state_size, dtype=torch.float64)
        mask = torch.zeros(spec.state_size, dtype=torch.bool)
        full[positions] = modulation_t
        mask[positions] = True
        self.indices = positions
        self.register_buffer("modulation", full)
        self.register_buffer("wrap_mask", mask)

    def state_error(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        error = read(memory, "state_des") - state
        period = cast_like(self.modulation, error)
        wrapped = error - period * torch.floor((error + 0.5 * period) / period)
        mask = self.wrap_mask if self.wrap_mask.device == error.device else self.wrap_mask.to(error.device)
        return torch.where(mask, wrapped, error)
