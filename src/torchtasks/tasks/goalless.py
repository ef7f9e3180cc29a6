"""Tasks without a goal state: desired space, goalless, optimisation and condition tasks."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase

from torchtasks._checks import cast_like
from torchtasks.rewards.base import RewardFunction
from torchtasks.rewards.constant import ConstantReward
from torchtasks.rewards.state_function import StateFunctionReward
from torchtasks.spaces import Box, EnvSpec, rows_outside
from torchtasks.tasks.desired_state import check_flag
from torchtasks.tasks.leaf import RewardTask
from torchtasks.tasks.protocol import Task, outcome_names

__all__ = ["ConditionTask", "DesiredSpaceTask", "GoallessTask", "OptimizationTask"]


class DesiredSpaceTask(RewardTask):
    """Reach a region of the state space: success when the state lies in ``space_des`` (inclusive).

    The reward sees the raw state and action.

    Args:
        spec: state and action boxes.
        space_des: the desired box, same size as the state.
        reward: reward function of ``(state, action)``; any reward function is accepted.
            Default: ``ConstantReward(0.0)``.

    Pyrado name: ``DesSpaceTask`` (whose default reward raised and which accepted only constant rewards).

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import DesiredSpaceTask
        >>> task = DesiredSpaceTask(EnvSpec(Box(-2.0, 2.0).select([0]), 1), Box([0.5], [1.0]))
        >>> memory = task.reset(torch.zeros(2, 1))
        >>> task.has_succeeded(torch.tensor([[0.7], [0.2]]), memory)
        tensor([ True, False])
    """

    def __init__(self, spec: EnvSpec, space_des: Box, reward: RewardFunction | None = None) -> None:
        super().__init__(spec, ConstantReward(0.0) if reward is None else reward)
        if not isinstance(space_des, Box):
            raise TypeError(f"space_des must be a torchtasks.spaces.Box, got {type(space_des).__name__}")
        if space_des.size != spec.state_size:
            raise ValueError(f"space_des must have {spec.state_size} entries (the state size), got {space_des.size}")
        self.space_des = space_des
        self.register_buffer("space_low", space_des.low.clone())
        self.register_buffer("space_high", space_des.high.clone())

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return ~rows_outside(state, cast_like(self.space_low, state), cast_like(self.space_high, state))


class GoallessTask(RewardTask):
    """A task without a goal: the reward sees the raw state and action; it never succeeds.

    It fails when the state leaves ``spec.state_space`` or, for rewards that can fail (e.g.
    :class:`~torchtasks.rewards.AntForwardReward` with ``terminate_when_unhealthy``), when the
    reward says so. Used by the locomotion tasks.

    Args:
        spec: state and action boxes.
        reward: reward function of ``(state, action)``; may be stateful.

    Pyrado name: ``GoallessTask``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ForwardVelocityReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import GoallessTask
        >>> task = GoallessTask(EnvSpec(3, 2), ForwardVelocityReward(dt=0.1, index=0, ctrl_cost_weight=0.0))
        >>> memory = task.reset(torch.zeros(1, 3))
        >>> task.step_reward(torch.tensor([[0.5, 0.0, 0.0]]), torch.zeros(1, 2), memory)[0]
        tensor([5.])
    """


class OptimizationTask(RewardTask):
    """Minimise a function of the state: the step reward is a :class:`StateFunctionReward` of the state.

    Never succeeds; fails when the state leaves ``spec.state_space``.

    Args:
        spec: state and action boxes.
        reward: a :class:`~torchtasks.rewards.StateFunctionReward`.

    Pyrado name: ``OptimProxyTask``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import StateFunctionReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import OptimizationTask
        >>> task = OptimizationTask(EnvSpec(2, 1), StateFunctionReward(lambda s: (s**2).sum(-1)))
        >>> task.step_reward(torch.ones(1, 2), torch.zeros(1, 1), task.reset(torch.ones(1, 2)))[0]
        tensor([-2.])
    """

    def __init__(self, spec: EnvSpec, reward: StateFunctionReward) -> None:
        if not isinstance(reward, StateFunctionReward):
            raise TypeError(f"reward must be a StateFunctionReward, got {type(reward).__name__}")
        super().__init__(spec, reward)

    def _reward_inputs(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDictBase
    ) -> tuple[torch.Tensor, None]:
        return state, None


class ConditionTask(Task):
    """A task that ends when a condition of the state holds; its step reward is 0.

    With ``is_success=True`` the condition is the success (and leaving the state box is a
    failure); with ``is_success=False`` the condition is the failure and the task never succeeds
    (leaving the state box is then not a failure).

    Args:
        spec: state and action boxes.
        condition: ``state [*B, n] -> bool[*B]``.
        is_success: whether the condition means success (True) or failure (False).

    Pyrado name: ``ConditionOnlyTask``.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import ConditionTask
        >>> task = ConditionTask(EnvSpec(1, 1), lambda s: s[..., 0] > 1.0, is_success=False)
        >>> task.has_failed(torch.tensor([[2.0], [0.0]]), task.reset(torch.zeros(2, 1)))
        tensor([ True, False])
    """

    def __init__(self, spec: EnvSpec, condition: Callable[[torch.Tensor], torch.Tensor], is_success: bool) -> None:
        super().__init__(spec)
        if not callable(condition):
            raise TypeError(f"condition must be callable, got {type(condition).__name__}")
        if not isinstance(is_success, bool):
            raise TypeError(f"is_success must be a bool, got {is_success!r}")
        self.condition = condition
        self.is_success = is_success

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        return state.new_zeros(state.shape[:-1]), memory

    @property
    def termination_names(self) -> dict[str, str]:
        return outcome_names(can_succeed=self.is_success, can_fail=True)

    def _condition(self, state: torch.Tensor) -> torch.Tensor:
        return check_flag(self.condition(state), state, "condition")

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        if self.is_success:
            return self._condition(state)
        return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        if self.is_success:
            return super()._has_failed(state, memory)
        return self._condition(state)
