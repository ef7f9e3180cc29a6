"""A reward computed by a user function of the state (objectives, costs)."""

from __future__ import annotations

from collections.abc import Callable

import torch

from torchtasks._checks import check_input
from torchtasks.rewards.base import RewardFunction

__all__ = ["StateFunctionReward"]


class StateFunctionReward(RewardFunction):
    """Reward from a function of the state: ``-fn(state)`` (``negate=True``) or ``fn(state)``.

    ``fn`` maps ``[*B, n]`` to ``[*B]`` with tensor operations (so the reward stays batched,
    differentiable and compilable). The action is ignored: call ``reward(state, None)``.

    Args:
        fn: the function of the state, e.g. a cost to minimise.
        negate: return ``-fn(state)`` (Pyrado's behaviour, for costs) or ``fn(state)``.

    Pyrado name: ``StateBasedRewFcn`` (whose ``flip_sign`` had no effect; it always negated).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import StateFunctionReward
        >>> reward = StateFunctionReward(lambda s: (s**2).sum(-1))
        >>> reward(torch.tensor([[1.0, 2.0]]), None)
        tensor([-5.])
    """

    uses_action = False

    def __init__(self, fn: Callable[[torch.Tensor], torch.Tensor], negate: bool = True) -> None:
        super().__init__()
        if not callable(fn):
            raise TypeError(f"fn must be callable, got {type(fn).__name__}")
        if not isinstance(negate, bool):
            raise TypeError(f"negate must be a bool, got {negate!r}")
        self.fn = fn
        self.negate = negate

    def forward(self, state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        check_input(state, "state")
        value = self.fn(state)
        if not isinstance(value, torch.Tensor) or value.shape != state.shape[:-1]:
            shape = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
            raise ValueError(
                f"fn must return a tensor of shape {tuple(state.shape[:-1])} (one value per row), got {shape}"
            )
        return -value if self.negate else value

    def extra_repr(self) -> str:
        return f"fn={getattr(self.fn, '__name__', self.fn)!s}, negate={self.negate}"
