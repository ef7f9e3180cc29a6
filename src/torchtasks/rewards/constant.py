"""A reward that is the same constant in every step."""

from __future__ import annotations

import torch

from torchtasks._checks import check_finite_scalar
from torchtasks.rewards.base import RewardFunction

__all__ = ["ConstantReward"]


class ConstantReward(RewardFunction):
    """The same value in every step, e.g. ``-1`` per step to reward finishing quickly.

    Args:
        value: the finite reward paid per step.

    Pyrado names: ``ZeroPerStepRewFcn`` (0), ``PlusOnePerStepRewFcn`` (1), ``MinusOnePerStepRewFcn`` (-1).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ConstantReward
        >>> ConstantReward(-1.0)(torch.zeros(2, 3), None)
        tensor([-1., -1.])
    """

    uses_action = False

    def __init__(self, value: float = 0.0) -> None:
        super().__init__()
        self.value = check_finite_scalar(value, "value")

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self._check_inputs(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return error_state.new_full(error_state.shape[:-1], self.value)

    def extra_repr(self) -> str:
        return f"value={self.value}"
