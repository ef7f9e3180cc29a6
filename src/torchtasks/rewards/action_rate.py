"""The rate of change of the actions: :class:`ActionRateReward` (the previous action in memory)."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from torchtasks._checks import check_input, check_positive_int, check_same_batch
from torchtasks._memory import make_memory, read
from torchtasks.rewards.base import RewardFunction, squared_sum

__all__ = ["ActionRateReward"]


class ActionRateReward(RewardFunction):
    """``Σ_j (a_j - a_prev_j)²``: how much the action changed since the last step; a penalty's kernel.

    IsaacLab's ``action_rate_l2``. Stateful: the previous action lives in memory (``"last_action"``), zeros at
    :meth:`reset` (an env's last action after a reset, as IsaacLab's action manager and the batched env's
    ``last_action`` reading have it), so the first step after a reset pays ``Σ a²``. The value is non-negative:
    give it a negative weight in a :class:`~torchtasks.rewards.CompoundReward`. Differentiable in the action;
    the memory keeps the state's dtype (the action is cast to it).

    Args:
        action_size: the number of action entries ``m`` (the memory is ``[*B, m]``).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ActionRateReward
        >>> reward = ActionRateReward(action_size=2)
        >>> memory = reward.reset(torch.zeros(1, 5))
        >>> value, memory = reward.step(torch.zeros(1, 5), torch.tensor([[1.0, 2.0]]), memory)
        >>> value, memory["last_action"]
        (tensor([5.]), tensor([[1., 2.]]))
        >>> reward.step(torch.zeros(1, 5), torch.tensor([[1.0, 1.0]]), memory)[0]
        tensor([1.])
    """

    stateful = True

    def __init__(self, action_size: int) -> None:
        super().__init__()
        self.action_size = check_positive_int(action_size, "action_size")

    def reset(self, init_state: torch.Tensor) -> TensorDict:
        check_input(init_state, "init_state")
        zeros = init_state.new_zeros((*init_state.shape[:-1], self.action_size))
        return TensorDict({"last_action": zeros}, batch_size=init_state.shape[:-1])

    def step(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> tuple[torch.Tensor, TensorDict]:
        check_input(state, "state")
        check_input(action, "action", self.action_size)
        check_same_batch(state, action, "state", "action")
        if not isinstance(memory, TensorDict) or "last_action" not in memory.keys():
            raise TypeError("memory must be the TensorDict returned by ActionRateReward.reset(init_state)")
        if memory.batch_size != state.shape[:-1]:
            raise ValueError(
                f"memory has batch size {tuple(memory.batch_size)} but the state has batch shape "
                f"{tuple(state.shape[:-1])}"
            )
        return self._step(state, action, memory)

    def _step(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> tuple[torch.Tensor, TensorDict]:
        last = read(memory, "last_action")
        current = action.to(last.dtype)
        return squared_sum(current - last), make_memory({"last_action": current}, memory.batch_size)

    def forward(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> tuple[torch.Tensor, TensorDict]:
        return self.step(state, action, memory)

    def extra_repr(self) -> str:
        return f"action_size={self.action_size}"
