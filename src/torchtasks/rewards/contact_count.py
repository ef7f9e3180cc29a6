"""The number of selected entries above a threshold (undesired contacts): :class:`ContactCountReward`."""

from __future__ import annotations

from collections.abc import Iterable

import torch

from torchtasks._checks import cast_like, check_finite_scalar
from torchtasks.rewards._selection import EntrySelection
from torchtasks.rewards.base import RewardFunction, check_ignored_action, row_sum
from torchtasks.spaces import Box

__all__ = ["ContactCountReward"]


class ContactCountReward(RewardFunction):
    """``Σ_i [f_i > threshold]``: how many of the selected entries (contact forces) exceed ``threshold``.

    IsaacLab's ``undesired_contacts`` (a body touching where it should not, e.g. a thigh on the ground, counted
    when its contact force exceeds 1 N), read from entries that hold one force magnitude (or touch sensor value)
    per body. Non-negative: give it a negative weight in a :class:`~torchtasks.rewards.CompoundReward`. Piecewise
    constant: built from a comparison, it carries no autograd graph; a NaN entry counts 0. Ignores the action.

    Args:
        threshold: the finite force above which an entry counts (strictly above).
        indices: the entries read (non-negative ints, or labels of ``space``).
        space: a :class:`~torchtasks.spaces.Box` whose labels name the entries in ``indices``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ContactCountReward
        >>> ContactCountReward(1.0, indices=[0, 1, 2])(torch.tensor([[0.0, 1.0, 5.0], [3.0, 2.0, 5.0]]), None)
        tensor([1., 3.])
    """

    uses_action = False

    def __init__(self, threshold: float, indices: Iterable[int | str] | int | str, *, space: Box | None = None) -> None:
        super().__init__()
        self._register_scalar("threshold", check_finite_scalar(threshold, "threshold"))
        self.selection = EntrySelection(indices, space, "indices")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return self.selection.size_problem(state_size, who)

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self.selection.check(error_state, "error_state", type(self).__name__)
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        forces = self.selection.select(error_state)
        above = (forces > cast_like(self.threshold, forces)).to(forces.dtype)
        return row_sum(above)

    def extra_repr(self) -> str:
        return f"threshold={float(self.threshold)}, indices={self.selection.positions}"
