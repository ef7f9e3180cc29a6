"""The L2 kernel of selected state entries: :class:`SquaredSumReward`."""

from __future__ import annotations

from collections.abc import Iterable

import torch

from torchtasks.rewards._selection import EntrySelection
from torchtasks.rewards.base import RewardFunction, check_ignored_action, squared_sum
from torchtasks.spaces import Box

__all__ = ["SquaredSumReward"]


class SquaredSumReward(RewardFunction):
    """``Σ_i x_i²`` of selected state entries: a penalty's kernel, to be given a negative weight.

    IsaacLab's ``*_l2`` terms, read from named entries: ``lin_vel_z_l2`` (the base's vertical velocity),
    ``ang_vel_xy_l2`` (roll and pitch rates), ``joint_torques_l2`` (actuator forces), ``flat_orientation_l2`` (the
    x and y of the projected gravity). The value is non-negative, as IsaacLab's: give it a negative weight in a
    :class:`~torchtasks.rewards.CompoundReward` (``weights={"lin_vel_z": -2.0}``). Differentiable; ignores the
    action.

    Args:
        indices: the entries read (non-negative ints, or labels of ``space``).
        space: a :class:`~torchtasks.spaces.Box` whose labels name the entries in ``indices``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import SquaredSumReward
        >>> from torchtasks.spaces import Box
        >>> space = Box.unbounded(3, labels=["vz", "wx", "wy"])
        >>> SquaredSumReward(["wx", "wy"], space=space)(torch.tensor([[5.0, 1.0, -2.0]]), None)
        tensor([5.])
    """

    uses_action = False

    def __init__(self, indices: Iterable[int | str] | int | str, *, space: Box | None = None) -> None:
        super().__init__()
        self.selection = EntrySelection(indices, space, "indices")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return self.selection.size_problem(state_size, who)

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self.selection.check(error_state, "error_state", type(self).__name__)
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return squared_sum(self.selection.select(error_state))

    def extra_repr(self) -> str:
        return f"indices={self.selection.positions}"
