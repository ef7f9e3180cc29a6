"""Multiplicative composition of rewards: :class:`ProductReward` of named factors, and :class:`AffineReward`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDict

from torchtasks._checks import check_finite_scalar
from torchtasks.rewards.base import RewardFunction
from torchtasks.rewards.compound import CompoundReward

__all__ = ["AffineReward", "ProductReward", "hamacher_product"]


def hamacher_product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Meta-World's Hamacher product of two values in ``[0, 1]``: ``ab / (a + b − ab)``, 0 where both are 0.

    A t-norm that is 1 only when both are 1 and, unlike the plain product, rewards raising the smaller
    factor more. The zero case is a ``where`` on a safe denominator, so gradients stay finite.

    Example:
        >>> import torch
        >>> hamacher_product(torch.tensor([1.0, 0.5, 0.0]), torch.tensor([1.0, 0.5, 0.0]))
        tensor([1.0000, 0.3333, 0.0000])
    """
    product = a * b
    denominator = a + b - product
    positive = denominator > 0
    safe = torch.where(positive, denominator, torch.ones_like(denominator))
    return torch.where(positive, product / safe, torch.zeros_like(product))


class ProductReward(CompoundReward):
    """Product of named reward factors, ``Π_k factor_k(e_s, e_a)``, with the per-factor values available.

    dm_control composes its rewards this way (walker: ``stand · (5·move + 1)/6``): every factor must
    be high for the product to be high. With ``hamacher=True`` the factors are combined with
    Meta-World's Hamacher product (:func:`hamacher_product`, folded left to right), meant for factors
    in ``[0, 1]``. Any factor may be an affine map of a reward (:class:`AffineReward`).

    The factors appear in the reward breakdown by name, like the terms of a
    :class:`CompoundReward`, but they are **factors, not summands**: the step reward is their product,
    not their sum. Factors may be stateful (their memory is kept under their name).

    Args:
        rewards: a mapping ``name -> reward function`` or a sequence (named ``term0``, ``term1``, ...).
        hamacher: combine with the Hamacher product instead of the plain product.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import AffineReward, ProductReward, ToleranceReward
        >>> upright = ToleranceReward(bounds=(1.0, float("inf")), margin=1.0, indices=[0])
        >>> speed = ToleranceReward(bounds=(1.0, float("inf")), margin=1.0, sigmoid="linear",
        ...                         value_at_margin=0.0, indices=[1])
        >>> reward = ProductReward({"upright": upright, "move": AffineReward(speed, scale=5 / 6, offset=1 / 6)})
        >>> state = torch.tensor([[1.2, 1.5], [1.2, 0.0], [0.0, 1.5]])
        >>> reward(state, None)
        tensor([1.0000, 0.1667, 0.1000])
        >>> reward.terms(state, None)["move"]
        tensor([1.0000, 0.1667, 1.0000])
    """

    def __init__(
        self, rewards: Mapping[str, RewardFunction] | Sequence[RewardFunction], *, hamacher: bool = False
    ) -> None:
        super().__init__(rewards)
        if not isinstance(hamacher, bool):
            raise TypeError(f"hamacher must be a bool, got {hamacher!r}")
        self.hamacher = hamacher

    def combine_terms(self, values: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The product (or Hamacher product) of the factors, left to right."""
        iterator = iter(values.values())
        total = next(iterator)
        for value in iterator:
            total = hamacher_product(total, value) if self.hamacher else total * value
        return total

    def extra_repr(self) -> str:
        return "hamacher=True" if self.hamacher else ""


class AffineReward(RewardFunction):
    """An affine map of a reward: ``scale · reward(e_s, e_a) + offset``.

    Turns a reward into a factor of a :class:`ProductReward` (dm_control's ``(5·move + 1)/6`` is
    ``AffineReward(move, scale=5/6, offset=1/6)``) or re-weights a term of a sum. A stateful reward
    keeps its memory.

    Args:
        reward: the reward to map.
        scale, offset: finite numbers.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import AffineReward, ConstantReward
        >>> AffineReward(ConstantReward(0.5), scale=4.0, offset=-1.0)(torch.zeros(2, 1), None)
        tensor([1., 1.])
    """

    def __init__(self, reward: RewardFunction, scale: float = 1.0, offset: float = 0.0) -> None:
        super().__init__()
        if not isinstance(reward, RewardFunction):
            raise TypeError(f"reward must be a RewardFunction, got {type(reward).__name__}")
        self.reward = reward
        self.scale = check_finite_scalar(scale, "scale")
        self.offset = check_finite_scalar(offset, "offset")
        self.stateful = reward.stateful
        self.can_fail = reward.can_fail
        self.uses_action = reward.uses_action

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return self.reward._size_problem(state_size, action_size, f"{who} ({type(self.reward).__name__})")

    def _map(self, value: torch.Tensor) -> torch.Tensor:
        return value * self.scale + self.offset

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        return self._map(self.reward(error_state, error_action))

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return self._map(self.reward._value(error_state, error_action))

    def reset(self, init_state: torch.Tensor) -> TensorDict:
        return self.reward.reset(init_state)

    def step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        value, memory = self.reward.step(state, action, memory)
        return self._map(value), memory

    def _step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        value, memory = self.reward._step(state, action, memory)
        return self._map(value), memory

    def has_failed(self, state: torch.Tensor) -> torch.Tensor:
        return self.reward.has_failed(state)

    def extra_repr(self) -> str:
        return f"scale={self.scale}, offset={self.offset}"
