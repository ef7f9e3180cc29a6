"""Which state entries a reward term reads: non-negative positions, given as ints or as labels of a Box."""

from __future__ import annotations

from collections.abc import Iterable

import torch

from torchtasks._checks import check_input, check_non_negative_int
from torchtasks.rewards.base import entries
from torchtasks.spaces import Box

__all__ = ["EntrySelection"]


class EntrySelection:
    """The state entries a reward term reads, resolved once at construction.

    ``indices`` are non-negative ints, or labels of ``space`` (then ints and labels may be mixed, as
    :meth:`~torchtasks.spaces.Box.indices` resolves them). Duplicates and an empty selection are a ``ValueError``.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box
        >>> selection = EntrySelection(["b", "a"], Box.unbounded(3, labels=["a", "b", "c"]), "indices")
        >>> selection.positions, selection.select(torch.tensor([[1.0, 2.0, 3.0]]))
        ([1, 0], tensor([[2., 1.]]))
    """

    def __init__(self, indices: Iterable[int | str] | int | str, space: Box | None, name: str) -> None:
        if space is not None and not isinstance(space, Box):
            raise TypeError(f"space must be a torchtasks.spaces.Box or None, got {type(space).__name__}")
        if isinstance(indices, (str, int)) or not isinstance(indices, Iterable):
            indices = [indices]  # type: ignore[list-item]
        indices = list(indices)
        if not indices:
            raise ValueError(f"{name} must name at least one state entry, got an empty selection")
        if space is not None:
            positions = space.indices(indices)
        else:
            if any(isinstance(index, str) for index in indices):
                raise TypeError(f"{name} names labels, {indices}: pass the space they label (space=...)")
            positions = [check_non_negative_int(index, f"{name}[{i}]") for i, index in enumerate(indices)]
            if len(set(positions)) != len(positions):
                raise ValueError(f"{name} must not contain duplicates, got {positions}")
        self.name = name
        self.positions: list[int] = positions
        self.index = torch.tensor(positions, dtype=torch.long)

    def size_problem(self, state_size: int, who: str) -> str | None:
        """Why states of ``state_size`` entries cannot be read (``None`` if they can)."""
        if max(self.positions) < state_size:
            return None
        return f"{who} reads state entries {self.name}={self.positions}, but the task's state has {entries(state_size)}"

    def check(self, state: object, name: str, owner: str) -> torch.Tensor:
        """Check that ``state`` is a floating ``[*B, n]`` tensor holding every selected entry; return it."""
        state = check_input(state, name)
        if max(self.positions) >= state.shape[-1]:
            raise ValueError(
                f"{owner}: {self.name}={self.positions} is out of range for {name} of shape {tuple(state.shape)}"
            )
        return state

    def select(self, state: torch.Tensor) -> torch.Tensor:
        """``state[..., positions]`` (``[*B, k]``)."""
        index = self.index if self.index.device == state.device else self.index.to(state.device)
        return state.index_select(-1, index)
