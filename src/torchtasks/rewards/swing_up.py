"""Shaped rewards for swing-up tasks (pendulum on a cart, Quanser cart-pole)."""

from __future__ import annotations

import math

import torch

from torchtasks._checks import check_finite_scalar, check_input, check_int, check_weight
from torchtasks.rewards.base import RewardFunction, check_ignored_action, entries, index_problem, squared_sum

__all__ = ["CartPoleSwingUpReward", "SwingUpReward"]


def _entry(error_state: torch.Tensor, index: int, name: str) -> torch.Tensor:
    size = error_state.shape[-1]
    if not -size <= index < size:
        raise ValueError(f"{name}={index} is out of range for error_state of shape {tuple(error_state.shape)}")
    return error_state[..., index]


class SwingUpReward(RewardFunction):
    """Shaped swing-up reward for under-actuated systems.

    ``10 - c_pole·(c_theta_sq·θ² + ln(θ² + c_theta_log)) - c_cart·|e_x| - c_act·Σ e_a²`` with
    ``θ = e_s[index_theta]`` and ``e_x = e_s[index_x]``. The logarithm makes the pole cost
    negative (a bonus) near θ = 0. For a multi-dimensional action the action cost sums the
    squares (Pyrado only supported a single action).

    Args:
        c_pole, c_cart, c_act: weights of the pole, cart and action costs.
        c_theta_sq, c_theta_log: shape of the pole cost.
        index_x, index_theta: positions of the cart position and pole angle in the state error.

    Pyrado name: ``UnderActuatedSwingUpRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import SwingUpReward
        >>> reward = SwingUpReward()
        >>> reward(torch.zeros(1, 4), torch.zeros(1, 1))
        tensor([12.3026])
    """

    def __init__(
        self,
        c_pole: float = 1.0,
        c_cart: float = 0.2,
        c_act: float = 1e-3,
        c_theta_sq: float = 1.0,
        c_theta_log: float = 0.1,
        index_x: int = 0,
        index_theta: int = 1,
    ) -> None:
        super().__init__()
        for name, value in (
            ("c_pole", c_pole),
            ("c_cart", c_cart),
            ("c_act", c_act),
            ("c_theta_sq", c_theta_sq),
        ):
            self._register_scalar(name, value, check=check_weight)
        c_theta_log = check_finite_scalar(c_theta_log, "c_theta_log")
        if c_theta_log <= 0:
            raise ValueError(f"c_theta_log must be positive (it keeps the logarithm finite), got {c_theta_log}")
        self._register_scalar("c_theta_log", c_theta_log)
        self.index_x = check_int(index_x, "index_x")
        self.index_theta = check_int(index_theta, "index_theta")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return index_problem(who, "index_x", self.index_x, state_size) or index_problem(
            who, "index_theta", self.index_theta, state_size
        )

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        self._check_inputs(error_state, error_action)
        _entry(error_state, self.index_theta, "index_theta")
        _entry(error_state, self.index_x, "index_x")
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        theta_sq = error_state[..., self.index_theta] ** 2
        pole_cost = self.c_theta_sq * theta_sq + torch.log(theta_sq + self.c_theta_log)
        cart_cost = error_state[..., self.index_x].abs()
        action_cost = squared_sum(error_action)
        return 10.0 - (self.c_pole * pole_cost + self.c_cart * cart_cost + self.c_act * action_cost)


class CartPoleSwingUpReward(RewardFunction):
    """Reward of the Quanser cart-pole swing-up: ``f·(1 - (|e_s[1]|/π)²) + (1 - f)·|e_s[0]|``.

    Kept exactly as in Pyrado, including its quirk: the cart term *grows* with the cart position
    error, so the value is only "roughly in [0, 1]" near the track centre. The action is ignored.

    Args:
        factor: weight ``f`` of the pole term, in ``[0, 1]``.

    Pyrado name: ``QCartPoleSwingUpRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import CartPoleSwingUpReward
        >>> CartPoleSwingUpReward(factor=0.9)(torch.zeros(1, 4), None)
        tensor([0.9000])
    """

    uses_action = False

    def __init__(self, factor: float = 0.9) -> None:
        super().__init__()
        factor = check_finite_scalar(factor, "factor")
        if not 0.0 <= factor <= 1.0:
            raise ValueError(f"factor must lie in [0, 1], got {factor}")
        self._register_scalar("factor", factor)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        if state_size >= 2:
            return None
        return f"{who} reads state entries 0 and 1 (x, θ), but the task's state has {entries(state_size)}"

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        check_input(error_state, "error_state")
        if error_state.shape[-1] < 2:
            raise ValueError(f"error_state must have at least 2 entries (x, θ), got {tuple(error_state.shape)}")
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        pole = 1.0 - (error_state[..., 1].abs() / math.pi) ** 2
        cart = error_state[..., 0].abs()
        return self.factor * pole + (1.0 - self.factor) * cart
