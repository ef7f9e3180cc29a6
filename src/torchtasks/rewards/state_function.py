"""A reward computed by a user function of the state (objectives, costs)."""

from __future__ import annotations

from collections.abc import Callable

import torch

from torchtasks._checks import SUPPORTED_FLOATS, check_input
from torchtasks.rewards.base import RewardFunction, check_ignored_action

__all__ = ["StateFunctionReward"]


class StateFunctionReward(RewardFunction):
    """Reward from a function of the state: ``-fn(state)`` (``negate=True``) or ``fn(state)``.

    ``fn`` maps ``[*B, n]`` to a floating ``[*B]`` with tensor operations (so the reward stays batched,
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
        check_ignored_action(state, error_action, "state")
        return self._value(state, error_action)

    def _value(self, state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        value = self.fn(state)
        # dtype and shape only (no values): cheap for every step, so a bad function fails at its first call
        if not isinstance(value, torch.Tensor) or value.dtype not in SUPPORTED_FLOATS:
            got = (
                f"a {value.dtype} tensor"
                if isinstance(value, torch.Tensor)
                else f"{value!r} of type {type(value).__name__}"
            )
            raise TypeError(
                f"fn must return a floating (float32 or float64) tensor of shape [*B] = {tuple(state.shape[:-1])} "
                f"(one value per row), got {got}"
            )
        if value.shape != state.shape[:-1]:
            raise ValueError(
                f"fn must return a floating tensor of shape [*B] = {tuple(state.shape[:-1])} (one value per row), "
                f"got shape {tuple(value.shape)}"
            )
        return -value if self.negate else value

    def extra_repr(self) -> str:
        return f"fn={getattr(self.fn, '__name__', self.fn)!s}, negate={self.negate}"
