"""Rewards on the cosine of one entry of the state error (angles)."""

from __future__ import annotations

import torch

from torchtasks._checks import check_input, check_int
from torchtasks.rewards.base import RewardFunction, check_ignored_action, index_problem

__all__ = ["CosineReward", "ShiftedCosineReward"]


class CosineReward(RewardFunction):
    """Cosine of one entry of the state error: ``cos(e_s[index])``, in ``[-1, 1]``.

    Maximal (1) at zero error and minimal (-1) at an error of ±π. The action is ignored.

    Args:
        index: position of the angle in the state error.

    Pyrado name: ``CosOfOneEleRewFcn`` (whose docstring had maximum and minimum swapped).

    Example:
        >>> import torch, math
        >>> from torchtasks.rewards import CosineReward
        >>> CosineReward(index=1)(torch.tensor([[5.0, 0.0], [5.0, math.pi]]), None)
        tensor([ 1., -1.])
    """

    uses_action = False

    def __init__(self, index: int) -> None:
        super().__init__()
        self.index = check_int(index, "index")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return index_problem(who, "index", self.index, state_size)

    def _check(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> None:
        check_input(error_state, "error_state")
        size = error_state.shape[-1]
        if not -size <= self.index < size:
            raise ValueError(f"index {self.index} is out of range for error_state of shape {tuple(error_state.shape)}")
        check_ignored_action(error_state, error_action)

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self._check(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return torch.cos(error_state[..., self.index])

    def extra_repr(self) -> str:
        return f"index={self.index}"


class ShiftedCosineReward(CosineReward):
    """Cosine shifted and scaled into ``[0, 1]``: ``0.5 · (cos(e_s[index]) + 1)``.

    1 at zero error, 0 at an error of ±π. The action is ignored.

    Pyrado name: ``SSCosOfOneEleRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ShiftedCosineReward
        >>> ShiftedCosineReward(index=0)(torch.zeros(1, 1), None)
        tensor([1.])
    """

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return 0.5 * (torch.cos(error_state[..., self.index]) + 1.0)
