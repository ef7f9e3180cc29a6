"""The exponential tracking kernel of velocity commands: :class:`ExpTrackingReward`."""

from __future__ import annotations

from collections.abc import Iterable

import torch

from torchtasks._checks import cast_like, check_finite_scalar
from torchtasks.rewards._selection import EntrySelection
from torchtasks.rewards.base import RewardFunction, check_ignored_action, squared_sum
from torchtasks.spaces import Box

__all__ = ["ExpTrackingReward"]


class ExpTrackingReward(RewardFunction):
    """``exp(-Σ_i e_i² / std²)`` of selected entries ``e`` (tracking errors): 1 on the command, falling with the error.

    IsaacLab's and mjlab's ``track_lin_vel_xy_exp`` and ``track_ang_vel_z_exp`` (``std = sqrt(0.25)`` in
    IsaacLab's velocity task): the entries are the errors ``command - measured`` of the tracked velocities, e.g. the
    ``error_*`` entries a :class:`~torchtasks.tasks.CommandTrackingTask` gives its reward. Differentiable; ignores
    the action. ``std`` is a registered buffer (a Curriculum can narrow it).

    Args:
        std: the kernel's width, positive and finite (the error at which the reward is ``exp(-1)``).
        indices: the entries read (non-negative ints, or labels of ``space``).
        space: a :class:`~torchtasks.spaces.Box` whose labels name the entries in ``indices``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ExpTrackingReward
        >>> reward = ExpTrackingReward(std=0.5, indices=[1, 2])
        >>> reward(torch.tensor([[9.0, 0.0, 0.0], [9.0, 0.3, 0.4]]), None)  # exp(-0.25 / 0.25)
        tensor([1.0000, 0.3679])
    """

    uses_action = False

    def __init__(self, std: float, indices: Iterable[int | str] | int | str, *, space: Box | None = None) -> None:
        super().__init__()
        self._register_scalar("std", std, check=_check_std)
        self.selection = EntrySelection(indices, space, "indices")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return self.selection.size_problem(state_size, who)

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self.selection.check(error_state, "error_state", type(self).__name__)
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        std = cast_like(self.std, error_state)
        return torch.exp(-squared_sum(self.selection.select(error_state)) / (std * std))

    def extra_repr(self) -> str:
        return f"std={float(self.std)}, indices={self.selection.positions}"


def _check_std(value: object, name: str) -> float:
    std = check_finite_scalar(value, name)
    if std <= 0:
        raise ValueError(f"{name} must be positive, got {std}")
    return std
